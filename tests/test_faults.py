"""A rub as an effect (src/hybridtwin/model/faults.py): its force and derivative, and the harmonic balance of the
stepped rotor rubbing at d1 against a reference that needs no harmonic balance: an isotropic rotor's unbalance
response is a circular forward orbit, on which the rub acts as a constant stiffness and cross-coupling, so the
steady orbit's radius R solves one scalar equation R = |X_u(R)| of linear solves (bisection)."""

import numpy as np
import pytest
from example_machines import stepped_machine

from hybridtwin.model.effect_base import Params
from hybridtwin.model.faults import Rub
from hybridtwin.model.model import Model
from hybridtwin.solvers.solver import solve


def test_the_rub_force_its_derivative_and_sense():
    rub = Rub(node=3)
    assert [p.name for p in rub.parameters] == ["delta_3", "k_rub_3", "mu_3"] and rub.dofs == ("u3", "v3")
    p = Params({"delta_3": np.array([1e-3]), "k_rub_3": np.array([5e3]), "mu_3": np.array([0.3])})
    rng = np.random.default_rng(0)
    q = rng.normal(0, 1.5e-3, (1, 2, 200))
    F, J = rub.force(q, p)
    r = np.hypot(q[0, 0], q[0, 1])
    inside = r < 1e-3
    assert inside.any() and (~inside).any() and not F[0][:, inside].any()  # nothing inside the clearance
    # beyond it: the normal force k (r - delta) inwards, the friction mu times it along -(rotation) = -(-v, u) / r
    normal = -(F[0, 0] * q[0, 0] + F[0, 1] * q[0, 1]) / r
    tangential = (-F[0, 0] * q[0, 1] + F[0, 1] * q[0, 0]) / r
    np.testing.assert_allclose(normal[~inside], 5e3 * (r - 1e-3)[~inside], rtol=1e-12)
    np.testing.assert_allclose(tangential[~inside], -0.3 * normal[~inside], rtol=1e-12)
    # the derivative against central differences (step 1e-9 m, away from the kink at r = delta: error ~1e-6)
    far = np.abs(r - 1e-3) > 1e-5
    for j in range(2):
        step = np.zeros_like(q)
        step[:, j] = 1e-9
        numeric = (rub.force(q + step, p)[0] - rub.force(q - step, p)[0]) / 2e-9
        np.testing.assert_allclose(J[0, :, j][:, far], numeric[0][:, far], rtol=1e-5, atol=1e-6)


def test_the_harmonic_balance_of_a_rub_is_the_circular_orbits_fixed_point():
    machine = stepped_machine()
    effects = machine.effects()
    base = [effects[n] for n in ("linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1")]
    rub = machine.place(Rub(), "d1")
    assert [p.name for p in rub.parameters] == ["delta_d1", "k_rub_d1", "mu_d1"] and rub.node == 8
    model = Model(base + [rub], machine)
    rpm, k, mu = 3900.0, 5e6, 0.2
    values = {name: par.nominal for name, par in model.parameters.items()} | {
        "m_e": 0.02, "delta_d1": 1e-3, "k_rub_d1": 0.0, "mu_d1": mu}
    u, v = machine.dof("u8"), machine.dof("v8")
    free = solve(model.system(values, rpm), 3)
    delta = 0.4 * abs(free.harmonics[0, 1, u])  # the ring at 40 % of the free orbit's radius (19 um)
    values |= {"delta_d1": delta, "k_rub_d1": k}

    system = model.system(values | {"k_rub_d1": 0.0}, rpm)  # the linear parts; the rub added by hand below
    Omega = system.Omega[0]
    Z = system.K[0] + 1j * Omega * system.C[0] - Omega**2 * system.M[0]

    def response(R: float) -> np.ndarray:
        g = k * max(0.0, 1.0 - delta / R)  # on a circle of radius R: F = -g [[1, -mu], [mu, 1]] (u, v)
        A = Z.copy()
        A[u, u] += g
        A[v, v] += g
        A[u, v] -= g * mu
        A[v, u] += g * mu
        return np.linalg.solve(A, system.forcing[1][0])

    lo, hi = delta, abs(free.harmonics[0, 1, u])  # |X_u(R)| - R changes sign in between
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if abs(response(mid)[u]) > mid else (lo, mid)
    reference = response(0.5 * (lo + hi))
    steady = solve(model.system(values, rpm), 3)
    assert steady.success[0]
    X = steady.harmonics[0]
    # 1X: the fixed point to the solver's tolerance (1e-10 of the residual) and the AFT's 64 samples of a force that
    # is smooth on a circle: 1e-8 relative; the orbit circular (no 2X, 3X beyond 1e-8 of the 1X)
    np.testing.assert_allclose(X[1, [u, v]], reference[[u, v]], rtol=1e-8)
    assert np.abs(X[2:, [u, v]]).max() < 1e-8 * np.abs(X[1, u])
    # in contact (beyond the clearance), and held down by the ring (measured: 18.8 -> 14.1 um)
    assert delta < abs(X[1, u]) < 0.9 * abs(free.harmonics[0, 1, u])
