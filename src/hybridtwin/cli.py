"""Command line: ``hybridtwin simulate | effects | variants``.

Conventions (stated once, here and in the README): amplitudes are 0-peak,
u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when the unbalance points to +x,
the shaft turns from +x towards +y; SI units, units in column names.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from .effects import Effect, builtin_effects
from .sensor import harmonics_frame, time_series_frame
from .solver import SteadyState, solve, solve_sweep
from .variants import BUILTIN_VARIANTS, EffectsFileError, Variant, load_effects_files


class UsageError(Exception):
    """Bad input from the user: printed as one clear line, exit status 2."""


def _parameter(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. k_b=2411.3), got {text!r}")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name} is not a number: {value!r}") from None


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite number: {text!r}")
    return value


def _positive(text: str) -> float:
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _harmonics(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def load_variants(config: Path | None, effects_files: Sequence[Path]) -> tuple[dict[str, Variant], dict[str, Effect]]:
    """Variants and user effects from a config file (``variants:``, ``effects_files:``) and effect files."""
    specs = dict(BUILTIN_VARIANTS)
    files = list(effects_files)
    if config is not None:
        if not config.is_file():
            raise UsageError(f"config file {config} does not exist")
        try:
            data = yaml.safe_load(config.read_text()) or {}
        except yaml.YAMLError as err:
            raise UsageError(f"config file {config} is not valid YAML: {err}") from None
        specs = dict(data.get("variants") or specs)
        files += [config.parent / f for f in data.get("effects_files") or []]
    try:
        user = load_effects_files(files)
    except EffectsFileError as err:
        raise UsageError(str(err)) from None
    try:
        variants = {name: Variant.from_spec(name, spec, user) for name, spec in specs.items()}
    except ValueError as err:
        raise UsageError(f"{config or 'built-in variants'}: {err}") from None
    return variants, user


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hybridtwin", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    sim = sub.add_parser(
        "simulate", help="periodic steady state at one operating point; sensor (node 1) harmonics as CSV",
        description="Solve the periodic steady state at one operating point and print the sensor-node "
                    "harmonics as CSV: harmonic,u_re_m,u_im_m,v_re_m,v_im_m with "
                    "u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when the unbalance points to +x.",
    )
    _common(sim)
    sim.add_argument("--rpm", type=_positive, required=True, help="rotational speed [RPM]")
    sim.add_argument("--eccentric-mass-g", type=_non_negative, default=None,
                     help="eccentric (unbalance) mass [g] (default: the variant's value, 0 g nominal)")
    sim.add_argument("--set", dest="values", type=_parameter, action="append", default=[], metavar="NAME=VALUE",
                     help="parameter value in SI units (repeatable), e.g. --set k_b=2411.3")
    sim.add_argument("--harmonics", type=_harmonics, default=5, help="highest harmonic H (default 5)")
    sim.add_argument("--method", choices=("newton", "fixed-point"), default="newton",
                     help="harmonic-balance iteration (default newton)")
    sim.add_argument("--sweep-from", type=_positive, default=None, metavar="RPM",
                     help="reach --rpm by continuation from this speed (run-up if lower, run-down if higher)")
    sim.add_argument("--sweep-step", type=_positive, default=25.0, metavar="RPM",
                     help="speed step of the continuation (default 25 RPM)")
    sim.add_argument("--output", type=Path, default=None, help="write the harmonics CSV here instead of stdout")
    sim.add_argument("--time-series", type=Path, default=None, metavar="CSV",
                     help="also write time_s,x_m,y_m at the sensor over --cycles revolutions")
    sim.add_argument("--dt", type=_positive, default=5e-4, help="time step of --time-series [s] (default 5e-4)")
    sim.add_argument("--cycles", type=_positive, default=2.0, help="revolutions in --time-series (default 2)")

    eff = sub.add_parser("effects", help="list the available physical effects and their parameters")
    _common(eff, variant=False)
    var = sub.add_parser("variants", help="describe the model variants")
    _common(var)
    from .preprocessing import add_check_data_command  # measured data (issue 4)
    from .rig import add_rig_command

    add_check_data_command(sub)
    add_rig_command(sub)
    return parser


def _common(parser: argparse.ArgumentParser, variant: bool = True) -> None:
    if variant:
        parser.add_argument("--variant", default="geometric", help="model variant (default geometric)")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML with 'variants:' (and 'effects_files:'), e.g. config/config.yaml")
    parser.add_argument("--effects-file", type=Path, action="append", default=[],
                        help="Python file defining extra Effect instances (repeatable)")


def _select(variants: dict[str, Variant], name: str) -> Variant:
    if name not in variants:
        raise UsageError(f"unknown variant {name!r} (available: {', '.join(sorted(variants))})")
    return variants[name]


def simulate(args: argparse.Namespace) -> int:
    variants, _ = load_variants(args.config, args.effects_file)
    variant = _select(variants, args.variant)
    values = dict(args.values)
    if args.eccentric_mass_g is not None:
        if "m_e" in values:
            raise UsageError("give the eccentric mass once: --eccentric-mass-g or --set m_e=..., not both")
        values["m_e"] = args.eccentric_mass_g * 1e-3
    try:
        overrides = variant.values(values)
    except ValueError as err:
        raise UsageError(str(err)) from None
    _warn_defaults_and_ranges(variant, values)
    result = _solve(variant, overrides, args)
    if not result.success[0]:
        print(f"hybridtwin simulate: failed at {args.rpm:g} RPM: {result.message[0]}", file=sys.stderr)
        return 1
    print(f"# {variant.name} at {args.rpm:g} RPM, branch {result.branch[0]}: {result.message[0]}", file=sys.stderr)
    shaft = variant.model.shaft
    harmonics_frame(result, shaft).to_csv(args.output or sys.stdout, index=False, float_format="%.9e")
    if args.time_series:
        t = np.arange(0.0, args.cycles * 2 * np.pi / result.Omega[0], args.dt)
        time_series_frame(result, shaft, t).to_csv(args.time_series, index=False, float_format="%.9e")
    return 0


def _solve(variant: Variant, values: dict, args: argparse.Namespace) -> SteadyState:
    options = {"harmonics": args.harmonics, "method": args.method}
    if args.sweep_from is None:
        return solve(variant.model.system(values, args.rpm), **options)
    n_steps = max(1, int(np.ceil(abs(args.rpm - args.sweep_from) / args.sweep_step)))
    speeds = np.linspace(args.sweep_from, args.rpm, n_steps + 1)
    sweep = solve_sweep(lambda rpm, rows: variant.model.system(values, rpm), speeds, 1,
                        direction="up" if args.rpm >= args.sweep_from else "down", **options)
    return sweep.results[-1]


def _warn_defaults_and_ranges(variant: Variant, given: dict[str, float]) -> None:
    defaulted = [k for k in variant.unknown if k not in given]
    if defaulted:
        nominal = ", ".join(f"{k}={variant.model.parameters[k].nominal:g}" for k in defaulted)
        print(f"# note: unknown parameter(s) not given, nominal values used: {nominal}", file=sys.stderr)
    for name, value in given.items():
        lo, hi = variant.unknown.get(name, variant.model.parameters[name].bounds)
        if not lo <= value <= hi:
            print(f"# warning: {name}={value:g} lies outside its range [{lo:g}, {hi:g}]", file=sys.stderr)


def list_effects(args: argparse.Namespace) -> int:
    _, user = load_variants(args.config, args.effects_file)
    for effect in (builtin_effects() | user).values():
        print(effect.describe(), end="\n\n")
    return 0


def describe_variants(args: argparse.Namespace) -> int:
    variants, _ = load_variants(args.config, args.effects_file)
    print(_select(variants, args.variant).describe())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    command = {"simulate": simulate, "effects": list_effects, "variants": describe_variants}.get(args.command)
    command = command or args.handler  # check-data, rig: registered with set_defaults(handler=...)
    try:
        return command(args)
    except UsageError as err:
        print(f"hybridtwin {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
