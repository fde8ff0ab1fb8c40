"""The full solver as a forward model (forward.SolverModel): warm starts and exact sensitivities.

References, independent of what is checked:
- cold starts: the same model with warm starts off solves every point by a run-up from 300 RPM,
  the branch the rig reaches (the definition of the model's response);
- forward differences of those cold solves (``analytic=False``, the former method) for the Jacobian;
- for the stability of a reported steady state: the solver's own run-up sweep (``solve_sweep``, 25 RPM
  steps from 300 RPM, stability assessed at every step), a route to the state that shares nothing with the
  model's warm starts.
"""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from hybridtwin.identify.forward import SolverModel, StabilityWarning, check_stability, floquet_radii
from hybridtwin.model.variants import builtin_variant

GEOMETRIC = builtin_variant("geometric")
NAMES = list(GEOMETRIC.unknown)
LOWER, UPPER = GEOMETRIC.bounds(NAMES)


def _model(rpm, mass_g, **options):
    return SolverModel(GEOMETRIC, f"r{rpm:g}", rpm, mass_g, NAMES, LOWER, UPPER, 5, **options)


def _path(rng, n, start, scale):
    """A random walk in normalised parameters, like the points an LM visits (steps of ``scale``)."""
    x = np.clip(start + np.cumsum(scale * rng.standard_normal((n, len(NAMES))), axis=0), -0.95, 0.95)
    return x


@pytest.mark.parametrize("rpm,mass_g", [(650.0, 25.9), (900.0, 0.0), (850.0, 14.8)])
def test_warm_starts_give_the_run_up_response(rpm, mass_g):
    rng = np.random.default_rng(int(rpm))
    warm, cold = _model(rpm, mass_g), _model(rpm, mass_g, warm=False)
    with threadpool_limits(1):
        points = _path(rng, 12, rng.uniform(-0.5, 0.5, len(NAMES)), 0.08)
        for batch in np.array_split(points, 4):  # batches of 3, as LM trials
            M_warm, J_warm = warm.evaluate(batch)
            M_cold, J_cold = cold.evaluate(batch)
            ok = np.isfinite(M_cold).all(axis=(1, 2))
            assert (np.isfinite(M_warm).all(axis=(1, 2)) == ok).all()
            # the same steady state, converged to tol 1e-10 ||x|| by either route: agreement to ~1e-9
            scale = np.abs(M_cold[ok]).max()
            assert np.abs(M_warm[ok] - M_cold[ok]).max() < 1e-8 * scale
            assert np.abs(J_warm[ok] - J_cold[ok]).max() < 1e-6 * np.abs(J_cold[ok]).max()
    assert warm.n_warm > 0 and cold.n_warm == 0  # the warm model really continued in the parameters
    assert warm.n_solves == cold.n_solves == cold.n_run_ups


def test_exact_sensitivities_match_differences_of_the_run_up():
    exact = _model(800.0, 14.8)
    differences = _model(800.0, 14.8, analytic=False, warm=False, step=1e-6)
    x = np.array([[0.1, -0.2, 0.3, -0.4, 0.2], [-0.5, 0.4, -0.1, 0.6, -0.3]])
    with threadpool_limits(1):
        M1, J1 = exact.evaluate(x)
        M2, J2 = differences.evaluate(x)
    assert np.abs(M1 - M2).max() < 1e-8 * np.abs(M2).max()
    for j in range(len(NAMES)):
        column = np.abs(J2[..., j]).max()
        # forward differences at 1e-6 (normalised): truncation ~1e-6 relative, the solves' tolerance
        # ~1e-10 / 1e-6 = 1e-4 of the smallest columns at most; a wrong sign or factor is O(1)
        assert np.abs(J1[..., j] - J2[..., j]).max() < 2e-4 * column, NAMES[j]
    # the exact Jacobian costs no extra solve: 2 sets solved, against 2 (1 + 5) for the differences
    assert exact.n_solves == 2 and differences.n_solves == 12


def test_a_far_point_is_not_continued_across_a_branch():
    # near the fold (950 RPM, no unbalance) the run-up response can change branch with the parameters:
    # whatever the previous points were, every response equals the cold run-up's
    rng = np.random.default_rng(5)
    warm, cold = _model(950.0, 0.0), _model(950.0, 0.0, warm=False)
    points = rng.uniform(-0.9, 0.9, (16, len(NAMES)))
    with threadpool_limits(1):
        for batch in np.array_split(points, 8):
            M_warm, _ = warm.evaluate(batch, jacobian=False)
            M_cold, _ = cold.evaluate(batch, jacobian=False)
            ok = np.isfinite(M_cold).all(axis=(1, 2))
            assert (np.isfinite(M_warm).all(axis=(1, 2)) == ok).all()
            assert np.abs(M_warm[ok] - M_cold[ok]).max() <= 1e-8 * np.abs(M_cold[ok]).max()


def test_an_lm_fit_with_warm_starts_ends_where_the_cold_one_does():
    """The LM's iterates take large steps early on; continuing along them must not change the fit. A misfit
    case (the data have a softer lower bearing the model lacks, so the fit ends far from the data): warm
    starts accepted too loosely (0.5 of the predicted change + 1e-2 of the state) sent this fit elsewhere
    (chi^2/dof 4312 against 3697)."""
    from hybridtwin.identify import identification as idn
    from hybridtwin.identify import lm
    from hybridtwin.identify.protocol import ProtocolOptions
    from hybridtwin.model.variants import Variant

    truth = Variant.from_spec("truth", {"effects": [e.name for e in GEOMETRIC.model.effects] + ["lower_bearing_compliance"],
                                        "unknown": {"dk_lo": (-1e9, 1e9)}})
    rng = np.random.default_rng(6)
    data = []
    for rpm, mass in ((500.0, 25.9), (650.0, 25.9), (750.0, 14.8), (850.0, 14.8)):
        values = {"k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "q_x": 0.002, "q_y": 0.0015, "dk_lo": -3000.0}
        model = SolverModel(truth, "t", rpm, mass, list(values), np.array(list(values.values())) - 1.0,
                            np.array(list(values.values())) + 1.0, 3)
        M = model.evaluate(np.zeros((1, len(values))), jacobian=False)[0][0]
        noise = 8e-7 * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
        data.append(idn.RunData(f"r{rpm:g}", rpm, mass, "fit", M + noise, np.full(M.shape, 8e-7)))
    options = ProtocolOptions(trials=3, monte_carlo=0, seed=2, lm=lm.LMOptions(max_iterations=60))
    fits = []
    with threadpool_limits(1):
        for warm in (True, False):
            models = [SolverModel(GEOMETRIC, d.run, d.rpm, d.eccentric_mass_g, NAMES, LOWER, UPPER, 3, warm=warm)
                      for d in data]
            fits.append(idn.identify(models, data, (), options))
    # the same LM on the same responses: every trial ends at the same loss (the solves' tolerance 1e-10)
    np.testing.assert_allclose(fits[0].protocol.trials.loss, fits[1].protocol.trials.loss, rtol=1e-6)


# the geometric machine lightly damped (zeta_s = 0.01, no upper-bearing damper), the bow and k_b nominal: its
# run-up branch with 14.8 g loses stability just below its fold (|mu| = 2.28 at 866 RPM, tests/test_stability.py)
LIGHT = {"k_b": 2331.5, "zeta_s": 0.01, "zeta_bup": 0.0, "q_x": 0.005, "q_y": 0.005}


def _run_up_radius(variant, values, rpm, mass_g, harmonics=5):
    """The reference: the Floquet radius of the solver's own run-up to ``rpm`` (stability assessed there)."""
    from hybridtwin.solvers.continuation import solve_sweep

    full = variant.values({**values, "m_e": mass_g * 1e-3})
    speeds = np.append(np.arange(300.0, rpm, 25.0), rpm)
    sweep = solve_sweep(lambda s, rows: variant.model.system(full, s), speeds, 1, harmonics=harmonics)
    return sweep.results[-1].floquet_radius[0]


@pytest.mark.parametrize("rpm,mass_g,stable", [(700.0, 25.9, True), (860.0, 14.8, False), (866.0, 14.8, False)])
def test_the_reported_state_carries_the_stability_of_the_run_up_it_stands_for(rpm, mass_g, stable):
    x = np.array([[2 * (LIGHT[p] - lo) / (hi - lo) - 1 for p, lo, hi in zip(NAMES, LOWER, UPPER)], [np.nan] * 5])
    warm, cold = _model(rpm, mass_g), _model(rpm, mass_g, warm=False)
    with threadpool_limits(1):
        warm.evaluate(x[:1])  # an LM's evaluation (no stability check), then the check of that point
        radius_warm = warm.floquet_radius(x)
        radius_cold = cold.floquet_radius(x)
        reference = _run_up_radius(GEOMETRIC, LIGHT, rpm, mass_g)
    assert warm.n_warm == 1  # the check re-solved the state the evaluation reported (warm start, same branch)
    # the same steady state (converged to 1e-10 by either route) gives the same multipliers: measured ~1e-10
    np.testing.assert_allclose([radius_warm[0], radius_cold[0]], reference, rtol=1e-6)
    assert (reference < 1.0) == stable
    assert np.isnan(radius_warm[1]) and np.isnan(radius_cold[1])  # no parameters, no state
    # floquet_radii batches runs of one variant like evaluate_runs: the same numbers, None for no solver model
    together = floquet_radii([_model(rpm, mass_g), _model(700.0, 25.9), object()], [x, x[:1], x])
    np.testing.assert_allclose(together[0][0], reference, rtol=1e-6)
    assert together[1][0] < 1.0 and together[2] is None


def test_an_unstable_optimum_is_flagged_on_the_fit_and_never_reported_as_converged():
    """A full-solver fit of two runs whose optimum has an unstable steady state at one of them (866 RPM, above):
    the check names that run on the fit's message, in its notes and in a warning; the stable run is not named."""
    from hybridtwin.identify import identification as idn
    from hybridtwin.identify import lm
    from hybridtwin.identify.protocol import ProtocolOptions
    from hybridtwin.model.variants import Variant

    variant = Variant.from_spec("light", {"effects": [e.name for e in GEOMETRIC.model.effects],
                                          "unknown": {"k_b": (2300.0, 2360.0), "zeta_s": (0.009, 0.011)},
                                          "fixed": {"zeta_bup": 0.0}})
    names = ["k_b", "zeta_s"]
    lower, upper = variant.bounds(names)
    truth = np.array([[2 * (LIGHT["k_b"] - 2300.0) / 60.0 - 1, 2 * (LIGHT["zeta_s"] - 0.009) / 0.002 - 1]])
    rng = np.random.default_rng(3)
    data, models = [], []
    with threadpool_limits(1):
        for rpm, mass in ((700.0, 25.9), (866.0, 14.8)):
            model = SolverModel(variant, f"r{rpm:g}", rpm, mass, names, lower, upper, 3)
            M = model.evaluate(truth, jacobian=False)[0][0]
            noise = 1e-6 * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
            data.append(idn.RunData(f"r{rpm:g}", rpm, mass, "fit", M + noise, np.full(M.shape, 1e-6)))
            models.append(SolverModel(variant, f"r{rpm:g}", rpm, mass, names, lower, upper, 3))
        fit = idn.identify(models, data, (), ProtocolOptions(trials=2, monte_carlo=0, seed=1,
                                                             lm=lm.LMOptions(max_iterations=40)))
        before = fit.message
        with pytest.warns(StabilityWarning, match=r"unstable steady state at run\(s\) r866 \(\|mu\| = 2\.\d+\)"):
            check = check_stability(fit)
        fitted = dict(zip(names, fit.x[:2]))
        reference = [_run_up_radius(variant, fitted, rpm, mass, 3) for rpm, mass in ((700.0, 25.9), (866.0, 14.8))]
    assert check.runs == ["r700", "r866"] and check.unstable_runs == ["r866"]
    assert list(check.stable) == [True, False]
    # the optimum's states, checked at the fitted parameters, against the run-up reference there: the same states
    # to the solves' tolerance (1e-10), so the same multipliers (rtol 1e-6 leaves room; the radius at the truth,
    # 0.0025 away in zeta_s, differs by 2e-3)
    np.testing.assert_allclose(check.floquet_radius, reference, rtol=1e-6)
    assert fit.message == f"unstable steady state at run(s) r866; {before}"
    notes = [n for n in fit.uncertainty.notes if n.startswith("unstable steady state")]
    assert len(notes) == 1 and "r866" in notes[0] and "r700" not in notes[0]
    with pytest.warns(StabilityWarning):
        check_stability(fit)  # checked again: flagged once, not twice
    assert fit.message.count("unstable") == 1 and len(fit.uncertainty.notes) == len(set(fit.uncertainty.notes))
    # the full-solver polish, which every joint fit of the workflow and every per-run polish ends with, checks its
    # own optimum the same way: the same run named, the stable one not
    from hybridtwin.identify.polish import polish

    with threadpool_limits(1), pytest.warns(StabilityWarning, match=r"run\(s\) r866 \("):
        polished = polish(fit, models, random_starts=0)
    assert polished.message.startswith("unstable steady state at run(s) r866;") and "r700" not in polished.message
    # nothing to check without solver models: a library fit, or a fit read back from its table (no problem)
    from types import SimpleNamespace

    assert check_stability(SimpleNamespace(problem=None)) is None
    assert check_stability(SimpleNamespace(problem=SimpleNamespace(models=[object()]))) is None


def test_the_lockstep_run_ups_are_each_runs_own_run_up_bit_for_bit():
    """``run_ups`` (every set on its own speed ramp, one lockstep sweep) against ``run_up`` called set by set:
    the solver treats scenarios independently and each set keeps its own ramp from 300 RPM, so the states
    (and the jump flags) are the same numbers, not just close. Speeds below, at and above the ramp's start,
    both sides of the resonance, the three eccentric masses."""
    from hybridtwin.identify.forward import run_up, run_ups

    variant = builtin_variant("geometric")
    rng = np.random.default_rng(3)
    rpm = np.repeat([250.0, 300.0, 450.0, 700.0, 850.0, 950.0, 1000.0], 3)
    S = rpm.size
    values = variant.values({"k_b": rng.uniform(2000, 3500, S), "zeta_s": rng.uniform(0.01, 0.05, S),
                             "m_e": np.tile([0.0148, 0.0216, 0.0], 7)})
    values = {k: np.broadcast_to(np.asarray(v, float), (S,)).copy() for k, v in values.items()}
    with threadpool_limits(1):
        states, jumped = run_ups(variant, rpm, values, 5)
        for s in range(S):
            own, jump = run_up(variant, [rpm[s]], {k: v[s:s + 1] for k, v in values.items()}, 5, jumps=True)
            np.testing.assert_array_equal(states.harmonics[s], own[0].harmonics[0])
            assert jumped[s] == jump[0]
    assert states.success.all()
