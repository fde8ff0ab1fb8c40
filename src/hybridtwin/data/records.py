"""One run's record: read and check it (docs/measurement-format.md, "A record"; docs/data-checks.md).

A record (CSV) holds time_s, one displacement column per sensor of the machine named after it, <sensor>_mm or
<sensor>_m (also <sensor>_um, <sensor>_mils) (the VARM's sensors are x and y: time_s, x_mm, y_mm), and an optional
keyphasor column (required for a runup or coastdown: ``run_kinds``, ``order_tracking``). It goes through the text
reader every file of a data set goes through (``text_table.read_text_table``: its conventions are in that
module's docstring), and its problems are ``text_table.DataError`` (the file unusable) or findings emitted as a
``text_table.DataWarning`` (a flat or clipped channel: ``detect_saturation``). The runs sheet that lists the
records is ``hybridtwin.data.measurements``'.

Inside, everything is SI: ``read_record`` converts millimetres (micrometres, mils) to metres.
"""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from ..model.probes import DEFAULT_ANGLE_DEG, ProbeAngleError, plane_xy
from ..model.sensor import DEFAULT_CHANNELS, machine_order, sensor_pairs
from .instrument_records import instrument_table, is_instrument_file
from .text_table import DataError, DataWarning, decode_text, problems_message, read_text_table, require_columns
from .record_columns import (fast_numeric_table, keyphasor_column, keyphasor_marks, numeric_column, time_problems,
                             uniform_time_base)

Array = np.ndarray


#: displacement column suffix -> metres per unit (a mil is a thousandth of an inch, 25.4 um)
UNITS = {"mm": 1e-3, "m": 1.0, "um": 1e-6, "mils": 25.4e-6}
RECORD_COLUMNS = ("time_s", "keyphasor")

#: the paper's lasers: +-14 mm measuring range (sensor_range_mm) ...
SENSOR_RANGE_MM = 14.0
#: ... and the smallest displacement step they resolve (sensor_resolution_mm)
SENSOR_RESOLUTION_MM = 1e-3

#: fewest whole revolutions a record must hold (at its nominal speed) to be analysed
MIN_REVOLUTIONS = 5
#: saturation: at least this many consecutive samples at a channel's extreme value form a flat top
FLAT_TOP_SAMPLES = 3
#: ... and at least this many samples sit at that extreme value (or on the sensor's rail) in all
SATURATED_SAMPLES = 5
#: ... and, on a channel written at a coarse resolution, more than this many times the samples of the next level
#: inward: a clipped top piles samples up at one level; a sine's unclipped peak holds at most ~1.7 times the next
#: level's samples (its time within one step of the peak, sqrt(2), against the next step's, 2 - sqrt(2)); a sine
#: clipped at 99.5 % of its amplitude, written in steps of 1/470 of it, holds 4.7 times
CLIP_PILEUP = 3.0
#: the rail: samples within max(RAIL_RESOLUTIONS resolutions, RAIL_FRACTION of the range) of +-range
RAIL_RESOLUTIONS = 10.0
RAIL_FRACTION = 0.002


@dataclass(frozen=True)
class Sensor:
    """What the displacement sensor can report: +-range_m and the smallest step resolution_m [m]."""

    range_m: float = SENSOR_RANGE_MM * 1e-3
    resolution_m: float = SENSOR_RESOLUTION_MM * 1e-3

    @property
    def rail_band_m(self) -> float:
        """Samples within this of +-range are on the rail (saturated), beyond range + band impossible."""
        return max(RAIL_RESOLUTIONS * self.resolution_m, RAIL_FRACTION * self.range_m)

    @classmethod
    def for_run(cls, row, range_m: float | None = None, resolution_m: float | None = None) -> Sensor:
        """The sensor of one runs-sheet row: its sensor_* cells, else the given defaults, else the built-in."""
        def value(column: str, default: float | None, builtin: float) -> float:
            cell = row.get(column) if hasattr(row, "get") else None
            if cell is not None and not pd.isna(cell):
                return float(cell) * 1e-3
            return float(default) if default is not None else builtin

        return cls(value("sensor_range_mm", range_m, cls.range_m),
                   value("sensor_resolution_mm", resolution_m, cls.resolution_m))


@dataclass(frozen=True)
class Record:
    """One run's record in SI units.

    time_s: (N,); channels: {sensor name: (N,) displacement [m]} in the
    machine's sensor order (the VARM: x, y); keyphasor: (N,) bool or None when
    the file has no keyphasor column; units: the displacement unit of each
    channel in the file ("mm", "m", "um" or "mils"; one string: every channel's); lines: (N,)
    the file line of each sample (None for a record made in memory: line =
    index + 2); pairs: (x channel index, y channel index) of each probe pair at
    one node (its orbit; the backward-whirl check reads the first), default the
    pair (x, y) when both are channels.
    """

    path: Path
    time_s: Array
    channels: Mapping[str, Array]
    keyphasor: Array | None
    units: Mapping[str, str] | str
    lines: Array | None = None
    pairs: tuple[tuple[int, int], ...] | None = None
    #: the probes' own readings where a rotated pair was turned into x, y (``read_record``): what the sensors
    #: saw, for the checks that read a probe (its range, its flat tops); None where channels are the readings
    readings: Mapping[str, Array] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", dict(self.channels))
        if isinstance(self.units, str):
            object.__setattr__(self, "units", {name: self.units for name in self.channels})
        if self.pairs is None:
            names = list(self.channels)
            pairs = ((names.index("x"), names.index("y")),) if {"x", "y"} <= set(names) else ()
            object.__setattr__(self, "pairs", pairs)

    @classmethod
    def xy(cls, path, time_s: Array, x_m: Array, y_m: Array, keyphasor: Array | None = None, unit: str = "m",
           lines: Array | None = None) -> "Record":
        """A record of the two channels x and y (the VARM's)."""
        return cls(path, time_s, {"x": x_m, "y": y_m}, keyphasor, unit, lines)

    @property
    def names(self) -> tuple[str, ...]:
        """The channels' names, in order."""
        return tuple(self.channels)

    @property
    def data(self) -> Array:
        """Every channel as columns, (N, C) [m]."""
        return np.column_stack([self.channels[name] for name in self.channels])

    @property
    def x_m(self) -> Array:
        return self.channel("x")

    @property
    def y_m(self) -> Array:
        return self.channel("y")

    @property
    def unit(self) -> str:
        """The file's displacement unit: "mm" or "m", or each channel's joined by "/" when they differ."""
        units = list(self.units.values())
        return units[0] if len(set(units)) == 1 else "/".join(units)

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
        """The displacement channel of sensor ``name`` [m]."""
        try:
            return self.channels[name]
        except KeyError:
            raise KeyError(f"{self.path}: no channel {name!r} (channels: {', '.join(self.channels)})") from None

    def channel_unit(self, name: str) -> str:
        """The unit of channel ``name`` in the file (a key of ``UNITS``: "mm", "m", "um", "mils")."""
        return self.units[name]

    def line(self, index) -> Array:
        """File line number(s) of sample index(es)."""
        index = np.asarray(index)
        return self.lines[index] if self.lines is not None else index + 2


def record_channels(sensors=None) -> tuple[tuple[str, ...], tuple[tuple[int, int], ...] | None]:
    """(channel names, probe pairs) a record must hold for ``sensors``: None, the VARM's x and y; a ``Machine``
    (its sensors' names and ``sensor_pairs``); the config form {name: {node, direction}} (a ``machine:``
    section's ``sensors``); a sequence of sensor names (pairs: x, y when both are there); or of objects with
    ``name``, ``node``, ``direction`` (a machine's sensors)."""
    if sensors is None:
        return DEFAULT_CHANNELS, None
    if hasattr(sensors, "sensors"):  # a Machine
        sensors = sensors.sensors
    if isinstance(sensors, Mapping):
        sensors = [SimpleNamespace(name=str(name), node=spec.get("node"), direction=spec.get("direction"))
                   for name, spec in sensors.items()]
    items = list(sensors)
    if all(isinstance(item, str) for item in items):
        return tuple(items), None
    items = [items[i] for i in machine_order(items)]  # the machine's channel order, however they were declared
    return tuple(str(item.name) for item in items), tuple(sensor_pairs(items))


def probe_angles(sensors=None) -> dict[str, float]:
    """Each sensor's mounting angle [deg] where it is given (``angle_deg`` of a ``Machine``'s sensors or of the
    config form); a sensor without one stands along its direction (absent from the result)."""
    if sensors is None or isinstance(sensors, str):
        return {}
    if hasattr(sensors, "sensors"):
        sensors = sensors.sensors
    if isinstance(sensors, Mapping):
        return {str(n): float(spec["angle_deg"]) for n, spec in sensors.items()
                if isinstance(spec, Mapping) and spec.get("angle_deg") is not None}
    return {str(s.name): float(s.angle_deg) for s in sensors
            if not isinstance(s, str) and getattr(s, "angle_deg", None) is not None}


def _plane_xy_channels(channels: dict, pairs, angles: Mapping[str, float], path: Path) -> dict:
    """The channels with each rotated probe pair turned into its plane's x and y (``model.probes.plane_xy``): the
    analysis and the model then read x and y; the channels keep the probes' names (docs/measurement-format.md,
    "Probe angles"). Pairs at the default angles (0, 90) are left as read, bit for bit."""
    if not angles or not pairs:
        return channels
    names = list(channels)
    out = dict(channels)
    for i, j in pairs:
        a, b = names[i], names[j]
        ai, aj = angles.get(a, DEFAULT_ANGLE_DEG["x"]), angles.get(b, DEFAULT_ANGLE_DEG["y"])
        if (ai, aj) == (DEFAULT_ANGLE_DEG["x"], DEFAULT_ANGLE_DEG["y"]):
            continue
        try:
            plane = plane_xy(channels[a], channels[b], ai, aj, names=(a, b))
        except ProbeAngleError as err:
            raise DataError(f"{path}: {err}") from None
        out[a], out[b] = plane.x, plane.y
    return out


@dataclass(frozen=True)
class Saturation:
    """A flat or clipped channel of a record.

    kind: "flat" (the whole channel is constant, within the sensor's resolution:
    no signal) or "clipped" (flat tops at the channel's extreme value, or
    samples on the sensor's rail: the sensor saturated there).
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
                    f"{self.total_samples} samples): no signal, the sensor is dead or disconnected; the run is "
                    "kept out of the fit")
        share = 100.0 * self.n_samples / self.total_samples
        return (f"{self.path}: channel {self.channel} is clipped at {self.level_m * 1e3:+.4f} mm: {self.n_samples} "
                f"samples ({share:.1f} %) in {self.n_flat_tops} flat top(s); the sensor saturated, so the "
                "harmonics of this run are biased; the run is kept out of the fit")

    @property
    def short(self) -> str:
        if self.kind == "flat":
            return f"{self.channel} flat"
        return f"{self.channel} clipped at {self.level_m * 1e3:+.3f} mm ({self.n_samples} samples)"


# --- a record ---------------------------------------------------------------------------


def read_record(path: str | Path, sensors=None, channels: str | Mapping | None = None) -> Record:
    """Read and validate one record (docs/measurement-format.md, "A record").

    sensors: the machine whose sensors name the channels (a ``Machine``, its
    sensors, or their names; ``record_channels``); None: the VARM's x and y.
    A file an instrument wrote (.mat, .h5/.hdf5, .tdms, .uff/.unv, .mf4/.mdf:
    ``instrument_records``) is read by its format's library, the channels
    chosen by ``channels`` (the runs sheet's channels cell), then checked as a
    CSV record is, a sample counted where a CSV line would be.
    Checks: the file exists and parses (``read_text_table``); a time_s column
    and one displacement column per sensor with a known unit (<sensor>_mm or
    <sensor>_m, e.g. x_mm/y_mm), no column of an unknown sensor; every cell
    numeric and present (no NaN, no empty cell, no decimal comma); time
    strictly increasing and uniform (no gaps: a step > 1.5 median steps; every
    stamp within its rounding plus 5 % of a step of t0 + n dt, ``record_columns.time_problems``);
    a keyphasor column, if any, a two-level signal (0/1, true/false, 0/5 V, ...)
    with at least one rising edge. Raises ``DataError`` naming the file, lines
    and columns. The record's time_s is the least-squares uniform base t0 + n dt
    (``uniform_time_base``), free of the stamps' rounding and jitter; its
    keyphasor is True on the rising edges (``record_columns.keyphasor_marks``).
    Plausibility of the values (units, range, speed) is
    ``hybridtwin.data.plausibility``'s.
    """
    path = Path(path)
    names, pairs = record_channels(sensors)
    instrument = is_instrument_file(path)
    if instrument:
        values, keyphasor, line, time_col, chosen = _instrument_record(path, names, channels)
    else:
        values, keyphasor, line, time_col, chosen = _clean_record(path, names) or _checked_record(path, names)
    problems = time_problems(values[time_col], line)
    if problems:
        raise DataError(problems_message(path, _as_samples(problems) if instrument else problems))
    time_s = uniform_time_base(values[time_col])  # the written stamps less their rounding and jitter
    channels = {name: values[column] * UNITS[unit] for name, (column, unit) in chosen.items()}
    readings = channels
    channels = _plane_xy_channels(channels, pairs, probe_angles(sensors), path)
    return Record(path, time_s, channels, keyphasor, {name: unit for name, (_, unit) in chosen.items()}, line,
                  pairs, None if channels is readings else readings)


def _clean_record(path: Path, names: Sequence[str]) -> tuple | None:
    """``read_record``'s columns from a clean all-numeric file at the C parser's speed (``fast_numeric_table``: an
    83-s record at 5 kHz in 0.24 s, 13.5 s cell by cell), or None: ``_checked_record`` then reads it or says why."""
    fast = path.is_file() and fast_numeric_table(decode_text(path, path.read_bytes()).replace("\r\n", "\n")
                                                 .replace("\r", "\n"), ",")
    if not fast or len(fast[0]) < 3:
        return None
    table, line = fast
    time_col, chosen = _record_columns(path, table.columns, names)
    values = {c: table[c].to_numpy() for c in (time_col, *(c for c, _ in chosen.values()))}
    keyphasor = None
    if "keyphasor" in table:
        levels = table["keyphasor"].to_numpy()
        distinct = np.unique(levels)
        keyphasor = keyphasor_marks(levels > distinct[0]) if distinct.size == 2 else None
        if keyphasor is None or not keyphasor.any():
            return None
    return values, keyphasor, line, time_col, chosen


def _record_layout(path: Path, table: pd.DataFrame, names: Sequence[str]) -> tuple:
    """A record's time column and chosen channels (``_record_columns``), refused with fewer than 3 samples: the
    checks a CSV record and an instrument's file share."""
    time_col, chosen = _record_columns(path, table.columns, names)
    if len(table) < 3:
        raise DataError(f"{path}: only {len(table)} sample(s); a record needs many revolutions of samples")
    return time_col, chosen


def _checked_record(path: Path, names: Sequence[str]) -> tuple:
    """``read_record``'s columns read cell by cell (``read_text_table``), every problem raised as one DataError."""
    table, line = read_text_table(path, ",")
    time_col, chosen = _record_layout(path, table, names)
    problems: list[str] = []
    values = {}
    for column in (time_col, *(c for c, _ in chosen.values())):
        values[column], found = numeric_column(table[column], column, line, allow_empty=False)
        problems += found
    keyphasor = None
    if "keyphasor" in table:
        keyphasor, found = keyphasor_column(table["keyphasor"], line)
        problems += found
    if problems:
        raise DataError(problems_message(path, problems))
    return values, keyphasor, line, time_col, chosen


def _as_samples(problems: Sequence[str]) -> list[str]:
    """A CSV record's messages for a binary one: its samples counted where the CSV's lines are."""
    return [re.sub(r"\bline(s?)\b", r"sample\1", p).replace("line(s)", "sample(s)") for p in problems]


def _as_text(values: Array) -> pd.Series:
    """Numbers as the cells a CSV would hold them in ("nan" for NaN, shortest exact decimal otherwise)."""
    return pd.Series(np.asarray(values, float).astype(str), dtype=object)


def _instrument_record(path: Path, names: Sequence[str], channels) -> tuple:
    """``read_record``'s columns from an instrument's file (``instrument_records.instrument_table``), with the
    CSV record's checks: its columns (``_record_columns``), every value finite, the keyphasor two-level."""
    table = instrument_table(path, names, channels)
    line = np.arange(1, len(table) + 1)
    time_col, chosen = _record_layout(path, table, names)
    problems: list[str] = []
    values = {}
    for column in (time_col, *(c for c, _ in chosen.values())):
        values[column] = table[column].to_numpy(float)
        if not np.isfinite(values[column]).all():  # the CSV's messages, from the numbers written as text
            problems += numeric_column(_as_text(values[column]), column, line, allow_empty=False)[1]
    keyphasor = None
    if "keyphasor" in table:
        levels = table["keyphasor"].to_numpy(float)
        distinct = np.unique(levels)
        keyphasor = keyphasor_marks(levels > distinct[0]) if distinct.size == 2 else None
        if keyphasor is None or not keyphasor.any():
            keyphasor, found = keyphasor_column(_as_text(levels), line)
            problems += found
    if problems:
        raise DataError(problems_message(path, _as_samples(problems)))
    return values, keyphasor, line, time_col, chosen


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


def detect_saturation(record: Record, sensor_range_m: float | None = None,
                      resolution_m: float | None = None) -> list[Saturation]:
    """Flat and clipped channels of a record, each also emitted as a ``DataWarning``.

    Flat: the whole channel spans no more than the sensor's resolution (exactly
    constant when no resolution is given). Clipped, at either extreme of a
    channel: at least SATURATED_SAMPLES samples equal to that extreme (within
    1e-7 of the channel's span) including at least one run of FLAT_TOP_SAMPLES
    consecutive ones (noise makes an unsaturated peak practically never repeat
    its exact value), and more than CLIP_PILEUP times the samples at the next
    level inward (the step between the channel's written values: a quiet
    channel written in coarse steps repeats its peak values without being
    clipped); or, with ``sensor_range_m``, at least SATURATED_SAMPLES
    samples on the rail, within ``Sensor.rail_band_m`` of +-range: a saturated
    laser whose output still carries a little noise.
    """
    sensor = Sensor(sensor_range_m or SENSOR_RANGE_MM * 1e-3, resolution_m or 0.0)
    found = []
    for name in record.names:
        values = record.channel(name)
        spread = float(np.ptp(values))
        if spread <= max(1e-12 * max(1.0, float(np.abs(values).max())), resolution_m or 0.0):
            found.append(Saturation(record.path, name, "flat", float(np.median(values)), values.size, 1,
                                    values.size))
            continue
        tol = 1e-7 * spread
        levels = np.unique(values)
        step = float(np.min(np.diff(levels)))  # the written resolution, where the values are quantised
        for sign, extreme in ((1.0, float(values.max())), (-1.0, float(values.min()))):
            at = np.abs(values - extreme) <= tol
            tops = _flat_tops(at)
            inward = int(np.sum(np.abs(values - (extreme - sign * step)) <= tol)) if step > 2 * tol else 0
            if at.sum() >= SATURATED_SAMPLES and tops > 0 and at.sum() > CLIP_PILEUP * inward:
                found.append(Saturation(record.path, name, "clipped", extreme, int(at.sum()), tops, values.size))
                continue
            if sensor_range_m is None:
                continue
            rail = sign * values >= sensor.range_m - sensor.rail_band_m
            if rail.sum() >= SATURATED_SAMPLES or (rail.any() and abs(extreme) >= sensor.range_m):
                found.append(Saturation(record.path, name, "clipped", float(np.median(values[rail])),
                                        int(rail.sum()), _flat_tops(rail), values.size))
    for item in found:
        warnings.warn(item.describe(), DataWarning, stacklevel=2)
    return found


# --- helpers ----------------------------------------------------------------------------


def _record_columns(path: Path, columns: Sequence[str], names: Sequence[str] = DEFAULT_CHANNELS
                    ) -> tuple[str, dict[str, tuple[str, str]]]:
    """(time column, {sensor name: (its column, unit)}) of a record header, or DataError."""
    listed, varm = ", ".join(names), tuple(names) == DEFAULT_CHANNELS
    expected = ("time_s, x_mm and y_mm (or x_m and y_m)" if varm else
                f"time_s and one column <sensor>_mm (or <sensor>_m) for each of the machine's sensors {listed}")
    require_columns(path, columns, ("time_s",), RECORD_COLUMNS, f"a record needs {expected}, optionally keyphasor")
    problems, chosen = [], {}
    own = {}
    for axis in names:  # headers are read in lower case (read_text_table): a sensor X1's column X1_mm is x1_mm
        low = axis.lower()
        candidates = [(c, c[len(low) + 1:]) for c in columns if c.startswith(f"{low}_") and c not in RECORD_COLUMNS]
        # a column of another sensor whose name starts with this one's (x and x_b): not this sensor's
        own[axis] = [(c, u) for c, u in candidates
                     if not any(c.startswith(f"{other.lower()}_") and len(other) > len(axis) for other in names)]
    claimed = {c for found in own.values() for c, _ in found}
    for axis in names:
        known = [(c, u) for c, u in own[axis] if u in UNITS]
        unknown = [c for c, u in own[axis] if u not in UNITS]
        if unknown and not known:
            problems.append(f"column {unknown[0]!r}: unknown unit {unknown[0][len(axis) + 1:]!r} "
                            f"(use {axis}_mm or {axis}_m); micrometres {axis}_um, mils {axis}_mils")
        elif len(known) > 1:
            problems.append(f"columns {[c for c, _ in known]}: more than one {axis} displacement column")
        elif not known:
            close = difflib.get_close_matches(f"{axis.lower()}_mm", [c for c in columns if c not in claimed], n=1,
                                              cutoff=0.5)
            hint = f" (found {close[0]!r}: misnamed?)" if close and close[0] not in RECORD_COLUMNS else ""
            problems.append(f"missing column {axis}_mm (or {axis}_m){hint}")
        else:
            chosen[axis] = known[0]
    extra = [c for c in columns if c not in RECORD_COLUMNS and c not in claimed]
    if extra:
        has = ("time_s, x_mm, y_mm or x_m, y_m, keyphasor" if varm else
               f"time_s, a column <sensor>_mm or <sensor>_m for each of the machine's sensors {listed}, keyphasor")
        problems.append(f"unexpected column(s) {extra} (a record has {has})")
    if varm and any(c.rsplit("_", 1)[-1] in UNITS for c in extra):
        problems.append("displacement columns of other sensors than the VARM's x and y: the record of a machine "
                        "of your own? Its channels are read by its config's sensors (check-data --config FILE)")
    if problems:
        sensors = "" if varm else f"; the machine's sensors {listed}"
        raise DataError(f"{path}: line 1 (header): " + "; ".join(problems) + f"; the header has {list(columns)}"
                        + sensors)
    return "time_s", chosen


def _flat_tops(at: Array) -> int:
    """Number of runs of >= FLAT_TOP_SAMPLES consecutive True values."""
    edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int(np.sum(stops - starts >= FLAT_TOP_SAMPLES))
