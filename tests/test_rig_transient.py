"""The virtual rig's time integrator (RigSpec.integrator "time"): records made by integrating eq. 29 in time
(hybridtwin.solvers.transient, no harmonic-balance code) carry the same truth as the harmonic-balance rig's, with every
nuisance still applied, and the choice is recorded and validated.

Tolerance of the comparison with harmonic balance (HB), max_h |X_time - X_HB| / max_h |X_HB| per run and
channel: each speed is integrated until the harmonics of two successive periods differ by less than
TIME_SETTLE_TOLERANCE = 1e-6 of the largest (twice in a row). The transient left then decays by
rho = exp(-T / tau) per period (tau = 0.3 s, T = 0.12-0.15 s here), so it is at most 1e-6 / (1 - rho) = 3.4e-6;
Radau's own error at atol = 3e-6 x the amplitude is <= 1.2e-7, and HB with H = 7 is exact to ~1e-16 at these
speeds. 2e-5 keeps a margin of 5 over that bound (measured here: < 5e-7; the default 22-run plan: <= 2.1e-6).
A wrong phase convention, sign, harmonic or branch would be off by 1e-2 to 1.
"""

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridtwin.solvers import transient as tr
from hybridtwin.cli import main
from hybridtwin.data.measurements import read_runs
from hybridtwin.data.records import read_record
from hybridtwin.rig.rig import (
    TIME_UNIQUE_TOLERANCE, Imperfections, RigError, RigSpec, Truth, generate,
)
from hybridtwin.model.sensor import sensor_dofs

H = 7
TOLERANCE = 2e-5
PLAN = pd.DataFrame({"run": ["a", "b", "c"], "rpm": [400.0, 450.0, 500.0], "eccentric_mass_g": 25.9,
                     "role": ["fit", "fit", "validate"]})
IMPERFECTIONS = Imperfections(duration_s=1.0, noise_mm=(0.02, 0.08), keyphasor=True)


def harmonics(table: pd.DataFrame, channel: str) -> np.ndarray:
    return np.stack([table[f"{channel}{h}_re_m"] + 1j * table[f"{channel}{h}_im_m"] for h in range(H + 1)], 1)


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The same plan and seed through both integrators: (time folder, time truth, hb truth)."""
    folder = tmp_path_factory.mktemp("time")
    time_truth = generate(PLAN, RigSpec(imperfections=IMPERFECTIONS, seed=7, harmonics=H, integrator="time"),
                          folder)
    hb_truth = generate(PLAN, RigSpec(imperfections=IMPERFECTIONS, seed=7, harmonics=H),
                        tmp_path_factory.mktemp("hb"))
    return folder, time_truth, hb_truth


def test_time_integrated_harmonics_agree_with_harmonic_balance(both):
    _, time_truth, hb_truth = both
    for channel in ("x", "y"):
        Z_time, Z_hb = harmonics(time_truth, channel), harmonics(hb_truth, channel)
        scale = np.abs(Z_hb).max(1)
        assert (scale > 1e-4).all()  # 0.37-0.67 mm: a real response, not two zeros agreeing
        assert (np.abs(Z_time - Z_hb).max(1) / scale < TOLERANCE).all()
    # one branch reached from both sides: the time run-down from rest at 700 RPM agrees with the run-up
    assert time_truth["unique"].all() and (time_truth["updown_difference_rel"] < TOLERANCE).all()
    assert TIME_UNIQUE_TOLERANCE > 10 * TOLERANCE
    assert (time_truth["branch"] == "time run-up").all()
    assert time_truth["message"].str.startswith("settled after").all()


def test_nuisances_apply_to_time_integrated_records(both):
    folder, time_truth, hb_truth = both
    # the same draws as the HB rig: they come from (seed, run id), not from the integrator
    columns = ["rpm_true", "phase_origin_rad", "offset_x_m", "offset_y_m", "noise_x_m", "noise_y_m"]
    pd.testing.assert_frame_equal(time_truth[columns], hb_truth[columns])
    assert (time_truth["rpm_true"] != time_truth["rpm"]).all()  # the speed error
    sheet = read_runs(folder / "runs.tsv")
    for row, path in zip(time_truth.itertuples(), sheet["record"]):
        record = read_record(path)
        assert record.n_samples == 2000 and record.keyphasor is not None and record.keyphasor.sum() >= 6
        # record minus the truth's clean signal at the drawn speed and phase origin = offset + noise
        angle = 2 * np.pi * row.rpm_true / 60 * record.time_s + row.phase_origin_rad
        rotation = np.exp(1j * np.outer(angle, np.arange(H + 1)))
        for channel, data in (("x", record.x_m), ("y", record.y_m)):
            Z = harmonics(time_truth.loc[[row.Index]], channel)[0]
            residual = data - (rotation @ Z).real
            noise, offset = getattr(row, f"noise_{channel}_m"), getattr(row, f"offset_{channel}_m")
            assert abs(residual.mean() - offset) < 5 * noise / np.sqrt(record.n_samples) + 1e-7
            assert residual.std() == pytest.approx(noise, rel=0.1)  # 2000 samples: std known to 1.6 %


def test_truth_yaml_records_the_integrator(both, tmp_path):
    folder, _, _ = both
    key = yaml.safe_load((folder / "truth.yaml").read_text())
    assert key["integrator"] == "time"
    assert RigSpec.from_mapping({k: key[k] for k in ("seed", "harmonics", "integrator")}).integrator == "time"
    assert RigSpec().to_mapping()["integrator"] == "hb"  # the default, written too
    # the command line: --integrator time for one run
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\nk\t450\t36.0\n")
    code = main(["rig", "--plan", str(tmp_path / "plan.tsv"), "--out", str(tmp_path / "out"), "--duration-s", "0.2",
                 "--integrator", "time"])
    assert code == 0
    assert yaml.safe_load((tmp_path / "out" / "truth.yaml").read_text())["integrator"] == "time"


def test_bad_integrator_is_rejected_by_name(tmp_path, capsys):
    with pytest.raises(RigError, match=r"integrator must be one of \['hb', 'time'\], got 'rk4'"):
        RigSpec.from_mapping({"integrator": "rk4"})
    with pytest.raises(RigError, match="got 'euler'"):
        RigSpec(integrator="euler")
    (tmp_path / "spec.yaml").write_text("integrator: leapfrog\n")
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\nk\t450\t36.0\n")
    assert main(["rig", "--spec", str(tmp_path / "spec.yaml"), "--plan", str(tmp_path / "plan.tsv"),
                 "--out", str(tmp_path / "out")]) == 1
    assert "got 'leapfrog'" in capsys.readouterr().err


def test_a_response_that_diverges_in_time_is_no_steady_state(tmp_path):
    # tests/test_rig.py's lightly damped Geometric machine at 900 RPM: harmonic balance finds periodic orbits
    # (run-up and run-down differ), but integrated in time the response escapes (the softening u v^2 term),
    # from rest and from 1100 RPM alike (also on a quasi-static run-up from 700 RPM in 25-50 RPM steps)
    truth = Truth.from_spec({"effects": ["centrifugal_softening", "structural_damping", "upper_housing",
                                         "lower_bearing", "unbalance", "shaft_bow", "geometric_spring"],
                             "values": {"k_b": 2411.3, "zeta_s": 0.01, "zeta_bup": 0.0, "q_x": 0.006, "q_y": 0.006}})
    spec = RigSpec(truth, Imperfections(duration_s=0.2, speed_error=0.0), harmonics=5, integrator="time")
    plan = pd.DataFrame({"run": ["d"], "rpm": [900.0], "eccentric_mass_g": [0.0]})
    with pytest.raises(RigError, match=r"no periodic steady state at: d \(time run-up: 900.00 RPM, period \d+: "
                                       r"a displacement reached .* m \(> 1 m\) .* the response diverges"):
        generate(plan, spec, tmp_path)


def test_settle_reports_a_period_budget_too_short():
    truth = Truth.from_spec()
    system = truth.variant.model.system(truth.variant.values({**truth.values, "m_e": 0.0259}), 450.0)
    first_order = tr.FirstOrder.from_system(system, fast_forces=True)
    with pytest.raises(tr.NotSettledError, match="no periodic steady state after 3 periods"):
        tr.settle(first_order, sensor_dofs(truth.variant.model.shaft), H, max_periods=3)


def test_identified_polynomial_forces_equal_evaluate():
    # the fast path of the time integrator evaluates the bearing force from its monomials: same rhs and Jacobian
    truth = Truth.from_spec()
    system = truth.variant.model.system(truth.variant.values({**truth.values, "m_e": 0.0259}), 700.0)
    slow, fast = tr.FirstOrder.from_system(system), tr.FirstOrder.from_system(system, fast_forces=True)
    assert fast.polynomials and all(p is not None for p in fast.polynomials)
    rng = np.random.default_rng(3)
    for size in (1e-1, 1e-2, 1e-4):
        y = size * rng.standard_normal(2 * slow.n)
        F_slow, J_slow = slow.local_force(y[: slow.n], True)
        F_fast, J_fast = fast.local_force(y[: slow.n], True)
        np.testing.assert_allclose(F_fast, F_slow, rtol=0, atol=1e-10 * np.abs(F_slow).max())
        np.testing.assert_allclose(J_fast, J_slow, rtol=0, atol=1e-10 * np.abs(J_slow).max())
        np.testing.assert_allclose(fast.rhs(0.01, y), slow.rhs(0.01, y), rtol=0,
                                   atol=1e-12 * np.abs(slow.rhs(0.01, y)).max())
