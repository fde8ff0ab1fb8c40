"""Measured runs: read and check the runs sheet, through the one text reader every file of a data set goes
through (docs/measurement-format.md, docs/data-checks.md).

A data set is a runs sheet (TSV, one row per run: run, rpm, eccentric_mass_g,
path, role; optional sensor_range_mm, sensor_resolution_mm; extra columns
carried through) and one record (CSV) per run: time_s, one displacement
column per sensor of the machine named after it, <sensor>_mm or <sensor>_m
(also <sensor>_um, <sensor>_mils) (the VARM's sensors are x and y: time_s, x_mm,
y_mm), and an optional keyphasor column (required for a runup or coastdown:
``run_kinds``, ``order_tracking``). The records are read and checked by
``hybridtwin.data.records``.

Both files go through one text reader (``hybridtwin.data.text_table``: its conventions are in that module's
docstring), so every reader of a sheet (``hybridtwin check-data``, the workflow at parse time, every script) treats a
file the same way.
"""

from __future__ import annotations

import math

import difflib
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .record_columns import listed, numeric_column
from .text_table import (DataError, DataWarning, duplicate_values, problems_message, read_text_table,  # noqa: F401
                         require_columns)  # DataError, DataWarning, read_text_table: re-exported, the data set's errors
from .run_kinds import SWEEP_COLUMNS, BandPlan, expand_bands, has_sweep_columns, is_transient_row, sweep_cells

Array = np.ndarray

SHEET_COLUMNS = ("run", "rpm", "eccentric_mass_g", "path", "role")
REQUIRED_SHEET_COLUMNS = ("run", "rpm", "eccentric_mass_g", "path")  # role defaults to "fit"
#: optional per-run facts of the displacement sensor (empty cell: the configured or built-in default)
SENSOR_COLUMNS = ("sensor_range_mm", "sensor_resolution_mm")
#: optional: the angle of a run's trial (eccentric) mass [deg] at the keyphasor mark, from +x towards +y (the sense
#: of rotation); empty or absent: 0 (docs/measurement-format.md)
TRIAL_ANGLE_COLUMN = "eccentric_mass_angle_deg"
#: optional: which of a binary record's channels are the sensors, the keyphasor and the time, with units
#: ("x=Probe1[mm]; y=Probe2[mm]; keyphasor=Tacho"; hybridtwin.data.instrument_records)
CHANNELS_COLUMN = "channels"
_CHANNEL_ENTRY = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=\s*(.*?)\s*(?:\[\s*([^\]]*?)\s*\])?\s*$")
ROLES = ("fit", "validate")
RUN_ID = re.compile(r"^[A-Za-z0-9_-]+$")
#: run ids that pandas reads as missing values (its default NA strings that are valid ids): they would vanish from
#: the result tables
MISSING_LOOKING_IDS = ("NA", "NULL", "NaN", "None", "nan", "null")

#: an eccentric mass below this [g] (but above 0) looks like kilograms written in the grams column
KG_LOOKING_MASS_G = 0.1


def parse_channels(text) -> dict[str, tuple[str, str | None]]:
    """The sheet's channels cell as {name: (the file's channel, unit or None)}; empty or NaN: {}. ValueError
    naming the entry that is not ``<name>=<channel>[unit]`` or a name given twice."""
    if text is None or (isinstance(text, float) and np.isnan(text)) or not str(text).strip():
        return {}
    out = {}
    for entry in str(text).split(";"):
        if not entry.strip():
            continue
        found = _CHANNEL_ENTRY.match(entry)
        if not found or not found.group(2):
            raise ValueError(f"channels entry {entry.strip()!r} is not <name>=<channel> (e.g. x=Probe1 or "
                             "x=Probe1[mm]; entries separated by ';')")
        name, channel, unit = found.group(1), found.group(2), found.group(3)
        if name in out:
            raise ValueError(f"channels: {name!r} given twice")
        out[name] = (channel, unit or None)
    return out


def kg_looking(mass_g: float) -> str:
    """Why an eccentric mass of ``mass_g`` grams looks like kilograms written as grams ("0.0148 g looks like kilograms
    (14.8 g?)": above 0 and below KG_LOOKING_MASS_G), or "" when it does not: the runs sheet's check, which
    ``hybridtwin simulate --eccentric-mass-g`` and the machine commands share."""
    return f"{mass_g:g} g looks like kilograms ({mass_g * 1e3:g} g?)" if 0 < mass_g < KG_LOOKING_MASS_G else ""


# --- the runs sheet ---------------------------------------------------------------------


def read_runs(path: str | Path, check_files: bool = True, require_path: bool = True,
              require_mass: bool = False) -> pd.DataFrame:
    """Read and validate a runs sheet (docs/measurement-format.md, "The runs sheet"; docs/data-checks.md).

    Returns the sheet with ``rpm`` and ``eccentric_mass_g`` as floats (NaN where
    the mass is unknown), ``role`` lower-case and "fit" where empty or absent,
    the sensor_* columns (if any) as floats, eccentric_mass_angle_deg (if
    present) as floats (0 where empty), and an added column ``record``
    with each record's path resolved against the sheet's folder. Extra columns
    are kept. ``attrs["lines"]`` holds each row's line in the file. A sheet with
    any of the columns kind, rpm_start, rpm_end (transient records:
    ``run_kinds``) also gets ``kind`` ("steady" where empty) and ``rpm_start``,
    ``rpm_end`` as floats (NaN on steady rows); ``rpm`` may then be empty (NaN)
    on runup and coastdown rows. Without them nothing is added.

    Raises ``DataError`` listing every problem: missing or duplicated columns,
    bad or duplicate run ids (also differing only in case), non-numeric,
    non-finite or out-of-range speeds and masses (negative, or a mass that
    looks like kilograms), non-numeric or non-finite trial-mass angles, unknown roles, bad sensor facts, empty or shared
    record paths and (with ``check_files``) records that do not exist. With
    ``require_mass`` an empty mass is an error (the workflow and check-data: the
    libraries are built per speed and mass). With ``require_path`` False the
    sheet may be a bare run plan without a path column (the virtual rig's input).
    """
    path = Path(path)
    known = SHEET_COLUMNS + SENSOR_COLUMNS + SWEEP_COLUMNS + (TRIAL_ANGLE_COLUMN, CHANNELS_COLUMN)
    table, line = read_text_table(path, "\t", known)
    required = REQUIRED_SHEET_COLUMNS if require_path else REQUIRED_SHEET_COLUMNS[:3]
    if "kind" in table.columns:  # a sheet of transient records (run_kinds) may leave out rpm
        required = tuple(c for c in required if c != "rpm")
    require_columns(path, table.columns, required, known,
                     "a runs sheet needs the columns run, rpm, eccentric_mass_g, path (and optionally role)")
    if "path" not in table:
        table["path"] = ""
    if table.empty:
        raise DataError(f"{path}: the runs sheet has no runs (only a header)")
    problems: list[str] = []
    runs = table["run"]
    problems += listed("column run: empty (every run needs an id)", line[(runs == "").to_numpy()],
                        ["''"] * int((runs == "").sum()))
    bad_id = ~runs.str.fullmatch(RUN_ID.pattern) & (runs != "")
    problems += [f"line {n}, column run: {v!r} is not a valid run id (letters, digits, '-', '_' only: it becomes "
                 "a file name)" for n, v in zip(line[bad_id], runs[bad_id])]
    missing_looking = runs.isin(MISSING_LOOKING_IDS)
    problems += [f"line {n}, column run: {v!r} reads as a missing value in the result tables (a pandas default): "
                 f"name the run otherwise" for n, v in zip(line[missing_looking.to_numpy()], runs[missing_looking])]
    for run_id, lines in duplicate_values(runs[runs != ""], line[(runs != "").to_numpy()]):
        problems.append(f"lines {', '.join(map(str, lines))}, column run: duplicate run id {run_id!r}")
    for key, lines in duplicate_values(runs[runs != ""].str.lower(), line[(runs != "").to_numpy()]):
        ids = sorted({runs.iloc[i] for i in np.flatnonzero(runs.str.lower() == key)})
        if len(ids) > 1:
            problems.append(f"lines {', '.join(map(str, lines))}, column run: run ids {ids} differ only in case "
                            "(their files clash on case-insensitive file systems)")
    kind, rpm, rpm_start, rpm_end, found = sweep_cells(table, line)  # rpm as before on a sheet of steady runs
    problems += found
    problems += [f"line {n}, column rpm: {v:g} is not a positive speed" for n, v in zip(line, rpm) if v <= 0]
    mass, found = numeric_column(table["eccentric_mass_g"], "eccentric_mass_g", line, allow_empty=not require_mass,
                                  empty_hint="the libraries are built per speed and eccentric mass: write 0 "
                                             "for no added mass")
    problems += found
    problems += [f"line {n}, column eccentric_mass_g: {v:g} g is negative" for n, v in zip(line, mass) if v < 0]
    problems += [f"line {n}, column eccentric_mass_g: {kg_looking(v)}; the column is in grams"
                 for n, v in zip(line, mass) if kg_looking(v)]
    role = table["role"].str.lower() if "role" in table else pd.Series("", index=table.index)
    role = role.where(role != "", "fit")
    bad_role = ~role.isin(ROLES)
    for n, v in zip(line[bad_role], table["role"][bad_role] if "role" in table else []):
        close = difflib.get_close_matches(v.lower(), ROLES, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        problems.append(f"line {n}, column role: {v!r} is not a role: use {' or '.join(ROLES)}{hint}")
    sensors = {}
    for column in SENSOR_COLUMNS:
        if column in table:
            sensors[column], found = numeric_column(table[column], column, line, allow_empty=True)
            problems += found + [f"line {n}, column {column}: {v:g} mm is not positive"
                                 for n, v in zip(line, sensors[column]) if v <= 0]
    if TRIAL_ANGLE_COLUMN in table:  # any finite angle (taken modulo 360 by the model); empty: 0
        angle, found = numeric_column(table[TRIAL_ANGLE_COLUMN], TRIAL_ANGLE_COLUMN, line, allow_empty=True)
        problems += found
    if CHANNELS_COLUMN in table:  # its syntax here; the names against the file and the machine when it is read
        for n, cell in zip(line, table[CHANNELS_COLUMN]):
            try:
                parse_channels(cell)
            except ValueError as err:
                problems.append(f"line {n}, column {CHANNELS_COLUMN}: {err}")
    rel = table["path"]
    if require_path:
        problems += [f"line {n}, column path: empty (the record of run {r!r} is not given)"
                     for n, r, p in zip(line, runs, rel) if not p]
        # the same file however it is spelled (./records/a.csv, records//a.csv, a link to it)
        same_file = pd.Series([str((path.parent / p).resolve()) for p in rel], index=rel.index)
        given = rel != ""
        for shared, lines in duplicate_values(same_file[given], line[given.to_numpy()]):
            spelled = sorted(set(rel[same_file == shared]))
            problems.append(f"lines {', '.join(map(str, lines))}, column path: runs "
                            f"{runs[same_file == shared].tolist()} share the record "
                            f"{' = '.join(repr(s) for s in spelled)}")
    record = [path.parent / p if p else None for p in rel]
    if check_files:
        for n, r, p, f in zip(line, runs, rel, record):
            if p and f.is_dir():
                problems.append(f"line {n}, column path: {p!r} of run {r!r} is a folder, not a record ({f})")
            elif p and not f.is_file():
                problems.append(f"line {n}, column path: record {p!r} of run {r!r} does not exist (looked for {f})")
    if problems:
        raise DataError(problems_message(path, problems))
    out = table.rename(columns={"record": "sheet_record"})  # a column of the user's: kept, under another name
    out["run"], out["rpm"], out["eccentric_mass_g"], out["path"], out["role"] = runs, rpm, mass, rel, role
    for column, values in sensors.items():
        out[column] = values
    if TRIAL_ANGLE_COLUMN in table:
        out[TRIAL_ANGLE_COLUMN] = np.where(table[TRIAL_ANGLE_COLUMN] == "", 0.0, angle)
    if has_sweep_columns(table.columns):  # kind, rpm_start, rpm_end: only on a sheet that has one of them
        out["kind"], out["rpm_start"], out["rpm_end"] = kind, rpm_start, rpm_end
    out["record"] = [str(f) if f is not None else "" for f in record]
    out.attrs.update(lines=line.tolist(), source=str(path))
    return out


def trial_angles(table: pd.DataFrame) -> Array:
    """Each row's trial-mass angle [deg] as ``read_runs`` parsed it (``TRIAL_ANGLE_COLUMN``, floats, 0 where the
    cell was empty), carried by the tables made from the sheet (the harmonics table); 0 where the table has no such
    column (and on a row of a table joined with one without it). No parsing here: the sheet's cells are parsed once,
    by ``read_runs``, which names a bad one's file, line and column; a column of anything but numbers is refused."""
    if TRIAL_ANGLE_COLUMN not in table:
        return np.zeros(len(table))
    column = table[TRIAL_ANGLE_COLUMN]
    if not pd.api.types.is_numeric_dtype(column) or pd.api.types.is_bool_dtype(column):
        raise TypeError(f"column {TRIAL_ANGLE_COLUMN} holds {column.dtype} values, not the angles read_runs parses "
                        "(numbers): read the runs sheet with read_runs")
    return np.nan_to_num(column.to_numpy(float), nan=0.0)


def sheet_of(sheet: str | Path | pd.DataFrame) -> pd.DataFrame:
    """A runs sheet as the workflow reads it (``read_runs`` with the mass required), or the one already read (a
    DataFrame ``read_runs`` returned, passed on as it is: the workflow reads its sheet once per plan)."""
    return sheet if isinstance(sheet, pd.DataFrame) else read_runs(sheet, require_mass=True)


def sheet_entry(sheet: str | Path | pd.DataFrame, run: str) -> dict:
    """One run's row of a runs sheet (read as the workflow does, or already read: ``sheet_of``) as a plain dict
    (``record`` resolved, NaN -> None), or ``DataError``."""
    runs = sheet_of(sheet)
    rows = runs[runs["run"] == run]
    if rows.empty:
        raise DataError(f"{runs.attrs.get('source', sheet)}: no run {run!r} (runs: {', '.join(runs['run'])})")
    return {k: (None if pd.isna(v) else (v.item() if hasattr(v, "item") else v)) for k, v in rows.iloc[0].items()}


def runs_with_role(sheet: str | Path | pd.DataFrame, role: str) -> list[str]:
    """Runs of a runs sheet (a path, or the sheet already read: ``sheet_of``) with this role, read as check-data
    reads it (no role column: every run fits); a transient record's runs are its speed bands
    (``run_kinds.expand_bands``), with the record's role."""
    runs = expand_bands(sheet_of(sheet))
    return runs.loc[runs["role"] == role, "run"].tolist()


def check_coverage(runs: pd.DataFrame, rpm_range: Sequence[float] | None = None,
                   mass_range_g: Sequence[float] | None = None, source: str | Path = "runs sheet",
                   range_names: tuple[str, str] = ("rpm range", "eccentric mass range")) -> None:
    """Raise ``DataError`` for runs whose speed or eccentric mass lies outside the covered ranges.

    rpm_range, mass_range_g: [low, high] that the configured model libraries
    cover (inclusive); None skips that check. A range given high first is an
    error of the setting (named by ``range_names``), not of the data. A run with
    an unknown mass (NaN) is reported too when a mass range is given: it cannot
    be shown to be covered.
    """
    checks = (("rpm", rpm_range, "RPM", "speed", range_names[0]),
              ("eccentric_mass_g", mass_range_g, "g", "eccentric mass", range_names[1]))
    for _, bounds, unit, _, name in checks:
        if bounds is not None and (len(bounds) != 2 or not float(bounds[0]) <= float(bounds[1])):
            raise DataError(f"{name}: {list(bounds)} {unit} is not [low, high] with low <= high (a setting, not "
                            "the data: swap the two values)")
    problems = []
    line = runs.attrs.get("lines", list(np.arange(len(runs)) + 2))
    for column, bounds, unit, what, _ in checks:
        if bounds is None:
            continue
        lo, hi = (float(b) for b in bounds)
        values = runs[column].to_numpy(float, copy=True)
        if column == "rpm" and "kind" in runs:  # a transient row: the speeds of its fitted bands, both ends
            for i, row in enumerate(runs.to_dict("records")):
                if is_transient_row(row):
                    plan = BandPlan.of(row)
                    ends = (plan.bands[0][0], plan.bands[-1][1]) if plan.bands else (math.nan, math.nan)
                    values[i] = ends[0] if not lo <= ends[0] <= hi else ends[1]
        for n, run_id, value in zip(line, runs["run"], values):
            if np.isnan(value):
                problems.append(f"line {n}, run {run_id!r}: {what} unknown, cannot check it lies in "
                                f"[{lo:g}, {hi:g}] {unit}")
            elif not lo <= value <= hi:
                problems.append(f"line {n}, run {run_id!r}: {what} {value:g} {unit} is outside the covered "
                                f"range [{lo:g}, {hi:g}] {unit}")
    if problems:
        raise DataError(problems_message(Path(source), problems))
