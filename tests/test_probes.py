"""Probes at any angle: the plane's x, y from two rotated probes (closed forms), their noise propagated, the
machine's sensors with angle_deg, and a VARM described by its sensors alone."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from jsonschema import validators

from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import MachineSpecError, Sensor
from hybridtwin.model.probes import ProbeAngleError, plane_xy, probe_readings, rotation

SCHEMA = Path(__file__).parents[1] / "src" / "hybridtwin" / "config.schema.yaml"


def test_probes_at_plus_minus_45_give_x_and_y():
    """Closed form: probes at 45 and 135 deg read (x + y)/sqrt2 and (y - x)/sqrt2."""
    x, y = np.array([1.0, -2.0, 0.3]), np.array([0.5, 4.0, -1.0])
    p1, p2 = (x + y) / np.sqrt(2), (y - x) / np.sqrt(2)
    out = plane_xy(p1, p2, 45.0, 135.0)
    assert np.allclose(out.x, x, rtol=0, atol=1e-15) and np.allclose(out.y, y, rtol=0, atol=1e-15)


@pytest.mark.parametrize("a1, a2", [(30.0, 100.0), (-45.0, 45.0), (10.0, 21.0), (200.0, 95.0)])
def test_any_non_collinear_pair_round_trips(a1, a2):
    rng = np.random.default_rng(1)
    x = rng.standard_normal(5) + 1j * rng.standard_normal(5)  # complex harmonics: the relation is real and linear
    y = rng.standard_normal(5) + 1j * rng.standard_normal(5)
    p1, p2 = probe_readings(x, y, a1, a2)
    a1r, a2r = np.deg2rad(a1), np.deg2rad(a2)
    assert np.allclose(p1, x * np.cos(a1r) + y * np.sin(a1r), atol=1e-14)  # a probe reads x cos a + y sin a
    out = plane_xy(p1, p2, a1, a2)
    # |sin(a2 - a1)| >= 0.19 here: R^-1 amplifies round-off by at most ~10, so 1e-13 is generous
    assert np.allclose(out.x, x, atol=1e-13) and np.allclose(out.y, y, atol=1e-13)


def test_default_angles_return_the_readings_themselves():
    p1, p2 = np.array([1.0, np.nan]), np.array([2.0, 3.0])
    out = plane_xy(p1, p2, 0.0, 90.0, 0.1, 0.2)
    assert out.x is p1 and out.y is p2  # bit for bit, NaN kept where it was (no 0 * NaN mixing)
    assert out.sigma_x == 0.1 and out.sigma_y == 0.2 and out.correlation == 0.0
    assert np.array_equal(rotation(0.0, 90.0), np.eye(2))  # exact: cos(90 deg) is 0, not 6e-17


@pytest.mark.parametrize("a1, a2", [(0.0, 5.0), (0.0, 180.0), (45.0, 225.0), (30.0, 39.9)])
def test_collinear_probes_are_refused(a1, a2):
    with pytest.raises(ProbeAngleError) as err:
        plane_xy(np.zeros(3), np.zeros(3), a1, a2, names=("xa", "ya"))
    assert "probes xa at" in str(err.value) and "collinear" in str(err.value) and "sin(10 deg)" in str(err.value)


def test_just_beyond_ten_degrees_is_accepted():
    plane_xy(np.zeros(3), np.zeros(3), 30.0, 40.5)  # 10.5 deg apart


def test_noise_closed_form_at_45_degrees():
    """At 45/135 deg R is a rotation, R^-1 = R^T: x = (p1 - p2)/sqrt2, y = (p1 + p2)/sqrt2, so
    var_x = var_y = (s1^2 + s2^2)/2 and cov = (s1^2 - s2^2)/2: rho = (s1^2 - s2^2)/(s1^2 + s2^2)."""
    s1, s2 = 2.0, 1.0
    out = plane_xy(0.0, 0.0, 45.0, 135.0, s1, s2)
    assert out.sigma_x == pytest.approx(np.sqrt(2.5), rel=1e-12)
    assert out.sigma_y == pytest.approx(np.sqrt(2.5), rel=1e-12)
    assert out.correlation == pytest.approx(0.6, rel=1e-12)
    equal = plane_xy(0.0, 0.0, 45.0, 135.0, 1.0, 1.0)  # orthogonal probes of equal noise: uncorrelated
    assert equal.correlation == pytest.approx(0.0, abs=1e-15) and equal.sigma_x == pytest.approx(1.0, rel=1e-15)


def test_noise_propagation_matches_sampling():
    """sigma_x, sigma_y, rho against 40000 draws: a sample standard deviation's relative standard error is
    1/sqrt(2n) = 0.35 %, a correlation's (1 - rho^2)/sqrt(n) <= 0.005; tolerances are 5 of those."""
    n, s1, s2, a1, a2 = 40000, 3e-6, 1e-6, 20.0, 75.0
    rng = np.random.default_rng(7)
    p1, p2 = s1 * rng.standard_normal(n), s2 * rng.standard_normal(n)
    out = plane_xy(p1, p2, a1, a2, s1, s2)
    assert np.std(out.x) == pytest.approx(out.sigma_x, rel=5 / np.sqrt(2 * n))
    assert np.std(out.y) == pytest.approx(out.sigma_y, rel=5 / np.sqrt(2 * n))
    assert np.corrcoef(out.x, out.y)[0, 1] == pytest.approx(out.correlation, abs=5 / np.sqrt(n))
    assert abs(out.correlation) > 0.1  # the case is one where the correlation matters


def test_sensor_angles_default_and_validate():
    assert Sensor("x", 1, "x").angle_deg == 0.0 and Sensor("y", 1, "y").angle_deg == 90.0
    assert Sensor("x", 1, "x") == Sensor("x", 1, "x", 0.0) and not Sensor("x", 1, "x").rotated
    assert Sensor("p", 1, "x", 45).rotated
    with pytest.raises(ValueError, match="angle_deg must be a finite number"):
        Sensor("x", 1, "x", float("nan"))


def test_machine_with_angles_from_mapping_and_back():
    spec = {"sensors": {"x": {"node": 1, "direction": "x", "angle_deg": 45},
                        "y": {"node": 1, "direction": "y", "angle_deg": 135.0}}}
    machine = Machine.from_mapping(spec)
    varm = Machine.varm()
    # only sensors: the VARM's shaft, bearings and unbalance plane with these sensors
    assert machine.segments == varm.segments and machine.bearings == varm.bearings
    assert machine.unbalance_planes == varm.unbalance_planes and machine.sensor_dofs() == varm.sensor_dofs()
    assert [s.angle_deg for s in machine.sensors] == [45.0, 135.0]
    assert not machine.is_varm  # its probes differ from the VARM's
    again = Machine.from_mapping(machine.to_mapping())
    assert again.to_mapping() == machine.to_mapping() and again.sensors == machine.sensors
    assert "angle 45 deg" in machine.describe()


def test_default_angles_leave_the_varm_as_it_was():
    varm = Machine.varm()
    assert "angle_deg" not in str(varm.to_mapping())
    plain = Machine.from_mapping({"sensors": {"x": {"node": 1, "direction": "x"}, "y": {"node": 1, "direction": "y"}}})
    assert plain.is_varm and plain.to_mapping() == varm.to_mapping()


def test_collinear_pair_in_a_machine_is_a_spec_error():
    with pytest.raises(MachineSpecError) as err:
        Machine.from_mapping({"sensors": {"a": {"node": 1, "direction": "x", "angle_deg": 45},
                                          "b": {"node": 1, "direction": "y", "angle_deg": 50}}})
    assert "probes a at 45 deg and b at 50 deg" in str(err.value)


def test_sensor_angle_must_be_a_number():
    with pytest.raises(MachineSpecError) as err:
        Machine.from_mapping({"sensors": {"x": {"node": 1, "direction": "x", "angle_deg": "45"}}})
    assert "angle_deg" in str(err.value) and "must be a number" in str(err.value)


def test_schema_accepts_sensors_alone_with_angles_and_refuses_other_keys():
    schema = yaml.safe_load(SCHEMA.read_text())["properties"]["machine"]
    validator = validators.validator_for(schema)(schema)
    good = {"sensors": {"x": {"node": 1, "direction": "x", "angle_deg": -45}}}
    assert not list(validator.iter_errors(good))
    bad = {"sensors": {"x": {"node": 1, "direction": "x", "angle": -45}}}
    assert list(validator.iter_errors(bad))
    assert list(validator.iter_errors({"segments": []}))  # sensors required


def test_a_record_of_rotated_probes_is_read_as_the_planes_x_and_y(tmp_path):
    """The record holds the probes' readings (at 45 and 135 degrees); read with the machine's angles it gives the
    plane's x and y, which the analysis and the model compare (to the written digits: 1e-7 mm)."""
    from hybridtwin.data.records import read_record

    t = np.arange(400) / 2000.0
    x, y = 0.3 * np.cos(2 * np.pi * 10 * t), 0.2 * np.sin(2 * np.pi * 10 * t + 0.4)
    a1, a2 = np.radians(45.0), np.radians(135.0)
    p1, p2 = x * np.cos(a1) + y * np.sin(a1), x * np.cos(a2) + y * np.sin(a2)
    path = tmp_path / "r.csv"
    np.savetxt(path, np.column_stack([t, p1, p2]), delimiter=",", header="time_s,x_mm,y_mm", comments="",
               fmt=["%.6f", "%.7f", "%.7f"])
    sensors = {"x": {"node": 1, "direction": "x", "angle_deg": 45.0},
               "y": {"node": 1, "direction": "y", "angle_deg": 135.0}}
    record = read_record(path, sensors)
    np.testing.assert_allclose(record.channel("x"), 1e-3 * x, atol=2e-10)
    np.testing.assert_allclose(record.channel("y"), 1e-3 * y, atol=2e-10)
    plain = read_record(path, {"x": {"node": 1, "direction": "x"}, "y": {"node": 1, "direction": "y"}})
    np.testing.assert_array_equal(plain.channel("x"), 1e-3 * np.loadtxt(path, delimiter=",", skiprows=1)[:, 1])
