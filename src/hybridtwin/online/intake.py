"""A new record read and checked as the workflow reads its runs, for a given twin (docs/online.md).

A record comes as a row of a runs sheet (``read_sheet``: the workflow's sheet format, check-data's reader) or as a
single file with its speed and mass given (``record_row``). It is read with the twin's sensors (a record of another
probe set fails here, naming its columns), checked and analysed as check-data and the workflow do: a steady record
by ``preprocessing.preprocess_run`` (true speed, harmonics with their sigmas), a run-up or coast-down by
``transient.track_record`` (speed bands from the keyphasor, the slow-roll runout removed). A steady record the data
checks flag (clipped, flat, noise only, ...), one outside the speeds the twin was fitted at, or a transient record
with no usable band inside them is a ``RecordError`` naming the file and the problem; a transient record's bands
outside that range are left out with a note.

Time stamps: a sheet's ``timestamp`` column (ISO 8601), else the one given on the command line, else the record
file's modification time (``timestamp_source`` says which).
"""

from __future__ import annotations

import datetime as dt
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..data.measured import RunData, run_data
from ..data.measurements import DataError, DataWarning, read_runs
from ..data.records import read_record
from ..data.preprocessing import preprocess_run
from ..data.run_kinds import is_transient_row
from ..data.transient import track_record
from .twin import Twin

#: a record's speed may exceed the twin's fitted speeds by this fraction before it is outside them (the runs'
#: true speeds scatter by ~0.1 % about the plan's; a record at a plan speed is inside)
SPEED_MARGIN = 0.01


class RecordError(ValueError):
    """A record that cannot be assessed against the twin: one message naming the file and the problem."""


@dataclass
class Intake:
    """A record analysed for the twin: its harmonics table rows (one per steady run or speed band, the workflow's
    columns), the runs assessed (``data``, inside the twin's speeds and usable), those left out with why."""

    run: str
    path: Path
    kind: str
    eccentric_mass_g: float
    timestamp: str
    timestamp_source: str
    table: pd.DataFrame
    data: list[RunData]
    left_out: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def read_sheet(path: str | Path) -> list[dict]:
    """The rows of a runs sheet (the workflow's format, read by check-data's reader), in time order when it has a
    ``timestamp`` column, else in its own order; each with its resolved ``record``."""
    try:
        sheet = read_runs(path, require_mass=True)
    except DataError as err:
        raise RecordError(str(err)) from None
    rows = [{k: (None if _missing(v) else v) for k, v in row.items()} for row in sheet.to_dict("records")]
    if "timestamp" in sheet:
        stamps = {row["run"]: _timestamp(row.get("timestamp"), f"{path}, run {row['run']}") for row in rows}
        rows.sort(key=lambda row: stamps[row["run"]] or "")
    return rows


def record_row(path: str | Path, rpm: float | None, eccentric_mass_g: float, kind: str = "steady",
               rpm_start: float | None = None, rpm_end: float | None = None, run: str | None = None,
               eccentric_mass_angle_deg: float = 0.0) -> dict:
    """A single record as a runs-sheet row: its id (``run``, default the file's stem), its speed (steady) or sweep
    (runup, coastdown), eccentric mass and, when not 0, the trial mass's angle (``eccentric_mass_angle_deg`` [deg],
    the runs sheet's column: any finite value)."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"{path}: no such record file")
    row = {"run": run or path.stem, "eccentric_mass_g": float(eccentric_mass_g), "path": path.name,
           "record": str(path), "role": "fit", "kind": kind}
    if eccentric_mass_angle_deg:
        if not math.isfinite(float(eccentric_mass_angle_deg)):
            raise RecordError(f"{path}: the trial mass's angle must be a finite number of degrees, got "
                              f"{eccentric_mass_angle_deg!r}")
        row["eccentric_mass_angle_deg"] = float(eccentric_mass_angle_deg)
    if kind == "steady":
        if rpm is None:
            raise RecordError(f"{path}: a steady record needs its speed (--rpm)")
        row["rpm"] = float(rpm)
    else:
        if rpm_start is None or rpm_end is None:
            raise RecordError(f"{path}: a {kind} needs its nominal sweep (--rpm-start, --rpm-end)")
        row |= {"rpm": math.nan, "rpm_start": float(rpm_start), "rpm_end": float(rpm_end)}
    return row


def intake(twin: Twin, row: Mapping, timestamp: str | None = None) -> Intake:
    """One sheet row's record analysed for ``twin`` (module docstring); ``RecordError`` when it cannot be
    assessed."""
    path = Path(row["record"])
    machine = twin.variant.model.shaft
    range_m = float(twin.card["sensor_range_mm"]) * 1e-3
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        try:
            record = read_record(path, machine, row.get("channels"))
            if is_transient_row(row):
                tracked = track_record(record, row, twin.harmonics, range_m)
                table, found = tracked.bands, list(tracked.warnings)
            else:
                table = preprocess_run(row, twin.harmonics, range_m, record=record)[0]
                found = []
        except DataError as err:
            raise RecordError(str(err)) from None
    found = [str(w.message) for w in caught] + found
    stamp, source = _stamp(row, timestamp, path)
    kind = str(row.get("kind") or "steady").strip().lower()
    lo, hi = twin.rpm_range
    data, left_out = [], {}
    for band in table["run"]:
        run = run_data(table, band, twin.harmonics, keyphasor=bool(twin.card["keyphasor"]),
                       channels=twin.variant.channels)
        if not run.usable:
            left_out[run.run] = run.note
        elif not (lo * (1 - SPEED_MARGIN) <= run.rpm <= hi * (1 + SPEED_MARGIN)):
            left_out[run.run] = (f"{run.rpm:.1f} RPM is outside the speeds the twin was fitted at, "
                                 f"{lo:.0f}-{hi:.0f} RPM")
        else:
            data.append(run)
    if not data:
        why = "; ".join(f"{band}: {note}" for band, note in list(left_out.items())[:3])
        what = "no usable speed band inside the twin's speeds" if kind != "steady" else "it cannot be assessed"
        raise RecordError(f"{path}: {what} ({why})")
    return Intake(str(row["run"]), path, kind, float(row["eccentric_mass_g"]), stamp, source, table, data,
                  left_out, found)


def _stamp(row: Mapping, given: str | None, path: Path) -> tuple[str, str]:
    sheet = _timestamp(row.get("timestamp"), f"{path} (its timestamp)")
    if sheet:
        return sheet, "sheet"
    if given:
        return _timestamp(given, "--timestamp"), "option"
    mtime = dt.datetime.fromtimestamp(path.stat().st_mtime, dt.timezone.utc)
    return mtime.isoformat(timespec="seconds"), "file"


def _timestamp(value, where: str) -> str | None:
    """An ISO 8601 time stamp (seconds), None for an empty cell, a ``RecordError`` for one that is not a time."""
    if value is None or _missing(value) or str(value).strip() == "":
        return None
    try:
        return pd.Timestamp(str(value).strip()).isoformat(timespec="seconds")
    except ValueError:
        raise RecordError(f"{where}: {value!r} is not a time stamp (ISO 8601, e.g. 2026-11-27T14:05:00)") from None


def _missing(value) -> bool:
    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False
