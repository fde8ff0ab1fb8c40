"""Reading the workflow configuration (config/config.yaml) into package objects, and checking it.

``check`` (called once by the Snakefile, before any job is planned) validates the configuration against the
package's schema (src/hybridtwin/config.schema.yaml, ``settings.SCHEMA_FILE``; its ``default:`` entries are the only
defaults: ``hybridtwin.settings`` builds each section from them) and cross-checks every name in it: variants named
under ``offline``/``identification``/``diagnosis``, parameters (``per_run``), effects and candidates, effects
files, ranges. Each problem is one line naming the file (and line) the value comes from, the key, the
bad value and the allowed names (``ConfigError``).
"""

from __future__ import annotations

import difflib
import errno
import logging
import os
import shutil
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from traceback import extract_tb

import pandas as pd
import yaml
from threadpoolctl import threadpool_limits

from .data.measured import read_harmonics
from .data.measurements import sheet_of, trial_angles  # sheet_of: the one reader of runs sheets (check-data's)
from .data.run_kinds import expand_bands
from .model.candidates import candidates_for
from .model.effects import Effect, builtin_effects, trial_angle_rad
from .model.machine import Machine
from .model.machine_parts import MachineSpecError
from .model.ross_io import machine_from_section
from .rig.rig import RigSpec
from .solvers.solver import DEFAULT_HARMONICS
from .model.whirl import WhirlModel
from .model.variants import EffectsFileError, Variant, load_effects_files, unbalance_hint
from .settings import SCHEMA_FILE, offline_settings

CONFIG_DIR = Path("config")
CONFIG_FILE = CONFIG_DIR / "config.yaml"


def user_effects(config: Mapping, config_dir: Path = CONFIG_DIR) -> dict[str, Effect]:
    """Effects from the config's ``effects_files`` (paths relative to the config folder)."""
    return load_effects_files([config_dir / path for path in config.get("effects_files") or []])


def effects_files_used(config: Mapping, names: Iterable[str], config_dir: Path = CONFIG_DIR) -> list[str]:
    """The config's ``effects_files`` (as written) that define an effect one of the variants ``names`` lists: what
    building them reads (an edit of another file, e.g. one adding a diagnosis candidate, does not touch them)."""
    used = {str(e) for name in names for e in (config["variants"][name].get("effects") or [])}
    return [path for path in config.get("effects_files") or []
            if used & _effects_defined(str(config_dir / path), _mtime(config_dir / path))]


def _mtime(path: Path) -> int:
    return path.stat().st_mtime_ns if path.is_file() else -1


@cache
def _effects_defined(path: str, mtime_ns: int) -> frozenset[str]:
    """The names of the effects one effects file defines (read once per version of the file)."""
    return frozenset(load_effects_files([path])) if mtime_ns >= 0 else frozenset()


def candidate_effects(config: Mapping, config_dir: Path = CONFIG_DIR) -> dict[str, Effect]:
    """Effects the diagnosis may test besides the built-in candidates: the config's effects files', and the
    candidates the machine sizes to each of its bearings with nominal k (``bearing_candidates``), by name."""
    return user_effects(config, config_dir) | machine(config, config_dir).candidates()


#: the built-in candidate a machine of your own is offered besides those sized to it (effects.SpeedDependentDamping)
SPEED_DAMPING = "speed_damping"


def candidate_names(names: Sequence[str] | None, config: Mapping) -> list[str] | None:
    """The candidates to test: ``names`` (``diagnosis: candidates``) when given; when null, None (every built-in
    candidate) on the VARM, and on a machine of your own (``config``'s ``machine:``) the candidates sized to it
    (``Machine.sized_candidates``: at its bearings and unbalance planes; the built-in ones act at the VARM's upper
    bearing, node 0) and the speed-dependent damping (mass-proportional, dimensionless: any machine's)."""
    if names is not None or config.get("machine") is None:
        return None if names is None else list(names)
    placed = list(machine(config).sized_candidates())
    return placed + [SPEED_DAMPING] if placed else None


def machine(config: Mapping, config_dir: str | Path = CONFIG_DIR) -> Machine:
    """The rotor of the ``machine:`` section (``Machine.from_mapping``; absent: the VARM), or of the ROSS rotor file
    it names (``{ross: rotor.toml, ...}``, relative to ``config_dir``: ``ross_io.machine_from_section``)."""
    spec = config.get("machine")
    if isinstance(spec, Mapping) and "ross" in spec:
        return machine_from_section(spec, config_dir)
    return Machine.from_mapping(spec)


def variant(config: Mapping, name: str, config_dir: Path = CONFIG_DIR) -> Variant:
    """The variant ``name`` declared under ``variants:``, built on the config's machine."""
    if name not in config["variants"]:
        raise KeyError(f"variant {name!r} is not declared in the config (declared: {sorted(config['variants'])})")
    rotor = machine(config, config_dir)
    return Variant.from_spec(name, config["variants"][name], user_effects(config, config_dir) | rotor.effects(),
                             shaft=rotor)


def whirl_settings(config: Mapping) -> dict:
    """What the data checks' whirl rule takes from a config (``whirl_model``'s input, a rule's params): its
    ``machine``, ``variants`` and ``effects_files`` when it describes a machine of its own; empty for the VARM
    (its one plane's 1X whirls forward at every speed of its isotropic models: the model-free rule holds, and
    an edit of a variant reruns no data check)."""
    if config.get("machine") is None or not config.get("variants"):
        return {}
    return {key: config[key] for key in ("machine", "variants", "effects_files") if config.get(key) is not None}


def whirl_model(config: Mapping, config_dir: Path = CONFIG_DIR) -> WhirlModel | None:
    """The machine's model of the 1X whirl (``hybridtwin.model.whirl.WhirlModel``) for the data checks: every
    variant the config declares, built on its machine; None without a ``machine:`` section or variants
    (``whirl_settings``), where the checks keep their model-free rule (docs/data-checks.md)."""
    settings = whirl_settings(config)
    if not settings:
        return None
    return WhirlModel([variant(settings, name, config_dir) for name in settings["variants"]])


def offline(config: Mapping) -> dict:
    """The ``offline:`` options with the schema's defaults filled in (``settings.OfflineSettings.options``)."""
    return offline_settings(config).options()


def data_check_settings(config: Mapping) -> dict:
    """What the data checks take from a config, one derivation for the workflow's check_data and preprocess rules
    (their params) and ``hybridtwin check-data`` (its defaults, each option overriding one): ``harmonics`` (H;
    without a config, solver.DEFAULT_HARMONICS), ``coverage`` (``rpm`` and ``eccentric_mass_g`` ranges, or empty),
    ``sensor_range_mm`` (offline.sensor_range_mm with its default: the probes' range; a sheet's sensor_range_mm
    column overrides it run by run)."""
    return {"harmonics": config.get("harmonics", DEFAULT_HARMONICS), "coverage": config.get("coverage") or {},
            "sensor_range_mm": offline(config)["sensor_range_mm"]}  # as written (a param's value: 14 stays 14)


def offline_for(config: Mapping, name: str, keys: Sequence[str] | None = None) -> dict:
    """The ``offline:`` options as variant ``name``'s rules see them: its own n_s and sPGD options
    (``spgd`` updated by its ``spgd_variants`` entry) only, so that declaring another variant (and its
    n_s or sPGD options) never changes this one's rule parameters (nothing of it reruns); with
    ``keys``, only those options, so that a rule reruns only when an option it uses changes (the sPGD
    options or the library scope never re-sample or re-solve the scenarios): ``OfflineSettings.for_variant``."""
    return offline_settings(config).for_variant(name, len(variant(config, name).unknown), keys)


def spgd_for(config: Mapping, name: str) -> dict:
    """The sPGD options of variant ``name`` (declared or not): ``offline.spgd`` updated by its
    ``offline.spgd_variants`` entry."""
    return offline_settings(config).spgd_for(name)


def n_scenarios(config: Mapping, variant_: Variant) -> int:
    """n_s of a variant: the config's per-variant value or the paper's default for its unknown count."""
    return offline_settings(config).n_scenarios_of(variant_.name, len(variant_.unknown))


def run_plan(source: Mapping | str | Path | pd.DataFrame, measured: str | Path | None = None) -> pd.DataFrame:
    """The runs the libraries are built for: run, rpm, eccentric_mass_g, role (from the runs sheet; a transient
    record's speed bands, ``run_kinds.expand_bands``, each a run at the band's centre).

    ``source`` is the runs sheet's path, a config naming it under ``runs:`` (a workflow script passes the
    sheet it has as input), or the sheet already read (``measurements.sheet_of``: the workflow reads it once). With ``measured`` (the preprocessed table, results/data/harmonics.tsv) each run's
    rpm is the true speed refined from its record (rpm_true) instead of the nominal one.
    """
    read = sheet_of(source["runs"] if isinstance(source, Mapping) else source)
    path = read.attrs.get("source", "runs sheet")
    sheet = expand_bands(read).copy()  # a run-up's speed bands are runs (data/transient); a copy: `read` may be
    # the workflow's one sheet, shared by every input function, and the speeds below are written in place
    if measured is not None:
        speeds = read_harmonics(measured).set_index("run")["rpm_true"]
        missing = sorted(set(sheet["run"]) - set(speeds.index))
        if missing:
            raise ValueError(f"{measured} has no refined speed for run(s) {missing}")
        sheet["rpm"] = sheet["run"].map(speeds).fillna(sheet["rpm"]).to_numpy(float)  # flat: not refined
    unknown_mass = sheet.loc[sheet["eccentric_mass_g"].isna(), "run"].tolist()
    if unknown_mass:
        raise ValueError(f"{path}: run(s) {unknown_mass} have no eccentric_mass_g; the offline "
                         "libraries are built per (rpm, eccentric mass) and need it")
    return sheet[["run", "rpm", "eccentric_mass_g"] + (["role"] if "role" in sheet else [])]


def angles_on_libraries(config: Mapping, sheet: pd.DataFrame) -> str | None:
    """What is wrong when runs of ``sheet`` (read_runs) carry a trial mass at a non-zero angle
    (eccentric_mass_angle_deg) and a variant fits on sPGD libraries (offline.scope run or global): the libraries are
    built per (rpm, eccentric mass) with the mass on +x, so the angle is refused rather than ignored; None when
    fine."""
    angled = [r for r, a in zip(sheet["run"], trial_angles(sheet)) if trial_angle_rad(a) != 0.0]
    on_libraries = [v for v in config["variants"] if offline_for(config, v)["scope"] != "none"]
    if not angled or not on_libraries:
        return None
    return (f"run(s) {angled} carry a trial mass at an angle (eccentric_mass_angle_deg), but variant(s) "
            f"{on_libraries} fit on sPGD libraries, built per (rpm, eccentric mass) with the mass on +x: set "
            "offline: scope: none (the full solver) for them")


def rule_logger(log_path: str, name: str) -> logging.Logger:
    """A logger writing to the rule's log file; BLAS pinned to one thread (jobs run in parallel); a full disk
    said in one message (``on_disk_full``)."""
    threadpool_limits(1)
    logging.basicConfig(filename=log_path, level=logging.INFO, force=True,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    log = logging.getLogger(name)
    on_disk_full(log)
    return log


# --- a full disk in a job (issue 55) ----------------------------------------------------------------


def disk_full(err: BaseException | None) -> OSError | None:
    """The "No space left on device" (errno ENOSPC, 28; EDQUOT, a quota, alike) in ``err`` or the exceptions it
    was raised from (a writer wraps it: zarr, pandas), or None."""
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
            return err
        err = err.__cause__ or err.__context__
    return None


def _size(path: Path) -> int:
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def disk_full_message(err: OSError, outputs: Sequence[str] = (), workdir: str | Path = ".", largest: int = 3
                      ) -> str:
    """What a job says when the disk is full: the file (or store) it was writing (the error's, else the job's
    outputs), the space left on that file system, what to free (the largest folders of the workflow's results/,
    and .snakemake/), and that the same command then resumes."""
    written = err.filename or ", ".join(map(str, outputs)) or "its outputs"
    folder = Path(str(err.filename or (outputs[0] if outputs else workdir))).absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    workdir = Path(workdir)
    folders = [p for p in (workdir / "results").glob("*/*") if p.is_dir()] if (workdir / "results").is_dir() else []
    sizes = sorted(((_size(p), p) for p in folders), key=lambda item: -item[0])[:largest]
    cache_dir = workdir / ".snakemake"
    biggest = ", ".join(f"{p} ({n / 1e6:.0f} MB)" for n, p in sizes if n) or "none"
    cached = f"; .snakemake/ holds {_size(cache_dir) / 1e6:.0f} MB (its conda/ and singularity/ can go)" \
        if cache_dir.is_dir() else ""
    return (f"disk full (errno {err.errno}, {os.strerror(err.errno)}) while writing {written}: "
            f"{free / 1e6:.0f} MB free on the file system of {folder}. Free space there, e.g. results of a variant "
            f"no longer in the config, or another run's folder; the largest under results/: {biggest}{cached}. "
            "Then run the same snakemake command again: the jobs that finished are kept, this job's partial outputs "
            "are removed by Snakemake and it runs again, then the rest.")


def on_disk_full(log: logging.Logger) -> None:
    """Make a full disk end the job (the script Snakemake runs) with ``disk_full_message`` on standard error and
    in the log (with where it was raised, one line: Snakemake shows a failed job's log, and a traceback there would
    bury the message), instead of the writer's traceback. Other errors: unchanged."""
    previous = sys.excepthook

    def hook(kind, value, traceback):
        full = disk_full(value)
        if full is None:
            return previous(kind, value, traceback)
        job = getattr(sys.modules.get("__main__"), "snakemake", None)
        outputs = [str(path) for path in getattr(job, "output", [])]
        message = disk_full_message(full, outputs)
        where = extract_tb(traceback)[-1] if traceback is not None else None
        log.error("%s (%s: %s%s)", message, kind.__name__, value,
                  f", raised at {where.filename}:{where.lineno} in {where.name}" if where else "")
        print(f"{log.name}: error: {message}", file=sys.stderr)

    sys.excepthook = hook


# --- checking a configuration before any job runs ---------------------------------------------------


class ConfigError(ValueError):
    """A bad configuration: one line per problem, '<file>, line <n>: <key>: <problem> (<allowed values>)'."""

    def __init__(self, problems: Sequence[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass
class Sources:
    """Where a merged configuration's values come from: config files in increasing precedence (the
    workflow's config/config.yaml, then each ``--configfile``), then ``--config KEY=VALUE`` (highest)."""

    files: Sequence[str | Path] = (CONFIG_FILE,)
    command_line: Mapping = field(default_factory=dict)

    def locate(self, path: Sequence[str | int]) -> str:
        """The file and line that set the value at ``path`` (the source of highest precedence that has it);
        for a key no source sets (a missing key), the nearest enclosing key that one does."""
        path = tuple(path)
        if path and path[0] in self.command_line:
            return f"--config {path[0]}=..."
        for depth in range(len(path), 0, -1):
            for file in reversed(list(self.files)):
                line = _line_of(str(file), path[:depth])
                if line is not None:
                    return f"{file}, line {line}"
        return str(self.files[0]) if self.files else "config"


def check(config: Mapping, schema: str | Path = SCHEMA_FILE, files: Sequence[str | Path] = (CONFIG_FILE,),
          command_line: Mapping | None = None, config_dir: str | Path = CONFIG_DIR) -> None:
    """Validate ``config`` against the JSON schema, then cross-check every name in it; ``ConfigError`` lists
    each problem on one line (file and line from ``files``/``command_line``, see ``Sources``).

    The names checked: every variant's effects (built in or from ``effects_files``) and its unknown/fixed
    parameters; the variants named in ``offline.n_scenarios``, ``offline.spgd_variants``,
    ``identification.sparsity`` and ``diagnosis.sparse_variant``; ``identification.per_run`` (each must be
    an unknown of some variant, else that parameter would silently be shared); ``diagnosis.candidates``;
    the effects files and the runs sheet exist; coverage ranges are ranges; every ``rig`` entry builds.
    """
    sources = Sources([_relative(f) for f in files], dict(command_line or {}))
    schema_data = yaml.safe_load(Path(schema).read_text())
    problems = list(_schema_problems(config, schema_data))
    try:
        names = list(_name_problems(config, Path(config_dir)))
    except (TypeError, AttributeError, KeyError, ValueError):
        if not problems:  # a malformed section the schema let through would be a bug of the schema
            raise
        names = []  # a section of the wrong type, already reported by the schema
    # a section the schema found wrong (e.g. variants.final) is reported once, by the schema
    wrong = {path[:2] for path, _, _ in problems}
    problems += [p for p in names if not any(p[0][:len(w)] == w for w in wrong)]
    if problems:
        raise ConfigError([f"{sources.locate(path)}: {key or 'top level'}: {message}"
                           for path, key, message in problems])


def check_or_exit(config: Mapping, schema: str | Path = SCHEMA_FILE, files: Sequence[str | Path] = (CONFIG_FILE,),
                  command_line: Mapping | None = None, config_dir: str | Path = CONFIG_DIR) -> None:
    """``check`` for the Snakefile: on a bad config, exit with one line per problem and no traceback."""
    try:
        check(config, schema, files, command_line, config_dir)
    except ConfigError as err:
        sys.exit("\n".join(f"config error: {problem}" for problem in err.problems))


Problem = tuple[tuple, str, str]  # (path of the bad value, key as shown, what is wrong)


def _relative(file: str | Path) -> Path:
    """A file as the user names it: relative to the working directory when inside it."""
    try:
        return Path(file).absolute().relative_to(Path.cwd())
    except ValueError:
        return Path(file)


def _key(path: Iterable[str | int]) -> str:
    return ".".join(str(p) for p in path if not isinstance(p, int))


def _short(value, width: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + "..."


SIZED = ("linear_bearing", "bearing_anisotropy", "cross_coupled_stiffness", "cross_coupled_damping")


def _bare_bearing(effect: str, rotor):
    """The bearing an effect sized to its nominal coefficients is placed at, when declared without them (None
    otherwise), and the coefficient it lacks."""
    kind, _, bearing = effect.partition("@")
    for b in getattr(rotor, "bearings", ()) if kind in SIZED else ():
        if b.name == bearing and (b.k is None or (kind == "cross_coupled_damping" and not b.c)):
            return b, "k (and c)" if b.k is None else "c > 0"
    return None, ""


def _bare_text(bearing, need: str) -> str:
    return (f"bearing {bearing.name!r} is declared without its nominal {need} in machine.bearings (e.g. "
            f"{bearing.name}: {{node: {bearing.node}, k: 2.0e+06, c: 300}})")


def _missing_plane(plane: str, rotor) -> str:
    """Why unbalance@``plane`` does not exist on ``rotor``, and how to declare it (``variants.unbalance_hint``)."""
    return unbalance_hint(plane, [p.name for p in getattr(rotor, "unbalance_planes", ())])


def _no_such_effect(effect: str, registry: Mapping, rotor) -> str:
    """Why ``effect`` is not offered: a bearing effect at a bearing declared without nominal coefficients, or no
    such name (with the closest)."""
    kind, _, bearing = effect.partition("@")
    if kind == "unbalance" and bearing:  # unbalance@<plane>: the plane is not declared
        return f"no effect named {effect!r}: {_missing_plane(bearing, rotor)}"
    bare, need = _bare_bearing(effect, rotor)
    if bare is not None:
        return f"no effect named {effect!r}: {_bare_text(bare, need)}, which {effect} needs"
    return f"no effect named {effect!r} {_allowed(effect, registry, 'effects')}"


def _place(effect) -> str | None:
    """'linear_bearing@b' -> 'b'; None for an effect not placed."""
    name, at, place = str(effect).partition("@")
    return place if at else None


def _cause(effect, known: set[str], rotor) -> tuple | None:
    """Why a placed effect name is not known, when the machine is to blame: ("place", p) for a place it does not
    have, ("bare", bearing, need) for a bearing declared without the coefficients the effect is sized to."""
    place = _place(effect)
    if place is None or effect in known:
        return None
    if place not in {_place(n) for n in known} - {None}:
        return ("place", place)
    bare, need = _bare_bearing(str(effect), rotor)
    return ("bare", bare.name, need) if bare is not None else None


def _shared_causes(config: Mapping, known: set[str], rotor) -> dict[tuple, list[Problem]]:
    """Causes (``_cause``) shared by two or more effect names in the variants, diagnosis.candidates or the rig's
    truths: {cause: [(path, key, name) of each use, in the config's order]}, each then said once."""
    uses: dict[tuple, list[Problem]] = {}

    def scan(path: tuple, names) -> None:
        for i, name in enumerate(names or []) if isinstance(names, list) else ():
            cause = _cause(name, known, rotor)
            if cause is not None:
                uses.setdefault(cause, []).append((path + (i,), _key(path), str(name)))

    for name, spec in (config.get("variants") or {}).items():
        scan(("variants", name, "effects"), (spec or {}).get("effects") if isinstance(spec, Mapping) else None)
    diagnosis = config.get("diagnosis")
    scan(("diagnosis", "candidates"), diagnosis.get("candidates") if isinstance(diagnosis, Mapping) else None)
    for name, spec in (config.get("rig") or {}).items() if isinstance(config.get("rig"), Mapping) else ():
        truth = spec.get("truth") if isinstance(spec, Mapping) else None
        scan(("rig", name, "truth", "effects"), truth.get("effects") if isinstance(truth, Mapping) else None)
    return {cause: found for cause, found in uses.items() if len(found) > 1}


def _shared_cause_problem(cause: tuple, uses: list[Problem], known: set[str], rotor) -> Problem:
    """One problem for every use of a shared cause: at the machine's bearing (bare), or at the first use."""
    names = ", ".join(sorted({effect for _, _, effect in uses}))
    keys = ", ".join(dict.fromkeys(k for _, k, _ in uses))
    if cause[0] == "bare":
        bearing = next(b for b in rotor.bearings if b.name == cause[1])
        path = ("machine", "bearings", bearing.name)
        return path, _key(path), (f"{_bare_text(bearing, cause[2])}, which {len(uses)} effects placed at it need "
                                  f"({names}); named in {keys}")
    places = {_place(n) for n in known} - {None}
    path, key, _ = uses[0]
    if all(effect.startswith("unbalance@") for _, _, effect in uses):  # a missing unbalance plane: how to declare it
        return path, key, (f"{len(uses)} effects are placed at {cause[1]!r} ({names}): "
                           f"{_missing_plane(cause[1], rotor)}; named in {keys}")
    return path, key, (f"{len(uses)} effects are placed at {cause[1]!r} ({names}), which the machine does not have "
                       f"{_allowed(cause[1], places, 'places')}; named in {keys}")


def _allowed(name: str, names: Iterable[str], what: str) -> str:
    names = sorted(map(str, names))
    close = difflib.get_close_matches(str(name), names, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return f"({hint}{what}: {', '.join(names) if names else 'none'})"


@cache
def _compose(text: str):
    try:
        return yaml.compose(text)
    except yaml.YAMLError:
        return None


def _line_of(file: str, path: tuple) -> int | None:
    """1-based line of the key (or list item) at ``path`` in a YAML file; None if the file does not set it."""
    try:
        node = _compose(Path(file).read_text())
    except OSError:
        return None
    line = None
    for key in path:
        if isinstance(node, yaml.MappingNode):
            match = [(k, v) for k, v in node.value if str(k.value) == str(key)]
            if not match:
                return None
            line, node = match[-1][0].start_mark.line + 1, match[-1][1]
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            node = node.value[key]
            line = node.start_mark.line + 1
        else:
            return None
    return line


def _expects(schema: Mapping) -> str:
    """What a schema accepts, in a few words (for the alternatives of a oneOf)."""
    if "enum" in schema:
        return "one of " + ", ".join("null" if v is None else str(v) for v in schema["enum"])
    kind = schema.get("type", "value")
    words = ["/".join(kind) if isinstance(kind, list) else {"null": "null", "array": "a list"}.get(kind, kind)]
    for key, symbol in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<")):
        if key in schema:
            words.append(f"{symbol} {schema[key]}")
    if isinstance(schema.get("items"), Mapping):
        words.append(f"of {_expects(schema['items'])}")
    if isinstance(schema.get("additionalProperties"), Mapping):
        words = ["a mapping of name:", _expects(schema["additionalProperties"])]
    return " ".join(words)


def _schema_problems(config: Mapping, schema: Mapping) -> Iterable[Problem]:
    # here, not at import: jsonschema (~60 ms, 50 modules) only where a config is checked, not in every rule script
    from jsonschema import validators
    from jsonschema.exceptions import best_match

    validator = validators.validator_for(schema)(schema)
    errors = sorted(validator.iter_errors(dict(config)), key=lambda e: [str(p) for p in e.absolute_path])
    for error in errors:
        if error.context:  # oneOf/anyOf: a deeper error of the closest alternative, or what each one expects
            deeper = best_match([error])
            if len(deeper.absolute_path) <= len(error.absolute_path):
                path = tuple(error.absolute_path)
                yield path, _key(path), f"{_short(error.instance)} is none of: " \
                                        f"{'; '.join(_expects(option) for option in error.validator_value)}"
                continue
            error = deeper
        path = tuple(error.absolute_path)
        value, kind = error.instance, error.validator
        if kind == "additionalProperties" and isinstance(value, Mapping):
            known = list(error.schema.get("properties", {}))
            for extra in sorted(set(value) - set(known), key=str):
                yield path + (extra,), _key(path), f"unknown key {extra!r} {_allowed(extra, known, 'allowed')}"
        elif kind == "required" and isinstance(value, Mapping):
            for missing in [k for k in error.validator_value if k not in value]:
                yield path, _key(path), f"missing key {missing!r}"
        elif kind == "enum":
            yield path, _key(path), f"{_short(value)} is not allowed (allowed: " \
                                    f"{', '.join('null' if v is None else str(v) for v in error.validator_value)})"
        elif kind == "type":
            yield path, _key(path), f"{_short(value)} is not of type {error.validator_value}"
        else:
            yield path, _key(path), error.message if len(error.message) < 200 else error.message[:197] + "..."


def _name_problems(config: Mapping, config_dir: Path) -> Iterable[Problem]:
    runs = config.get("runs")
    if runs is not None and not Path(runs).is_file():
        yield ("runs",), "runs", f"runs sheet {str(runs)!r} does not exist (paths are relative to the project root)"

    user: dict[str, Effect] = {}
    for i, path in enumerate(config.get("effects_files") or []):
        try:
            user |= load_effects_files([config_dir / path])
        except EffectsFileError as err:
            yield ("effects_files", i), "effects_files", f"{err} (paths are relative to {config_dir}/)"

    rotor, machine_ok = Machine.varm(), False
    try:
        rotor = machine(config, config_dir)
        rotor.sensor_node  # at least one x, y probe pair (its orbit); the records hold a channel per sensor
        machine_ok = True
    except MachineSpecError as err:
        yield ("machine",) + err.path, _key(("machine",) + err.path), err.message
    except ValueError as err:
        yield ("machine", "sensors"), "machine.sensors", str(err)
    placed = user | rotor.effects()  # effects at the machine's named nodes, e.g. linear_bearing@drive_end
    variants = dict(config.get("variants") or {})
    registry = builtin_effects() | placed
    testable = dict(user) | (rotor.candidates() if machine_ok else {})  # candidates sized to the machine's bearings
    # the machine to blame for several effect names (a place it lacks, a bearing without its coefficients): one
    # problem, not one per name
    known = set(registry) | set(testable)
    lost = _shared_causes(config, known, rotor) if machine_ok else {}
    for cause, uses in lost.items():
        yield _shared_cause_problem(cause, uses, known, rotor)
    for name, spec in variants.items():
        where = ("variants", name)
        bad = False
        parameters = set()
        for i, effect in enumerate(spec.get("effects") or []):
            if effect in registry:
                parameters |= {p.name for p in registry[effect].parameters}
            else:
                bad = True
                if "@" in str(effect) and (not machine_ok or _cause(effect, known, rotor) in lost):
                    continue  # placed at a name of the machine, whose own problem is reported
                yield where + ("effects", i), _key(where + ("effects",)), \
                    _no_such_effect(str(effect), registry, rotor)
        for kind in ("unknown", "fixed") if not bad else ():  # parameters only once the effects are known
            for parameter in spec.get(kind) or {}:
                if parameter not in parameters:
                    bad = True
                    yield where + (kind, parameter), _key(where + (kind,)), \
                        f"{parameter!r} is a parameter of none of the variant's effects " \
                        f"{_allowed(parameter, parameters, 'parameters')}"
        if not bad:
            try:
                Variant.from_spec(name, spec, placed, shaft=rotor)
            except ValueError as err:
                yield where, _key(where), str(err)

    def variant_names(path: tuple, names: Iterable[str]) -> Iterable[Problem]:
        for key in names:
            if key not in variants:
                yield path + (key,), _key(path), f"no variant named {key!r} {_allowed(key, variants, 'variants')}"

    offline_ = config.get("offline") or {}
    yield from variant_names(("offline", "n_scenarios"), offline_.get("n_scenarios") or {})
    yield from variant_names(("offline", "spgd_variants"), offline_.get("spgd_variants") or {})

    identification = config.get("identification") or {}
    if isinstance(identification.get("sparsity"), Mapping):
        yield from variant_names(("identification", "sparsity"), identification["sparsity"])
    unknowns = {p for spec in variants.values() for p in (spec.get("unknown") or {})}
    for i, parameter in enumerate(identification.get("per_run") or []):
        if parameter not in unknowns:
            yield ("identification", "per_run", i), "identification.per_run", \
                f"{parameter!r} is an unknown of no variant, so nothing would be estimated per run " \
                f"{_allowed(parameter, unknowns, 'unknown parameters')}"

    for name, spec in variants.items():
        own = set((spec or {}).get("unknown") or {})
        for i, parameter in enumerate((spec or {}).get("per_run") or []):
            if parameter not in own:
                yield ("variants", name, "per_run", i), f"variants.{name}.per_run", \
                    f"{parameter!r} is not an unknown of variant {name!r} " \
                    f"{_allowed(parameter, own, 'its unknown parameters')}"

    diagnosis = config.get("diagnosis") or {}
    available = [c.name for c in candidates_for([])] + list(testable)  # built in, effects files, bearings
    for i, candidate in enumerate(diagnosis.get("candidates") or []):
        if "@" in str(candidate) and (not machine_ok or _cause(candidate, known, rotor) in lost):
            continue  # placed at a bearing of the machine, whose own problem is reported (not one line per name)
        bare, need = _bare_bearing(str(candidate), rotor)
        if candidate not in available and bare is not None:
            yield ("diagnosis", "candidates", i), "diagnosis.candidates", \
                f"no candidate effect named {candidate!r}: {_bare_text(bare, need)}, which {candidate} needs"
            continue
        if candidate not in available:
            yield ("diagnosis", "candidates", i), "diagnosis.candidates", \
                f"no candidate effect named {candidate!r} " \
                f"{_allowed(candidate, available, 'candidates, built in, from effects_files or at the bearings')}"
            continue
        try:
            candidates_for([], [candidate], testable)
        except ValueError as err:  # a user effect that cannot be a candidate
            yield ("diagnosis", "candidates", i), "diagnosis.candidates", str(err)
    sparse = diagnosis.get("sparse_variant")
    if sparse is not None and sparse not in variants:
        yield ("diagnosis", "sparse_variant"), "diagnosis.sparse_variant", \
            f"no variant named {sparse!r} {_allowed(sparse, list(variants) + ['null (none)'], 'variants')}"

    coverage = config.get("coverage") or {}
    for key, smallest in (("rpm", "0 <"), ("eccentric_mass_g", "0 <=")):
        if key in coverage:
            lo, hi = coverage[key]
            if not (lo < hi and (lo > 0 if key == "rpm" else lo >= 0)):
                yield ("coverage", key), f"coverage.{key}", f"[{lo:g}, {hi:g}] is not a range [low, high] " \
                                                             f"with {smallest} low < high"

    for name, spec in (config.get("rig") or {}).items() if machine_ok else ():  # a bad machine: reported above
        truth = (spec or {}).get("truth") if isinstance(spec, Mapping) else None
        if isinstance(truth, Mapping) and any(_cause(e, known, rotor) in lost for e in truth.get("effects") or []):
            continue  # an effect of its truth placed where the machine has nothing: reported above
        try:
            RigSpec.from_mapping(spec, user, rotor)  # the truth on the config's machine, as the rig rule builds it
        except ValueError as err:
            yield ("rig", name), f"rig.{name}", str(err)

    section = config.get("online") or {}
    if section.get("variant") is not None and section["variant"] not in variants:
        yield ("online", "variant"), "online.variant", \
            f"no variant named {section['variant']!r} {_allowed(section['variant'], variants, 'variants')}"
    if section.get("records") is not None and not Path(section["records"]).is_file():
        yield ("online", "records"), "online.records", \
            f"runs sheet {str(section['records'])!r} does not exist (paths are relative to the project root)"
