"""The cells of a runs sheet's or a record's columns read as numbers, time stamps and keyphasor marks (the
measurements' reader, ``hybridtwin.data.measurements``; docs/measurement-format.md, docs/data-checks.md).

Each reader returns its values and the problems it found, one line per kind of problem with the file lines it
concerns (``listed``); the caller gathers every problem of a file before raising. Time stamps: a record sampled
uniformly is read on its least-squares time base t0 + n dt (``uniform_time_base``), free of the rounding of the
written stamps and of small timing jitter; gaps, repeats and reversals are problems (``time_problems``). The
keyphasor: any two-level signal, its marks at the rising edges (``keyphasor_marks``).
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from ..tables import (harmonic_column, harmonic_stem,  # noqa: F401 (re-exported: the columns named once)
                      run_harmonics, wide_harmonics)

Array = np.ndarray

#: a time stamp further than this fraction of a step (plus the rounding of the written stamps) off the uniform
#: time base t0 + n dt is "non-uniform"; closer, it is timing jitter of a uniformly sampled record
#: (``time_problems`` says why 5 %)
UNIFORM_TOLERANCE = 0.05
#: a time step longer than this many median steps is a gap (missing samples)
GAP_FACTOR = 1.5
_MAX_LISTED = 8  # problems listed per category before "... and N more"
_MISSING_WORDS = ("nan", "na", "n/a", "null", "none")
_NUMBER_WITH_UNIT = r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*[A-Za-z%]+"
_NOT_PLAIN_NUMBERS = re.compile(r"[^0-9eE+\-., \t\n]")


def fast_numeric_table(text: str, sep: str) -> tuple[pd.DataFrame, Array] | None:
    """A table every cell of which is a finite number, read at the C parser's speed: (float columns named as
    ``text_table.read_text_table`` names them, lower case; the file line of each row), or None wherever anything
    needs the careful reader (a quote, a blank line, a line with another number of cells, an empty, missing or
    non-numeric cell, a repeated or unnamed column): that reader then finds it and says so, with its lines.
    ``text``: the decoded file with its line ends made "\n". The C parser's numbers are ``numeric_column``'s
    (``pd.to_numeric``) bit for bit (tests/test_measurements.py checks it on several number formats)."""
    body = text.rstrip("\n")
    if '"' in text or not body or body.startswith("\n") or "\n\n" in body:
        return None
    end = body.find("\n")
    if end < 0:
        return None
    header = [h.strip().lower() for h in body[:end].split(sep)]
    rows = body.count("\n")
    if len(header) < 2 or "" in header or len(set(header)) != len(header) or \
            body.count(sep) != (len(header) - 1) * (rows + 1):
        return None
    if _NOT_PLAIN_NUMBERS.search(body, end):  # only digits, signs, points and exponents below the header: the C
        return None  # parser also reads true/false (and 1,000-like forms) as numbers, which the careful reader refuses
    try:
        table = pd.read_csv(io.StringIO(body), sep=sep, header=0, names=header, dtype=np.float64, engine="c",
                            skip_blank_lines=False, index_col=False)
    except (ValueError, pd.errors.ParserError):
        return None
    if len(table) != rows or not np.isfinite(table.to_numpy()).all():
        return None
    return table, np.arange(2, rows + 2)


def numeric_column(cells: pd.Series, column: str, line: Array, allow_empty: bool,
                    empty_hint: str = "") -> tuple[Array, list[str]]:
    """Parse a column of stripped strings as floats; problems name line and column."""
    text = cells.astype(str)
    values = pd.to_numeric(text, errors="coerce").to_numpy(float)
    empty = (text == "").to_numpy()
    missing_word = text.str.lower().isin(_MISSING_WORDS).to_numpy()
    comma = text.str.contains(",", regex=False).to_numpy()
    with_unit = text.str.fullmatch(_NUMBER_WITH_UNIT).to_numpy(bool) & ~missing_word
    other = np.isnan(values) & ~empty & ~missing_word & ~comma & ~with_unit
    raw = text.to_numpy()
    gaps = (empty | missing_word) if not allow_empty else missing_word
    hint = f"; {empty_hint}" if empty_hint else ""
    problems = []
    for mask, what in ((comma, "decimal comma or thousands separator (write 25.9, or 1000)"),
                       (with_unit, "a unit inside the number (write the number only: the unit is in the column "
                                   "name)"),
                       (other, "not a number"), (gaps, f"missing value (empty or NaN{hint})"),
                       (np.isinf(values), "not finite")):
        problems += listed(f"column {column}: {what}", line[mask], [repr(v) for v in raw[mask]])
    return values, problems


def keyphasor_column(cells: pd.Series, line: Array) -> tuple[Array | None, list[str]]:
    """The marks of a keyphasor column: True on the first sample of each high pulse (``keyphasor_marks``).

    Any two-level signal is a keyphasor: 0/1 written as integers or floats, true/false (any case), a 0/5 V
    TTL signal or any other low/high pair of numbers; the higher level is "high". A cell that is neither a
    finite number nor true/false, or more than two levels (an analogue tach signal), is a problem.
    """
    text = cells.astype(str).str.strip()
    words = text.str.lower().map({"true": 1.0, "false": 0.0})
    levels = pd.to_numeric(text, errors="coerce").to_numpy(float)
    levels = np.where(words.notna().to_numpy(), words.to_numpy(float), levels)
    accepted = ("a two-level signal: 0/1 (or 0.0/1.0, true/false), 0/5 V or any other low/high pair of numbers, "
                "the marks at its rising edges")
    bad = ~np.isfinite(levels)
    if bad.any():
        return None, listed(f"column keyphasor: not a level of {accepted}", line[bad],
                             [repr(v) for v in text.to_numpy()[bad]])
    distinct = np.unique(levels)
    if distinct.size > 2:
        first = np.sort(np.unique(levels, return_index=True)[1])[:3]  # the first three levels in the file
        shown = ", ".join(f"{text.iloc[i]!r} (line {line[i]})" for i in first)
        return None, [f"column keyphasor: {distinct.size} distinct levels ({shown}, ...), an analogue signal; a "
                      f"keyphasor column holds {accepted} (threshold an analogue tach signal into 0/1)"]
    if distinct.size < 2:
        return None, [f"column keyphasor: no mark (one level, {text.iloc[0]!r}, throughout) in the whole record; "
                      "drop the column if there is no keyphasor"]
    marks = keyphasor_marks(levels > distinct[0])
    if not marks.any():
        return None, ["column keyphasor: no mark (no rising edge: only a pulse already high on the first sample) in "
                      "the whole record; drop the column if there is no keyphasor"]
    return marks, []


def keyphasor_marks(high: Array) -> Array:
    """The once-per-turn marks of a two-level keyphasor signal: True on the first sample of each high pulse.

    high: (N,) bool, the signal at its high level. A pulse already high on the first sample began before
    the record unless it is as wide as the record's other pulses (their median width; kept when it is the
    only pulse): its rising edge was not recorded and it is left out (a missed mark, which the phase
    origin's regression tolerates). Marks written one sample wide (0/1) are their own rising edges.
    """
    high = np.asarray(high, bool)
    edges = np.diff(np.concatenate(([0], high.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    marks = np.zeros(high.size, bool)
    marks[starts] = True
    if starts.size > 1 and starts[0] == 0 and stops[0] - starts[0] < np.median(stops[1:] - starts[1:]):
        marks[0] = False
    return marks


def time_problems(t: Array, line: Array) -> list[str]:
    """Problems of a record's time stamps: not increasing, gaps, or steps not uniform (``uniform_time_base``).

    A record is uniformly sampled when every stamp lies within the tolerance of ``uniform_time_base``: half
    a unit of the last decimal the stamps are written with (``time_resolution``: 0.00039 s and 0.0004 s
    are both 1/2560 s written with 5 decimals) plus UNIFORM_TOLERANCE = 5 % of a step of random timing
    jitter. Why 5 %: a missing or extra sample moves every later stamp by a whole step and a gap is a step
    longer than GAP_FACTOR = 1.5 steps, so jitter within 5 % is never mistaken for either; and the analysis
    then uses the uniform base, so if the samples really were taken at the jittered instants each errs by
    at most 5 % of the signal's change over one step, at random: noise, not a bias of the harmonics (jitter
    within +-5 % has sigma_t <= 2.9 % of a step; harmonic h is attenuated by exp(-(h Omega sigma_t)^2 / 2),
    1 - 3e-4 for 5X at 3000 RPM sampled at 2 kHz).
    A gap is a step longer than GAP_FACTOR median steps plus the stamps' resolution.
    """
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        return listed("column time_s: not increasing", line[bad + 1],
                       [f"{t[i + 1]:.9g} s after {t[i]:.9g} s" for i in bad])
    median = float(np.median(step))
    resolution = time_resolution(t)
    gap = np.flatnonzero(step > GAP_FACTOR * median + resolution)
    if gap.size:  # the uniformity is judged once the gaps are mended (a gap shifts every later stamp)
        return listed("column time_s: gap (missing samples)", line[gap + 1],
                       [f"{step[i]:.6g} s = {step[i] / median:.1f} steps after {t[i]:.9g} s" for i in gap])
    base = uniform_time_base(t)
    dt = (base[-1] - base[0]) / (t.size - 1)
    tolerance = 0.5 * resolution + UNIFORM_TOLERANCE * dt
    off = t - base
    jitter = np.flatnonzero(np.abs(off) > tolerance)
    rounding = f"half a unit of the last decimal written, {0.5 * resolution:.3g} s, plus " if resolution else ""
    return listed(f"column time_s: non-uniform step (dt {dt:.6g} s, the least-squares fit t0 + n dt; tolerance "
                   f"{rounding}{100 * UNIFORM_TOLERANCE:g} % of a step: {tolerance:.3g} s)", line[jitter],
                   [f"{t[i]:.9g} s is {off[i]:+.3g} s = {100 * off[i] / dt:+.1f} % of a step off" for i in jitter])


def time_resolution(t: Array) -> float:
    """The unit of the last decimal the time stamps are written with [s], inferred from their values.

    The largest 10^-d such that every stamp is a whole multiple of it (to the stamps' floating-point
    precision): stamps written with 5 decimals give 1e-5 s (their rounding is at most half of it). Stamps
    that need more decimals than a double resolves give that precision (about 1e-15 s for stamps of
    seconds).
    """
    t = np.asarray(t, float)
    size = float(np.abs(t).max(initial=0.0))
    for decimals in range(0, 19):
        scaled = t * 10.0**decimals
        precision = 4 * np.finfo(float).eps * size * 10.0**decimals
        if np.all(np.abs(scaled - np.rint(scaled)) <= max(precision, 1e-9)):
            return 10.0**-decimals
    return 0.0


#: stamps within this fraction of a step of the uniform base are kept as written (``uniform_time_base``)
UNCHANGED_STAMPS = 1e-9


def uniform_time_base(t: Array) -> Array:
    """The uniform time base t0 + n dt (n = 0 .. N-1) nearest to the time stamps t in least squares [s].

    A uniformly sampled record's stamps differ from it by their rounding and timing jitter only; the
    analysis uses it in their place (``read_record``). Computed about the first stamp, so that stamps of
    epoch seconds keep their precision.
    """
    n = np.arange(t.size, dtype=float)
    n_mean = n.mean()
    since = t - t[0]
    dt = float(np.dot(n - n_mean, since - since.mean()) / np.dot(n - n_mean, n - n_mean))
    base = t[0] + (since.mean() + dt * (n - n_mean))
    # stamps already uniform to float precision (written with enough digits) are kept as they are: the base
    # would differ from them by round-off only (4e-16 s on the bundled records), and the analysis of such a
    # record stays bit for bit what it was
    return t if np.max(np.abs(base - t), initial=0.0) <= UNCHANGED_STAMPS * abs(dt) else base


def listed(problem: str, lines: Array, details: Sequence[str]) -> list[str]:
    """One message for a problem found on several lines (the first few listed, the count given)."""
    lines = list(lines)
    if not lines:
        return []
    shown = ", ".join(f"line {n} ({d})" for n, d in zip(lines[:_MAX_LISTED], details))
    more = f" ... and {len(lines) - _MAX_LISTED} more" if len(lines) > _MAX_LISTED else ""
    return [f"{problem} on {len(lines)} line(s): {shown}{more}"]


# --- the names of the harmonics table's columns, and the sheet's columns carried into it -----------------


def highest_harmonic(table, channels: Sequence[str]) -> int:
    """The highest h such that every channel has its harmonics 1..h (columns <channel><h>_re_m) in ``table``; 0
    when the first is missing."""
    h = 0
    while channels and all(harmonic_column(c, h + 1, "re") in table for c in channels):
        h += 1
    return h


def split_stem(stem: str) -> tuple[str, int]:
    """``harmonic_stem``'s inverse: (channel, h) of a stem (x1 -> (x, 1), x1_1 -> (x1, 1))."""
    if "_" in stem:
        channel, h = stem.rsplit("_", 1)
        if channel[-1:].isdigit():
            return channel, int(h)
    channel = stem.rstrip("0123456789")
    return channel, int(stem[len(channel):])


def carried_columns(sheet_row: Mapping, analysed: Iterable[str]) -> dict:
    """The runs sheet's columns carried into a result row: all but the resolved record path, and one named like a
    column of the analysis (note, usable, unit, keyphasor, status, ...) as sheet_<name>, not overwritten."""
    taken = set(analysed)
    return {(f"sheet_{k}" if k in taken else k): v for k, v in sheet_row.items() if k != "record"}


def harmonic_columns(names: Sequence[str], harmonics: int, X, sigma, noise, complex_parts: bool = True) -> dict:
    """The harmonics table's per-channel columns of one row (``preprocessing.run_row``, a transient band's row):
    noise_<c>_m, offset_<c>_m, offset_<c>_sigma_m, then per channel and harmonic h = 1..H its real and imaginary
    part (``complex_parts``), amplitude and sigma: the wide view of the run's long harmonic table
    (``tables.run_harmonics``, ``tables.wide_harmonics``). X, sigma: (C, H+1) (h = 0 the offset), noise (C,); None:
    NaN."""
    nan = float("nan")
    row = {}
    for i, name in enumerate(names):
        row[f"noise_{name}_m"] = noise[i] if X is not None else nan
    for i, name in enumerate(names):
        row[f"offset_{name}_m"] = X[i, 0].real if X is not None else nan
        row[f"offset_{name}_sigma_m"] = sigma[i, 0] if X is not None else nan
    if X is None:
        X, sigma = np.full((len(names), harmonics + 1), complex(nan, nan)), np.full((len(names), harmonics + 1), nan)
    wide = wide_harmonics(run_harmonics("", names, X[:, :harmonics + 1], sigma[:, :harmonics + 1]))
    parts = wide.columns[1:] if complex_parts else [c for c in wide.columns[1:]
                                                    if not c.endswith(("_re_m", "_im_m"))]
    return row | dict(wide.loc[0, parts].items())
