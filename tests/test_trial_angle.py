"""Trial weights at an angle (issue 39, item 5): a run's trial mass at eccentric_mass_angle_deg theta (from +x
towards +y, the sense of rotation, at the keyphasor mark t = 0) turns its 1X force by exp(i theta).

References, each independent of the code under test: the closed form of a linear model (its response is linear in
the force, so the trial mass's share turns by exp(i theta) and the bow's stays); the time invariance of the
nonlinear model (a mass at theta is the mass at 0 a time theta / Omega later, so with no other forcing every
harmonic h turns by exp(i h theta)), checked against the time integrator; the rig's records, preprocessed; an
identification on them that recovers the truth with the angles and misfits without them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridtwin import config as cfg
from hybridtwin.data.measurements import DataError, read_runs
from hybridtwin.data.preprocessing import preprocess_run
from hybridtwin.data.record_columns import harmonic_column
from hybridtwin.rig.rig import DEFAULT_TRUTH, Imperfections, RigSpec, Truth, generate, solve_truth
from hybridtwin.identify import identification as idn
from hybridtwin.identify.run_fits import fit_joint, fit_run, refuse_angle_on_library
from hybridtwin.model.effects import builtin_effects, trial_mass_values
from hybridtwin.model.machine import Machine
from hybridtwin.model.model import Model
from hybridtwin.model.sensor import sensor_dofs
from hybridtwin.solvers.solver import solve
from hybridtwin.settings import IdentificationSettings

# the VARM with a linear spring (the lower bearing's) at the upper bearing instead of its nonlinear springs
LINEAR = ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "lower_bearing@upper",
          "unbalance", "shaft_bow"]
NO_BOW = {**DEFAULT_TRUTH["values"], "q_x": 0.0, "q_y": 0.0}  # no residual unbalance: the trial mass alone


def _steady(model, values, rpm, H=3):
    result = solve(model.system({k: np.atleast_1d(v) for k, v in values.items()}, rpm), H)
    assert result.success[0]
    return result.harmonics[0]  # (H + 1, n)


@pytest.mark.parametrize("angle_deg", [90.0, 217.5, -30.0])
def test_a_linear_model_turns_the_trial_mass_share_by_exp_i_theta_and_keeps_the_bow(angle_deg):
    fx = builtin_effects() | Machine.varm().effects()
    model = Model([fx[name] for name in LINEAR])
    base = {p.name: p.nominal for e in model.effects for p in e.parameters} | {"q_x": 0.002, "q_y": 0.0015}
    at_zero = _steady(model, base | trial_mass_values(20.0), 700.0)
    at_theta = _steady(model, base | trial_mass_values(20.0, angle_deg), 700.0)
    bow_only = _steady(model, base | trial_mass_values(20.0) | {"r_me": 0.0}, 700.0)  # same point mass, no force
    rotation = np.exp(1j * np.deg2rad(angle_deg))
    expected = bow_only[1] + rotation * (at_zero[1] - bow_only[1])  # closed form: X = X_bow + e^{i theta} X_me
    # a linear solve of the same matrix: round-off (1e-12 of the response) is all that may differ
    np.testing.assert_allclose(at_theta[1], expected, rtol=0, atol=1e-12 * np.abs(at_zero[1]).max())
    assert np.abs(at_theta[1] - at_zero[1]).max() > 0.1 * np.abs(at_zero[1]).max()  # the angle does act
    # without the bow the whole 1X turns: exp(i theta) exactly
    no_bow = base | {"q_x": 0.0, "q_y": 0.0}
    np.testing.assert_allclose(_steady(model, no_bow | trial_mass_values(20.0, angle_deg), 700.0)[1],
                               rotation * _steady(model, no_bow | trial_mass_values(20.0), 700.0)[1],
                               rtol=0, atol=1e-12 * np.abs(at_zero[1]).max())


def test_the_angle_zero_is_the_model_before_angles_bit_for_bit():
    assert trial_mass_values(14.8, 0.0) == {"m_e": 14.8e-3} == trial_mass_values(14.8, 360.0)
    assert trial_mass_values(14.8, -90.0)["angle_me"] == pytest.approx(1.5 * np.pi)


def test_the_nonlinear_varm_at_an_angle_is_the_angle_zero_orbit_later_by_theta_over_omega_time_integrated():
    truth = Truth.from_spec({"values": NO_BOW})
    theta = 70.0
    runs = pd.DataFrame({"run": ["a", "b"], "rpm_true": [650.0, 650.0], "eccentric_mass_g": [14.8, 14.8],
                         "eccentric_mass_angle_deg": [0.0, theta]})
    hb = solve_truth(truth, runs, harmonics=3)
    time = solve_truth(truth, runs.iloc[[1]].reset_index(drop=True), harmonics=3, integrator="time")
    h = np.arange(4)[:, None]
    shifted = np.exp(1j * h * np.deg2rad(theta)) * hb.Z[0]  # harmonic h of x(t + theta / Omega)
    scale = np.abs(hb.Z[0]).max()
    # harmonic balance at theta against the shifted orbit at 0: the same Newton tolerance (1e-9 of the response)
    np.testing.assert_allclose(hb.Z[1], shifted, rtol=0, atol=1e-8 * scale)
    # the time integrator (no harmonic-balance code) settles to TIME_SETTLE_TOLERANCE = 1e-6 per period; its
    # DFT of one settled period agrees with the HB orbit to ~1e-5 of the response (tests/test_transient.py)
    np.testing.assert_allclose(time.Z[0], shifted, rtol=0, atol=1e-4 * scale)
    assert np.abs(hb.Z[1] - hb.Z[0]).max() > 0.5 * scale  # 70 degrees apart: far more than the tolerance


@pytest.fixture(scope="module")
def angled_rig(tmp_path_factory):
    """Records of the rig integrated in time (not our harmonic balance), every default nuisance on (speed error,
    random offsets, noise), a keyphasor: runs with the mass on +x and at 120 / 250 degrees."""
    out = tmp_path_factory.mktemp("angled")
    plan = pd.DataFrame({"run": ["r0", "r120", "s0", "s250"], "rpm": [600.0, 600.0, 720.0, 720.0],
                         "eccentric_mass_g": [14.8, 14.8, 25.9, 25.9],
                         "eccentric_mass_angle_deg": [0.0, 120.0, 0.0, 250.0], "role": "fit"})
    spec = RigSpec(Truth.from_spec({"values": {**NO_BOW, "q_x": 0.002, "q_y": 0.0015}}),
                   Imperfections(duration_s=2.0, keyphasor=True), seed=11, harmonics=3, integrator="time")
    truth = generate(plan, spec, out)
    sheet = read_runs(out / "runs.tsv")
    table = pd.concat([preprocess_run(row, 3)[0] for _, row in sheet.iterrows()], ignore_index=True)
    return out, truth, sheet, table


def test_the_rig_writes_the_angle_and_its_records_show_the_1x_turned(angled_rig, tmp_path):
    out, truth, sheet, table = angled_rig
    np.testing.assert_array_equal(sheet["eccentric_mass_angle_deg"], [0.0, 120.0, 0.0, 250.0])
    # with no bow the truth's 1X turns by exactly theta (time invariance, as above) ...
    spec_no_bow = RigSpec(Truth.from_spec({"values": NO_BOW}),
                          Imperfections(duration_s=2.0, keyphasor=True), seed=11, harmonics=3, integrator="time")
    plan = sheet[["run", "rpm", "eccentric_mass_g", "eccentric_mass_angle_deg", "role"]].iloc[:2]
    generate(plan, spec_no_bow, tmp_path)
    rows = read_runs(tmp_path / "runs.tsv")
    measured = pd.concat([preprocess_run(row, 3)[0] for _, row in rows.iterrows()], ignore_index=True)
    for c in ("x", "y"):
        X = measured[harmonic_column(c, 1, "re")] + 1j * measured[harmonic_column(c, 1, "im")]
        sigma = measured[harmonic_column(c, 1, "sigma")]
        turn = np.angle(X[1] / X[0], deg=True)
        # ... and the records, preprocessed against their keyphasor, show it within their noise: the phase's
        # standard uncertainty is sigma / |X| per run (sigma per real and imaginary part), 5 of them allowed
        allowed = np.rad2deg(5 * np.hypot(sigma[0] / abs(X[0]), sigma[1] / abs(X[1])))
        assert abs((turn - 120.0 + 180.0) % 360.0 - 180.0) < allowed, (c, turn, allowed)


def test_identification_on_angled_records_recovers_the_truth_and_ignoring_the_angle_misfits(angled_rig):
    out, truth, sheet, table = angled_rig
    config = yaml.safe_load(open(cfg.CONFIG_FILE))
    variant = cfg.variant(config, "final")  # the rig's truth: Geometric + slope spring
    options = IdentificationSettings.from_config(config).rule("final", "joint") | {"per_run": [], "trials": 2,
                                                                                   "polish": False}
    runs = list(sheet["run"])
    H = 2
    fit = fit_joint(variant, options, [], table, {}, None, H, runs=runs).fit
    # an exact model on records of noise 0.05 mm: chi^2/dof near 1 (dof ~ 4 runs x 8 numbers - 7 shared - 4
    # phases = 21: 1 +- 0.3); the truth's bow inside its 95 % interval
    assert fit.chi2_dof < 2.0, fit.chi2_dof
    shared = fit.table().set_index("parameter")
    for p in ("q_x", "q_y", "k_b"):
        assert shared.loc[p, "ci_low"] <= spec_value(p) <= shared.loc[p, "ci_high"], (p, shared.loc[p].to_dict())
    ignored = fit_joint(variant, options, [], table.drop(columns="eccentric_mass_angle_deg"), {}, None, H,
                        runs=runs).fit
    assert ignored.chi2_dof > 20 * fit.chi2_dof, (ignored.chi2_dof, fit.chi2_dof)  # the same data, angles lost


def spec_value(p):
    return {**DEFAULT_TRUTH["values"], "q_x": 0.002, "q_y": 0.0015}[p]


@pytest.mark.parametrize("cell, what", [("north", "not a number"), ("inf", "not finite"), ("NaN", "missing value"),
                                        ("12,5", "decimal comma")])
def test_a_bad_angle_is_named_with_file_line_and_column(tmp_path, cell, what):
    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\teccentric_mass_angle_deg\n"
                     "a\t600\t14.8\t90\n"
                     f"b\t700\t14.8\t{cell}\n")
    with pytest.raises(DataError) as err:
        read_runs(sheet, check_files=False, require_path=False)
    text = str(err.value)
    assert str(sheet) in text and "line 3" in text and "column eccentric_mass_angle_deg" in text and what in text


def test_an_empty_or_absent_angle_is_zero_and_any_finite_angle_is_allowed(tmp_path):
    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\teccentric_mass_angle_deg\na\t600\t14.8\t\nb\t700\t14.8\t-450\n")
    read = read_runs(sheet, check_files=False, require_path=False)
    np.testing.assert_array_equal(read["eccentric_mass_angle_deg"], [0.0, -450.0])
    sheet.write_text("run\trpm\teccentric_mass_g\na\t600\t14.8\n")
    assert "eccentric_mass_angle_deg" not in read_runs(sheet, check_files=False, require_path=False)


def test_trial_angles_reads_the_column_read_runs_parsed_and_parses_nothing_again(tmp_path):
    """One parser (read_runs) for the angle cells; trial_angles takes its floats, from the sheet and from the
    harmonics table written from it and read back; a column of text (a sheet not read by read_runs) is refused,
    not coerced (the old pd.to_numeric(errors="coerce") turned "north" into 0 without a word)."""
    from hybridtwin.data.measured import read_harmonics, write_harmonics
    from hybridtwin.data.measurements import trial_angles

    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\teccentric_mass_angle_deg\na\t600\t14.8\t\nb\t700\t14.8\t-450\n"
                     "c\t800\t14.8\t12.5\n")
    read = read_runs(sheet, check_files=False, require_path=False)
    np.testing.assert_array_equal(trial_angles(read), [0.0, -450.0, 12.5])
    write_harmonics(read[["run", "rpm", "eccentric_mass_g", "eccentric_mass_angle_deg"]], tmp_path / "h.tsv")
    np.testing.assert_array_equal(trial_angles(read_harmonics(tmp_path / "h.tsv")), [0.0, -450.0, 12.5])
    joined = pd.concat([read.iloc[1:], read.drop(columns="eccentric_mass_angle_deg").iloc[:1]], ignore_index=True)
    np.testing.assert_array_equal(trial_angles(joined), [-450.0, 12.5, 0.0])
    np.testing.assert_array_equal(trial_angles(read.drop(columns="eccentric_mass_angle_deg")), [0.0, 0.0, 0.0])
    raw = pd.read_csv(sheet, sep="\t", dtype=str, keep_default_na=False)  # the cells as text, not parsed
    with pytest.raises(TypeError, match="read_runs"):
        trial_angles(raw)


def test_the_libraries_refuse_an_angled_run_naming_the_option(tmp_path):
    data = idn.RunData("b", 700.0, 14.8, "fit", np.zeros((2, 2), complex), np.ones((2, 2)),
                       eccentric_mass_angle_deg=45.0)
    with pytest.raises(ValueError, match="offline: scope: none"):
        refuse_angle_on_library(data)
    config = yaml.safe_load(open(cfg.CONFIG_FILE))
    variant = cfg.variant(config, "geometric")
    library = SimpleNamespace(parameters=["k_b"], lower=np.zeros(1), upper=np.ones(1))
    options = IdentificationSettings.from_config(config).rule("geometric", "run")
    with pytest.raises(ValueError, match="eccentric_mass_angle_deg 45"):
        fit_run(variant, options, library, data, None, 2)
    sheet = pd.DataFrame({"run": ["a", "b"], "eccentric_mass_angle_deg": [0.0, 45.0]})
    library_config = config | {"variants": {"geometric": config["variants"]["geometric"]},
                               "offline": {**config.get("offline", {}), "scope": "run"}}
    assert "offline: scope: none" in cfg.angles_on_libraries(library_config, sheet)
    solver_config = library_config | {"offline": {**config.get("offline", {}), "scope": "none"}}
    assert cfg.angles_on_libraries(solver_config, sheet) is None
    assert cfg.angles_on_libraries(library_config, sheet.assign(eccentric_mass_angle_deg=[0.0, 360.0])) is None
