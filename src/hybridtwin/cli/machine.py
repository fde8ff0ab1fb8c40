"""``hybridtwin machine | campbell | modes | response``: the machine of the config before any data, at nominal values
(or those given with --set), as tables (TSV) and figures (PNG) in an output folder, and a summary on standard output.

- ``machine``: what was read (``Machine.describe``): segments and layers, disks, bearings and their tables, unbalance
  planes, probes, and the ROSS rotor file it came from when the config names one (``machine: {ross: ...}``).

- ``campbell``: natural frequencies, damping ratios and log decrements of every whirl branch vs speed
  (``model.campbell``, ``machine_plots.campbell_figure``), the critical speeds (1X crossings) with their damping and,
  with --operating-range, their separation margin from it.
- ``modes``: the undamped mode shapes at one speed (``machine_plots.undamped_modes``, ``mode_shape_figure``).
- ``response``: the unbalance response at every probe along a run-up and a run-down (``machine_response``), Bode
  and polar plots, every resonance peak with its amplification factor (API 684 half-power method) and, with
  --operating-range, its separation margin and the margin API 617 requires.

Tables are written with every float to full precision (``write_table``); ``read_table`` reads one back exactly
(the response's table: ``hybridtwin.report.response_plots.read_dense``). The library behind: hybridtwin.report.machine_plots and
hybridtwin.report.machine_response.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from ..data.measurements import DataError, read_runs
from ..tables import MACHINE_VIEW
from .common import (UsageError, positive_int_arg, non_negative_arg, parameter_setting, positive_arg, chosen_variant,
                     config_file, config_machine, read_config, variant_values)

# the report's modules (matplotlib, the solvers) are imported by the commands that use them, not by every command
# line: `hybridtwin simulate` starts as fast as before

#: the columns read back as text (the rest are numbers, ``pair`` and ``meets`` True/False, ``stable``
#: True/False/NaN)
TEXT_COLUMNS = MACHINE_VIEW.text
BOOLEAN_COLUMNS = ("pair", "meets")


def write_table(table: pd.DataFrame, path: Path) -> None:
    """A table as TSV, every float as its shortest exact repr (``0.0``, ``1e-05``: a float stays a float, to the
    last bit), so that ``read_table`` is its exact inverse, values and types."""
    try:
        MACHINE_VIEW.write(table, path)
    except OSError as err:
        raise UsageError(f"{path}: cannot write: {err.strerror or err}") from None


def read_table(path) -> pd.DataFrame:
    """A table ``write_table`` wrote, the same values and types (text columns as text, True/False as booleans)."""
    table = MACHINE_VIEW.read(path)
    for c in BOOLEAN_COLUMNS:
        if c in table:
            table[c] = table[c].map({True: True, False: False, "True": True, "False": False}).astype(bool)
    if "stable" in table:  # True, False or NaN (not assessed), as response_plots.read_dense reads it
        stable = table["stable"].map({True: True, False: False, "True": True, "False": False}).astype(object)
        table["stable"] = stable.where(stable.notna(), np.nan)
    return table


def add_machine_commands(sub, common) -> None:
    """Register ``campbell``, ``modes`` and ``response`` on the CLI's subparsers (``common``: the options every
    model command shares, --variant, --add-effect, --config, --effects-file)."""
    parser = sub.add_parser(
        "machine", help="what the config's machine is: shaft, layers, disks, bearings, planes, probes",
        description="The rotor the config describes (its 'machine:' section; the VARM without one) as it was read: "
                    "the shaft's segments and the layers on them, disks, bearings and seals (their coefficient "
                    "tables), unbalance planes and probes, and the ROSS rotor file it was read from when the section "
                    "names one (machine: {ross: rotor.toml, ...}).")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML with 'machine:', default ./config/config.yaml when it exists, else the VARM")
    parser.set_defaults(handler=machine_command)

    intro = ("of the config's machine (its 'machine:' section; the VARM without one) at nominal values, or those "
             "given with --set, before any data")
    parser = sub.add_parser(
        "campbell", help="natural frequencies and damping (log decrement) vs speed, critical speeds",
        description=f"The Campbell diagram {intro}: the whirl frequency, damping ratio and logarithmic decrement "
                    "(2 pi zeta / sqrt(1 - zeta^2)) of each forward and backward branch over the speeds, and the "
                    "critical speeds (crossings of the 1X line) with their damping and, with --operating-range, "
                    "their separation margin. Writes campbell.tsv, critical_speeds.tsv and campbell.png to --out; "
                    "prints the critical speeds.")
    _model_options(parser, common)
    _speed_range(parser)
    parser.add_argument("--speeds", type=positive_int_arg, default=121, help="number of speeds (default 121)")
    parser.add_argument("--modes", type=positive_int_arg, default=6, help="lowest modes followed (default 6)")
    parser.set_defaults(handler=_single_threaded(campbell_command))

    parser = sub.add_parser(
        "modes", help="undamped mode shapes at one speed",
        description=f"The undamped mode shapes {intro} at --rpm (gyroscopic coupling kept when the variant has "
                    "it): each mode's frequency and whirl, and its deflection along the shaft (the whirl "
                    "ellipse's semi-major axis, largest +1). Writes modes.tsv, mode_shapes.tsv (z_m, one column "
                    "per mode) and mode_shapes.png to --out; prints the modes.")
    _model_options(parser, common)
    parser.add_argument("--rpm", type=non_negative_arg, default=0.0, help="speed [RPM] (default 0)")
    parser.add_argument("--modes", type=positive_int_arg, default=4, help="modes drawn (default 4)")
    parser.set_defaults(handler=_single_threaded(modes_command))

    parser = sub.add_parser(
        "response", help="unbalance response (Bode, polar) with amplification factors and separation margins",
        description=f"The unbalance response {intro}: the harmonics at every probe along a run-up and a run-down "
                    "by harmonic balance with continuation (unstable stretches marked), on a grid refined around "
                    "each critical speed; every resonance peak of the 1X amplitude with its half-power points and "
                    "amplification factor AF = N_c / (N2 - N1) (API 684) and, with --operating-range, its separation "
                    "margin and the one API 617 requires for its AF. Writes response.tsv, peaks.tsv, bode.png and "
                    "polar.png to --out; prints the peaks.")
    _model_options(parser, common)
    _speed_range(parser)
    parser.add_argument("--eccentric-mass-g", type=non_negative_arg, required=True,
                        help="the unbalance: eccentric mass [g] at radius r_me on the unbalance plane")
    parser.add_argument("--speeds", type=positive_int_arg, default=121,
                        help="evenly spaced speeds (default 121), besides those refined at each critical speed")
    parser.add_argument("--harmonics", type=positive_int_arg, default=None,
                        help="highest harmonic H (default 1 for a linear model, 3 for a nonlinear one)")
    parser.set_defaults(handler=_single_threaded(response_command))


def machine_command(args: argparse.Namespace) -> int:
    """Print the config's machine as read (``Machine.describe``) and where it came from."""
    source = config_file(args.config)
    machine = config_machine(source)
    spec = read_config(source).get("machine") if source is not None else None
    if source is None or not spec:
        print(f"# the VARM (the bundled default: {'no config' if source is None else f'{source} has no machine:'})")
    elif isinstance(spec, dict) and "ross" in spec:
        print(f"# {source}: machine read from the ROSS rotor file {source.parent / spec['ross']}; unbalance planes "
              "and probes from the config")
    else:
        print(f"# {source}: machine:")
    print(machine.describe())
    print(f"  {machine.n_dof} DOFs ({machine.n_nodes} nodes x 4), shear {'on' if machine.shear else 'off'}, rotary "
          f"inertia {'on' if machine.rotary_inertia else 'off'}")
    return 0


def _single_threaded(command):
    """``command`` with BLAS on one thread (as every workflow rule): its matrices are small, and threads that
    share the cores with other work made an eigenvalue solve 8 times slower (2 cores, load 5)."""
    def run(args: argparse.Namespace) -> int:
        with threadpool_limits(1):
            return command(args)
    return run


def _model_options(parser: argparse.ArgumentParser, common) -> None:
    common(parser)
    parser.add_argument("--set", dest="values", type=parameter_setting, action="append", default=[],
                        metavar="NAME=VALUE",
                        help="parameter value in SI units (repeatable), e.g. --set k_a=2.5e7 (default: nominal)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (made if missing; default results/machine/<variant>/ in the project "
                             "folder, beside the workflow's results)")


def _speed_range(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rpm", type=non_negative_arg, nargs=2, metavar=("LOW", "HIGH"), default=None,
                        help="speed range [RPM] (default 0 to 1.25 times the top of --operating-range, else 0 to "
                             "1.25 times the fastest run of the config's runs sheet, as the report's Campbell "
                             "diagram)")
    parser.add_argument("--operating-range", type=positive_arg, nargs=2, metavar=("MIN", "MAX"), default=None,
                        help="the machine's operating speed range [RPM]: each critical speed's separation margin "
                             "from it")


def project_folder(config: Path | None) -> Path:
    """The folder the workflow runs in for ``config``: the workflow's layout is <project>/config/config.yaml, and
    its relative paths (``runs:``, results/) start at <project>; a config elsewhere: its own folder; none: here."""
    if config is None:
        return Path(".")
    return config.parent.parent if config.parent.name == "config" else config.parent


def sheet_speeds(config: Path | None) -> tuple[list[float], Path | None]:
    """The speeds [RPM] of the runs sheet the config names (``runs:``, relative to the project folder), steady
    runs' rpm and the ends of run-ups and coast-downs, and the sheet's path; ([], None) without a config or a
    ``runs:`` entry. A sheet that cannot be read is a UsageError naming it (``measurements.read_runs``'s
    message)."""
    if config is None:
        return [], None
    entry = read_config(config).get("runs")
    if not entry:
        return [], None
    path = Path(entry) if Path(entry).is_absolute() else project_folder(config) / entry
    try:
        sheet = read_runs(path, check_files=False)
    except (DataError, OSError) as err:
        raise UsageError(f"the runs sheet of {config} (runs: {entry}): {err}") from None
    speeds = pd.concat([sheet[c] for c in ("rpm", "rpm_start", "rpm_end") if c in sheet]).dropna()
    return [float(v) for v in speeds if v > 0], path


def _speeds(args: argparse.Namespace) -> tuple[float, float]:
    if args.operating_range is not None and args.operating_range[0] > args.operating_range[1]:
        raise UsageError(f"--operating-range {args.operating_range[0]:g} {args.operating_range[1]:g}: MIN above MAX")
    if args.rpm is None:
        if args.operating_range is not None:
            return 0.0, 1.25 * args.operating_range[1]
        config = config_file(args.config)
        speeds, sheet = sheet_speeds(config)
        if not speeds:
            where = (f"{config} names no runs sheet with a speed (runs:)" if config is not None else
                     "no config (./config/config.yaml or --config) names a runs sheet")
            raise UsageError(f"give the speeds: --rpm LOW HIGH, or --operating-range MIN MAX (then 0 to 1.25 MAX); "
                             f"{where}")
        hi = 1.25 * max(speeds)
        print(f"# speeds 0 to {hi:g} RPM: 1.25 times the fastest run of the runs sheet {sheet}", file=sys.stderr)
        return 0.0, hi
    lo, hi = args.rpm
    if not hi > lo:
        raise UsageError(f"--rpm {lo:g} {hi:g}: HIGH must be above LOW")
    return lo, hi


def _setup(args: argparse.Namespace):
    variant, source = chosen_variant(args)
    values = variant_values(variant, args)
    out = args.out if args.out is not None else project_folder(source) / "results" / "machine" / variant.name
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"--out {out}: cannot make the folder: {err.strerror or err}") from None
    machine = getattr(variant.model.shaft, "name", "shaft")
    where = "" if source is None else f" ({source})"
    print(f"# {variant.name} on {machine}{where}", file=sys.stderr)
    return variant, values, out, f"{variant.name} on {machine}"


def _save(figure, path: Path) -> None:
    from ..report import machine_plots as mp  # here: matplotlib (the comment above the imports)

    try:
        figure.savefig(path, dpi=100)
    except OSError as err:
        raise UsageError(f"{path}: cannot write: {err.strerror or err}") from None
    finally:
        mp.plt.close(figure)


def _print(table: pd.DataFrame, columns: list[str], empty: str) -> None:
    if table.empty:
        print(empty)
    else:
        print(table[columns].to_string(index=False, float_format=lambda v: f"{v:.6g}"))


# --- campbell ---------------------------------------------------------------------------------------------------


def campbell_command(args: argparse.Namespace) -> int:
    from ..report import machine_plots as mp  # here: matplotlib (the comment above the imports)
    from ..report import machine_response as mr  # here: matplotlib (the comment above the imports)

    lo, hi = _speeds(args)
    variant, values, out, label = _setup(args)
    speeds = np.linspace(lo, hi, args.speeds)
    try:
        figure = mp.campbell_figure(variant.model, values, speeds, n_modes=args.modes,
                                    operating=args.operating_range, title=f"Campbell diagram, {label}")
    except ValueError as err:
        raise UsageError(str(err)) from None
    table, critical = figure.campbell, figure.critical.copy()
    if args.operating_range is not None:
        critical["separation_margin_pct"] = [mr.separation_margin(r, tuple(args.operating_range))
                                             for r in critical["rpm"]]
    _save(figure, out / "campbell.png")
    write_table(table.reset_index(drop=True), out / "campbell.tsv")
    write_table(critical, out / "critical_speeds.tsv")
    columns = ["rpm", "frequency_hz", "whirl", "branch", "damping_ratio", "log_decrement"]
    columns += ["separation_margin_pct"] if args.operating_range is not None else []
    _print(critical, columns, f"no critical speed (1X crossing) between {lo:g} and {hi:g} RPM")
    unstable = table[table["log_decrement"] < 0]
    if len(unstable):
        print(f"# warning: {unstable['rpm'].nunique()} speed(s) with a negative log decrement (an unstable mode), "
              f"from {unstable['rpm'].min():g} RPM", file=sys.stderr)
    print(f"# written: {out / 'campbell.tsv'}, critical_speeds.tsv, campbell.png", file=sys.stderr)
    return 0


# --- modes ------------------------------------------------------------------------------------------------------


def modes_command(args: argparse.Namespace) -> int:
    from ..report import machine_plots as mp  # here: matplotlib (the comment above the imports)

    variant, values, out, label = _setup(args)
    try:
        figure = mp.mode_shape_figure(variant.model, values, args.rpm, n_modes=args.modes,
                                      title=f"Undamped mode shapes at {args.rpm:g} RPM, {label}")
    except ValueError as err:
        raise UsageError(str(err)) from None
    modes = figure.modes
    z, shapes = figure.shapes
    _save(figure, out / "mode_shapes.png")
    write_table(modes, out / "modes.tsv")
    write_table(pd.DataFrame({"z_m": z} | {f"mode_{k + 1}": shapes[:, k] for k in range(shapes.shape[1])}),
                out / "mode_shapes.tsv")
    shown = modes.assign(mode=modes["mode"] + 1)
    _print(shown, ["mode", "frequency_hz", "whirl", "pair"], "no oscillating mode")
    print(f"# written: {out / 'modes.tsv'}, mode_shapes.tsv, mode_shapes.png", file=sys.stderr)
    return 0


# --- response ---------------------------------------------------------------------------------------------------


def response_command(args: argparse.Namespace) -> int:
    from ..report import machine_response as mr  # here: matplotlib (the comment above the imports)
    from ..report.response_plots import write_dense  # here: matplotlib (the comment above the imports)

    lo, hi = _speeds(args)
    if lo <= 0:
        lo = 0.01 * hi  # no steady state to speak of at rest: the sweep starts at 1 % of the top
    variant, values, out, label = _setup(args)
    model = variant.model
    harmonics = args.harmonics or (3 if any(e.is_nonlinear for e in model.effects) else 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        table = mr.unbalance_response(model, values, (lo, hi), harmonics=harmonics, n_speeds=args.speeds)
    failed = table[table["stable"].isna()]
    if len(failed) == len(table):
        raise UsageError(f"no steady state at any speed: {failed['branch'].iloc[0]}")
    peaks = mr.amplification_factors(table)
    if args.operating_range is not None:
        peaks = mr.separation_margins(peaks, tuple(args.operating_range))
    write_dense(table, out / "response.tsv")
    write_table(peaks, out / "peaks.tsv")
    mass = f"{1e3 * values.get('m_e', 0.0):g} g"
    _save(mr.bode_figure(table, peaks, harmonics=range(1, min(harmonics, 3) + 1),
                         title=f"Unbalance response, {label}, {mass} (solid run-up, dashed run-down, dotted "
                               "unstable; grey: half-power band)"), out / "bode.png")
    _save(mr.polar_figure(table, title=f"Unbalance response, {label}, {mass}: 1X polar (labels: RPM)"),
          out / "polar.png")
    shown = peaks[peaks["sweep"] == "run-up"].assign(amplitude_0pk_um=lambda t: 1e6 * t["amplitude_0pk_m"])
    columns = ["channel", "rpm_peak", "amplitude_0pk_um", "rpm_half_power_low", "rpm_half_power_high",
               "amplification_factor"]
    columns += ["separation_margin_pct", "required_margin_pct", "meets"] if args.operating_range is not None else []
    _print(shown, columns, f"no resonance peak of the 1X response between {lo:g} and {hi:g} RPM")
    if len(failed):
        print(f"# warning: no steady state at {failed['rpm'].nunique()} speed(s) (left blank in response.tsv): "
              f"{failed['branch'].iloc[0]}", file=sys.stderr)
    if (table["stable"] == False).any():  # noqa: E712 (object column)
        print(f"# note: unstable stretches (dotted in bode.png; stable False in response.tsv) between "
              f"{table.loc[table['stable'] == False, 'rpm'].min():g} and "  # noqa: E712
              f"{table.loc[table['stable'] == False, 'rpm'].max():g} RPM", file=sys.stderr)  # noqa: E712
    print(f"# written: {out / 'response.tsv'} (read it with hybridtwin.report.response_plots.read_dense), "
          "peaks.tsv, bode.png, polar.png", file=sys.stderr)
    return 0

