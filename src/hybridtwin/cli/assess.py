"""``hybridtwin assess``: a new record (or a runs sheet of them) judged against a built twin (docs/online.md).

The assessment itself is the online stage's (``hybridtwin.online``); this is the command line around it: options,
one line per record on the console, the files written (never into the twin's folder) and the exit status."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..identify.uncertainty import ALPHA
from .common import non_negative_arg, number_arg, positive_arg


def add_assess_command(sub) -> None:
    """Register ``hybridtwin assess`` on the CLI's subparsers."""
    parser = sub.add_parser(
        "assess", help="judge a new record against a built twin: consistent, changed, or a new discrepancy",
        description="Read a record (CSV, with --rpm and --eccentric-mass-g, or --kind runup/coastdown with "
                    "--rpm-start, --rpm-end) or a runs sheet of records (TSV, the workflow's format; an optional "
                    "timestamp column orders them), check each as check-data does, and judge it against the twin "
                    "in --twin (results/<variant> of a built project; read only): consistent (chi^2/dof and its "
                    "p-value), changed (which parameters moved, with intervals and significance against the twin's "
                    "own uncertainty) or a new discrepancy (its fingerprint and the diagnosis candidates ranked). "
                    "One line per record on the console; per record a folder with its tables and a one-page "
                    "figure; the twin's trend (trend.tsv, trend.png) updated. Exit status 1 when a record could "
                    "not be assessed (named with its problem; the others are assessed), 2 on bad options.")
    parser.add_argument("record", type=Path, help="a record (CSV) or a runs sheet (TSV) of records")
    parser.add_argument("--twin", type=Path, required=True, help="the twin's folder, results/<variant> of a project")
    parser.add_argument("--rpm", type=positive_arg, default=None, help="a steady record's nominal speed [RPM]")
    parser.add_argument("--eccentric-mass-g", type=non_negative_arg, default=None,
                        help="the record's eccentric (unbalance) mass [g] (a single record)")
    parser.add_argument("--eccentric-mass-angle-deg", type=number_arg, default=None, metavar="DEG",
                        help="the trial mass's angle at the keyphasor mark [deg], from +x towards +y, the sense of "
                             "rotation (a single record; default 0; a runs sheet's column eccentric_mass_angle_deg)")
    parser.add_argument("--kind", choices=("steady", "runup", "coastdown"), default="steady",
                        help="a single record's kind (default steady)")
    parser.add_argument("--rpm-start", type=positive_arg, default=None, help="a run-up's or coast-down's nominal start")
    parser.add_argument("--rpm-end", type=positive_arg, default=None, help="... and end [RPM]")
    parser.add_argument("--run", default=None, help="a single record's id (default: its file name's stem)")
    parser.add_argument("--timestamp", default=None,
                        help="a single record's time (ISO 8601; default: the file's modification time)")
    parser.add_argument("--alpha", type=positive_arg, default=None,
                        help=f"the level of the tests (default {ALPHA:g}: beyond the noise at p < {ALPHA:g})")
    parser.add_argument("--out", type=Path, default=None,
                        help="where the assessments and the trend go (default assessments/<variant>)")
    parser.add_argument("--no-figure", action="store_true", help="no figures (faster)")
    parser.set_defaults(handler=assess_command)


def assess_command(args) -> int:
    """``hybridtwin assess``: 0 every record assessed, 1 one or more could not be, 2 bad options or twin."""
    # here, not at import: the online stage loads zarr and the twin's stores (~0.4 s), which the other commands and
    # --help do without
    from ..online.assess import ALPHA, assess
    from ..online.intake import RecordError, intake, read_sheet, record_row
    from ..online.trend import add, plot_trend, read_trend
    from ..online.twin import TwinError, load_twin

    start = time.perf_counter()
    alpha = ALPHA if args.alpha is None else args.alpha
    if not 0 < alpha < 1:
        return _error(f"--alpha {alpha:g}: a level between 0 and 1")
    try:
        twin = load_twin(args.twin)
    except TwinError as err:
        return _error(str(err))
    out = args.out or Path("assessments") / twin.name
    try:
        if args.record.suffix.lower() in (".tsv", ".txt"):
            if args.rpm is not None or args.eccentric_mass_g is not None or args.eccentric_mass_angle_deg is not None:
                return _error(f"{args.record}: a runs sheet gives each record's speed and mass; --rpm, "
                              "--eccentric-mass-g and --eccentric-mass-angle-deg are for a single record")
            rows = read_sheet(args.record)
        else:
            if args.eccentric_mass_g is None:
                return _error(f"{args.record}: a single record needs --eccentric-mass-g (0 for no added mass)")
            rows = [record_row(args.record, args.rpm, args.eccentric_mass_g, args.kind, args.rpm_start,
                               args.rpm_end, args.run, args.eccentric_mass_angle_deg or 0.0)]
    except RecordError as err:
        return _error(str(err), 1)
    failed = 0
    for row in rows:
        try:
            record = intake(twin, row, args.timestamp if len(rows) == 1 else None)
            result = assess(twin, record, alpha)
        except RecordError as err:
            print(f"hybridtwin assess: error: {err}", file=sys.stderr)
            failed += 1
            continue
        for warning in result.warnings:
            print(f"hybridtwin assess: {record.run}: warning: {warning}", file=sys.stderr)
        for band, why in record.left_out.items():
            print(f"hybridtwin assess: {record.run}: {band} left out: {why}", file=sys.stderr)
        folder = out / record.run
        result.write(folder)
        add(out / "trend.tsv", result)
        print(result.line(), flush=True)  # the verdict first: the figures take about as long again
        if not args.no_figure:
            from ..online.assess_plots import plot_assessment  # here: matplotlib, for the figure only

            _save(plot_assessment(result), folder / "figure.png")
    if not args.no_figure and (out / "trend.tsv").is_file():
        _save(plot_trend(read_trend(out / "trend.tsv"), twin.name), out / "trend.png")
    print(f"# {len(rows) - failed} of {len(rows)} record(s) assessed against {args.twin} in "
          f"{time.perf_counter() - start:.1f} s; tables, figures and the trend in {out}", file=sys.stderr)
    return 1 if failed else 0


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt  # here: matplotlib, for the figures only

    fig.savefig(path, dpi=110)
    plt.close(fig)


def _error(message: str, status: int = 2) -> int:
    print(f"hybridtwin assess: error: {message}", file=sys.stderr)
    return status
