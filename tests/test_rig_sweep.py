"""The virtual rig's run-ups and coast-downs (hybridtwin.rig.sweep): records by time integration along a speed
profile with every nuisance, the answer key, and bad specifications."""

import math

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridtwin.data.measurements import DataError
from hybridtwin.rig.rig import Imperfections, RigError, RigSpec, Truth, generate, read_plan
from hybridtwin.model.sensor import pair_dofs
from hybridtwin.solvers.solver import solve

PLAN = ("run\trpm\teccentric_mass_g\trole\tkind\trpm_start\trpm_end\n"
        "s600\t600\t25.9\tfit\t\t\t\n"
        "up1\t\t25.9\tfit\trunup\t600\t660\n"
        "down1\t\t14.8\tvalidate\tCoastdown\t660\t600\n")
SWEEP = {"sweep_rate_rpm_s": 60.0, "dwell_start_s": 1.0, "dwell_end_s": 0.3, "sweep_ramp_s": 0.25,
         "runout_um": [100.0, 30.0], "unit": "um"}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    (folder / "plan.tsv").write_text(PLAN)
    spec = RigSpec(Truth.from_spec(), Imperfections.from_mapping(SWEEP), seed=5)
    truth = generate(read_plan(folder / "plan.tsv"), spec, folder / "out")
    return folder, spec, truth


def test_plan_reads_transient_rows(made):
    folder, _, _ = made
    plan = read_plan(folder / "plan.tsv")
    assert list(plan["kind"]) == ["steady", "runup", "coastdown"]
    assert np.isnan(plan["rpm"][1]) and plan["rpm_start"][1] == 600 and np.isnan(plan["rpm_start"][0])


def test_records_and_answer_key(made):
    folder, _, truth = made
    out = folder / "out"
    sheet = pd.read_csv(out / "runs.tsv", sep="\t")
    assert list(sheet["path"]) == ["records/s600.csv", "records/up1.csv", "records/down1.csv"]
    record = pd.read_csv(out / "records" / "up1.csv")
    assert list(record.columns) == ["time_s", "x_um", "y_um", "keyphasor"]
    assert record["time_s"].iloc[1] == pytest.approx(2e-4)  # 5 kHz
    # 1 s dwell + 1 s sweep + 0.3 s dwell
    assert record["time_s"].iloc[-1] == pytest.approx(2.3, abs=1e-3)
    key = yaml.safe_load((out / "truth.yaml").read_text())["imperfections"]
    assert key["runout_um"] == [100.0, 30.0] and key["sweep_rate_rpm_s"] == 60.0
    row = truth.set_index("run").loc["up1"]
    for column in ("rpm_start_true", "rpm_end_true", "sweep_rate_mean_rpm_s", "runout1_x_re_m", "runout2_y_im_m",
                   "probe_angle_x_deg", "keyphasor_marks", "radau_steps"):
        assert np.isfinite(float(row[column])), column
    assert row["probe_angle_x_deg"] == 0 and row["probe_angle_y_deg"] == 90
    # the true sweep: 60 RPM in 1 s nominal, the ends within 4 sigma of the 0.1 % speed error
    assert abs(row["rpm_start_true"] - 600) < 4 * 0.6 and abs(row["rpm_end_true"] - 660) < 4 * 0.66
    assert row["sweep_rate_mean_rpm_s"] == pytest.approx(abs(row["rpm_end_true"] - row["rpm_start_true"]) / 1.0)
    assert truth["run"].tolist() == ["s600", "up1", "down1"]


@pytest.mark.parametrize("run", ["up1", "down1"])
def test_keyphasor_follows_the_speed_profile(made, run):
    """The speed from the keyphasor's mark intervals (60 / interval) starts at the true start speed, ends at the
    true end speed and moves one way: marks 0.2 ms apart (one sample) at 10 revolutions per second read the
    speed to ~0.2 % (1.2 RPM); 2 RPM of margin."""
    folder, _, truth = made
    record = pd.read_csv(folder / "out" / "records" / f"{run}.csv")
    row = truth.set_index("run").loc[run]
    marks = record["time_s"].to_numpy()[record["keyphasor"].to_numpy() == 1]
    rpm = 60.0 / np.diff(marks)
    assert abs(np.median(rpm[:8]) - row["rpm_start_true"]) < 2.0
    assert abs(np.median(rpm[-2:]) - row["rpm_end_true"]) < 2.0
    trend = np.polyfit(np.arange(rpm.size), rpm, 1)[0]
    assert (trend > 0) == (run == "up1")
    assert row["keyphasor_marks"] == marks.size


def test_dwell_holds_the_steady_orbit_with_runout(made):
    """In the start dwell (1 s at the true start speed) a record is the steady periodic response projected on
    the probe, plus the slow-roll runout, offset and noise. The 1X and 2X vectors fitted on the keyphasor's angle
    (2 pi per mark, a straight line through the dwell's marks) against harmonic balance at the true start speed
    (another solver than the rig's time integration) plus the answer key's runout: the noise of a vector over
    ~4500 samples is 50 um sqrt(2 / 4500) = 1.1 um, the angle read from marks quantised to 0.2 ms leaves
    ~1e-3 rad (~1.5 um on a 1.5 mm orbit); 6 um bounds both. Without the runout (100 um at 1X, 30 um at 2X,
    each x U(0.5, 1)) the vectors would miss by >= 15 um."""
    folder, spec, truth = made
    row = truth.set_index("run").loc["up1"]
    record = pd.read_csv(folder / "out" / "records" / "up1.csv")
    t = record["time_s"].to_numpy()
    marks = t[record["keyphasor"].to_numpy() == 1]
    dwell = marks[marks < 0.95]
    slope, intercept = np.polyfit(dwell, 2 * np.pi * np.arange(dwell.size), 1)
    inside = (t >= dwell[0]) & (t < dwell[-1])
    theta = slope * t[inside] + intercept
    values = spec.truth.variant.values({**spec.truth.values, "m_e": 25.9e-3})
    hb = solve(spec.truth.variant.model.system(values, row["rpm_start_true"]), 7)
    U, V = (hb.harmonics[0][:, d] for d in pair_dofs(spec.truth.machine))
    design = np.column_stack([np.ones(theta.size), np.cos(theta), np.sin(theta), np.cos(2 * theta),
                              np.sin(2 * theta)])
    for name, model_h in (("x", U), ("y", V)):
        coef = np.linalg.lstsq(design, record[f"{name}_um"].to_numpy()[inside] * 1e-6, rcond=None)[0]
        for h in (1, 2):
            measured = coef[2 * h - 1] - 1j * coef[2 * h]
            runout = row[f"runout{h}_{name}_re_m"] + 1j * row[f"runout{h}_{name}_im_m"]
            assert abs(measured - (model_h[h] + runout)) < 6e-6, (name, h)
            assert abs(runout) > 15e-6


def test_probe_angles_project_the_response(tmp_path):
    """Probes at +-45 degrees read cos(a) x + sin(a) y: the dwell's 1X vectors of the rotated pair against
    those of the same run with the model's x, y probes (the same seed: the same conditions and noise), combined
    by the angles. Noise of the difference ~1.5 um at this length (0.5 s at 5 kHz), the runout and offsets
    (same draws) cancel after projection only if the rotation is right: 5 um margin."""
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\tkind\trpm_start\trpm_end\n"
                                       "up\t\t25.9\trunup\t700\t720\n")
    vectors = {}
    for label, angles in (("xy", {}), ("rotated", {"x": 45.0, "y": -45.0})):
        imperfections = Imperfections.from_mapping({**SWEEP, "runout_um": [0.0, 0.0], "offset_mm": 0.0,
                                                    "dwell_start_s": 0.5, "sweep_rate_rpm_s": 40.0,
                                                    "probe_angles_deg": angles})
        generate(read_plan(tmp_path / "plan.tsv"), RigSpec(Truth.from_spec(), imperfections, seed=2),
                 tmp_path / label)
        record = pd.read_csv(tmp_path / label / "records" / "up.csv")
        t = record["time_s"].to_numpy()
        marks = t[record["keyphasor"].to_numpy() == 1]
        dwell = marks[marks < 0.45]
        slope, intercept = np.polyfit(dwell, 2 * np.pi * np.arange(dwell.size), 1)
        inside = (t >= dwell[0]) & (t < dwell[-1])
        theta = slope * t[inside] + intercept
        design = np.column_stack([np.ones(theta.size), np.cos(theta), np.sin(theta)])
        coef = np.linalg.lstsq(design, record[["x_um", "y_um"]].to_numpy()[inside] * 1e-6, rcond=None)[0]
        vectors[label] = coef[1] - 1j * coef[2]
    X, Y = vectors["xy"]
    c = math.cos(math.radians(45))
    assert abs(vectors["rotated"][0] - (c * X + c * Y)) < 5e-6
    assert abs(vectors["rotated"][1] - (c * X - c * Y)) < 5e-6
    assert abs(vectors["rotated"][0] - X) > 50e-6  # the rotation changes the reading (a 1.5 mm orbit)


def test_steady_rows_of_a_mixed_plan_are_written_as_without_transient_rows(made, tmp_path):
    folder, spec, _ = made
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\trole\ns600\t600\t25.9\tfit\n")
    generate(read_plan(tmp_path / "plan.tsv"), spec, tmp_path / "out")
    assert (tmp_path / "out" / "records" / "s600.csv").read_bytes() == \
        (folder / "out" / "records" / "s600.csv").read_bytes()
    steady_key = yaml.safe_load((tmp_path / "out" / "truth.yaml").read_text())["imperfections"]
    assert "runout_um" in steady_key  # SWEEP differs from the defaults: written even for a steady plan
    assert "runout_um" not in yaml.safe_load(yaml.safe_dump(RigSpec().to_mapping()))["imperfections"]


@pytest.mark.parametrize("values, message", [
    ({"sweep_wobble": 1.2}, "sweep_wobble must be in"),
    ({"sweep_rate_rpm_s": 0}, "sweep_rate_rpm_s must be positive"),
    ({"sweep_shape": "s-curve"}, "sweep_shape must be"),
    ({"unit": "inch"}, "unit must be 'mm' or 'm', or 'um' or 'mils'"),
    ({"runout_um": [1, 2, 3]}, "runout_um must be"),
    ({"probe_angles_deg": [45, -45]}, "probe_angles_deg must be a mapping"),
])
def test_bad_imperfections_are_named(values, message):
    with pytest.raises(RigError, match=message):
        Imperfections.from_mapping(values)


def test_bad_plans_and_angles_are_named(tmp_path):
    bad = tmp_path / "bad.tsv"
    bad.write_text("run\trpm\teccentric_mass_g\tkind\trpm_start\trpm_end\n"
                   "a\t\t10\trunup\t700\t600\nb\t\t10\tcoastdown\t\t600\nc\t\t10\tspinup\t1\t2\n")
    with pytest.raises(DataError) as err:
        read_plan(bad)
    text = str(err.value)
    assert str(bad) in text and "line 4, column kind: 'spinup'" in text
    assert "line 2, columns rpm_start, rpm_end: a runup from 700 RPM to 600 RPM slows down" in text  # read_runs's
    assert "column rpm_start: missing value" in text and "line 3 ('')" in text
    assert "column rpm:" not in text  # the unknown kind's row is not taken for a steady one
    good = tmp_path / "good.tsv"
    good.write_text("run\trpm\teccentric_mass_g\tkind\trpm_start\trpm_end\ns\t600\t10\t\t\t\n"
                    "u\t\t10\trunup\t600\t700\n")
    plan = read_plan(good)
    for angles, message in (({"z": 10.0}, "does not have"), ({"x": 45.0}, "applies to run-ups")):
        spec = RigSpec(Truth.from_spec(), Imperfections.from_mapping({"probe_angles_deg": angles}))
        with pytest.raises(RigError, match=message):
            generate(plan, spec, tmp_path / "out")
        assert not (tmp_path / "out" / "records").exists()  # refused before any record


def test_a_start_that_stalls_above_the_settle_tolerance_is_settled_again_and_said(tmp_path, monkeypatch):
    """Where the start's harmonics stall above the settle tolerance (measured: a 0 g run-up from 100 RPM of a
    truth with a cross-coupled stiffness, 1.2e-6-3e-6 for 80 periods), the rig settles again to
    START_TOLERANCE_RETRY and says so in the answer key; a start that diverges is not retried but named."""
    from hybridtwin.rig import sweep as rig_sweep
    from hybridtwin.solvers.transient import NotSettledError

    real = rig_sweep.integrate_sweep
    calls = []

    def stalling(*args, settle_options=None, **kwargs):
        calls.append(dict(settle_options or {}))
        if not settle_options:
            raise NotSettledError("599.90 RPM: no periodic steady state after 20 periods (12 s): the last "
                                  "period-to-period change of the harmonics is 2.99e-06 of the largest", budget=True)
        return real(*args, settle_options=settle_options, **kwargs)

    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\tkind\trpm_start\trpm_end\n"
                                       "up\t\t25.9\trunup\t600\t620\n")
    imperfections = Imperfections.from_mapping({**SWEEP, "dwell_start_s": 0.3, "dwell_end_s": 0.1})
    monkeypatch.setattr(rig_sweep, "integrate_sweep", stalling)
    truth = generate(read_plan(tmp_path / "plan.tsv"), RigSpec(Truth.from_spec(), imperfections, seed=3),
                     tmp_path / "out")
    assert calls == [{}, {"tolerance": rig_sweep.START_TOLERANCE_RETRY}]
    message = truth.set_index("run").loc["up", "message"]
    assert "the default tolerance not reached" in message and "2.99e-06" in message

    def diverging(*args, **kwargs):
        raise NotSettledError("600.00 RPM, period 3: a displacement exceeds 1 m")

    monkeypatch.setattr(rig_sweep, "integrate_sweep", diverging)
    with pytest.raises(RigError, match="could not be integrated: 600.00 RPM, period 3: a displacement exceeds"):
        generate(read_plan(tmp_path / "plan.tsv"), RigSpec(Truth.from_spec(), imperfections, seed=3),
                 tmp_path / "out2")
