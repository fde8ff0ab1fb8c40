"""A large finite-element rotor's harmonic balance in band storage (solvers/banded.py), its assembly by local blocks
(effect_base.LocalMatrix) and its stability check once per distinct linear system (model.distinct_scenarios): the
same results as the dense computation they replace, and as independent references (the equations' own residual,
finite differences of the solve, the full monodromy matrix)."""

import numpy as np
import pytest

from hybridtwin.model.bearing_table import BearingTable
from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import Bearing, Disk, ShaftSegment, UnbalancePlane
from hybridtwin.model.model import Model, distinct_scenarios
from hybridtwin.solvers import banded, floquet
from hybridtwin.solvers.solver import sensitivity, solve

EPS = np.finfo(float).eps
STEEL = dict(E=211e9, rho=7810.0, alpha=2.0, beta=2e-6)
#: a seal-like table: direct stiffness and damping growing with speed, cross-coupled stiffness kxy = -kyx
TABLE = BearingTable((0.0, 3000.0, 6000.0), kxx=(2e7, 2.2e7, 2.5e7), kxy=(0.0, 1e6, 3e6), kyx=(0.0, -1e6, -3e6),
                     kyy=(1.8e7, 2e7, 2.3e7), cxx=(800.0, 900.0, 1000.0), cxy=(0.0,) * 3, cyx=(0.0,) * 3,
                     cyy=(700.0, 800.0, 900.0))


def fine_machine() -> Machine:
    """tests/example_machines.py's stepped rotor meshed three times finer (51 elements, 208 DOFs: above
    ``banded.BANDED_MIN_DOF``), bearing a at node 6 from a table over speed, a linear bearing z at node 39."""
    return Machine(
        "fine", [ShaftSegment(0.2, 0.04, n_elements=12, **STEEL),
                 ShaftSegment(0.5, 0.05, d_in=0.02, n_elements=30, **STEEL),
                 ShaftSegment(0.3, 0.035, n_elements=9, **STEEL)],
        disks=[Disk(24, 15.3, 0.12, 0.062, "d1"), Disk(48, 7.4, 0.037, 0.019, "d2")],
        bearings=[Bearing("a", 6, table=TABLE), Bearing("z", 39, k=1e7, c=500.0)],
        unbalance_planes=[UnbalancePlane("d1", 24)])


def fine_model(nonlinear: bool) -> Model:
    fx = fine_machine().effects()
    names = ["bearing_table@a", "linear_bearing@z", "gyroscopic", "unbalance@d1", "shaft_damping"]
    return Model([fx[n] for n in names + (["radial_spring@z"] if nonlinear else [])], fine_machine())


def values(model: Model, S: int) -> dict[str, np.ndarray]:
    # l_i = 2 um: the cubic spring at z carries ~30 % of its linear force at the response's amplitude (Newton needs
    # 1 to 4 iterations), so the nonlinear path is exercised
    nominal = {"m_e": 0.02, "r_me": 0.04, "angle_me": 0.0, "k_z": 1e7, "c_z": 500.0, "k_b": 2000.0, "l_i": 2e-6}
    return {k: np.full(S, nominal[k]) for k in model.parameters}


RPM = np.linspace(1000.0, 6000.0, 6)


@pytest.fixture
def dense(monkeypatch):
    """The solves as before band storage: every block dense."""
    monkeypatch.setattr(banded, "BANDED_MIN_DOF", 10**9)


def test_a_band_solve_equals_the_dense_one_and_flags_a_singular_member():
    rng = np.random.default_rng(0)
    S, n, k = 5, 150, 4
    offsets = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    A = np.where(offsets <= k, rng.standard_normal((S, n, n)) + 1j * rng.standard_normal((S, n, n)), 0.0)
    order = rng.permutation(n)  # the DOFs shuffled: the band is to be found again
    A = A[:, order[:, None], order[None, :]]
    A[3, 7] = 0.0  # a row of zeros: singular, in the others' pattern
    b = rng.standard_normal((S, n, 2)) + 0j
    plan = banded.band_plan(banded.pattern_of(A))
    assert plan is not None and plan.k <= 2 * k  # RCM recovers a band of the order of the original
    ok = np.ones(S, bool)
    x = banded.solve_band(plan, banded.to_band(plan, A), b, ok)
    assert ok.tolist() == [True, True, True, False, True] and np.isnan(x[3]).all()
    for s in (0, 1, 2, 4):
        reference = np.linalg.solve(A[s], b[s])
        # both are LU with partial pivoting, backward stable: forward errors within cond(A) n eps of each other
        bound = n * EPS * np.linalg.cond(A[s])
        assert np.linalg.norm(x[s] - reference) <= bound * np.linalg.norm(reference)
        # and the equations themselves: backward error at round-off, ||A x - b|| <= n eps ||A|| ||x||
        assert np.linalg.norm(A[s] @ x[s] - b[s]) <= n * EPS * np.linalg.norm(A[s], 2) * np.linalg.norm(x[s])


def test_a_band_product_equals_the_dense_one():
    rng = np.random.default_rng(2)
    S, n, k = 3, 120, 3
    offsets = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    order = rng.permutation(n)
    A = np.where(offsets <= k, rng.standard_normal((S, n, n)), 0.0)[:, order[:, None], order[None, :]]
    X = rng.standard_normal((S, n, 5))
    plan = banded.band_plan(banded.pattern_of(A))
    # sums of at most 2k + 1 = 7 products of standard normal numbers: round-off a few eps of the entries' size
    np.testing.assert_allclose(banded.band_product(plan, A, X), A @ X, rtol=0, atol=1e-13)


def test_small_systems_keep_the_dense_solve():
    assert banded.band_plan(np.eye(72, dtype=bool)) is None  # the stepped rotor's 72 DOFs: dense, as before
    assert banded.band_plan(np.ones((200, 200), bool)) is None  # no band at all: dense


def test_a_linear_large_rotor_response_equals_the_dense_solve_and_its_equations(dense):
    model = fine_model(nonlinear=False)
    system = model.system(values(model, RPM.size), RPM)
    Q_dense = solve(system, 3, stability=False).harmonics[:, 1]
    banded.BANDED_MIN_DOF = 100  # the monkeypatch restores the dense setting's original afterwards
    assert banded.band_plan(banded.pattern_of(system.K, system.C, system.M)).k <= 8  # 208 DOFs in a band of 8
    Q = solve(system, 3, stability=False).harmonics[:, 1]
    for s, Omega in enumerate(system.Omega):
        D = system.K[s] + 1j * Omega * system.C[s] - Omega**2 * system.M[s]
        F = system.forcing[1][s]
        # the residual of (K + i Omega C - Omega^2 M) Q = F: backward stable (LU with partial pivoting)
        assert np.linalg.norm(D @ Q[s] - F) <= system.n_dof * EPS * np.linalg.norm(D, 2) * np.linalg.norm(Q[s])
        # two backward stable solves of one system differ by at most cond(D) times their backward errors
        bound = system.n_dof * EPS * np.linalg.cond(D)
        assert np.linalg.norm(Q[s] - Q_dense[s]) <= bound * np.linalg.norm(Q_dense[s])


def test_a_nonlinear_large_rotor_and_its_sensitivities_equal_the_dense_computation(dense):
    model = fine_model(nonlinear=True)
    nominal = values(model, RPM.size)
    system = model.system(nominal, RPM)
    names, steps = ["k_z", "m_e", "k_b"], np.array([1e3, 1e-6, 1e-1])

    def build(v):
        return model.system(v, np.tile(RPM, len(next(iter(v.values()))) // RPM.size))

    before = solve(system, 5, tol=1e-12)
    dQ_before = sensitivity(build, nominal, names, before, steps)
    banded.BANDED_MIN_DOF = 100
    after = solve(system, 5, tol=1e-12)
    dQ_after = sensitivity(build, nominal, names, after, steps)
    assert after.success.all() and (after.iterations >= 1).all()  # the cubic spring is felt
    # each is converged to ||r|| <= 1e-12 ||x||; the Newton Jacobian's conditioning here is far below 1e3
    # (measured: the states agree to 4e-13 of their size at tol 1e-12), so 1e-9 relative holds with margin
    scale = np.abs(before.harmonics).max()
    np.testing.assert_allclose(after.harmonics, before.harmonics, rtol=0, atol=1e-9 * scale)
    # the stability check: the modes by LAPACK's generalised solver, the static deflections K^-1 B in band storage,
    # the truncated modes' damping by a sparse C: round-off of a radius of order 1 through one matrix exponential
    # and 64 steps, far inside 1e-10
    np.testing.assert_allclose(after.floquet_radius, before.floquet_radius, rtol=0, atol=1e-10)
    # the sensitivities: D_h's round-off (condition numbers up to 3e9 here, so n eps cond would allow 1e-4) and the
    # states' above; measured 2e-10 .. 1.5e-9 of each parameter's largest entry, held at 1e-7
    for j in range(len(names)):
        scale = np.abs(dQ_before[:, j]).max()
        np.testing.assert_allclose(dQ_after[:, j], dQ_before[:, j], rtol=0, atol=1e-7 * scale)


def test_large_rotor_sensitivities_equal_finite_differences_of_the_solve():
    model = fine_model(nonlinear=True)
    S = 3
    rpm = RPM[[1, 3, 5]]
    nominal = values(model, S)
    names = ["k_z", "m_e", "k_b"]  # through K, through the forcing, through the nonlinear force and K
    steps = np.array([1e3, 1e-6, 1e-1])
    state = solve(model.system(nominal, rpm), 5, tol=1e-13, stability=False)

    def build(v):
        return model.system(v, np.tile(rpm, len(next(iter(v.values()))) // S))

    dQ = sensitivity(build, nominal, names, state, steps)

    def central(name, delta):
        up, down = ({**nominal, name: nominal[name] + sign * delta} for sign in (1.0, -1.0))
        Q_up, Q_down = (solve(model.system(v, rpm), 5, tol=1e-14, stability=False).harmonics for v in (up, down))
        return (Q_up - Q_down) / (2.0 * delta)

    for j, name in enumerate(names):
        delta = 2e-3 * nominal[name][0]
        fd = (4.0 * central(name, delta) - central(name, 2.0 * delta)) / 3.0  # Richardson: the delta^2 term out
        # what is left: O(delta^4) ~ 1e-11 and the solves' round-off over delta (D_0's condition number is ~1e9):
        # measured 5e-8 .. 6e-7 of the largest derivative, so 1e-5 holds with a margin of 18
        np.testing.assert_allclose(dQ[:, j], fd, rtol=0, atol=1e-5 * np.abs(fd).max())


def test_the_large_rotors_stability_check_equals_the_full_monodromy():
    model = fine_model(nonlinear=True)
    system = model.system(values(model, RPM.size), RPM)
    state = solve(system, 5)
    full, _ = floquet.multipliers(system, state.harmonics, cutoff_factor=None)  # all 416 states, no reduction
    # the reduction's error (floquet.py's docstring: truncated modes act quasi-statically); on this machine the
    # radii (0.90 .. 0.99) differ from the full model's by < 1e-5 (measured 9e-6): 5e-5 is the margin
    np.testing.assert_allclose(state.floquet_radius, np.abs(full).max(axis=1), rtol=0, atol=5e-5)


def test_scenarios_that_share_their_system_share_their_stability_check_bit_for_bit(monkeypatch):
    model = fine_model(nonlinear=True)
    rpm = np.array([3000.0, 3000.0, 5000.0, 3000.0])
    v = values(model, rpm.size)
    v["angle_me"][1] = 1.0  # the unbalance elsewhere: the same linear system at 3000 RPM, another orbit
    system = model.system(v, rpm)
    state = solve(system, 5)
    assert distinct_scenarios(system.K, system.M)[0].tolist() == [0, 2]  # 3000 RPM's pencil once

    def each_its_own(*stacks):
        return np.arange(stacks[0].shape[0]), np.arange(stacks[0].shape[0])

    monkeypatch.setattr(floquet, "distinct_scenarios", each_its_own)  # every eigenproblem solved, as before
    assert floquet.spectral_radius(system, state.harmonics).tolist() == state.floquet_radius.tolist()


def test_distinct_scenarios_groups_equal_systems_only():
    rng = np.random.default_rng(1)
    K = rng.standard_normal((6, 30, 30))
    K[2], K[4] = K[0], K[1]
    K[5] = K[0]
    K[5, 7, 3] += 1e-15 * abs(K[5, 7, 3])  # one entry off by round-off: another system
    M = np.broadcast_to(np.eye(30), K.shape)
    first, inverse = distinct_scenarios(K, M)
    assert first.tolist() == [0, 1, 3, 5] and inverse.tolist() == [0, 1, 0, 2, 1, 3]
    nan = K.copy()
    nan[:2] = np.nan  # NaN is never equal to itself: no sharing
    assert distinct_scenarios(nan)[0].tolist()[:2] == [0, 1]


def test_a_table_bearing_adds_its_coefficients_at_its_node_only():
    """The assembly with the bearing's block added where it acts equals the assembly without it plus the table's
    K(Omega), C(Omega) at (u6, v6), exactly (an independent path: the table's own interpolation)."""
    fx = fine_machine().effects()
    rest = ["linear_bearing@z", "gyroscopic", "unbalance@d1", "shaft_damping"]
    with_table = Model([fx["bearing_table@a"]] + [fx[n] for n in rest], fine_machine())
    without = Model([fx[n] for n in rest], fine_machine())
    v = values(with_table, RPM.size)
    a, b = with_table.system(v, RPM), without.system(v, RPM)
    K_table, C_table = TABLE.matrices(a.Omega)
    dofs = np.array([with_table.shaft.dof("u6"), with_table.shaft.dof("v6")])
    for got, base, block in ((a.K, b.K, K_table), (a.C, b.C, C_table)):
        expected = base.copy()
        expected[:, dofs[:, None], dofs[None, :]] += block
        # K: K(0) at rest plus K(Omega) - K(0) at speed, the same two sums as before the blocks were local
        np.testing.assert_allclose(got, expected, rtol=4 * EPS, atol=0)
        np.testing.assert_array_equal(np.delete(np.delete(got - base, dofs, axis=1), dofs, axis=2), 0.0)
    np.testing.assert_array_equal(a.M, b.M)


def test_a_linear_machines_radius_is_each_scenarios_own_when_systems_are_shared():
    model = fine_model(nonlinear=False)
    rpm = np.array([2000.0, 4000.0, 2000.0, 2000.0])
    v = values(model, rpm.size)
    v["angle_me"][2] = 2.0  # the forcing alone differs: 2000 RPM's system three times
    system = model.system(v, rpm)
    assert distinct_scenarios(system.M, system.C, system.K)[0].tolist() == [0, 1]
    together = floquet.linear_spectral_radius(system)
    # a linear system's radius is its own eigenvalues' (no block-wide basis): each alone is the reference
    alone = [floquet.linear_spectral_radius(system.subset([s]))[0] for s in range(rpm.size)]
    assert together.tolist() == alone
