"""The kind of a run in the runs sheet: a steady run at one speed, or a transient record through a speed range
(a run-up or a coast-down; docs/measurement-format.md, "The runs sheet").

The sheet's optional columns (a user-facing contract):

- ``kind``: ``steady`` (also when the column is absent or the cell empty: one constant speed, the column
  ``rpm``), ``runup`` or ``coastdown`` (any case);
- ``rpm_start``, ``rpm_end``: the nominal sweep of a runup or coastdown row [RPM], both required there, a
  runup rising (rpm_end > rpm_start), a coastdown falling; empty on steady rows. A transient row's ``rpm`` may
  be empty (it is carried when given).

``sweep_cells`` reads these cells for ``measurements.read_runs``; a sheet without the columns reads exactly as
before (the same ``rpm`` check, the same messages, no column added). ``sheet_kinds`` gives every row's kind.
"""

from __future__ import annotations

import difflib

import numpy as np
import pandas as pd

from .record_columns import listed, numeric_column

Array = np.ndarray

STEADY, RUNUP, COASTDOWN = "steady", "runup", "coastdown"
KINDS = (STEADY, RUNUP, COASTDOWN)
TRANSIENT_KINDS = (RUNUP, COASTDOWN)
#: the sheet's optional columns of a transient record
SWEEP_COLUMNS = ("kind", "rpm_start", "rpm_end")


def has_sweep_columns(columns) -> bool:
    """Whether a sheet's header holds any of the transient columns (kind, rpm_start, rpm_end)."""
    return any(c in columns for c in SWEEP_COLUMNS)


def sweep_cells(table: pd.DataFrame, line: Array) -> tuple[Array, Array, Array, Array, list[str]]:
    """(kind, rpm, rpm_start, rpm_end, problems) of a runs sheet's cells (stripped strings, lower-case headers).

    kind: (R,) str, "steady" where the column is absent or the cell empty; rpm: floats, required (numeric, not
    empty) on steady rows exactly as without these columns, may be empty (NaN) on transient rows; rpm_start,
    rpm_end: floats (NaN on steady rows and where absent). Problems name line and column: an unknown kind; a
    transient row whose rpm_start or rpm_end is missing, not a number or not positive; a runup whose rpm_end <=
    rpm_start or a coastdown whose rpm_end >= rpm_start (equal: a sweep that never leaves one speed); a steady
    row with rpm_start or rpm_end (a transient record whose kind was forgotten).
    """
    n = len(table)
    problems: list[str] = []
    raw = table["kind"].str.lower() if "kind" in table else pd.Series([""] * n, index=table.index)
    kind = raw.where(raw != "", STEADY).to_numpy(str)
    for ln, cell in zip(line[~np.isin(kind, KINDS)], table["kind"][~np.isin(kind, KINDS)] if "kind" in table else []):
        close = difflib.get_close_matches(cell.lower(), KINDS, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        problems.append(f"line {ln}, column kind: {cell!r} is not a kind of run: use {', '.join(KINDS)} (empty: "
                        f"steady){hint}")
    transient = np.isin(kind, TRANSIENT_KINDS)
    cells = table["rpm"] if "rpm" in table else pd.Series([""] * n, index=table.index)
    rpm = np.full(n, np.nan)
    steady = kind == STEADY
    if steady.all():  # every row steady: the check (and its messages) of a sheet without kind
        rpm, found = numeric_column(cells, "rpm", line, allow_empty=False)
        problems += found
    else:  # rpm required on steady rows; on the others (transient, or of an unknown kind) it may be empty
        rpm[steady], found = numeric_column(cells[steady], "rpm", line[steady], allow_empty=False)
        problems += found
        rpm[~steady], found = numeric_column(cells[~steady], "rpm", line[~steady], allow_empty=True)
        problems += found
    ends = {}
    for column in ("rpm_start", "rpm_end"):
        ends[column] = np.full(n, np.nan)
        cells = table[column] if column in table else pd.Series([""] * n, index=table.index)
        if transient.any():
            ends[column][transient], found = numeric_column(
                cells[transient], column, line[transient], allow_empty=False,
                empty_hint="a runup or coastdown row needs its nominal sweep, rpm_start and rpm_end")
            problems += found
            bad = transient & (ends[column] <= 0)
            problems += [f"line {ln}, column {column}: {v:g} is not a positive speed"
                         for ln, v in zip(line[bad], ends[column][bad])]
        given = ~transient & (cells != "").to_numpy() & np.isin(kind, KINDS)
        problems += listed(f"column {column}: a speed on a steady row (rpm_start and rpm_end are the sweep of a "
                           "runup or coastdown: set its kind, or empty the cell)", line[given],
                           [repr(v) for v in cells[given]])
    start, end = ends["rpm_start"], ends["rpm_end"]
    valid = transient & (start > 0) & (end > 0)
    for ln, k, a, b in zip(line[valid], kind[valid], start[valid], end[valid]):
        if a == b:
            problems.append(f"line {ln}, columns rpm_start, rpm_end: a sweep that never leaves one speed ({a:g} RPM "
                            f"to {b:g} RPM): a {k} needs rpm_end {'above' if k == RUNUP else 'below'} rpm_start; a "
                            "record at one speed is a steady run (kind steady, rpm)")
        elif (k == RUNUP) != (b > a):
            problems.append(f"line {ln}, columns rpm_start, rpm_end: a {k} from {a:g} RPM to {b:g} RPM "
                            f"{'slows down' if k == RUNUP else 'speeds up'}: a {k} goes "
                            f"{'up' if k == RUNUP else 'down'} in speed (swap them, or the kind is "
                            f"{COASTDOWN if k == RUNUP else RUNUP})")
    return kind, rpm, start, end, problems


def sheet_kinds(runs: pd.DataFrame) -> pd.Series:
    """The kind of every row of a sheet read by ``read_runs``: its ``kind`` column, "steady" without one."""
    if "kind" in runs:
        return runs["kind"]
    return pd.Series(STEADY, index=runs.index, name="kind")


def is_transient(kind: str) -> bool:
    """Whether a row of this kind is a transient record (runup, coastdown)."""
    return str(kind) in TRANSIENT_KINDS
