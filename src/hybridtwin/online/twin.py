"""A built twin's folder, read only, and the prior it gives a new record (docs/online.md).

A twin is what the workflow leaves in ``results/{variant}/``. What the online assessment reads of it (``FILES``):

- ``twin.yaml``, the twin's card (rule ``twin_card``, ``make_card``/``write_card``, read back by ``read_card``):
  the variant as configured (its effects, unknowns and ranges, the machine and the effects files: the config's
  own form, so that ``hybridtwin.config.variant`` builds it), the harmonics, whether keyphasor phases were used,
  the diagnosis candidates, the sensor range, the fit runs (true speed, eccentric mass) and the joint fit's
  chi^2/dof. Effects files are named as in the config, relative to the project's ``config/`` folder (the project:
  the folder holding ``results/``);
- ``parameters.tsv``, the joint fit (``Identification.table``): the estimates and their standard errors;
- ``identification/correlation.tsv``: the joint fit's correlation of every entry;
- its sPGD library, when it was built with one (``offline.scope`` run or global; the card's ``library``,
  ``library_card``): ``library/{run}.zarr`` per run of the runs sheet (scope run) or ``library_global.zarr`` over
  the unknowns, rpm and eccentric mass (scope global), with each run's test errors against the full solver from
  ``library_validation.tsv``. A record's first verdict comes from it (``library_route``).

The prior (``Twin.prior``): the twin's estimates as a Gaussian over what a new record's fit estimates. Shared
parameters at their joint estimates with their joint covariance; a per-run parameter (the bow q_x, q_y on the VARM)
at its law over the fit runs (``identify.validation.bow_law``: q = c0 + c1 Omega^2 + c2 Omega^2 m_e) at the
record's speed and mass, with the law's uncertainty carried from the twin's covariance (the law is linear in the
runs' estimates, ``law_operator``) plus the runs' scatter about it beyond their own errors. A shared parameter the
twin left undetermined (at a range edge, not identifiable, no finite standard error) has no prior: the record's fit
estimates it alone, from the twin's value. The twin knows nothing of it to compare with, and held at a value the
twin could not determine it would push the parameters it compensates for into false "moves" (measured: a run-up of
the unchanged machine named a 1 % k_b move against a twin that held zeta_bup at its range edge).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from .. import config as cfg
from .. import tables
from ..identify.identification import TABLE_COLUMNS, read_parameters
from ..identify.validation import law_operator, law_terms
from ..model.candidates import Candidate, candidates_for
from ..model.variants import Variant

Array = np.ndarray

#: the card's format; a card of another format is refused with the command that rebuilds it
FORMAT = 1
#: what the assessment reads of a twin's folder
FILES = {"card": "twin.yaml", "parameters": "parameters.tsv", "correlation": "identification/correlation.tsv"}


class TwinError(ValueError):
    """A twin folder that cannot be assessed against: one line naming the file and the problem."""


#: the library's files in the twin's folder (``library_card``)
LIBRARY_FILES = {"run": "library/{run}.zarr", "global": "library_global.zarr", "validation": "library_validation.tsv"}
#: the library errors the card keeps of library_validation.tsv, per run and over all runs [%]
LIBRARY_ERRORS = ["median_error_pct", "p95_error_pct", "max_error_pct"]


def library_card(scope: str, validation: pd.DataFrame | None) -> dict | None:
    """The card's ``library`` entry: which library the twin has (None: none, ``offline.scope: none``), from its
    validation table (``offline.library.read_library_validation``): the scope, the files (``LIBRARY_FILES``), and
    per run of the sheet its speed as solved, eccentric mass and test errors, and the errors over all runs."""
    if scope == "none" or validation is None:
        return None
    if scope not in ("run", "global"):
        raise ValueError(f"offline.scope {scope!r}: run, global or none")
    runs = validation[validation["run"] != "all runs"]
    pooled = validation[validation["run"] == "all runs"]
    return {"scope": scope, "validation": LIBRARY_FILES["validation"],
            "file": LIBRARY_FILES["global"] if scope == "global" else LIBRARY_FILES["run"],
            "runs": [{"run": str(r["run"]), "rpm": float(r["rpm"]), "eccentric_mass_g": float(r["eccentric_mass_g"]),
                      **{c: float(r[c]) for c in LIBRARY_ERRORS}} for r in runs.to_dict("records")],
            "all_runs": {c: float(pooled[c].iloc[0]) if len(pooled) else math.nan for c in LIBRARY_ERRORS}}


def make_card(variant: str, model: Mapping, harmonics: int, keyphasor: bool, candidates: Sequence[str] | None,
              sensor_range_mm: float, runs: pd.DataFrame, fit: Mapping, library: Mapping | None = None) -> dict:
    """The card's mapping (``write_card`` writes it, ``read_card`` reads it back): ``model`` as the workflow's jobs
    receive it (``variants: {variant: spec}``, ``machine``, ``effects_files``), ``runs`` the fit runs (run, rpm,
    eccentric_mass_g), ``fit`` the joint fit's summary (chi2_dof, dof), ``library`` the twin's sPGD library
    (``library_card``; None: none)."""
    return {
        "format": FORMAT, "package": _version(), "variant": str(variant),
        "model": {"variants": {variant: _plain(model["variants"][variant])}, "machine": _plain(model.get("machine")),
                  "effects_files": [str(f) for f in model.get("effects_files") or []]},
        "harmonics": int(harmonics), "keyphasor": bool(keyphasor),
        "candidates": None if candidates is None else [str(c) for c in candidates],
        "sensor_range_mm": float(sensor_range_mm),
        "runs": [{"run": str(r.run), "rpm": float(r.rpm), "eccentric_mass_g": float(r.eccentric_mass_g)}
                 for r in runs.itertuples()],
        "fit": {"chi2_dof": float(fit["chi2_dof"]), "dof": int(fit["dof"])},
        "library": None if library is None else _plain(dict(library)),
    }


def write_card(card: Mapping, path: str | Path) -> None:
    with open(path, "w") as stream:
        yaml.safe_dump(dict(card), stream, sort_keys=False)


def read_card(path: str | Path) -> dict:
    """The card written by ``write_card`` (the same mapping), or a ``TwinError`` naming the file."""
    path = Path(path)
    try:
        card = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise TwinError(f"{path}: cannot be read: {' '.join(str(err).split())}") from None
    if not isinstance(card, Mapping) or "format" not in card:
        raise TwinError(f"{path}: not a twin card (no 'format' key)")
    if card["format"] != FORMAT:
        raise TwinError(f"{path}: a twin card of format {card['format']!r}, this hybridtwin reads format {FORMAT}: "
                        f"rebuild it (`snakemake --cores 2 {path}` in its project)")
    missing = sorted({"variant", "model", "harmonics", "keyphasor", "candidates", "sensor_range_mm", "runs", "fit"}
                     - set(card))
    if missing:
        raise TwinError(f"{path}: the card lacks {', '.join(missing)}: rebuild it (`snakemake --cores 2 {path}`)")
    return dict(card)


@dataclass(frozen=True)
class Prior:
    """The twin as a Gaussian prior over a record's fitted parameters [SI].

    ``names``: (parameter, None) for a shared parameter, (parameter, k) for a per-run one at the record's run k;
    ``mean`` (n,), ``covariance`` (n, n) over them; ``undetermined``: the shared parameters without a prior, each
    with the twin's value (a start) and why the twin left it undetermined."""

    names: tuple[tuple[str, int | None], ...]
    mean: Array
    covariance: Array
    undetermined: dict[str, tuple[float, str]]

    def index(self, name: str, run: int | None = None) -> int:
        return self.names.index((name, run))


@dataclass
class Twin:
    """A built twin (module docstring): its folder, card, variant and joint fit."""

    folder: Path
    card: dict
    variant: Variant
    parameters: pd.DataFrame
    correlation: pd.DataFrame

    @property
    def name(self) -> str:
        return str(self.card["variant"])

    @property
    def library(self) -> dict | None:
        """The twin's sPGD library as its card says (``library_card``), None when it has none (or its card predates
        the entry)."""
        return self.card.get("library") or None

    def library_line(self) -> str:
        """Which library the twin has, in words."""
        library = self.library
        if library is None:
            return "no library (offline.scope: none): every verdict on the full solver"
        if library["scope"] == "global":
            return (f"one global library ({library['file']}) over the unknowns, rpm and eccentric mass; test error "
                    f"median {library['all_runs']['median_error_pct']:.3g} %, max "
                    f"{library['all_runs']['max_error_pct']:.3g} %")
        return (f"a library per run ({library['file']}, {len(library['runs'])} runs); test error median "
                f"{library['all_runs']['median_error_pct']:.3g} %, max {library['all_runs']['max_error_pct']:.3g} %")

    @property
    def harmonics(self) -> int:
        return int(self.card["harmonics"])

    @property
    def runs(self) -> pd.DataFrame:
        """The fit runs: run, rpm (true speed), eccentric_mass_g."""
        return pd.DataFrame(self.card["runs"], columns=["run", "rpm", "eccentric_mass_g"])

    @property
    def rpm_range(self) -> tuple[float, float]:
        """The speeds the twin was fitted at [RPM]: a record outside them is beyond what it knows."""
        rpm = self.runs["rpm"].to_numpy(float)
        return float(rpm.min()), float(rpm.max())

    @property
    def shared(self) -> list[str]:
        rows = self.parameters
        return list(dict.fromkeys(rows.loc[(rows["run"] == "all") & (rows["kind"] != "nuisance"), "parameter"]))

    @property
    def local(self) -> list[str]:
        """The per-run parameters (the bow on the VARM), re-estimated for every run of a record."""
        rows = self.parameters
        return [p for p in self.variant.unknown if p in set(rows.loc[rows["kind"] == "per_run", "parameter"])]

    def estimate(self, name: str) -> tuple[float, float]:
        """A shared parameter's joint estimate and standard error [SI]."""
        row = self.parameters[(self.parameters["parameter"] == name) & (self.parameters["run"] == "all")].iloc[0]
        return float(row["value"]), float(row["stderr"])

    def undetermined(self) -> dict[str, str]:
        """The shared parameters the joint fit left undetermined, each with why."""
        out = {}
        for row in self.parameters[(self.parameters["run"] == "all")].itertuples():
            why = [text for bad, text in ((bool(row.at_bound), "at a range edge"),
                                          (not bool(row.identifiable), "not identifiable"),
                                          (not (math.isfinite(row.stderr) and row.stderr > 0),
                                           "no finite standard error")) if bad]
            if why:
                out[row.parameter] = ", ".join(why)
        return out

    def covariance(self) -> tuple[list[tuple[str, str]], Array, Array]:
        """The joint fit's entries (parameter, run) without the phases, their values and covariance [SI]
        (standard errors times correlations; 0 where the fit gave none: an undetermined entry)."""
        rows = self.parameters[self.parameters["kind"] != "nuisance"]
        entries = list(zip(rows["parameter"], rows["run"]))
        labels = [p if r == "all" else f"{p}[{r}]" for p, r in entries]
        correlation = self.correlation.loc[labels, labels].to_numpy(float)
        stderr = rows["stderr"].to_numpy(float)
        covariance = np.nan_to_num(stderr[:, None] * correlation * stderr[None, :])
        return entries, rows["value"].to_numpy(float), covariance

    def prior(self, points: Sequence[tuple[float, float]]) -> Prior:
        """The prior of a record whose runs are at ``points`` (rpm, eccentric_mass_g) (module docstring)."""
        entries, values, covariance = self.covariance()
        undetermined = {p: (self.estimate(p)[0], why) for p, why in self.undetermined().items()}
        names: list[tuple[str, int | None]] = [(p, None) for p in self.shared if p not in undetermined]
        rows = [self._selector(entries, p) for p, _ in names]
        scatter = [0.0] * len(rows)
        runs = self.runs.set_index("run")
        for p in self.local:
            mine = [i for i, (q, r) in enumerate(entries) if q == p and r != "all"
                    and math.isfinite(self._stderr(q, r))]
            table = pd.DataFrame({"value": values[mine], "stderr": [self._stderr(p, entries[i][1]) for i in mine],
                                  "rpm": [runs.loc[entries[i][1], "rpm"] for i in mine],
                                  "eccentric_mass_g": [runs.loc[entries[i][1], "eccentric_mass_g"] for i in mine]})
            operator = law_operator(table)  # (3, n): the runs' values -> the law's coefficients
            fitted = law_terms(table["rpm"], table["eccentric_mass_g"]) @ operator @ table["value"].to_numpy(float)
            used = int(np.count_nonzero(np.abs(operator).sum(1)))
            excess = float(np.sum((table["value"] - fitted) ** 2)) / max(len(mine) - used, 1)
            tau2 = max(0.0, excess - float(np.mean(table["stderr"] ** 2)))  # scatter beyond the runs' own errors
            for k, (rpm, mass) in enumerate(points):
                row = np.zeros(len(entries))
                row[mine] = law_terms(rpm, mass) @ operator
                names.append((p, k))
                rows.append(row)
                scatter.append(tau2)
        G = np.array(rows).reshape(len(rows), len(entries))
        return Prior(tuple(names), G @ values, G @ covariance @ G.T + np.diag(scatter), undetermined)

    def candidates(self) -> list[Candidate]:
        """The diagnosis's candidates for this twin (its card's ``candidates``, as the workflow's diagnosis)."""
        model = self.card["model"]
        names = cfg.candidate_names(self.card["candidates"], model)
        present = [e.name for e in self.variant.model.effects]
        return candidates_for(present, names, cfg.candidate_effects(model, self.config_dir))

    @property
    def config_dir(self) -> Path:
        """The project's config folder, where the card's effects files are (the folder holding results/)."""
        return self.folder.resolve().parent.parent / cfg.CONFIG_DIR

    def _stderr(self, parameter: str, run: str) -> float:
        rows = self.parameters
        return float(rows.loc[(rows["parameter"] == parameter) & (rows["run"] == run), "stderr"].iloc[0])

    @staticmethod
    def _selector(entries: list[tuple[str, str]], parameter: str) -> Array:
        row = np.zeros(len(entries))
        row[entries.index((parameter, "all"))] = 1.0
        return row


def load_twin(folder: str | Path) -> Twin:
    """The twin in ``folder`` (results/{variant}), every file checked: a ``TwinError`` names the first missing or
    unreadable one, or the disagreement between them. Nothing in the folder is written."""
    folder = Path(folder)
    if not folder.is_dir():
        raise TwinError(f"{folder}: no such twin folder (expected results/<variant> of a built project)")
    paths = {key: folder / name for key, name in FILES.items()}
    if not paths["card"].is_file():
        raise TwinError(f"{paths['card']}: missing: the twin was built by a hybridtwin older than `assess`, or not "
                        f"completely; in its project run `snakemake --cores 2 {paths['card']}`")
    card = read_card(paths["card"])
    for key in ("parameters", "correlation"):
        if not paths[key].is_file():
            raise TwinError(f"{paths[key]}: missing: the twin is incomplete (its joint fit, rule identify_joint); "
                            f"in its project run `snakemake --cores 2 {paths[key]}`")
    try:
        parameters = read_parameters(paths["parameters"])
        correlation = tables.CORRELATION.read(paths["correlation"])
    except (OSError, ValueError, pd.errors.ParserError) as err:
        raise TwinError(f"{folder}: cannot read its fit: {' '.join(str(err).split())}") from None
    missing = [c for c in TABLE_COLUMNS if c not in parameters]
    if missing:
        raise TwinError(f"{paths['parameters']}: not a joint fit's parameter table (no column(s) {missing})")
    try:
        variant = cfg.variant(card["model"], card["variant"], folder.resolve().parent.parent / cfg.CONFIG_DIR)
    except (ValueError, KeyError, OSError) as err:
        raise TwinError(f"{paths['card']}: its variant cannot be built: {' '.join(str(err).split())}") from None
    fitted = set(parameters.loc[parameters["kind"] != "nuisance", "parameter"])
    if fitted != set(variant.unknown):
        raise TwinError(f"{paths['parameters']}: its parameters {sorted(fitted)} are not the card's variant's unknowns "
                        f"{sorted(variant.unknown)}: the files come from different builds")
    labels = [p if r == "all" else f"{p}[{r}]" for p, r in zip(parameters["parameter"], parameters["run"])]
    if sorted(labels) != sorted(map(str, correlation.index)):
        raise TwinError(f"{paths['correlation']}: its entries are not those of {paths['parameters']}: the files come "
                        "from different builds")
    return Twin(folder, card, variant, parameters, correlation)


def _plain(value):
    """Mappings and sequences of the config as plain YAML types."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _version() -> str:
    try:
        return metadata.version("hybridtwin")
    except metadata.PackageNotFoundError:
        return "unknown"
