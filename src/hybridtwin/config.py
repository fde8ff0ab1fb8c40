"""Reading the workflow configuration (config/config.yaml) into package objects."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import pandas as pd
from threadpoolctl import threadpool_limits

from .effects import Effect
from .scenarios import default_n_scenarios
from .variants import Variant, load_effects_files

CONFIG_DIR = Path("config")


def user_effects(config: Mapping, config_dir: Path = CONFIG_DIR) -> dict[str, Effect]:
    """Effects from the config's ``effects_files`` (paths relative to the config folder)."""
    return load_effects_files([config_dir / path for path in config.get("effects_files") or []])


def variant(config: Mapping, name: str, config_dir: Path = CONFIG_DIR) -> Variant:
    """The variant ``name`` declared under ``variants:``."""
    if name not in config["variants"]:
        raise KeyError(f"variant {name!r} is not declared in the config (declared: {sorted(config['variants'])})")
    return Variant.from_spec(name, config["variants"][name], user_effects(config, config_dir))


def offline(config: Mapping) -> dict:
    """The ``offline:`` options with their defaults filled in."""
    defaults = {"seed": 1, "speed": "measured", "n_scenarios": {}, "n_test": 200, "validation_fraction": 0.2,
                "chunks": 4, "scope": "run", "pieces": "mode_scaling",
                "sensor_range_mm": 14.0, "pod_energy_tolerance": 1e-10,
                "spgd": {"degree": [8, 12], "max_terms": 60, "ridge": 1e-8, "patience": 8, "backfit_iterations": 3,
                         "tolerance": 0.0},
                "enrichment": {"observable_below": 0.3, "n_scenarios": 6000, "chunks": 2}, "spgd_variants": {}}
    options = {**defaults, **(config.get("offline") or {})}
    for nested in ("spgd", "enrichment"):
        options[nested] = {**defaults[nested], **(options.get(nested) or {})}
    options["spgd_variants"] = dict(options.get("spgd_variants") or {})
    unknown = sorted(set(options["spgd_variants"]) - set(config.get("variants") or {}))
    if unknown:
        raise ValueError(f"config offline.spgd_variants: no variant named {unknown} "
                         f"(declared: {sorted(config.get('variants') or {})})")
    return options


def offline_for(config: Mapping, name: str, keys: Sequence[str] | None = None) -> dict:
    """The ``offline:`` options as variant ``name``'s rules see them: its own n_s and sPGD options
    (``spgd`` updated by its ``spgd_variants`` entry) only, so that declaring another variant (and its
    n_s or sPGD options) never changes this one's rule parameters (nothing of it reruns); with
    ``keys``, only those options, so that a rule reruns only when an option it uses changes (the sPGD
    options or the library scope never re-sample or re-solve the scenarios)."""
    options = offline(config)
    options["n_scenarios"] = n_scenarios(config, variant(config, name))
    options["spgd"] = _variant_spgd(options, name)
    del options["spgd_variants"]
    return options if keys is None else {k: options[k] for k in keys}


def spgd_for(config: Mapping, name: str) -> dict:
    """The sPGD options of variant ``name`` (declared or not): ``offline.spgd`` updated by its
    ``offline.spgd_variants`` entry."""
    return _variant_spgd(offline(config), name)


def _variant_spgd(options: Mapping, name: str) -> dict:
    return {**options["spgd"], **options["spgd_variants"].get(name, {})}


def n_scenarios(config: Mapping, variant_: Variant) -> int:
    """n_s of a variant: the config's per-variant value or the paper's default for its unknown count."""
    return int(offline(config)["n_scenarios"].get(variant_.name, default_n_scenarios(len(variant_.unknown))))


def run_plan(config: Mapping, measured: str | Path | None = None) -> pd.DataFrame:
    """The runs the libraries are built for: run, rpm, eccentric_mass_g, role (from the runs sheet).

    With ``measured`` (the preprocessed table, results/data/harmonics.tsv) each run's
    rpm is the true speed refined from its record (rpm_true) instead of the nominal one.
    """
    sheet = pd.read_csv(config["runs"], sep="\t", dtype={"run": str})
    if measured is not None:
        speeds = pd.read_csv(measured, sep="\t", dtype={"run": str}).set_index("run")["rpm_true"]
        missing = sorted(set(sheet["run"]) - set(speeds.index))
        if missing:
            raise ValueError(f"{measured} has no refined speed for run(s) {missing}")
        sheet["rpm"] = sheet["run"].map(speeds).to_numpy(float)
    unknown_mass = sheet.loc[sheet["eccentric_mass_g"].isna(), "run"].tolist()
    if unknown_mass:
        raise ValueError(f"{config['runs']}: run(s) {unknown_mass} have no eccentric_mass_g; the offline "
                         "libraries are built per (rpm, eccentric mass) and need it")
    return sheet[["run", "rpm", "eccentric_mass_g"] + (["role"] if "role" in sheet else [])]


def rule_logger(log_path: str, name: str) -> logging.Logger:
    """A logger writing to the rule's log file; BLAS pinned to one thread (jobs run in parallel)."""
    threadpool_limits(1)
    logging.basicConfig(filename=log_path, level=logging.INFO, force=True,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return logging.getLogger(name)
