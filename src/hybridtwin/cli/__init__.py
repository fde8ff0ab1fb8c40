"""Command line: ``hybridtwin simulate | effects | variants | check-data | rig | campbell | modes | response |
assess``.

Conventions (stated once, here and in the README): amplitudes are 0-peak,
u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when the unbalance points to +x,
the shaft turns from +x towards +y; SI units, units in column names.

Every bad value on the command line ends in one line on standard error (exit status 2),
never a traceback; a point where no periodic solution is found exits with status 1 and says why (so does an
unstable one, unless ``simulate --unstable``, which prints it marked).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..model.effects import builtin_effects
from ..model.sensor import pair_dofs, sensor_harmonics, sensor_names
from ..solvers.continuation import solve_sweep
from ..solvers.solver import SteadyState, solve
from ..model.variants import Variant
from ..tables import part_column

from .assess import add_assess_command
from .docs_images import add_docs_images_command
from .check_data import add_check_data_command
from .common import (
    MAX_SAMPLES, RUN_UP_FROM_RPM, RUNDOWN_FACTOR, RUNDOWN_MARGIN_RPM, SAME_BRANCH_RTOL, UsageError, positive_int_arg,
    non_negative_arg, number_arg, parameter_setting, CommandParser, positive_arg, package_version, build_variant,
    check_writable, chosen_variant,
    config_file, load_catalog, own_machine, variant_values,
)
from .machine import add_machine_commands
from .rig import add_rig_command

#: a harmonic whose amplitude is below this fraction of the table's largest is round-off (the solver's residual is
#: ~1e-16 of the largest; a real harmonic far below 1e-12 of it is below any probe's resolution): --polar leaves
#: its phase blank
ZERO_HARMONIC_RTOL = 1e-12


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="hybridtwin",
        description="Hybrid twins of rotating machines. Commands: simulate (one operating point), effects (the "
                    "physical effects), variants (the model variants), check-data (a runs sheet and its records), "
                    "rig (virtual-rig data), campbell, modes and response (the machine before any data: natural "
                    "frequencies and damping vs speed, mode shapes, unbalance response), assess (a new record judged "
                    "against a built twin), docs-images (the README's and docs' figures from a finished run). The workflow "
                    "itself runs with `snakemake --cores 2`.",
        epilog="Run `hybridtwin COMMAND --help` for a command's options.")
    parser.add_argument("--version", action="version", version=f"hybridtwin {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, title="commands", metavar="COMMAND")

    sim = sub.add_parser(
        "simulate", help="periodic steady state at one operating point; sensor harmonics as CSV",
        description="Solve the periodic steady state at one operating point of the config's machine (its "
                    "'machine:' section; the VARM without one) and print the harmonics at its first x, y probe "
                    "pair (node 1 on the VARM; --plane for another, or every probe) as CSV: "
                    "harmonic,u_re_m,u_im_m,v_re_m,v_im_m with "
                    "u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when the unbalance points to +x "
                    "(--polar: 0-peak amplitude [um] and phase [deg] instead). When the direct solve fails, "
                    f"the point is reached by continuation by itself: a run-up from {RUN_UP_FROM_RPM:g} RPM, else "
                    "a run-down from above; standard error says which branch is reported. An unstable solution "
                    "(a Floquet multiplier outside the unit circle) exits with status 1, or with --unstable is "
                    "printed, marked.",
    )
    _common(sim)
    sim.add_argument("--rpm", type=positive_arg, required=True, help="rotational speed [RPM]")
    sim.add_argument("--eccentric-mass-g", type=non_negative_arg, default=None,
                     help="eccentric (unbalance) mass [g] (default: the variant's value, 0 g nominal)")
    sim.add_argument("--eccentric-mass-angle-deg", type=number_arg, default=None, metavar="DEG",
                     help="the eccentric mass's angle at t = 0 [deg], from +x towards +y (the sense of rotation): "
                          "its force turns by it (default 0: on +x; any finite value, taken modulo 360)")
    sim.add_argument("--set", dest="values", type=parameter_setting, action="append", default=[], metavar="NAME=VALUE",
                     help="parameter value in SI units (repeatable), e.g. --set k_b=2411.3")
    sim.add_argument("--harmonics", type=positive_int_arg, default=5, help="highest harmonic H (default 5)")
    sim.add_argument("--method", choices=("newton", "fixed-point"), default="newton",
                     help="harmonic-balance iteration (default newton)")
    sim.add_argument("--sweep-from", type=positive_arg, default=None, metavar="RPM",
                     help="reach --rpm by continuation from this speed (run-up if lower, run-down if higher); "
                          "without it: the direct solve, and continuation only if that fails")
    sim.add_argument("--sweep-step", type=positive_arg, default=25.0, metavar="RPM",
                     help="speed step of the continuation (default 25 RPM)")
    sim.add_argument("--polar", action="store_true",
                     help="print harmonic,x_amplitude_0pk_um,x_phase_deg,y_amplitude_0pk_um,y_phase_deg: "
                          "x_h(t) = A cos(h Omega t + phase), A 0-peak [um], phase [degrees]")
    sim.add_argument("--plane", default=None, metavar="NODE|PROBE|all",
                     help="the probe plane to print: a node with an x and a y probe, or a probe's name (its node); "
                          "'all': every probe, columns <probe>_re_m,<probe>_im_m (--polar: "
                          "<probe>_amplitude_0pk_um,<probe>_phase_deg; --time-series: <probe>_m) in the machine's "
                          "order (default: the first x, y pair, columns u_*, v_*)")
    sim.add_argument("--unstable", action="store_true",
                     help="print an unstable steady state too (by default an error): two more columns, "
                          "stable (True/False) and floquet_radius (the largest |Floquet multiplier|; > 1: a small "
                          "deviation grows by that factor per revolution, the machine does not stay there)")
    sim.add_argument("--output", type=Path, default=None, help="write the harmonics CSV here instead of stdout")
    sim.add_argument("--time-series", type=Path, default=None, metavar="CSV",
                     help="also write time_s,x_m,y_m at the sensor over --cycles revolutions")
    sim.add_argument("--dt", type=positive_arg, default=5e-4, help="time step of --time-series [s] (default 5e-4)")
    sim.add_argument("--cycles", type=positive_arg, default=2.0, help="revolutions in --time-series (default 2)")

    eff = sub.add_parser(
        "effects", help="list the physical effects (built in and your own) with their parameters",
        description="List every physical effect a variant can be built from: name, meaning, and each "
                    "parameter with its SI unit, nominal value and range. Built in, plus those defined in "
                    "--effects-file files and in the config's effects_files (./config/config.yaml when run "
                    "from the project root, or --config).")
    _common(eff, variant=False)
    var = sub.add_parser(
        "variants", help="list the model variants, or describe one (--variant)",
        description="List the model variants (name, description, effects, unknown parameters with their "
                    "ranges), or with --variant describe one in full (every effect and parameter). The variants "
                    "are those of ./config/config.yaml when run from the project root (or of --config), else the "
                    "built-in ones (geometric, expansion, final).")
    _common(var)
    add_check_data_command(sub)
    add_rig_command(sub)
    add_machine_commands(sub, _common)
    add_assess_command(sub)
    add_docs_images_command(sub)
    return parser


def _common(parser: argparse.ArgumentParser, variant: bool = True) -> None:
    if variant:
        parser.add_argument("--variant", default=None,
                            help="the variant to describe (default: list them all)" if parser.prog.endswith("variants")
                            else "model variant (default: geometric on the VARM, else the config's first variant)")
        parser.add_argument("--add-effect", action="append", default=[], metavar="NAME",
                            help="add this effect (built in or from --effects-file) to the variant (repeatable); "
                                 "its parameters keep their nominal values (simulate: unless --set)")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML with 'variants:' (and 'effects_files:', 'machine:'), default "
                             "./config/config.yaml when it exists, else the built-in variants on the VARM")
    parser.add_argument("--effects-file", type=Path, action="append", default=[],
                        help="Python file defining extra Effect instances (repeatable)")


# --- simulate -------------------------------------------------------------------------------------


def simulate(args: argparse.Namespace) -> int:
    variant, source = chosen_variant(args)
    machine = variant.model.shaft
    node = _plane(machine, args.plane, source)
    for option, path in (("--output", args.output), ("--time-series", args.time_series)):
        if path is not None:
            check_writable(path, option)
    if args.time_series is not None:
        samples = args.cycles * 60.0 / args.rpm / args.dt
        if samples > MAX_SAMPLES:
            raise UsageError(f"--time-series: {args.cycles:g} revolutions at dt = {args.dt:g} s are {samples:.3g} "
                             f"samples (at most {MAX_SAMPLES:.0e}): raise --dt or lower --cycles")
    values = variant_values(variant, args)
    result, notes, failures = _solve(variant, values, args)
    for note in notes:
        print(f"# {note}", file=sys.stderr)
    if result is None:
        print(f"hybridtwin simulate: failed at {args.rpm:g} RPM: {'; '.join(failures)}", file=sys.stderr)
        return 1
    stable = bool(result.stable[0])
    if not stable and not args.unstable:  # solved but unstable (solvers.floquet): not a state the machine stays in
        print(f"hybridtwin simulate: unstable at {args.rpm:g} RPM, branch {result.branch[0]}: {result.message[0]} "
              "(--unstable prints it)", file=sys.stderr)
        return 1
    where = "" if source is None else f" ({source})"
    print(f"# {variant.name}{where} at {args.rpm:g} RPM, branch {result.branch[0]}: {result.message[0]}",
          file=sys.stderr)
    if not stable:
        print(f"# UNSTABLE steady state printed (--unstable): largest Floquet multiplier |mu| = "
              f"{result.floquet_radius[0]:.4g} > 1, the machine does not stay in it", file=sys.stderr)
    table = _harmonics_table(result, machine, node, args.polar)
    if args.unstable:
        table["stable"], table["floquet_radius"] = stable, float(result.floquet_radius[0])
    _write(table, args.output, "--output", "%.6f" if args.polar else "%.9e")
    if args.time_series:
        t = np.arange(0.0, args.cycles * 2 * np.pi / result.Omega[0], args.dt)
        _write(_time_series(result, machine, node, t), args.time_series, "--time-series", "%.9e")
    return 0


def _plane(machine, plane: str | None, source: Path | None) -> int | str:
    """The node of --plane (a node number or a probe's name), "all", or the first x, y pair's node (default); a
    one-line error for a node without an x and a y probe, or no such pair at all."""
    if plane == "all":
        return "all"
    if plane is None:
        try:
            return machine.sensor_node  # the output is the first x, y probe pair's
        except ValueError as err:
            raise UsageError(f"{source}: {err}; --plane all prints every probe") from None
    pairs = {s.node for s in machine.sensors if s.direction == "x"} & {s.node for s in machine.sensors
                                                                        if s.direction == "y"}
    names = {s.name: s.node for s in machine.sensors}
    node = names.get(plane)
    if node is None:
        try:
            node = int(plane)
        except ValueError:
            raise UsageError(f"--plane {plane}: neither a node, a probe ({', '.join(names)}) nor 'all'") from None
    if node not in pairs:
        raise UsageError(f"--plane {plane}: node {node} has no x and y probe pair (pairs at node(s) "
                         f"{', '.join(map(str, sorted(pairs))) or 'none'}); --plane all prints every probe")
    return node


def _harmonics_table(result: SteadyState, machine, node: int | str, polar: bool) -> pd.DataFrame:
    """The harmonics at the x, y pair of ``node`` (columns u_*, v_*; polar x_*, y_*) or, for "all", at every probe
    (columns per probe name)."""
    if node != "all":
        return polar_frame(result, machine, node=node) if polar else harmonics_frame(result, machine, node=node)
    dofs = machine.sensor_dofs() if hasattr(machine, "sensor_dofs") else [machine.dof("u1"), machine.dof("v1")]
    Z = result.harmonics[0][:, dofs]
    table = pd.DataFrame({"harmonic": np.arange(result.H + 1)})
    for j, name in enumerate(sensor_names(machine)):
        if polar:
            table[f"{name}_amplitude_0pk_um"] = np.abs(Z[:, j]) * 1e6
            table[f"{name}_phase_deg"] = _phase_deg(Z[:, j], np.abs(Z).max())
        else:
            table[part_column(name, "re")], table[part_column(name, "im")] = Z[:, j].real, Z[:, j].imag
    return table


def _time_series(result: SteadyState, machine, node: int | str, t: np.ndarray) -> pd.DataFrame:
    if node != "all":
        return time_series_frame(result, machine, t, node=node)
    dofs = machine.sensor_dofs() if hasattr(machine, "sensor_dofs") else [machine.dof("u1"), machine.dof("v1")]
    series = result.time_series(t, dofs)[0]
    return pd.DataFrame({"time_s": t} | {f"{name}_m": series[:, j] for j, name in enumerate(sensor_names(machine))})


def _phase_deg(Z: np.ndarray, largest: float) -> np.ndarray:
    """Phases [deg] of harmonics Z, NaN (a blank cell) where a harmonic is zero to round-off (ZERO_HARMONIC_RTOL of
    ``largest``): a zero has no phase."""
    return np.where(np.abs(Z) > ZERO_HARMONIC_RTOL * largest, np.degrees(np.angle(Z)), np.nan)


def harmonics_frame(result: SteadyState, shaft, scenario: int = 0, node: int | None = None) -> pd.DataFrame:
    """One scenario's sensor harmonics as columns harmonic,u_re_m,u_im_m,v_re_m,v_im_m."""
    U, V = sensor_harmonics(result.harmonics, shaft, node)
    return pd.DataFrame({
        "harmonic": np.arange(result.H + 1),
        "u_re_m": U[scenario].real, "u_im_m": U[scenario].imag,
        "v_re_m": V[scenario].real, "v_im_m": V[scenario].imag,
    })


def time_series_frame(result: SteadyState, shaft, t: np.ndarray, scenario: int = 0,
                      node: int | None = None) -> pd.DataFrame:
    """x_m, y_m at times ``t`` [s], evaluated from the Fourier series (not resampled)."""
    xy = result.time_series(t, pair_dofs(shaft, node))[scenario]
    return pd.DataFrame({"time_s": t, "x_m": xy[:, 0], "y_m": xy[:, 1]})


def polar_frame(result: SteadyState, shaft, scenario: int = 0, node: int | None = None) -> pd.DataFrame:
    """Sensor harmonics as 0-peak amplitude [um] and phase [deg]: x_h(t) = A cos(h Omega t + phase); the phase
    blank (NaN) for a harmonic that is zero to round-off (``_phase_deg``)."""
    U, V = sensor_harmonics(result.harmonics, shaft, node)
    largest = max(np.abs(U[scenario]).max(), np.abs(V[scenario]).max())
    return pd.DataFrame({
        "harmonic": np.arange(result.H + 1),
        "x_amplitude_0pk_um": np.abs(U[scenario]) * 1e6, "x_phase_deg": _phase_deg(U[scenario], largest),
        "y_amplitude_0pk_um": np.abs(V[scenario]) * 1e6, "y_phase_deg": _phase_deg(V[scenario], largest),
    })


def _write(table: pd.DataFrame, path: Path | None, option: str, float_format: str) -> None:
    try:
        table.to_csv(path or sys.stdout, index=False, float_format=float_format)
    except OSError as err:
        raise UsageError(f"{option} {path}: cannot write: {err.strerror or err}") from None


def _solve(variant: Variant, values: dict, args: argparse.Namespace
           ) -> tuple[SteadyState | None, list[str], list[str]]:
    """The steady state at --rpm, notes for standard error, and why each attempt failed.

    --sweep-from: that continuation only. Otherwise the direct solve, and if it fails, continuation by
    itself: a run-up from ``RUN_UP_FROM_RPM`` (the rig's), then a run-down from above; the first that
    reaches the point is reported. After a run-up, the run-down is tried too: a different steady state
    there means the response is multi-valued at this speed (a note says how to get the other one).
    """
    if args.sweep_from is not None:
        result = _attempt(lambda: _sweep(variant, values, args, args.sweep_from))
        return (result, [], []) if result.success[0] else (None, [], [_failure(result, args.sweep_from)])
    result = _attempt(lambda: solve(variant.model.system(values, args.rpm), harmonics=args.harmonics,
                                    method=args.method))
    if result.success[0]:
        return result, [], []
    notes = [f"the direct solve failed ({result.message[0]}): reaching {args.rpm:g} RPM by continuation"]
    up_from = RUN_UP_FROM_RPM if args.rpm > RUN_UP_FROM_RPM else 0.5 * args.rpm
    down_from = max(RUNDOWN_FACTOR * args.rpm, args.rpm + RUNDOWN_MARGIN_RPM)
    up = _attempt(lambda: _sweep(variant, values, args, up_from))
    down = _attempt(lambda: _sweep(variant, values, args, down_from))
    if not (up.success[0] or down.success[0]):
        attempts = {"direct solve": result.message[0], f"continuation from {up_from:g} RPM": up.message[0],
                    f"continuation from {down_from:g} RPM": down.message[0]}
        if len(set(attempts.values())) == 1:
            return None, notes, [f"{result.message[0]} (direct solve, run-up and run-down alike)"]
        return None, notes, [f"{how}: {why}" for how, why in attempts.items()]
    chosen, start, other, other_start = (up, up_from, down, down_from) if up.success[0] else \
        (down, down_from, up, up_from)
    notes.append(f"reported: the steady state reached by continuation from {start:g} RPM "
                 f"(= --sweep-from {start:g}; {chosen.branch[0]})")
    if other.success[0]:
        scale = np.nanmax(np.abs(chosen.harmonics))
        if np.nanmax(np.abs(chosen.harmonics - other.harmonics)) > SAME_BRANCH_RTOL * scale:
            notes.append(f"the response is multi-valued here: continuation from {other_start:g} RPM "
                         f"({other.branch[0]}) reaches another steady state (--sweep-from {other_start:g})")
        else:
            notes.append(f"continuation from {other_start:g} RPM ({other.branch[0]}) reaches the same steady state")
    else:
        notes.append(f"continuation from {other_start:g} RPM failed: {other.message[0]}")
    return chosen, notes, []


def _sweep(variant: Variant, values: dict, args: argparse.Namespace, start_rpm: float) -> SteadyState:
    """The steady state at --rpm reached by continuation from ``start_rpm`` in steps <= --sweep-step."""
    n_steps = max(1, int(np.ceil(abs(args.rpm - start_rpm) / args.sweep_step)))
    speeds = np.linspace(start_rpm, args.rpm, n_steps + 1)
    sweep = solve_sweep(lambda rpm, rows: variant.model.system(values, rpm), speeds, 1,
                        direction="up" if args.rpm >= start_rpm else "down",
                        harmonics=args.harmonics, method=args.method)
    return sweep.results[-1]


def _attempt(run) -> SteadyState | _Failed:
    """A solve with floating-point warnings silenced (the outcome is reported) and a singular or
    non-finite system turned into a failed result, never a traceback."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return run()
        except (np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError, OverflowError) as err:
            return _Failed(f"the system cannot be solved ({type(err).__name__}: {err})")


class _Failed:
    """A solve that raised: not successful, with the reason (duck-types SteadyState's success/message/branch)."""

    def __init__(self, message: str):
        self.success, self.message, self.branch = np.array([False]), np.array([message], object), np.array(["-"])


def _failure(result, start_rpm: float) -> str:
    return f"continuation from {start_rpm:g} RPM: {result.message[0]}"


# --- effects, variants ----------------------------------------------------------------------------


def list_effects(args: argparse.Namespace) -> int:
    source = config_file(args.config)
    _, user, machine = load_catalog(source, args.effects_file)
    placed = machine.effects() if own_machine(source) else {}  # linear_bearing@a, unbalance@d1, gyroscopic, ...
    for effect in (builtin_effects() | placed | user).values():
        print(effect.describe(), end="\n\n")
    return 0


def describe_variants(args: argparse.Namespace) -> int:
    source = config_file(args.config)
    specs, user, machine = load_catalog(source, args.effects_file)
    if args.variant is not None:
        print(build_variant(args.variant, specs, user, source, args.add_effect, machine).describe())
        return 0
    if args.add_effect:
        raise UsageError("--add-effect needs --variant (the variant to add the effect to)")
    print(f"# variants of {source or 'the package (built in)'}; `hybridtwin variants --variant NAME` for details")
    for name in specs:
        variant = build_variant(name, specs, user, source, machine=machine)
        unknown = ", ".join(f"{k} [{lo:g}, {hi:g}]" for k, (lo, hi) in variant.unknown.items())
        print(f"{name}: {variant.description}\n  effects: {', '.join(e.name for e in variant.model.effects)}\n"
              f"  unknown: {unknown or 'none'}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    command = {"simulate": simulate, "effects": list_effects, "variants": describe_variants}.get(args.command)
    command = command or args.handler  # check-data, rig, campbell, ...: registered with set_defaults(handler=...)
    try:
        return command(args)
    except UsageError as err:
        print(f"hybridtwin {args.command}: error: {err}", file=sys.stderr)
        return 2

