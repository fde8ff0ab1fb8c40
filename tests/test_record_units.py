"""Record columns in micrometres and mils (besides mm and m), read into metres; micrometres written as mm caught."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.data.measurements import DataError
from hybridtwin.data.records import UNITS, Sensor, read_record
from hybridtwin.data.plausibility import check_magnitudes

RPM = 600.0


def orbit_mm(seconds: float = 1.0, fs: float = 2000.0, seed: int = 0):
    """A forward 1X orbit of 0.05 mm (50 um) with noise, about small offsets [s, mm, mm]."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    angle = 2 * np.pi * RPM / 60 * t
    x = 0.05 * np.cos(angle) + 0.01 + 0.002 * rng.standard_normal(t.size)
    y = 0.05 * np.sin(angle) - 0.01 + 0.002 * rng.standard_normal(t.size)
    return t, x, y


def write(path: Path, t, x, y, unit: str, scale: float) -> Path:
    pd.DataFrame({"time_s": t, f"x_{unit}": x * scale, f"y_{unit}": y * scale}).to_csv(
        path, index=False, float_format="%.10g")
    return path


@pytest.mark.parametrize("unit, per_mm", [("mm", 1.0), ("m", 1e-3), ("um", 1e3), ("mils", 1 / 0.0254)])
def test_units_read_into_metres(tmp_path, unit, per_mm):
    t, x, y = orbit_mm()
    record = read_record(write(tmp_path / "r.csv", t, x, y, unit, per_mm))
    # written with 10 significant digits: the read values equal x mm = x * 1e-3 m to 1e-9 relative
    assert np.allclose(record.x_m, x * 1e-3, rtol=1e-9, atol=0) and np.allclose(record.y_m, y * 1e-3, rtol=1e-9)
    assert record.unit == unit and record.channel_unit("x") == unit
    check_magnitudes(record, Sensor())  # 50 um in any of the four units is plausible for the paper's lasers


def test_a_mil_is_a_thousandth_of_an_inch():
    assert UNITS["mils"] == pytest.approx(25.4e-6, rel=1e-15) and UNITS["um"] == 1e-6


def test_unknown_unit_names_the_new_ones(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("time_s,x_in,y_um\n0,1,1\n0.001,1,1\n0.002,1,1\n")
    with pytest.raises(DataError) as err:
        read_record(path)
    assert "unknown unit 'in' (use x_mm or x_m); micrometres x_um, mils x_mils" in str(err.value)


def test_micrometres_written_as_mm_are_named(tmp_path):
    t, x, y = orbit_mm()
    record = read_record(write(tmp_path / "r.csv", t, x, y, "mm", 1e3))  # the um values under x_mm
    with pytest.raises(DataError) as err:
        check_magnitudes(record, Sensor())
    message = str(err.value)
    assert str(tmp_path / "r.csv") in message
    assert "column x_mm: beyond the sensor range +-14 mm" in message and "look like um written as mm" in message
    assert "column y_mm" in message and "name the column y_um" in message


def test_a_large_dc_offset_in_mm_is_not_called_micrometres(tmp_path):
    """A 500 mm offset on a 1 mm vibration: its span (2 mm) fits the range, so not um written as mm."""
    t, x, y = orbit_mm()
    record = read_record(write(tmp_path / "r.csv", t, 20 * x + 500.0, 20 * y, "mm", 1.0))
    with pytest.raises(DataError) as err:
        check_magnitudes(record, Sensor())
    assert "DC offset (median)" in str(err.value) and "um written as mm" not in str(err.value)
