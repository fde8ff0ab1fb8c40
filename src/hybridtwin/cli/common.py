"""What the commands share: the config they read (as the workflow reads it), the variants and effects it declares,
and the parsing of numbers on the command line. Every bad value ends in a ``UsageError`` (exit status 2)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path

import numpy as np
import yaml

from .. import config as config_module
from ..data.measurements import kg_looking
from ..model.effect_base import Effect
from ..model.effects import builtin_effects, trial_angle_rad
from ..model.machine import Machine, default_machine
from ..model.machine_parts import MachineSpecError
from ..model.variants import BUILTIN_VARIANTS, EffectsFileError, Variant, load_effects_files
from ..solvers.continuation import RUN_UP_FROM_RPM  # noqa: F401 (simulate's run-up start: the rig's and the fits')

#: the config read when --config is not given and the command runs from the project root
PROJECT_CONFIG = Path("config") / "config.yaml"
#: a run-down for the other branch starts this much above the point (at least RUNDOWN_MARGIN_RPM)
RUNDOWN_FACTOR, RUNDOWN_MARGIN_RPM = 1.5, 300.0
#: two branches at a point are different steady states when their harmonics differ by more than this,
#: relative to the largest (the solver converges to ~1e-10 relative; a second branch differs at O(1))
SAME_BRANCH_RTOL = 1e-6
#: most samples --time-series writes (about 10^7 rows, 0.5 GB of CSV)
MAX_SAMPLES = 10_000_000


class UsageError(Exception):
    """Bad input from the user: printed as one clear line, exit status 2."""


class CommandParser(argparse.ArgumentParser):
    """argparse with its errors on one line (no usage block before them), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def package_version() -> str:
    try:
        return metadata.version("hybridtwin")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"




def parameter_setting(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. k_b=2411.3), got {text!r}")
    return name.strip(), number_arg(value, name.strip())


def number_arg(text: str, name: str = "") -> float:
    """A finite float, or an argparse error (naming the parameter ``name`` when given)."""
    what = f"value of {name} is " if name else ""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}not a number: {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"{what}not a finite number: {text!r}")
    return value


def positive_arg(text: str) -> float:
    value = number_arg(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def non_negative_arg(text: str) -> float:
    value = number_arg(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def positive_int_arg(text: str) -> int:
    """An argparse type: an integer >= 1 (harmonics, speeds, modes)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


# --- variants and effects: built in, from a config, from effect files -------------------------------


def config_file(config: Path | None) -> Path | None:
    """--config, or ./config/config.yaml when run from the project root, or None (built-in variants)."""
    if config is not None:
        return config
    return PROJECT_CONFIG if PROJECT_CONFIG.is_file() else None


def read_config(config: Path) -> Mapping:
    """The mapping of a config file, or a one-line UsageError naming it."""
    if not config.is_file():
        raise UsageError(f"config file {config} does not exist")
    try:
        data = yaml.safe_load(config.read_text()) or {}
    except yaml.YAMLError as err:
        raise UsageError(f"config file {config} is not valid YAML: {' '.join(str(err).split())}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UsageError(f"config file {config} cannot be read: {err}") from None
    if not isinstance(data, Mapping):
        raise UsageError(f"config file {config}: expected a mapping of keys (variants:, effects_files:, ...)")
    return data


def config_machine(config: Path | None, data: Mapping | None = None) -> Machine:
    """The rotor of a config file's ``machine:`` section (hybridtwin.config.machine; none: the VARM)."""
    if config is None:
        return default_machine()
    data = read_config(config) if data is None else data
    try:
        return config_module.machine(data, config.parent)
    except MachineSpecError as err:
        raise UsageError(f"config file {config}: {err}") from None


def load_catalog(config: Path | None, effects_files: Sequence[Path]
                 ) -> tuple[dict[str, Mapping], dict[str, Effect], Machine]:
    """Variant specs, user effects and the machine: from a config file (``variants:``, ``effects_files:``,
    ``machine:``; the built-in variants when it declares none, the VARM when it has no machine) and effect
    files."""
    specs: dict[str, Mapping] = dict(BUILTIN_VARIANTS)
    files = list(effects_files)
    machine = default_machine()
    if config is not None:
        data = read_config(config)
        specs = dict(data.get("variants") or specs)
        files += [config.parent / f for f in data.get("effects_files") or []]
        machine = config_machine(config, data)
    try:
        user = load_effects_files(files)
    except EffectsFileError as err:
        raise UsageError(str(err)) from None
    return specs, user, machine


def build_variant(name: str, specs: Mapping[str, Mapping], user: Mapping[str, Effect], source: Path | None,
                  add: Sequence[str] = (), machine: Machine | None = None) -> Variant:
    """Variant ``name`` of ``specs`` built on ``machine`` (default the VARM), with the effects ``add`` (built in,
    from effect files or placed on the machine, e.g. ``linear_bearing@drive_end``) added."""
    if name not in specs:
        raise UsageError(f"unknown variant {name!r} (available: {', '.join(sorted(specs))}"
                         f"{'' if source is None else f' in {source}'})")
    machine = default_machine() if machine is None else machine
    user = dict(user) | machine.effects()  # as hybridtwin.config.variant
    spec = dict(specs[name])
    if add:
        registry = builtin_effects() | user
        present = list(spec.get("effects", []))
        for effect in add:
            if effect not in registry:
                raise UsageError(f"--add-effect {effect}: no such effect (available: {', '.join(sorted(registry))})")
            if effect in present:
                raise UsageError(f"--add-effect {effect}: variant {name!r} has it already")
            present.append(effect)
        spec["effects"] = present
    try:
        return Variant.from_spec(name if not add else "+".join([name, *add]), spec, user, shaft=machine)
    except ValueError as err:
        raise UsageError(f"{source or 'built-in variants'}: {err}") from None


def own_machine(config: Path | None) -> bool:
    """Whether ``config`` describes a machine of its own (a ``machine:`` section), not the VARM."""
    return config is not None and bool(read_config(config).get("machine"))


def chosen_variant(args: argparse.Namespace) -> tuple[Variant, Path | None]:
    """The variant the options name (--config, --effects-file, --variant, --add-effect) and the config it came
    from: --variant, else geometric on the VARM, else the config's first variant."""
    source = config_file(args.config)
    specs, user, machine = load_catalog(source, args.effects_file)
    name = args.variant or ("geometric" if "geometric" in specs and not own_machine(source) else next(iter(specs)))
    return build_variant(name, specs, user, source, args.add_effect, machine), source


def given_values(args: argparse.Namespace) -> dict[str, float]:
    """The parameter values the command line gives [SI]: --set NAME=VALUE, --eccentric-mass-g as m_e [kg]
    (refused, as the runs sheet refuses it, when it looks like kilograms: ``measurements.kg_looking``) and
    --eccentric-mass-angle-deg as angle_me [rad] (``effects.trial_angle_rad``: taken modulo 360)."""
    values = dict(args.values)
    mass_g = getattr(args, "eccentric_mass_g", None)
    if mass_g is not None:
        if "m_e" in values:
            raise UsageError("give the eccentric mass once: --eccentric-mass-g or --set m_e=..., not both")
        if kg_looking(mass_g):
            raise UsageError(f"--eccentric-mass-g {mass_g:g}: {kg_looking(mass_g)}; the option is in grams "
                             "(the runs sheet refuses such a mass too)")
        values["m_e"] = mass_g * 1e-3
    angle_deg = getattr(args, "eccentric_mass_angle_deg", None)
    if angle_deg is not None:
        if "angle_me" in values:
            raise UsageError("give the eccentric mass's angle once: --eccentric-mass-angle-deg or --set angle_me=..., "
                             "not both")
        values["angle_me"] = trial_angle_rad(angle_deg)
    return values


def variant_values(variant: Variant, args: argparse.Namespace) -> dict[str, float]:
    """The variant's complete parameter values with the command line's (``given_values``): nominal where not
    given (a note on standard error says which unknowns), a warning for a value outside its range, an error for
    one no machine can have (``check_physical``)."""
    given = given_values(args)
    try:
        values = variant.values(given)
    except ValueError as err:
        raise UsageError(str(err)) from None
    check_physical(variant, dict(args.values))  # --eccentric-mass-g: >= 0 by its parser
    warn_defaults_and_ranges(variant, given)
    return {name: float(value) for name, value in values.items()}


def check_physical(variant: Variant, given: Mapping[str, float]) -> None:
    """Values no machine can have are errors (outside a range is only a warning): a negative mass, or a
    value beyond a parameter's physical limits (``Parameter.limits``)."""
    for name, value in given.items():
        parameter = variant.model.parameters[name]
        if parameter.unit == "kg" and value < 0:
            raise UsageError(f"--set {name}={value:g}: a mass cannot be negative (kg)")
        if parameter.limits is not None and not parameter.limits[0] <= value <= parameter.limits[1]:
            lo, hi = parameter.limits
            raise UsageError(f"--set {name}={value:g}: outside its physical limits [{lo:g}, {hi:g}] {parameter.unit}")


def warn_defaults_and_ranges(variant: Variant, given: Mapping[str, float]) -> None:
    defaulted = [k for k in variant.unknown if k not in given]
    if defaulted:
        nominal = ", ".join(f"{k}={variant.model.parameters[k].nominal:g}" for k in defaulted)
        print(f"# note: unknown parameter(s) not given, nominal values used: {nominal}", file=sys.stderr)
    for name, value in given.items():
        lo, hi = variant.unknown.get(name, variant.model.parameters[name].bounds)
        if not lo <= value <= hi:
            print(f"# warning: {name}={value:g} lies outside its range [{lo:g}, {hi:g}]", file=sys.stderr)


def check_writable(path: Path, option: str) -> None:
    """An output file that cannot be written is an error before any solve."""
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, not a file")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise UsageError(f"{option} {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise UsageError(f"{option} {path}: not writable (permission denied)")


# --- the parser -----------------------------------------------------------------------------------
