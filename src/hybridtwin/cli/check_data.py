"""``hybridtwin check-data``: a runs sheet and its records checked as the workflow checks them (docs/data-checks.md).

The checks themselves are the data stage's (``hybridtwin.data.preprocessing.check_data``); this is the command line
around them: options, the config's defaults (as the workflow takes them), the printed summary and exit status."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

from ..config import data_check_settings, whirl_model
from ..data.measurements import DataError, DataWarning
from ..data.records import MIN_REVOLUTIONS, SENSOR_RANGE_MM, SENSOR_RESOLUTION_MM
from ..data.preprocessing import check_data, format_summary, has_usable_fit_run, write_tsv
from ..data.shared_problems import group_messages, group_problems
from .common import UsageError, config_file, config_machine, read_config


def add_check_data_command(sub) -> None:
    """Register ``hybridtwin check-data`` on the CLI's subparsers."""
    parser = sub.add_parser(
        "check-data", help="validate a runs sheet and its records; per-run summary (speed, noise, offsets, harmonics)",
        description="Validate a runs sheet (TSV: run, rpm, eccentric_mass_g, path, role) and every record it "
                    "lists (CSV: time_s, one column <sensor>_mm or <sensor>_m per sensor of the machine, x_mm, y_mm "
                    "on the VARM, optional keyphasor; or the file an instrument wrote, .mat, HDF5, TDMS, UFF 58, "
                    "MDF, its channels chosen in the sheet's channels column), then print per run and channel: "
                    "samples, duration, sample rate, the true speed refined from the record vs the nominal one, noise level, DC offsets, "
                    "amplitude per harmonic and saturation. Exit status 1 on invalid input.")
    parser.add_argument("runs", type=Path, help="the runs sheet (TSV); record paths are relative to its folder")
    parser.add_argument("--harmonics", type=int, default=None,
                        help="highest harmonic H analysed (default: the config's harmonics, else 5)")
    parser.add_argument("--min-revolutions", type=float, default=MIN_REVOLUTIONS,
                        help=f"fewest revolutions a record must hold (default {MIN_REVOLUTIONS})")
    parser.add_argument("--rpm-range", type=float, nargs=2, metavar=("LOW", "HIGH"), default=None,
                        help="speeds the model libraries cover [RPM]; runs outside are an error (default: the "
                             "config's coverage.rpm)")
    parser.add_argument("--mass-range-g", type=float, nargs=2, metavar=("LOW", "HIGH"), default=None,
                        help="eccentric masses the model libraries cover [g]; runs outside are an error (default: "
                             "the config's coverage.eccentric_mass_g)")
    parser.add_argument("--sensor-range-mm", type=_positive_mm, default=None,
                        help=f"sensor range [mm]: samples near +-range are clipped, beyond it impossible (default: "
                             f"the sheet's sensor_range_mm column, else the config's offline.sensor_range_mm, else "
                             f"{SENSOR_RANGE_MM:g})")
    parser.add_argument("--sensor-resolution-mm", type=_positive_mm, default=None,
                        help=f"sensor resolution [mm] (default: the sheet's sensor_resolution_mm column, else "
                             f"{SENSOR_RESOLUTION_MM:g})")
    parser.add_argument("--config", type=Path, default=None,
                        help="workflow config: its 'machine:' names the records' channels (one per sensor), its "
                             "harmonics, coverage and offline.sensor_range_mm are the checks' defaults, as in the "
                             "workflow; default ./config/config.yaml when it exists, else the VARM (channels x, y)")
    parser.add_argument("--output", type=Path, default=None, help="also write the full summary (SI units) as TSV")
    parser.add_argument("--strict", action="store_true",
                        help="exit 1 also when a run is flagged (kept out of the fit: flat, clipped, noise only, "
                             "backward whirl, spikes)")
    parser.set_defaults(handler=check_data_command)


def _positive_mm(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of mm, got {text}")
    return value


def check_data_command(args) -> int:
    """``hybridtwin check-data``: print the summary, warnings and errors; 0 valid, 1 invalid (or flagged, --strict).

    The checks are the workflow's (rule check_data): what the command line does not set comes from the config,
    as the workflow takes it (harmonics, coverage, offline.sensor_range_mm, the machine's sensors)."""
    try:
        source = config_file(args.config)
        data = read_config(source) if source is not None else {}
        machine = config_machine(source, data)
    except UsageError as err:
        print(f"hybridtwin check-data: error: {err}", file=sys.stderr)
        return 2
    settings = data_check_settings(data)  # the workflow's, from the config (its defaults without one)
    try:  # the machine's model of the 1X whirl: backward whirl flagged only where it predicts forward
        whirl = whirl_model(data, source.parent) if source is not None else None
    except (ValueError, OSError) as err:
        print(f"hybridtwin check-data: error: config file {source}: {err}", file=sys.stderr)
        return 2
    harmonics = args.harmonics if args.harmonics is not None else int(settings["harmonics"])
    if harmonics < 1:
        print(f"hybridtwin check-data: error: --harmonics must be >= 1, got {harmonics}", file=sys.stderr)
        return 2
    rpm_range = args.rpm_range or settings["coverage"].get("rpm")
    mass_range = args.mass_range_g or settings["coverage"].get("eccentric_mass_g")
    names = ("--rpm-range" if args.rpm_range else "config coverage.rpm",
             "--mass-range-g" if args.mass_range_g else "config coverage.eccentric_mass_g")
    range_mm = args.sensor_range_mm or settings["sensor_range_mm"]
    mm = {k: None if v is None else float(v) * 1e-3 for k, v in (("range", range_mm),
                                                                 ("resolution", args.sensor_resolution_mm))}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        try:
            summary, errors = check_data(args.runs, harmonics, rpm_range, mass_range, mm["range"],
                                         args.min_revolutions, mm["resolution"], names, sensors=machine,
                                         whirl=whirl)
        except DataError as err:
            print(f"hybridtwin check-data: error: {err}", file=sys.stderr)
            return 1
    print(format_summary(summary, harmonics))
    if args.output:
        try:
            write_tsv(summary, args.output)
        except OSError as err:
            print(f"hybridtwin check-data: error: cannot write {args.output}: {err.strerror}", file=sys.stderr)
            return 1
    # a problem several runs share is said once, with the runs it concerns (data/shared_problems.py)
    runs, paths = list(summary["run"]), dict(zip(summary["run"], summary["path"].astype(str)))
    for message, count in group_messages([str(w.message) for w in caught], runs, paths):
        same = f" (the same in {count - 1} more run(s))" if count > 1 else ""
        print(f"hybridtwin check-data: warning: {message}{same}", file=sys.stderr)
    for problem in group_problems(errors, paths):
        print(f"hybridtwin check-data: error: {problem.describe(len(summary))}", file=sys.stderr)
    flagged = (~summary["usable"].astype(bool)).sum() - len(errors)
    print(f"# {len(summary)} run(s): {len(summary) - len(errors) - flagged} ok, {flagged} flagged (kept out of the "
          f"fit), {len(errors)} invalid", file=sys.stderr)
    no_fit = not has_usable_fit_run(summary)
    if no_fit:  # as the workflow's check_data
        print(f"hybridtwin check-data: error: no usable fit run in {args.runs}: every run with role fit is kept out "
              "of the fit or invalid; nothing could be identified", file=sys.stderr)
    return 1 if errors or no_fit or (args.strict and flagged) else 0
