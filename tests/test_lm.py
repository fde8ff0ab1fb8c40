"""The batched Levenberg-Marquardt's ``fixed`` entries (a profile): held exactly at their start, the others at
the conditional optimum, which for a model linear in its parameters is a closed-form least-squares solution."""

from __future__ import annotations

import numpy as np

from hybridtwin.identify.arrow_problem import ArrowProblem, Layout
from hybridtwin.identify import lm

SIGMA = 1e-6  # [m] per real/imaginary part
U = np.array([[1.0 + 0.5j, -0.3 + 0.2j]]) * 1e-4  # (H = 1, 2 channels): response to a = 1 [m]
V = np.array([[0.2 - 0.7j, 0.9 + 0.1j]]) * 1e-4  # response to b = 1 [m]


class Linear:
    """M = a U + b V for a, b in [-1, 1] (normalised = physical): linear, so each conditional optimum is exact."""

    parameters = ["a", "b"]
    lower, upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    H = 1

    def evaluate(self, x, jacobian=True):
        x = np.atleast_2d(x)
        M = x[:, 0, None, None] * U + x[:, 1, None, None] * V
        dM = np.broadcast_to(np.stack([U, V], axis=-1), (len(x), 1, 2, 2)).astype(complex)
        return M, (dM if jacobian else None)


def _problem(X: np.ndarray) -> ArrowProblem:
    # a keyphasor: the phase has a prior (sigma 1e-3 rad) and is held at 0 below, so the model stays linear
    layout = Layout.build(["a", "b"], [-1.0, -1.0], [1.0, 1.0], ["r"], (), [1e-3])
    return ArrowProblem([Linear()], layout, np.full((1, 1, 2), SIGMA))


def _conditional(X: np.ndarray, known: np.ndarray, other: np.ndarray, value: float) -> float:
    """argmin_c ||X - value known - c other||^2 over real c (ordinary least squares in closed form)."""
    rest = X - value * known
    return float(np.real(np.vdot(other, rest)) / np.real(np.vdot(other, other)))


def test_fixed_entries_stay_and_the_others_reach_the_conditional_optimum():
    rng = np.random.default_rng(4)
    X = 0.3 * U - 0.6 * V + SIGMA * (rng.standard_normal((1, 2)) + 1j * rng.standard_normal((1, 2)))
    problem = _problem(X)
    # theta = (a, b, phase); trial 0 holds a at 0.8, trial 1 holds b at 0.1, trial 2 holds nothing but the phase
    theta0 = np.array([[0.8, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.0]])
    fixed = np.array([[True, False, True], [False, True, True], [False, False, True]])
    Xs = np.repeat(X[None, None], 3, axis=0)
    result = lm.levenberg_marquardt(problem, theta0, Xs, lm.LMOptions(max_iterations=50), fixed=fixed)
    assert np.array_equal(result.x[fixed], theta0[fixed])  # held exactly, not approximately
    # LM on a linear model converges to the least-squares solution to round-off; 1e-6 of the range is far below
    # what a wrong conditional (a or b moving) would give (their optima differ by ~0.1-0.5)
    assert abs(result.x[0, 1] - _conditional(X, U, V, 0.8)) < 1e-6
    assert abs(result.x[1, 0] - _conditional(X, V, U, 0.1)) < 1e-6
    ab, *_ = np.linalg.lstsq(np.vstack([np.c_[U.real.ravel(), V.real.ravel()], np.c_[U.imag.ravel(), V.imag.ravel()]]),
                             np.r_[X.real.ravel(), X.imag.ravel()], rcond=None)
    assert np.allclose(result.x[2, :2], ab, atol=1e-6)
    # a profile point cannot beat the free fit
    assert result.loss[2] <= result.loss[:2].min()


def test_a_shared_mask_applies_to_every_trial():
    X = 0.3 * U - 0.6 * V
    problem = _problem(X)
    theta0 = np.array([[-0.5, 0.9, 0.0], [0.5, -0.9, 0.0]])
    result = lm.levenberg_marquardt(problem, theta0, np.repeat(X[None, None], 2, axis=0),
                                    lm.LMOptions(max_iterations=50), fixed=np.array([True, False, True]))
    assert np.array_equal(result.x[:, 0], theta0[:, 0])
    for t in range(2):
        assert abs(result.x[t, 1] - _conditional(X, U, V, theta0[t, 0])) < 1e-6
