"""The configuration's settings, read once (issue 37): each section of config/config.yaml one frozen, typed object.

The schema (``config.schema.yaml`` beside this module, shipped with the package: the one file the Snakefile's
``hybridtwin.config.check`` validates a configuration against) holds the only defaults, its ``default:`` entries
(``defaults``). ``Settings.from_config`` builds every section from a validated configuration at the front door (the
workflow's common.smk, once per plan): the config's values as written (a 14 stays 14: a rule's params, and so
whether it reruns, do not change), the schema's defaults for the keys it leaves out. A value of the wrong type (a
configuration that skipped the check) stops with a ``SettingsError`` naming the key.

The stages below never read the config: they take these objects' fields, or the plain options a workflow rule's
params carry (``OfflineSettings.options``, ``IdentificationSettings.rule``...), built from them.
"""

from __future__ import annotations

import copy
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields, is_dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from .offline.scenarios import default_n_scenarios

#: the configuration's JSON schema (package data: found wherever the package is installed)
SCHEMA_FILE = Path(__file__).with_name("config.schema.yaml")


class SettingsError(ValueError):
    """A config value of the wrong type for its setting, or a key no setting has: the message names the key."""


@cache
def _schema() -> dict:
    return yaml.safe_load(SCHEMA_FILE.read_text())


def schema() -> dict:
    """The configuration's JSON schema (a copy: the caller may change it)."""
    return copy.deepcopy(_schema())


def _defaults_of(node: Mapping) -> dict:
    """{key: default} of a schema object's properties: its ``default:``, else (a nested object without one) the
    defaults of its own properties, when it has any."""
    out = {}
    for key, sub in node.get("properties", {}).items():
        if "default" in sub:
            out[key] = copy.deepcopy(sub["default"])
        elif nested := _defaults_of(sub):
            out[key] = nested
    return out


def defaults(section: str | None = None) -> dict:
    """The schema's defaults: of the whole configuration, or of one top-level ``section`` (e.g. ``"offline"``;
    ``"report"`` holds ``transient``). A fresh copy each call."""
    found = _defaults_of(_schema())
    return found if section is None else found.get(section, {})


# --- building a section from the config ----------------------------------------------------------------------


def _fits(value, hint) -> bool:
    """Whether ``value`` has the type ``hint`` names (the outer type: what the schema checked in depth)."""
    if hint is Any:
        return True
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, h) for h in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)  # 14 is a float as written
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    base = origin or hint
    if base in (dict, Mapping):
        return isinstance(value, Mapping)
    return isinstance(value, base)


def _build(cls, where: str, given: Mapping | None, default: Mapping):
    """``cls`` (a settings dataclass) from the config's section ``given`` over its schema ``default``; nested
    sections (a dataclass field) merged key by key alike."""
    given = dict(given or {})
    names = [f.name for f in fields(cls)]
    unknown = [key for key in given if key not in names]
    if unknown:
        raise SettingsError(f"config {where}.{unknown[0]}: no such setting (settings: {', '.join(names)})")
    hints = typing.get_type_hints(cls)
    values = {}
    for name in names:
        hint, key = hints[name], f"{where}.{name}"
        if is_dataclass(hint):
            sub = given.get(name)
            if sub is not None and not isinstance(sub, Mapping):
                raise SettingsError(f"config {key}: {sub!r} is not a mapping")
            values[name] = _build(hint, key, sub, default.get(name) or {})
            continue
        if name not in given and name not in default:
            raise SettingsError(f"config {key}: required, and the schema has no default for it")
        value = given[name] if name in given else copy.deepcopy(default[name])
        if not _fits(value, hint):
            raise SettingsError(f"config {key}: {value!r} is not of type {_type_name(hint)}")
        values[name] = value
    return cls(**values)


def _type_name(hint) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


class _Section:
    """What every section has: its values as plain options (a rule's params, as the workflow always passed them)."""

    def as_dict(self) -> dict:
        """The section's values as a plain (nested) dict, in the fields' order."""
        return asdict(self)


# --- the sections ----------------------------------------------------------------------------------------------
# Fields in the order the options always had (a rule's params are their repr: the same order, no rerun). The
# mappings inside (n_scenarios, spgd...) are plain dicts: a frozen section is never reassigned, and pickles as it
# is into a job (Snakemake params).


@dataclass(frozen=True)
class EnrichmentSettings(_Section):
    """``offline: enrichment:`` (hybridtwin.offline.scenarios.sample_enrichment)."""

    observable_below: float
    n_scenarios: int
    chunks: int


@dataclass(frozen=True)
class OfflineSettings(_Section):
    """``offline:``, the white-box stage (scenarios, snapshots, POD, sPGD libraries)."""

    seed: int
    speed: str
    n_scenarios: dict
    n_test: int
    validation_fraction: float
    chunks: int
    scope: str
    pieces: str
    sensor_range_mm: float
    pod_energy_tolerance: float
    spgd: dict
    enrichment: EnrichmentSettings
    spgd_variants: dict

    def spgd_for(self, name: str) -> dict:
        """The sPGD options of variant ``name`` (declared or not): ``spgd`` updated by its ``spgd_variants``
        entry."""
        return {**self.spgd, **(self.spgd_variants.get(name) or {})}

    def n_scenarios_of(self, name: str, n_unknown: int) -> int:
        """n_s of variant ``name`` with ``n_unknown`` unknowns: its ``n_scenarios`` entry, else the paper's default
        for that many unknowns (hybridtwin.offline.scenarios.default_n_scenarios)."""
        return int(self.n_scenarios.get(name, default_n_scenarios(n_unknown)))

    def for_variant(self, name: str, n_unknown: int, keys: Sequence[str] | None = None) -> dict:
        """The options as variant ``name``'s rules see them (``hybridtwin.config.offline_for``): its own n_s and sPGD
        options only, so that declaring another variant never changes this one's rule parameters; with ``keys``,
        only those options, so that a rule reruns only when an option it uses changes."""
        options = self.options()
        options["n_scenarios"] = self.n_scenarios_of(name, n_unknown)
        options["spgd"] = self.spgd_for(name)
        del options["spgd_variants"]
        return options if keys is None else {k: options[k] for k in keys}

    def options(self) -> dict:
        """The options as plain values (what ``hybridtwin.config.offline`` gives)."""
        options = self.as_dict()
        options["spgd_variants"] = {name: dict(spec or {}) for name, spec in self.spgd_variants.items()}
        return options


@dataclass(frozen=True)
class JointProtocol(_Section):
    """``identification: joint:``, the joint fit's protocol."""

    trials: int
    monte_carlo: int
    monte_carlo_starts: int


@dataclass(frozen=True)
class Polish(_Section):
    """``identification: polish:``, the full-solver polish of the fits."""

    joint: bool
    runs: bool
    max_iterations: int
    nested: bool


@dataclass(frozen=True)
class IdentificationSettings(_Section):
    """``identification:``, the grey-box fits; ``variant_per_run``: each variant's own ``per_run`` (its entry
    under ``variants:``), which overrides ``per_run`` for it alone."""

    trials: int
    monte_carlo: int
    monte_carlo_starts: int
    sparsity: float | dict
    l1_epsilon: float
    seed: int
    per_run: list
    model_error: str | None
    confidence: float
    max_iterations: int
    joint: JointProtocol
    polish: Polish
    keyphasor: bool
    validation_bow: str
    profile: bool
    variant_per_run: dict

    @classmethod
    def from_config(cls, config: Mapping) -> IdentificationSettings:
        own = {name: list(spec["per_run"]) for name, spec in (config.get("variants") or {}).items()
               if isinstance(spec, Mapping) and spec.get("per_run") is not None}
        given = dict(config.get("identification") or {})
        if "variant_per_run" in given:
            raise SettingsError("config identification.variant_per_run: no such setting (a variant's own per_run "
                                "is set under variants:)")
        return _build(cls, "identification", given | {"variant_per_run": own},
                      defaults("identification"))

    def for_variant(self, variant: str) -> dict:
        """The options of ``variant``'s fits: the section's, its own ``per_run`` over ``per_run``, and ``lambda``
        (``sparsity``'s value for it, 0 for a variant not named)."""
        out = self.as_dict()
        del out["variant_per_run"]
        if variant in self.variant_per_run:
            out["per_run"] = list(self.variant_per_run[variant])
        sparsity = self.sparsity
        out["lambda"] = float(sparsity.get(variant, 0.0) if isinstance(sparsity, Mapping) else sparsity)
        return out

    def rule(self, variant: str, rule: str) -> dict:
        """The part of ``for_variant`` a workflow rule (``run``, ``joint`` or ``validation``) depends on: its
        params, so that a change reruns only that rule."""
        options = self.for_variant(variant)
        common = {k: options[k] for k in ("lambda", "l1_epsilon", "seed", "model_error", "confidence",
                                          "max_iterations", "keyphasor")}
        polish = options["polish"]
        if rule == "run":
            return common | {"trials": options["trials"], "monte_carlo": options["monte_carlo"],
                             "monte_carlo_starts": options["monte_carlo_starts"],
                             "polish": polish["max_iterations"] if polish["runs"] else False}
        polish_joint = polish["max_iterations"] if polish["joint"] else False
        if rule == "joint":
            # polish: nested changes the job's input files (the nested fits), which reruns it by itself
            return common | {"joint": options["joint"], "per_run": options["per_run"], "polish": polish_joint,
                             "profile": bool(options["profile"])}
        return {"validation_bow": options["validation_bow"], "model_error": options["model_error"],
                "solver": bool(polish["joint"]), "keyphasor": options["keyphasor"],
                "per_run": options["per_run"]}  # per_run: a failing validation run's refit with the fit runs


@dataclass(frozen=True)
class DesignSettings(_Section):
    """``design:``, the next runs to take (hybridtwin.identify.design): ``runs`` (0: no design), the candidate
    speeds (``rpm`` from, to; None: the runs sheet's range) in steps of ``step_rpm``, ``masses_g`` (None: the
    sheet's), ``keyphasor`` (without and/or with one)."""

    runs: int
    rpm: list | None
    step_rpm: float
    masses_g: list | None
    keyphasor: list


@dataclass(frozen=True)
class DiagnosisSettings(_Section):
    """``diagnosis:``, which candidate effect a variant misses (hybridtwin.diagnose.diagnosis.diagnose takes
    ``options()``)."""

    candidates: list | None
    confirm: int | str
    starts: int
    widen: int
    thorough: int
    quick_iterations: int
    max_effects: int
    alpha: float
    explained: float
    misfit_ratio: float
    confounded_bic: float
    bic_threshold: float
    max_iterations: int
    sparse_variant: str | None

    def options(self) -> dict:
        """The options as plain values (``diagnose``'s ``options``)."""
        return self.as_dict()


@dataclass(frozen=True)
class TransientSettings(_Section):
    """``report: transient:``, how the figures of run-ups and coast-downs show what they show
    (hybridtwin.report.transient_plots.Display: amplitude and phase; frame; orbit_rpm)."""

    orbit_rpm: list | None
    frame: str
    amplitude: str
    phase: str


@dataclass(frozen=True)
class OnlineSettings(_Section):
    """``online:``, the twin judging new records (hybridtwin.online): the twin ``variant``, the ``records`` sheet,
    the level ``alpha`` of every test."""

    variant: str
    records: str
    alpha: float


@dataclass(frozen=True)
class Settings:
    """Every option section of a validated configuration, built once (``from_config``); ``online`` is None when
    the config has no ``online:`` section."""

    offline: OfflineSettings
    identification: IdentificationSettings
    design: DesignSettings
    diagnosis: DiagnosisSettings
    transient: TransientSettings
    online: OnlineSettings | None

    @classmethod
    def from_config(cls, config: Mapping) -> Settings:
        return cls(offline_settings(config), IdentificationSettings.from_config(config), design_settings(config),
                   diagnosis_settings(config), transient_settings(config), online_settings(config))


def offline_settings(config: Mapping) -> OfflineSettings:
    """The config's ``offline:`` section (spgd_variants naming only declared variants)."""
    built = _build(OfflineSettings, "offline", config.get("offline"), defaults("offline"))
    declared = sorted(config.get("variants") or {})
    unknown = sorted(set(built.spgd_variants) - set(declared))
    if unknown:
        raise SettingsError(f"config offline.spgd_variants: no variant named {unknown} (declared: {declared})")
    # offline.spgd's default is one mapping: a key the config's spgd leaves out keeps its default
    return replace(built, spgd={**defaults("offline")["spgd"], **built.spgd})


def design_settings(config: Mapping) -> DesignSettings:
    """The config's ``design:`` section."""
    return _build(DesignSettings, "design", config.get("design"), defaults("design"))


def diagnosis_settings(config: Mapping) -> DiagnosisSettings:
    """The config's ``diagnosis:`` section."""
    return _build(DiagnosisSettings, "diagnosis", config.get("diagnosis"), defaults("diagnosis"))


def transient_settings(config: Mapping) -> TransientSettings:
    """The config's ``report: transient:`` section."""
    return _build(TransientSettings, "report.transient", (config.get("report") or {}).get("transient"),
                  defaults("report").get("transient", {}))


def online_settings(config: Mapping) -> OnlineSettings | None:
    """The config's ``online:`` section; None when it has none (no twin online)."""
    section = config.get("online")
    return _build(OnlineSettings, "online", section, defaults("online")) if section else None
