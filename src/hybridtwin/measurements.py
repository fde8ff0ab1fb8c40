"""Measured runs: read and check the runs sheet and the records (docs/measurement-format.md).

A data set is a runs sheet (TSV, one row per run: run, rpm, eccentric_mass_g,
path, role; extra columns carried through) and one record (CSV) per run:
time_s, x_mm, y_mm (or x_m, y_m) and an optional keyphasor column.

Every check names the file, the line (the header is line 1, the first data row
line 2) or the column, and the problem. Problems that make a file unusable
raise ``DataError`` (all problems of a file at once, not just the first).
Problems that leave a run readable but suspicious (a flat channel, a clipped
channel: the laser micrometer saturates and writes flat tops at a constant
value) are returned as ``Saturation`` findings and also emitted as a
``DataWarning``, so the caller flags or excludes the run and says so; nothing
is dropped silently.

Inside, everything is SI: ``read_record`` converts millimetres to metres.
"""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

Array = np.ndarray

SHEET_COLUMNS = ("run", "rpm", "eccentric_mass_g", "path", "role")
REQUIRED_SHEET_COLUMNS = ("run", "rpm", "eccentric_mass_g", "path")  # role defaults to "fit"
ROLES = ("fit", "validate")
RUN_ID = re.compile(r"^[A-Za-z0-9_-]+$")
UNITS = {"mm": 1e-3, "m": 1.0}  # displacement column suffix -> metres per unit
_CHANNEL = re.compile(r"^([xy])_(.+)$")

#: fewest whole revolutions a record must hold (at its nominal speed) to be analysed
MIN_REVOLUTIONS = 5
#: a time step deviating from the median step by more than this fraction is "non-uniform"
UNIFORM_TOLERANCE = 0.01
#: a time step longer than this many median steps is a gap (missing samples)
GAP_FACTOR = 1.5
#: saturation: at least this many consecutive samples at a channel's extreme value form a flat top
FLAT_TOP_SAMPLES = 3
#: ... and at least this many samples sit at that extreme value in all
SATURATED_SAMPLES = 5
_MAX_LISTED = 8  # problems listed per category before "... and N more"


class DataError(ValueError):
    """Invalid measured data; the message names the file, line or column and the problem."""


class DataWarning(UserWarning):
    """A run that is kept but flagged (flat or clipped signal); the message says what and why."""


@dataclass(frozen=True)
class Record:
    """One run's record in SI units.

    time_s, x_m, y_m: (N,) arrays; keyphasor: (N,) bool or None when the file
    has no keyphasor column; unit: the displacement unit of the file ("mm" or "m").
    """

    path: Path
    time_s: Array
    x_m: Array
    y_m: Array
    keyphasor: Array | None
    unit: str

    @property
    def n_samples(self) -> int:
        return int(self.time_s.size)

    @property
    def dt_s(self) -> float:
        """Median sampling step [s]."""
        return float(np.median(np.diff(self.time_s)))

    @property
    def sample_rate_hz(self) -> float:
        return 1.0 / self.dt_s

    @property
    def duration_s(self) -> float:
        """Time covered by the samples, N * dt [s] (each sample stands for one step)."""
        return self.n_samples * self.dt_s

    def channel(self, name: str) -> Array:
        """The displacement channel "x" or "y" [m]."""
        return {"x": self.x_m, "y": self.y_m}[name]


@dataclass(frozen=True)
class Saturation:
    """A flat or clipped channel of a record.

    kind: "flat" (the whole channel is constant: no signal) or "clipped" (flat
    tops at the channel's extreme value: the sensor saturated there).
    level_m: the constant / clipping value; n_samples: samples at that value;
    n_flat_tops: separate runs of >= FLAT_TOP_SAMPLES consecutive samples there.
    """

    path: Path
    channel: str
    kind: str
    level_m: float
    n_samples: int
    n_flat_tops: int
    total_samples: int

    def describe(self) -> str:
        if self.kind == "flat":
            return (f"{self.path}: channel {self.channel} is flat (constant {self.level_m * 1e3:.4f} mm over all "
                    f"{self.total_samples} samples): no signal, the sensor is dead or disconnected")
        share = 100.0 * self.n_samples / self.total_samples
        return (f"{self.path}: channel {self.channel} is clipped at {self.level_m * 1e3:+.4f} mm: {self.n_samples} "
                f"samples ({share:.1f} %) in {self.n_flat_tops} flat top(s); the sensor saturated, so the "
                "harmonics of this run are biased")


# --- the runs sheet ---------------------------------------------------------------------


def read_runs(path: str | Path, check_files: bool = True, require_path: bool = True) -> pd.DataFrame:
    """Read and validate a runs sheet (docs/measurement-format.md, "The runs sheet").

    Returns the sheet with ``rpm`` and ``eccentric_mass_g`` as floats (NaN where
    the mass is unknown), ``role`` filled with "fit" where empty or absent, and
    an added column ``record`` with each record's path resolved against the
    sheet's folder. Extra columns are kept. Raises ``DataError`` listing every
    problem: missing columns, bad or duplicate run ids, non-numeric or
    out-of-range speeds and masses, unknown roles, empty paths and (with
    ``check_files``) records that do not exist. With ``require_path`` False the
    sheet may be a bare run plan without a path column (the virtual rig's input).
    """
    path = Path(path)
    table = _read_text_table(path, sep="\t")
    required = REQUIRED_SHEET_COLUMNS if require_path else REQUIRED_SHEET_COLUMNS[:3]
    _require_columns(path, table.columns, required, SHEET_COLUMNS,
                     "a runs sheet needs the columns run, rpm, eccentric_mass_g, path (and optionally role)")
    if "path" not in table:
        table["path"] = ""
    if table.empty:
        raise DataError(f"{path}: the runs sheet has no runs (only a header)")
    problems: list[str] = []
    line = np.arange(len(table)) + 2
    runs = table["run"].str.strip()
    bad_id = ~runs.str.fullmatch(RUN_ID.pattern)
    problems += [f"line {n}, column run: {v!r} is not a valid run id (letters, digits, '-', '_')"
                 for n, v in zip(line[bad_id], table["run"][bad_id])]
    for run_id, lines in _duplicates(runs, line):
        problems.append(f"lines {', '.join(map(str, lines))}, column run: duplicate run id {run_id!r}")
    rpm, rpm_problems = _numeric_column(table["rpm"], "rpm", line, allow_empty=False)
    problems += rpm_problems
    problems += [f"line {n}, column rpm: {v:g} is not a positive speed" for n, v in zip(line, rpm) if v <= 0]
    mass, mass_problems = _numeric_column(table["eccentric_mass_g"], "eccentric_mass_g", line, allow_empty=True)
    problems += mass_problems
    problems += [f"line {n}, column eccentric_mass_g: {v:g} g is negative" for n, v in zip(line, mass) if v < 0]
    role = table["role"].str.strip() if "role" in table else pd.Series("", index=table.index)
    role = role.where(role != "", "fit")
    bad_role = ~role.isin(ROLES)
    problems += [f"line {n}, column role: {v!r} is not a role (use {' or '.join(ROLES)})"
                 for n, v in zip(line[bad_role], role[bad_role])]
    rel = table["path"].str.strip()
    if require_path:
        problems += [f"line {n}, column path: empty (the record of run {r!r} is not given)"
                     for n, r, p in zip(line, runs, rel) if not p]
    record = [path.parent / p if p else None for p in rel]
    if check_files:
        problems += [f"line {n}, column path: record {p!r} of run {r!r} does not exist (looked for {f})"
                     for n, r, p, f in zip(line, runs, rel, record) if p and not f.is_file()]
    if problems:
        raise DataError(_format(path, problems))
    out = table.copy()
    out["run"], out["rpm"], out["eccentric_mass_g"], out["path"], out["role"] = runs, rpm, mass, rel, role
    out["record"] = [str(f) if f is not None else "" for f in record]
    return out


def sheet_entry(sheet: str | Path, run: str) -> dict:
    """One run's row of a runs sheet as a plain dict (``record`` resolved, NaN -> None), or ``DataError``."""
    runs = read_runs(sheet)
    rows = runs[runs["run"] == run]
    if rows.empty:
        raise DataError(f"{sheet}: no run {run!r} (runs: {', '.join(runs['run'])})")
    return {k: (None if pd.isna(v) else (v.item() if hasattr(v, "item") else v)) for k, v in rows.iloc[0].items()}


def check_coverage(runs: pd.DataFrame, rpm_range: Sequence[float] | None = None,
                   mass_range_g: Sequence[float] | None = None, source: str | Path = "runs sheet") -> None:
    """Raise ``DataError`` for runs whose speed or eccentric mass lies outside the covered ranges.

    rpm_range, mass_range_g: [low, high] that the configured model libraries
    cover (inclusive); None skips that check. A run with an unknown mass (NaN)
    is reported too when a mass range is given: it cannot be shown to be covered.
    """
    problems = []
    line = np.arange(len(runs)) + 2
    checks = (("rpm", rpm_range, "RPM", "speed"), ("eccentric_mass_g", mass_range_g, "g", "eccentric mass"))
    for column, bounds, unit, what in checks:
        if bounds is None:
            continue
        lo, hi = (float(b) for b in bounds)
        for n, run_id, value in zip(line, runs["run"], runs[column].to_numpy(float)):
            if np.isnan(value):
                problems.append(f"line {n}, run {run_id!r}: {what} unknown, cannot check it lies in "
                                f"[{lo:g}, {hi:g}] {unit}")
            elif not lo <= value <= hi:
                problems.append(f"line {n}, run {run_id!r}: {what} {value:g} {unit} is outside the covered "
                                f"range [{lo:g}, {hi:g}] {unit}")
    if problems:
        raise DataError(_format(Path(source), problems))


# --- a record ---------------------------------------------------------------------------


def read_record(path: str | Path) -> Record:
    """Read and validate one record (docs/measurement-format.md, "A record").

    Checks: the file exists and parses; a time_s column and one x and one y
    displacement column with a known unit (x_mm/y_mm or x_m/y_m); every cell
    numeric and present (no NaN, no empty cell); time strictly increasing and
    uniform (no gaps: a step > 1.5 median steps; no jitter beyond 1 %); a
    keyphasor column, if any, holding only 0 and 1 with at least one mark.
    Raises ``DataError`` naming the file, lines and columns.
    """
    path = Path(path)
    table = _read_text_table(path, sep=",")
    time_col, x_col, y_col, unit = _record_columns(path, table.columns)
    line = np.arange(len(table)) + 2
    if len(table) < 3:
        raise DataError(f"{path}: only {len(table)} sample(s); a record needs many revolutions of samples")
    problems: list[str] = []
    values = {}
    for column in (time_col, x_col, y_col):
        values[column], found = _numeric_column(table[column], column, line, allow_empty=False)
        problems += found
    keyphasor = None
    if "keyphasor" in table:
        keyphasor, found = _keyphasor(table["keyphasor"], line)
        problems += found
    if problems:
        raise DataError(_format(path, problems))
    time_s = values[time_col]
    problems = _time_problems(time_s, line)
    if problems:
        raise DataError(_format(path, problems))
    scale_x, scale_y = UNITS[_CHANNEL.match(x_col).group(2)], UNITS[_CHANNEL.match(y_col).group(2)]
    return Record(path, time_s, values[x_col] * scale_x, values[y_col] * scale_y, keyphasor, unit)


def check_length(record: Record, rpm: float, min_revolutions: float = MIN_REVOLUTIONS) -> None:
    """Raise ``DataError`` when the record holds fewer than ``min_revolutions`` revolutions at ``rpm``."""
    revolutions = record.duration_s * rpm / 60.0
    if revolutions < min_revolutions:
        raise DataError(
            f"{record.path}: too short: {record.n_samples} samples, {record.duration_s:.3g} s = "
            f"{revolutions:.1f} revolution(s) at {rpm:g} RPM nominal; at least {min_revolutions:g} are needed "
            "for the synchronous analysis")


def check_sampling(record: Record, rpm: float, harmonics: int) -> None:
    """Raise ``DataError`` when the sampling cannot resolve harmonic ``harmonics`` at ``rpm``.

    The per-revolution fit of harmonics 0..H needs more than 2H + 1 samples per
    revolution (and HX below the Nyquist frequency, fs / 2).
    """
    per_revolution = record.sample_rate_hz * 60.0 / rpm
    if per_revolution <= 2 * harmonics + 1:
        raise DataError(
            f"{record.path}: {record.sample_rate_hz:g} Hz sampling gives {per_revolution:.1f} samples per "
            f"revolution at {rpm:g} RPM, too few to resolve {harmonics}X (need > {2 * harmonics + 1})")


def detect_saturation(record: Record, sensor_range_m: float | None = None) -> list[Saturation]:
    """Flat and clipped channels of a record, each also emitted as a ``DataWarning``.

    Flat: the whole channel is one constant value. Clipped (flat tops): at
    either extreme of a channel, at least SATURATED_SAMPLES samples equal to
    that extreme (within 1e-7 of the channel's range) including at least one
    run of FLAT_TOP_SAMPLES consecutive ones; noise makes an unsaturated peak
    practically never repeat its exact value. With ``sensor_range_m`` any sample
    at or beyond +-range also counts as clipped.
    """
    found = []
    for name in ("x", "y"):
        values = record.channel(name)
        spread = float(np.ptp(values))
        if spread <= 1e-12 * max(1.0, float(np.abs(values).max())):
            found.append(Saturation(record.path, name, "flat", float(values[0]), values.size, 1, values.size))
            continue
        tol = 1e-7 * spread
        for extreme in (float(values.max()), float(values.min())):
            at = np.abs(values - extreme) <= tol
            beyond = sensor_range_m is not None and abs(extreme) >= sensor_range_m - tol
            tops = _flat_tops(at)
            if beyond or (at.sum() >= SATURATED_SAMPLES and tops > 0):
                found.append(Saturation(record.path, name, "clipped", extreme, int(at.sum()), tops, values.size))
    for item in found:
        warnings.warn(item.describe(), DataWarning, stacklevel=2)
    return found


# --- helpers ----------------------------------------------------------------------------


def _read_text_table(path: Path, sep: str) -> pd.DataFrame:
    """All cells as stripped strings ('' where empty), blank lines kept so line numbers hold."""
    if not path.is_file():
        raise DataError(f"{path}: file does not exist")
    try:
        table = pd.read_csv(path, sep=sep, dtype=str, keep_default_na=False, skip_blank_lines=False)
    except pd.errors.EmptyDataError:
        raise DataError(f"{path}: file is empty (no header row)") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as err:
        raise DataError(f"{path}: cannot be parsed as {'TSV' if sep == chr(9) else 'CSV'}: {err}") from None
    return table.fillna("")


def _require_columns(path: Path, have: Sequence[str], required: Sequence[str], known: Sequence[str],
                     what: str) -> None:
    missing = [c for c in required if c not in have]
    if missing:
        hints = []
        for column in missing:
            close = difflib.get_close_matches(column, [h for h in have if h not in known], n=1, cutoff=0.5)
            close = close or [h for h in have if h.strip().lower() == column]
            if close:
                hints.append(f"{column!r} (found {close[0]!r}: misnamed?)")
            else:
                hints.append(repr(column))
        raise DataError(f"{path}: line 1 (header): missing column(s) {', '.join(hints)}; {what}; "
                        f"the header has {list(have)}")


def _record_columns(path: Path, columns: Sequence[str]) -> tuple[str, str, str, str]:
    """(time column, x column, y column, unit) of a record header, or DataError."""
    _require_columns(path, columns, ("time_s",), ("time_s", "keyphasor"),
                     "a record needs time_s, x_mm and y_mm (or x_m and y_m), optionally keyphasor")
    problems, chosen = [], {}
    for axis in ("x", "y"):
        candidates = [(c, m.group(2)) for c in columns if (m := _CHANNEL.match(c)) and m.group(1) == axis]
        known = [(c, u) for c, u in candidates if u in UNITS]
        unknown = [c for c, u in candidates if u not in UNITS]
        if unknown and not known:
            problems.append(f"column {unknown[0]!r}: unknown unit {_CHANNEL.match(unknown[0]).group(2)!r} "
                            f"(use {axis}_mm or {axis}_m)")
        elif len(known) > 1:
            problems.append(f"columns {[c for c, _ in known]}: more than one {axis} displacement column")
        elif not known:
            close = difflib.get_close_matches(f"{axis}_mm", list(columns), n=1, cutoff=0.5)
            hint = f" (found {close[0]!r}: misnamed?)" if close and close[0] not in ("time_s", "keyphasor") else ""
            problems.append(f"missing column {axis}_mm (or {axis}_m){hint}")
        else:
            chosen[axis] = known[0]
    extra = [c for c in columns if c not in ("time_s", "keyphasor") and not _CHANNEL.match(c)]
    if extra:
        problems.append(f"unexpected column(s) {extra} (a record has time_s, x_mm, y_mm or x_m, y_m, keyphasor)")
    if problems:
        raise DataError(f"{path}: line 1 (header): " + "; ".join(problems) + f"; the header has {list(columns)}")
    (x_col, x_unit), (y_col, y_unit) = chosen["x"], chosen["y"]
    return "time_s", x_col, y_col, x_unit if x_unit == y_unit else f"{x_unit}/{y_unit}"


def _numeric_column(cells: pd.Series, column: str, line: Array, allow_empty: bool) -> tuple[Array, list[str]]:
    """Parse a column of strings as floats; problems name line and column."""
    text = cells.str.strip()
    values = pd.to_numeric(text, errors="coerce").to_numpy(float)
    empty = (text == "").to_numpy()
    missing_word = text.str.lower().isin(("nan", "na", "n/a", "null", "none")).to_numpy()
    problems = []
    bad = np.isnan(values) & ~empty & ~missing_word
    raw = text.to_numpy()
    gaps = (empty | missing_word) if not allow_empty else missing_word
    for mask, what in ((bad, "not a number"), (gaps, "missing value (empty or NaN)"), (np.isinf(values), "not finite")):
        problems += _listed(f"column {column}: {what}", line[mask], [repr(v) for v in raw[mask]])
    return values, problems


def _keyphasor(cells: pd.Series, line: Array) -> tuple[Array | None, list[str]]:
    text = cells.str.strip()
    ok = text.isin(("0", "1")).to_numpy()
    if not ok.all():
        return None, _listed("column keyphasor: not 0 or 1", line[~ok], [repr(v) for v in text.to_numpy()[~ok]])
    marks = (text == "1").to_numpy()
    if not marks.any():
        return None, ["column keyphasor: no mark (no 1) in the whole record; drop the column if there is no "
                      "keyphasor"]
    return marks, []


def _time_problems(t: Array, line: Array) -> list[str]:
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        return _listed("column time_s: not increasing", line[bad + 1],
                       [f"{t[i + 1]:.9g} s after {t[i]:.9g} s" for i in bad])
    median = float(np.median(step))
    gap = np.flatnonzero(step > GAP_FACTOR * median)
    problems = _listed("column time_s: gap (missing samples)", line[gap + 1],
                       [f"{step[i]:.6g} s = {step[i] / median:.1f} steps after {t[i]:.9g} s" for i in gap])
    jitter = np.flatnonzero((np.abs(step - median) > UNIFORM_TOLERANCE * median) & (step <= GAP_FACTOR * median))
    problems += _listed(f"column time_s: non-uniform step (median {median:.6g} s, tolerance "
                        f"{100 * UNIFORM_TOLERANCE:g} %)", line[jitter + 1],
                        [f"step {step[i]:.6g} s" for i in jitter])
    return problems


def _listed(problem: str, lines: Array, details: Sequence[str]) -> list[str]:
    """One message for a problem found on several lines (the first few listed, the count given)."""
    lines = list(lines)
    if not lines:
        return []
    shown = ", ".join(f"line {n} ({d})" for n, d in zip(lines[:_MAX_LISTED], details))
    more = f" ... and {len(lines) - _MAX_LISTED} more" if len(lines) > _MAX_LISTED else ""
    return [f"{problem} on {len(lines)} line(s): {shown}{more}"]


def _duplicates(runs: pd.Series, line: Array) -> list[tuple[str, list[int]]]:
    out = []
    for run_id, group in pd.Series(line, index=runs.to_numpy()).groupby(level=0, sort=False):
        if len(group) > 1:
            out.append((str(run_id), group.tolist()))
    return out


def _flat_tops(at: Array) -> int:
    """Number of runs of >= FLAT_TOP_SAMPLES consecutive True values."""
    edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int(np.sum(stops - starts >= FLAT_TOP_SAMPLES))


def _format(path: Path, problems: Sequence[str]) -> str:
    if len(problems) == 1:
        return f"{path}: {problems[0]}"
    return f"{path}: {len(problems)} problems:\n" + "\n".join(f"  - {p}" for p in problems)
