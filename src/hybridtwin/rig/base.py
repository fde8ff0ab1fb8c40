"""What the virtual rig's two writers share (``rig`` for steady runs, ``sweep`` for run-ups and coast-downs):
its errors and warnings, the record writer, the units it writes and the per-run random streams."""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

Array = np.ndarray

#: a record is "inside the range" when |response + offset| + this many noise sigmas stays below the range
RANGE_SIGMAS = 4.0
#: record displacement units: metres per unit and the written format (0.1 um resolution, 10 nm in m)
UNIT_SCALES = {"mm": (1e-3, "%.4f"), "m": (1.0, "%.8f"), "um": (1e-6, "%.1f"), "mils": (25.4e-6, "%.5f")}


class RigError(ValueError):
    """A rig specification or plan that cannot be run, with the reason."""


class RigWarning(UserWarning):
    """A generated run whose steady state is not unique or unstable, or which leaves the sensor range."""


def write_record(path: Path, record: Mapping[str, Array | None], unit: str = "mm",
                 channels: Sequence[str] = ("x", "y")) -> None:
    """Write time_s, <c>_{unit} for each channel c (x_mm, y_mm on the VARM)[, keyphasor] as CSV (UNIT_SCALES:
    0.1 um resolution in mm and um, 10 nm in m, 0.01 um in mils)."""
    scale, fmt = (1e3, "%.4f") if unit == "mm" else (1.0, "%.8f") if unit == "m" else (
        1.0 / UNIT_SCALES[unit][0], UNIT_SCALES[unit][1])
    columns = [record["time_s"], *(record[f"{c}_m"] * scale for c in channels)]
    header = ["time_s", *(f"{c}_{unit}" for c in channels)]
    formats = ["%.6f"] + [fmt] * len(channels)
    if record.get("keyphasor") is not None:
        columns.append(record["keyphasor"])
        header.append("keyphasor")
        formats.append("%d")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.column_stack(columns), fmt=formats, delimiter=",", header=",".join(header), comments="")


def run_rng(seed: int, run_id: str, stream: int) -> np.random.Generator:
    """The generator of one run's draws (stream 0: conditions, 1: noise), independent of the plan's order."""
    return np.random.default_rng([int(seed), zlib.crc32(str(run_id).encode()), stream])
