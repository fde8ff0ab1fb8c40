"""The full solver as a forward model (forward.SolverModel): warm starts and exact sensitivities.

References, independent of what is checked:
- cold starts: the same model with warm starts off solves every point by a run-up from 300 RPM,
  the branch the rig reaches (the definition of the model's response);
- forward differences of those cold solves (``analytic=False``, the former method) for the Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from hybridtwin.forward import SolverModel
from hybridtwin.variants import builtin_variant

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
    from hybridtwin import identification as idn
    from hybridtwin import lm
    from hybridtwin.protocol import ProtocolOptions
    from hybridtwin.variants import Variant

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
