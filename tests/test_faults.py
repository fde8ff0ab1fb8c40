"""A rub as an effect (src/hybridtwin/model/faults.py): its force and derivative, and the harmonic balance of the
stepped rotor rubbing at d1 against a reference that needs no harmonic balance: an isotropic rotor's unbalance
response is a circular forward orbit, on which the rub acts as a constant stiffness and cross-coupling, so the
steady orbit's radius R solves one scalar equation R = |X_u(R)| of linear solves (bisection)."""

import numpy as np
import pytest
from example_machines import stepped_machine

from hybridtwin.model.effect_base import Params
from hybridtwin.model.faults import Crack, Looseness, Misalignment, Rub
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


# --- the breathing crack, the misalignment and the looseness ---------------------------------------------------


def _crack_model(crack, extra=()):
    machine = stepped_machine()
    effects = machine.effects()
    base = [effects[n] for n in ("linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1", *extra)]
    return machine, Model(base + [crack], machine)


def test_a_mayes_crack_on_the_sag_forces_1x_2x_3x_as_written_out():
    """Mayes's breathing f = (1 - cos theta) / 2 with the loss along xi only, on a sag along y only: the force along
    t in y is dk_xi f sin^2 theta s_y = dk_xi s_y / 4 (1 - cos/2 - cos 2 theta + cos 3 theta / 2) (written out by
    hand), so the harmonics are -1/8, -1/4, +1/8 of dk_xi s_y, each turned by h psi; in x dk_xy = f dk_xi sin cos
    gives dk_xi s_y / 4 (sin 2 theta - sin theta / 2 - sin 3 theta / 2) (0 without cross_terms). The mean loss,
    dk_xi / 4 (the mean of f cos^2), is the stiffness -dk_xi / 4 t t^T in x and y. The sag is the one of K q = M g
    solved here apart."""
    machine = stepped_machine()
    h = float(machine.z[9] - machine.z[8])
    crack = Crack(name="crack", node=8, place="d1", element_length_m=h)
    assert [p.name for p in crack.parameters] == ["dk_xi_d1", "dk_eta_d1", "psi_d1"]
    assert crack.switches == ("dk_xi_d1", "dk_eta_d1")
    _, model = _crack_model(crack)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.0}
    base = model.system(values, 3000.0)
    assert set(base.forcing) == {1} and not base.forcing[1].any()  # absent at zero: no harmonic at all
    xi, psi = 2e6, 0.7
    system = model.system(values | {"dk_xi_d1": xi, "psi_d1": psi}, 3000.0)
    t = np.array([-1.0, -h, 1.0, 0.0])
    x_dofs = [machine.dof(d) for d in ("u8", "du8", "u9", "du9")]
    y_dofs = [machine.dof(d) for d in ("v8", "dv8", "v9", "dv9")]
    dK = system.K[0] - base.K[0]
    np.testing.assert_allclose(dK[np.ix_(x_dofs, x_dofs)], -xi / 4 * np.outer(t, t), rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(dK[np.ix_(y_dofs, y_dofs)], -xi / 4 * np.outer(t, t), rtol=1e-12, atol=1e-6)
    K = system.K[0]  # the sag with the mean loss in K
    g = np.zeros(machine.n_dof)
    g[machine.translational("y")] = -9.81
    s_y = np.linalg.solve(K, system.M[0] @ g)[y_dofs] @ t
    assert abs(s_y) > 1e-9  # the weight bends the element (the test would hold vacuously at no sag)
    for harmonic, (cy, cx) in {1: (-1 / 8, 1j / 8), 2: (-1 / 4, -1j / 4), 3: (1 / 8, 1j / 8)}.items():
        # sin(h theta) = Re(-i exp(i h theta)): its phasor -i; theta = Omega t + psi
        F = system.forcing[harmonic][0]
        turn = np.exp(1j * harmonic * psi)
        np.testing.assert_allclose(F[y_dofs], cy * xi * s_y * turn * t, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(F[x_dofs], cx * xi * s_y * turn * t, rtol=1e-10, atol=1e-12)
        others = np.setdiff1d(np.arange(machine.n_dof), x_dofs + y_dofs)
        assert not F[others].any()


def test_a_gasch_crack_and_a_crack_without_cross_terms():
    """Gasch (open half the turn, cos theta < 0) with equal losses along xi and eta: dk_yy = dk f, so the force's
    harmonics are dk s_y times f's: f_1 = -2/pi, f_2 = 0, f_3 = +2/(3 pi) (the square wave's), the same in both
    breathing laws' notation; with dk_xi = dk_eta the cross term vanishes, so x has no force."""
    machine = stepped_machine()
    h = float(machine.z[9] - machine.z[8])
    crack = Crack(name="crack", node=8, place="d1", element_length_m=h, model="gasch", cross_terms=False)
    _, model = _crack_model(crack)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.0, "dk_xi_d1": 1e6, "dk_eta_d1": 1e6}
    system = model.system(values, 3000.0)
    t = np.array([-1.0, -h, 1.0, 0.0])
    y_dofs = [machine.dof(d) for d in ("v8", "dv8", "v9", "dv9")]
    x_dofs = [machine.dof(d) for d in ("u8", "du8", "u9", "du9")]
    g = np.zeros(machine.n_dof)
    g[machine.translational("y")] = -9.81
    s_y = np.linalg.solve(system.K[0], system.M[0] @ g)[y_dofs] @ t
    # the 18-term square wave (ROSS's sum) differs from the exact one only beyond the 35th harmonic
    for harmonic, f in {1: -2 / np.pi, 2: 0.0, 3: 2 / (3 * np.pi)}.items():
        F = system.forcing[harmonic][0]
        np.testing.assert_allclose(F[y_dofs], 1e6 * f * s_y * t, rtol=1e-9, atol=1e-9 * 1e6 * abs(s_y))
        assert not F[x_dofs].any()


def test_the_misalignment_pair_and_its_2x_response():
    """The pair: +a at node and -a at its partner, 2X only, no net force; its steady response is the linear 2X
    response (K + 2 i Omega C - 4 Omega^2 M) X = F solved here apart."""
    machine = stepped_machine()
    effects = machine.effects()
    mis = Misalignment(name="misalignment", node=2, partner=1, place="a")
    assert [p.name for p in mis.parameters] == ["f2x_c_a", "f2x_s_a", "f2y_c_a", "f2y_s_a"]
    model = Model([effects[n] for n in ("linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1")]
                  + [mis], machine)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.0}
    assert model.system(values, 3000.0).forcing.keys() == {1}
    on = values | {"f2x_c_a": 30.0, "f2x_s_a": -10.0, "f2y_c_a": 5.0, "f2y_s_a": 20.0}
    system = model.system(on, 3000.0)
    F = system.forcing[2][0]
    assert F[machine.dof("u2")] == 30 - 10j and F[machine.dof("u1")] == -(30 - 10j)
    assert F[machine.dof("v2")] == 5 + 20j and F[machine.dof("v1")] == -(5 + 20j) and np.count_nonzero(F) == 4
    steady = solve(system, 3)
    W = 2 * system.Omega[0]
    X = np.linalg.solve(system.K[0] + 1j * W * system.C[0] - W**2 * system.M[0], F)
    np.testing.assert_allclose(steady.harmonics[0, 2], X, rtol=1e-9, atol=1e-9 * np.abs(X).max())


def test_looseness_on_a_circular_orbit_is_the_fixed_point_of_a_softer_bearing():
    """An isotropic rotor (the stepped rotor, its bearings alike in x and y) whirls on circles; on a circle of radius
    R > delta at the loose bearing the effect adds k delta / R (u, v), a constant stiffness -k delta / R: the steady
    orbit's R solves R = |X_u(R)| of linear solves (bisection), the reference that needs no harmonic balance. The
    force's derivative against central differences."""
    machine = stepped_machine()
    effects = machine.effects()
    loose = Looseness(name="looseness@b", node=13, place="b", k_n_m=1e7)
    assert [p.name for p in loose.parameters] == ["delta_loose_b"] and loose.dofs == ("u13", "v13")
    p = Params({"delta_loose_b": np.array([1e-5])})
    rng = np.random.default_rng(3)
    q = rng.normal(0, 1.5e-5, (1, 2, 200))
    F, J = loose.force(q, p)
    r = np.hypot(q[0, 0], q[0, 1])
    inside = r < 1e-5
    assert inside.any() and (~inside).any()
    np.testing.assert_allclose(F[0][:, inside], 1e7 * q[0][:, inside], rtol=1e-12)  # inside: the spring undone
    np.testing.assert_allclose(np.hypot(*F[0][:, ~inside]), 1e7 * 1e-5, rtol=1e-12)  # beyond: k delta outwards
    far = np.abs(r - 1e-5) > 1e-7
    for j in range(2):
        step = np.zeros_like(q)
        step[:, j] = 1e-11
        numeric = (loose.force(q + step, p)[0] - loose.force(q - step, p)[0]) / 2e-11
        np.testing.assert_allclose(J[0, :, j][:, far], numeric[0][:, far], rtol=1e-5, atol=1e2)

    base = [effects[n] for n in ("linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1")]
    model = Model(base + [loose], machine)
    rpm = 3000.0
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.02, "delta_loose_b": 0.0}
    u, v = machine.dof("u13"), machine.dof("v13")
    tight = solve(model.system(values, rpm), 3)
    delta = 0.5 * abs(tight.harmonics[0, 1, u])
    system = model.system(values, rpm)
    Omega = system.Omega[0]
    Z = system.K[0] + 1j * Omega * system.C[0] - Omega**2 * system.M[0]

    def response(R: float) -> np.ndarray:
        A = Z.copy()
        A[u, u] -= 1e7 * delta / R
        A[v, v] -= 1e7 * delta / R
        return np.linalg.solve(A, system.forcing[1][0])

    lo, hi = delta, 50 * abs(tight.harmonics[0, 1, u])
    assert abs(response(lo)[u]) > lo and abs(response(hi)[u]) < hi
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if abs(response(mid)[u]) > mid else (lo, mid)
    reference = response(0.5 * (lo + hi))
    steady = solve(model.system(values | {"delta_loose_b": delta}, rpm), 3)
    assert steady.success[0]
    X = steady.harmonics[0]
    # the fixed point to the solver's tolerance and the AFT's 64 samples of a force smooth on a circle
    np.testing.assert_allclose(X[1, [u, v]], reference[[u, v]], rtol=1e-8)
    assert np.abs(X[2:, [u, v]]).max() < 1e-8 * np.abs(X[1, u])
    assert abs(X[1, u]) > abs(tight.harmonics[0, 1, u])  # the loose bearing lets the rotor move more


def test_the_faults_are_candidates_on_a_machine_sized_to_it():
    """At each bearing a looseness (0 .. 20 um) and a misalignment pair towards the nearer shaft end (its force
    range the 2X forces', 300 N here); at the unbalance plane d1 (node 8) a crack in element 8 (the tube 0.05/0.02 m,
    h = 0.05 m), its losses within 20 % of 3 E I / h^3; each absent at 0, so a model with all of them at 0 is the
    base model exactly."""
    machine = stepped_machine()
    sized = machine.sized_candidates()
    for b, node, partner in (("a", 2, 1), ("b", 13, 14)):
        assert sized[f"looseness@{b}"].parameters[0].bounds == (0.0, 2e-5)
        mis = sized[f"misalignment@{b}"]
        assert (mis.node, mis.partner) == (node, partner)
        assert mis.parameters[0].bounds == pytest.approx((-300.0, 300.0))
    crack = sized["crack@d1"]
    tip = 3 * 2.11e11 * np.pi * (0.05**4 - 0.02**4) / 64 / 0.05**3
    assert crack.node == 8 and crack.element_length_m == pytest.approx(0.05)
    assert crack.parameters[0].bounds == pytest.approx((0.0, 0.2 * tip))
    effects = machine.effects()
    names = ["looseness@a", "looseness@b", "misalignment@a", "misalignment@b", "crack@d1"]
    base_names = ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"]
    model = Model([effects[n] for n in base_names + names], machine)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.02}
    base = Model([effects[n] for n in base_names], machine)
    ours, theirs = solve(model.system(values, 3500.0), 3), solve(base.system(values, 3500.0), 3)
    np.testing.assert_array_equal(ours.harmonics, theirs.harmonics)
