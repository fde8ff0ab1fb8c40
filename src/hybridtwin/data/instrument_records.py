"""Records as instruments write them (issue 55): MATLAB .mat (v5 by scipy.io, v7.3 by h5py), HDF5 (h5py), NI TDMS
(npTDMS), universal file format 58 (pyuff) and ASAM MDF (asammdf), each read with the library made for it
(docs/measurement-format.md, "Records from instruments").

The runs sheet's optional ``channels`` column chooses the file's channels: entries ``<name>=<channel>`` separated by
";", where <name> is a sensor of the machine (x, y on the VARM), ``keyphasor`` or ``time``, and <channel> the
file's name for it (a .mat variable, an HDF5 dataset path, a TDMS "group/channel" or a channel name unique in the
file, a UFF 58 set's first id line, an MDF channel name), optionally with its unit in brackets: ``x=Probe 1[um]``.
A sensor the column does not name is looked for under the CSV record's column names (``x_mm``, ``x_m``, ``x_um``,
``x_mils``), then under its own name; the time likewise under ``time_s``.

Units and the sample rate come from the file's metadata where it has them: HDF5 attributes ``unit``/``units``
and ``sample_rate_hz``/``dt_s`` (``t0_s``), TDMS ``unit_string`` and ``wf_increment``/``wf_start_offset``, the
UFF 58 axis unit labels and abscissa increment, MDF channel units and the master (time) channel. A .mat file has
no such metadata: the units come from the brackets or the variable names (``x_mm``), the time from a time
variable or a scalar ``sample_rate_hz`` (or ``fs``, in Hz). A unit in brackets overrides the file's.

``instrument_table`` turns a file into the table a CSV record would read as (columns time_s, <sensor>_<unit>,
keyphasor; floats), so that ``records.read_record`` applies the same checks with the same messages, a sample
counted where a CSV line would be (sample 1 is the first).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .measurements import DataError, parse_channels

Array = np.ndarray

#: file suffix (lower case) -> format name; anything else is read as a CSV record
FORMATS = {".mat": "mat", ".h5": "hdf5", ".hdf5": "hdf5", ".hdf": "hdf5", ".tdms": "tdms", ".uff": "uff",
           ".unv": "uff", ".mf4": "mdf", ".mdf": "mdf"}
#: the package each format needs (pip name; the ``instruments`` extra of pyproject.toml installs them)
LIBRARIES = {"mat": "scipy (v7.3 files: h5py)", "hdf5": "h5py", "tdms": "npTDMS", "uff": "pyuff", "mdf": "asammdf"}
#: a unit as instruments write it -> the record's unit suffix (records.UNITS)
DISPLACEMENT_UNITS = {"mm": "mm", "m": "m", "um": "um", "µm": "um", "μm": "um", "micron": "um", "microns": "um",
                     "mil": "mils", "mils": "mils"}
TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3}
RATE_NAMES = ("sample_rate_hz", "fs", "Fs")


def is_instrument_file(path: str | Path) -> bool:
    """Whether ``path`` is read by this module (its suffix names an instrument format), not as a CSV record."""
    return Path(path).suffix.lower() in FORMATS


@dataclass
class Channel:
    """One channel of a file: its samples, its unit (None: the file says none), the sampling step and start [s]
    where the file gives them (None: not given)."""

    values: Array
    unit: str | None = None
    dt_s: float | None = None
    t0_s: float = 0.0
    time_s: Array | None = None  # the channel's own time stamps (MDF's master channel)


def _text(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray):
        value = value.item() if value.size == 1 else None
        return _text(value)
    value = str(value).strip()
    return value or None


def _require(module: str, fmt: str, path: Path):
    try:
        return importlib.import_module(module)
    except ImportError:
        raise DataError(f"{path}: a {fmt.upper()} record needs the package {LIBRARIES[fmt]}, not installed "
                        "(pip install 'hybridtwin[instruments]')") from None


# --- one reader per format: {channel name: Channel} ----------------------------------------------------------


def _mat(path: Path) -> dict[str, Channel]:
    from scipy import io as sio  # here: scipy.io (~50 ms) only for a .mat record, not for every command line

    try:
        data = sio.loadmat(path, squeeze_me=True)
    except NotImplementedError:  # a v7.3 file: HDF5 inside
        return _hdf5(path, matlab=True)
    except (ValueError, OSError) as err:
        raise DataError(f"{path}: not a MATLAB .mat file scipy.io can read ({err})") from None
    return {name: Channel(np.atleast_1d(np.asarray(value))) for name, value in data.items()
            if not name.startswith("__") and isinstance(value, np.ndarray | float | int)
            and np.asarray(value).dtype.kind in "biuf"}


def _hdf5(path: Path, matlab: bool = False) -> dict[str, Channel]:
    h5py = _require("h5py", "mat" if matlab else "hdf5", path)
    out = {}
    try:
        with h5py.File(path, "r") as f:
            def visit(name, item):
                if isinstance(item, h5py.Dataset) and item.dtype.kind in "biuf" and not name.startswith("#"):
                    attrs = item.attrs
                    unit = _text(attrs.get("unit", attrs.get("units")))
                    rate = next((float(np.asarray(attrs[k]).ravel()[0]) for k in ("sample_rate_hz", "sample_rate")
                                 if k in attrs), None)
                    dt = float(np.asarray(attrs["dt_s"]).ravel()[0]) if "dt_s" in attrs else None
                    dt = dt if dt is not None else (1.0 / rate if rate else None)
                    t0 = float(np.asarray(attrs["t0_s"]).ravel()[0]) if "t0_s" in attrs else 0.0
                    out[name] = Channel(np.asarray(item[()]).ravel(), unit, dt, t0)
            f.visititems(visit)
    except OSError as err:
        raise DataError(f"{path}: not an HDF5 file h5py can read ({err})") from None
    return out


def _tdms(path: Path) -> dict[str, Channel]:
    nptdms = _require("nptdms", "tdms", path)
    try:
        tdms = nptdms.TdmsFile.read(path)
    except Exception as err:  # noqa: BLE001 (npTDMS raises several kinds on a file it cannot read)
        raise DataError(f"{path}: not a TDMS file npTDMS can read ({err})") from None
    out = {}
    for group in tdms.groups():
        for channel in group.channels():
            props = channel.properties
            dt = props.get("wf_increment")
            out[f"{group.name}/{channel.name}"] = Channel(np.asarray(channel[:]), _text(props.get("unit_string")),
                                                          float(dt) if dt else None,
                                                          float(props.get("wf_start_offset", 0.0) or 0.0))
    return out


def _uff(path: Path) -> dict[str, Channel]:
    pyuff = _require("pyuff", "uff", path)
    try:
        sets = pyuff.UFF(str(path)).read_sets()
    except Exception as err:  # noqa: BLE001
        raise DataError(f"{path}: not a universal file pyuff can read ({err})") from None
    sets = [sets] if isinstance(sets, dict) else list(sets)
    out = {}
    for s in sets:
        if s.get("type") != 58:
            continue
        name = _text(s.get("id1")) or f"set {len(out) + 1}"
        x = np.asarray(s.get("x", []), float)
        dt = float(s["abscissa_inc"]) if s.get("abscissa_spacing", 1) == 1 and s.get("abscissa_inc") else None
        t0 = float(s.get("abscissa_min", x[0] if x.size else 0.0))
        out[name] = Channel(np.real(np.asarray(s["data"])), _text(s.get("ordinate_axis_units_lab")), dt, t0,
                            None if dt else x)
    return out


def _mdf(path: Path) -> dict[str, Channel]:
    asammdf = _require("asammdf", "mdf", path)
    try:
        mdf = asammdf.MDF(str(path))
    except Exception as err:  # noqa: BLE001
        raise DataError(f"{path}: not an MDF file asammdf can read ({err})") from None
    out = {}
    with mdf:
        for name in mdf.channels_db:
            if name in ("time", "t"):  # the master channel: each signal's timestamps
                continue
            try:
                signal = mdf.get(name)
            except Exception:  # noqa: BLE001 (a name in several groups: asammdf wants the group; take the first)
                group, index = mdf.channels_db[name][0]
                signal = mdf.get(name, group=group, index=index)
            if np.asarray(signal.samples).dtype.kind not in "biuf":
                continue
            out[name] = Channel(np.asarray(signal.samples), _text(signal.unit), None, 0.0,
                                np.asarray(signal.timestamps, float))
    return out


READERS = {"mat": _mat, "hdf5": _hdf5, "tdms": _tdms, "uff": _uff, "mdf": _mdf}


def file_channels(path: str | Path) -> dict[str, Channel]:
    """Every numeric channel of an instrument file, by the name the sheet's channels column gives it."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    return READERS[FORMATS[path.suffix.lower()]](path)


def _find(channels: Mapping[str, Channel], wanted: str) -> str | None:
    """The key of ``wanted`` in ``channels``: exact, else a unique channel whose last path part is it (a TDMS
    channel or an HDF5 dataset named without its group), else None."""
    if wanted in channels:
        return wanted
    tail = [k for k in channels if k.rsplit("/", 1)[-1] == wanted.rsplit("/", 1)[-1] and "/" in k]
    return tail[0] if len(tail) == 1 else None


def instrument_table(path: str | Path, names: Sequence[str], channels: str | Mapping | None = None) -> pd.DataFrame:
    """The record at ``path`` as the table a CSV record reads as: time_s, one column <sensor>_<unit> per sensor of
    ``names`` (its unit from the sheet's brackets, else the file's metadata, else the name the file gives it),
    keyphasor where the file has one; floats. channels: the sheet's cell (``parse_channels``) or its parsed form.
    DataError naming the file and what is missing (the file's channels listed)."""
    path = Path(path)
    chosen = channels if isinstance(channels, Mapping) else _parse(path, channels)
    found = file_channels(path)
    have = ", ".join(found) or "none"
    unknown = [n for n in chosen if n not in (*names, "keyphasor", "time")]
    if unknown:
        raise DataError(f"{path}: channels column names {unknown}, not a sensor of the machine ({', '.join(names)}), "
                        "keyphasor or time")
    problems, columns, steps = [], {}, []
    for name in (*names, "keyphasor", "time"):
        if name in chosen:
            source, unit = chosen[name]
            key = _find(found, source)
            if key is None:
                problems.append(f"no channel {source!r} (the channels column's {name}); the file's channels: {have}")
                continue
        else:
            guesses = {"time": ["time_s", "time", "t"], "keyphasor": ["keyphasor"]}.get(
                name, [f"{name}_{u}" for u in ("mm", "m", "um", "mils")] + [name])
            key = next((k for g in guesses if (k := _find(found, g)) is not None), None)
            if key is None:
                if name not in ("keyphasor", "time"):
                    problems.append(f"no channel for sensor {name} (looked for {', '.join(guesses)}); the file's "
                                    f"channels: {have}; choose it in the runs sheet's channels column "
                                    f"({name}=<channel>[mm])")
                continue
            unit = None
        channel = found[key]
        unit = unit or channel.unit
        if name == "time":
            scale = TIME_UNITS.get((unit or "s").lower())
            if scale is None:
                problems.append(f"channel {key!r} (time): unit {unit!r} is not a time unit (s, ms)")
                continue
            columns["time_s"] = np.asarray(channel.values, float) * scale
        elif name == "keyphasor":
            columns["keyphasor"] = np.asarray(channel.values, float)
        else:
            suffix = key.rsplit("/", 1)[-1].rsplit("_", 1)[-1] if unit is None else None
            if unit is None and suffix in DISPLACEMENT_UNITS:
                unit = suffix
            if unit is None:
                problems.append(f"channel {key!r} (sensor {name}): no unit in the file; give it in the runs "
                                f"sheet's channels column ({name}={key}[mm])")
                continue
            if unit.lower() not in DISPLACEMENT_UNITS and unit not in DISPLACEMENT_UNITS:
                problems.append(f"channel {key!r} (sensor {name}): unit {unit!r} is not a displacement unit "
                                f"({', '.join(sorted(set(DISPLACEMENT_UNITS.values())))}); a unit in brackets in "
                                "the channels column overrides the file's")
                continue
            columns[f"{name}_{DISPLACEMENT_UNITS.get(unit, DISPLACEMENT_UNITS.get(unit.lower()))}"] = np.asarray(
                channel.values, float)
        steps.append((key, channel))
    if problems:
        raise DataError(f"{path}: " + "; ".join(problems))
    lengths = {key: channel.values.size for key, channel in steps}
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: the chosen channels differ in length: "
                        + ", ".join(f"{k} {n} samples" for k, n in lengths.items()))
    if "time_s" not in columns:
        columns["time_s"] = _time(path, found, steps)
    table = pd.DataFrame(columns)
    return table[["time_s", *[c for c in table.columns if c != "time_s"]]]


def _time(path: Path, found: Mapping[str, Channel], steps: Sequence[tuple[str, Channel]]) -> Array:
    """The samples' times from the file's metadata: each chosen channel's own time stamps or its step (they must
    agree), else a .mat scalar sample rate (``RATE_NAMES``); DataError saying what to give otherwise."""
    n = steps[0][1].values.size
    own = [(k, c.time_s) for k, c in steps if c.time_s is not None]
    if own:
        key, t = own[0]
        for other, s in own[1:]:
            if s.size != t.size or not np.allclose(s, t, rtol=0, atol=1e-9 * max(1.0, float(np.abs(t).max()))):
                raise DataError(f"{path}: channels {key!r} and {other!r} have different time stamps")
        return np.asarray(t, float)
    rates = {(c.dt_s, c.t0_s) for _, c in steps if c.dt_s}
    if len(rates) > 1:
        raise DataError(f"{path}: the chosen channels have different sampling steps or starts: {sorted(rates)}")
    if rates:
        dt, t0 = rates.pop()
        return t0 + dt * np.arange(n)
    for name in RATE_NAMES:
        if name in found and found[name].values.size == 1 and float(found[name].values[0]) > 0:
            return np.arange(n) / float(found[name].values[0])
    raise DataError(f"{path}: no time: the file gives no sample rate for the chosen channels; add a time channel "
                    f"(time_s, or time=<channel> in the runs sheet's channels column) or a scalar "
                    f"{' or '.join(RATE_NAMES[:2])} [Hz]")


def _parse(path: Path, text) -> dict[str, tuple[str, str | None]]:
    try:
        return parse_channels(text)
    except ValueError as err:
        raise DataError(f"{path}: {err}") from None
