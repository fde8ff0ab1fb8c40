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
import math
from collections.abc import Mapping
from dataclasses import dataclass

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


# --- a transient row's speed bands: the pseudo-runs the workflow plans (hybridtwin.data.transient) ----------

#: speed band of a pseudo-run [RPM] unless the sheet's band_rpm says otherwise: narrow enough that the response
#: changes nearly linearly across it (the VARM's resonance is ~36 RPM wide at half power; the band fit carries a
#: linear term), wide enough to hold >= MIN_BAND_REVOLUTIONS at the sweep rates of a rig (10-20 RPM/s)
DEFAULT_BAND_RPM = 20.0
#: the slow-roll band, unless the sheet's slowroll_rpm gives its top: the lowest 10 % of the sweep's span (where
#: the bands start; the runout estimate reaches further when it needs to, ``slow_roll.slow_roll_band``)
SLOWROLL_SHARE = 0.1


def is_transient_row(row: Mapping) -> bool:
    """Whether a runs-sheet row is a run-up or coast-down (its ``kind``; steady when absent or empty)."""
    kind = row.get("kind", "steady")
    return isinstance(kind, str) and kind.strip().lower() in TRANSIENT_KINDS


def _number(row: Mapping, key: str, default: float) -> float:
    value = row.get(key, default)
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return default if math.isnan(value) else value


#: how a transient record's bands are fitted (the sheet's optional ``sweep_model``; docs/runups.md): "first_order",
#: the steady state corrected for the sweep rate (hybridtwin.solvers.sweep_forward), a band kept out only where even
#: that misses by more than the noise; "quasi_steady", the steady state, a band kept out where it misses
SWEEP_MODELS = ("first_order", "quasi_steady")
DEFAULT_SWEEP_MODEL = "first_order"


@dataclass(frozen=True)
class BandPlan:
    """A transient row's speed bands [RPM]: the slow-roll band and the fitted bands (lo, hi) in rising order;
    ``slowroll_given``: the slow-roll band's top is the sheet's ``slowroll_rpm`` (else the default share);
    ``sweep_model``: the forward model its bands are fitted with (the sheet's ``sweep_model``, ``SWEEP_MODELS``)."""

    run: str
    slowroll: tuple[float, float]
    bands: tuple[tuple[float, float], ...]
    slowroll_given: bool = False
    sweep_model: str = "first_order"

    @staticmethod
    def band_id(run: str, lo: float, hi: float) -> str:
        return f"{run}_b{int(round(0.5 * (lo + hi))):04d}"

    @property
    def ids(self) -> list[str]:
        return [self.band_id(self.run, lo, hi) for lo, hi in self.bands]

    @classmethod
    def of(cls, row: Mapping) -> "BandPlan":
        """From a transient row: rpm_start, rpm_end, and optionally band_rpm and slowroll_rpm."""
        start, end = _number(row, "rpm_start", math.nan), _number(row, "rpm_end", math.nan)
        lo, hi = min(start, end), max(start, end)
        width = _number(row, "band_rpm", DEFAULT_BAND_RPM)
        top = _number(row, "slowroll_rpm", lo + SLOWROLL_SHARE * (hi - lo))
        if not (math.isfinite(lo) and hi > lo and width > 0 and lo <= top < hi):
            raise ValueError(f"run {row.get('run')}: no speed bands in rpm_start {start}, rpm_end {end}, "
                             f"band_rpm {width}, slowroll_rpm {top}")
        n = int(math.floor((hi - top) / width + 1e-9))
        bands = tuple((top + k * width, top + (k + 1) * width) for k in range(n))
        given = not math.isnan(_number(row, "slowroll_rpm", math.nan))
        model = row.get("sweep_model", "")
        model = DEFAULT_SWEEP_MODEL if model is None or str(model).strip() in ("", "nan") else str(model).strip()
        if model not in SWEEP_MODELS:
            raise ValueError(f"run {row.get('run')}: sweep_model {model!r}: one of {', '.join(SWEEP_MODELS)}")
        return cls(str(row["run"]), (lo, top), bands, given, model)


def expand_bands(sheet: pd.DataFrame) -> pd.DataFrame:
    """The runs the workflow plans: steady rows as they are, each transient row replaced by its speed bands.

    A band row keeps the sheet row's columns (mass, role, path, record, extras), with ``run`` its id, ``rpm`` its
    centre, and ``parent_run``, ``band_lo_rpm``, ``band_hi_rpm`` added; steady rows get empty ones. A band id
    that is also a run of the sheet is an error."""
    if "kind" not in sheet or not sheet.apply(is_transient_row, axis=1).any():
        return sheet
    rows = []
    for _, row in sheet.iterrows():
        row = row.to_dict()
        if not is_transient_row(row):
            rows.append(row | {"parent_run": "", "band_lo_rpm": math.nan, "band_hi_rpm": math.nan})
            continue
        plan = BandPlan.of(row)
        for (lo, hi), run in zip(plan.bands, plan.ids):
            rows.append(row | {"run": run, "rpm": 0.5 * (lo + hi), "parent_run": row["run"], "band_lo_rpm": lo,
                               "band_hi_rpm": hi})
    out = pd.DataFrame(rows)
    clash = sorted(set(out["run"][out["parent_run"] != ""]) & set(sheet["run"]))
    if clash:
        raise ValueError(f"run(s) {clash} of the runs sheet have the id of a transient record's speed band "
                        "(<run>_b<RPM>): rename them")
    out.attrs = dict(sheet.attrs)
    return out
