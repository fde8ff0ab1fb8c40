"""Harmonic-balance solver (hybridtwin.solvers.solver) against independent references.

Every test compares the solver with something it does not share code with:
closed forms (linear frequency response, the H = 1 Duffing amplitude equation,
the circular orbit of an isotropic rotor, the static equilibrium), a different
algorithm (time integration with scipy's DOP853, finite differences, numpy's
FFT instead of the solver's DFT matrices, brentq on a scalar reduction), or a
conservation law (power balance).

Conventions checked along the way (solver.py docstring): the system is
M q'' + C q' + K q = Re(sum_h F_h exp(i h Omega t)) + F_nl(q), F_nl the force
ON the structure, and q(t) = Re(sum_h Q_h exp(i h Omega t)).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from hybridtwin import Effect, LocalForce, Model, Parameter, PolynomialBearing, System, Term, solve, solve_sweep
from hybridtwin.model.effects import K_B, base_effects
import hybridtwin.solvers.solver as solver_module
from hybridtwin.solvers.solver import _backtrack, Condensed
from hybridtwin.model.variants import builtin_variant

GEOMETRIC = builtin_variant("geometric")
SHAFT = GEOMETRIC.model.shaft
SENSOR_X = SHAFT.dof("u1")  # the laser micrometer reads node 1


# --- helpers ------------------------------------------------------------------------------


def duffing(Omega, gamma=0.1, P=0.18, mu=1.0, zeta=0.05, kappa=1.0) -> System:
    """mu x'' + zeta x' + kappa x + gamma x^3 = P cos(Omega t), one scenario per Omega.

    The cubic is a LocalForce ON the structure: F = -gamma x^3, dF/dx = -3 gamma x^2.
    """
    Omega = np.atleast_1d(np.asarray(Omega, dtype=float))
    S = Omega.size
    g = np.broadcast_to(np.asarray(gamma, dtype=float), (S,))

    def evaluate(q, rows):
        gr = g[rows][:, None, None]
        return -gr * q**3, (-3.0 * gr * q**2)[:, :, None, :]

    forcing = {1: np.broadcast_to(np.asarray(P, dtype=complex), (S,))[:, None].copy()}
    return System(np.full((S, 1, 1), mu), np.full((S, 1, 1), zeta), np.full((S, 1, 1), kappa), Omega,
                  forcing, [LocalForce("duffing_cubic", np.array([0]), evaluate, 3)])


def dynamic_stiffness(system: System, s: int, h: int) -> np.ndarray:
    w = h * system.Omega[s]
    return system.K[s] + 1j * w * system.C[s] - w * w * system.M[s]


def nonlinear_harmonics(system: System, s: int, Q: np.ndarray, n_time: int = 512) -> np.ndarray:
    """Fourier coefficients G_h (H+1, n) of F_nl(q(t)), by numpy's FFT on a fine grid.

    Independent of the solver's AFT (its own DFT matrices, sample count and condensation).
    n_time = 512 is alias-free for any cubic force with H < 128.
    """
    H = Q.shape[0] - 1
    spectrum = np.zeros((n_time // 2 + 1, Q.shape[1]), complex)
    spectrum[: H + 1] = Q
    spectrum[0] *= 2.0
    q = np.fft.irfft(spectrum, n=n_time, axis=0) * n_time / 2.0  # (N, n): Re(sum Q_h e^{i h tau})
    G = np.zeros_like(Q)
    for force in system.forces:
        F, _ = force.evaluate(q[:, force.dofs].T[None], system.rows[[s]])
        coeffs = np.fft.rfft(F[0], axis=1)[:, : H + 1] * (2.0 / n_time)
        coeffs[:, 0] /= 2.0
        G[:, force.dofs] += coeffs.T
    return G


def hb_residual(system: System, s: int, Q: np.ndarray) -> float:
    """Full-DOF harmonic-balance residual max_h |D_h Q_h - F_h - G_h|, relative.

    Scaled by the largest of the three terms, since near resonance D_h Q_h and G_h are
    much larger than the forcing that they nearly cancel.
    """
    G = nonlinear_harmonics(system, s, Q)
    worst = scale = 0.0
    for h in range(Q.shape[0]):
        F_h = system.forcing[h][s] if h in system.forcing else np.zeros_like(Q[h])
        DQ = dynamic_stiffness(system, s, h) @ Q[h]
        worst = max(worst, np.abs(DQ - F_h - G[h]).max())
        scale = max(scale, np.abs(DQ).max(), np.abs(F_h).max(), np.abs(G[h]).max())
    return worst / scale


def power_balance(system: System, s: int, Q: np.ndarray) -> tuple[float, float, float, float]:
    """Mean powers over a period from the harmonics: input, dissipated, nonlinear, stiffness.

    P_in = sum_h 1/2 Re(conj(i h W Q_h) . F_h), P_diss = sum_h 1/2 (h W)^2 Re(Q_h^H C Q_h),
    P_nl the same as P_in with the nonlinear force harmonics, P_K with -K Q_h.
    """
    W = system.Omega[s]
    P_in = P_diss = P_nl = P_K = 0.0
    G = nonlinear_harmonics(system, s, Q)
    for h in range(1, Q.shape[0]):
        velocity = 1j * h * W * Q[h]
        F_h = system.forcing[h][s] if h in system.forcing else np.zeros_like(Q[h])
        P_in += 0.5 * np.real(np.conj(velocity) @ F_h)
        P_diss += 0.5 * (h * W) ** 2 * np.real(np.conj(Q[h]) @ system.C[s] @ Q[h])
        P_nl += 0.5 * np.real(np.conj(velocity) @ G[h])
        P_K += 0.5 * np.real(np.conj(velocity) @ (-system.K[s] @ Q[h]))
    return P_in, P_diss, P_nl, P_K


def linear_spring_bearing() -> PolynomialBearing:
    """The Geometric upper bearing reduced to its linear part, 2 k_b per plane."""
    return PolynomialBearing(name="linear_spring", meaning="linear part of the four-spring bearing",
                             parameters=(K_B,), terms=(Term(lambda p: 2.0 * p.k_b, (1, 0, 0, 0), "2 k_b u"),))


class IsotropicCubic(Effect):
    """Test-only user effect: F = -a_iso (u^2 + v^2) (u, v) on node 0 (not in the package).

    Radially symmetric, so a forward circular orbit sees the constant stiffness a_iso r^2.
    """

    name = "isotropic_cubic"
    meaning = "isotropic cubic radial spring at the upper bearing (test effect)"
    parameters = (Parameter("a_iso", "N/m^3", (0.0, 1e12), 1e9, "isotropic cubic stiffness"),)
    dofs = ("u0", "v0")
    degree = 3

    def force(self, q, p):
        a = p.a_iso[:, None]
        u, v = q[:, 0], q[:, 1]
        r2 = u * u + v * v
        F = np.stack([-a * r2 * u, -a * r2 * v], axis=1)
        J = np.empty(q.shape[:2] + (2,) + q.shape[2:])
        J[:, 0, 0] = -a * (r2 + 2 * u * u)
        J[:, 0, 1] = J[:, 1, 0] = -a * 2 * u * v
        J[:, 1, 1] = -a * (r2 + 2 * v * v)
        return F, J


def geometric_system(rpm, **overrides) -> System:
    return GEOMETRIC.system(rpm, {k: np.asarray(v, float) for k, v in overrides.items()})


# --- linear limit -------------------------------------------------------------------------


def check_linear_response(system: System, res, harmonics: tuple[int, ...]) -> None:
    """1X equals the direct frequency-domain solve; the other harmonics vanish."""
    for s in range(system.n_scenarios):
        Q1 = np.linalg.solve(dynamic_stiffness(system, s, 1), system.forcing[1][s])
        # Same equations solved by LAPACK on another batch / after a zero Newton step:
        # agreement to round-off times cond(D) (~1e4), well inside 1e-10.
        assert np.abs(res.harmonics[s, 1] - Q1).max() <= 1e-10 * np.abs(Q1).max()
        # No forcing at the other harmonics and no nonlinearity: (numerically) zero there.
        assert np.abs(res.harmonics[s, list(harmonics)]).max() <= 1e-14 * np.abs(Q1).max()


def test_linear_limit_expansion_with_zero_nonlinear_coefficients():
    """Expansion model with k1 = k2 = k5 = k6 = k7 = 0: linear (k3, and the slope term k4,
    which makes K non-symmetric), but its zero-coefficient terms still go through AFT + Newton."""
    v = builtin_variant("expansion")
    zero = {f"k{i}": 0.0 for i in (1, 2, 5, 6, 7)}
    rpm = np.array([350.0, 700.0, 1000.0])
    system = v.system(rpm, {**zero, "k3": 4663.0, "k4": 341.1, "m_e": 0.0148})
    # the nonlinear path is exercised: the five zero-coefficient terms, evaluated together
    assert len(system.forces) == 1 and len(system.forces[0].name.split("+")) == 5
    assert not np.allclose(system.K[0], system.K[0].T)
    res = solve(system, harmonics=3)
    assert res.success.all()
    check_linear_response(system, res, (0, 2, 3))


def linear_model_system() -> System:
    values = GEOMETRIC.values({"m_e": 0.0148})  # unbalance plus bow: two forcing terms
    model = Model(base_effects() + [linear_spring_bearing()])
    return model.system(values, np.array([350.0, 700.0, 1000.0]))


def test_linear_model_without_nonlinear_forces():
    system = linear_model_system()
    assert system.forces == []  # nothing nonlinear left: the solver should reduce to linear solves
    res = solve(system, harmonics=3)
    assert res.success.all()
    check_linear_response(system, res, (0, 2, 3))


def test_linear_force_through_the_nonlinear_path():
    """A degree-1 LocalForce F = -k_x q goes through AFT + Newton and must equal a direct solve."""
    base = geometric_system([450.0, 900.0])
    dofs = np.array([SHAFT.dof("u0"), SHAFT.dof("dv0"), SHAFT.dof("u7")])
    k_x = np.array([500.0, -20.0, 3e3])  # per local DOF

    def evaluate(q, rows):
        J = np.zeros(q.shape[:2] + (q.shape[1],) + q.shape[2:])
        J[:, np.arange(3), np.arange(3)] = -k_x[None, :, None]
        return -k_x[None, :, None] * q, J

    system = System(base.M, base.C, base.K, base.Omega, base.forcing, [LocalForce("lin", dofs, evaluate, 1)])
    res = solve(system, harmonics=3)
    assert res.success.all()
    for s in range(2):
        K = system.K[s].copy()
        K[dofs, dofs] += k_x
        w = system.Omega[s]
        Q1 = np.linalg.solve(K + 1j * w * system.C[s] - w * w * system.M[s], system.forcing[1][s])
        # Newton solves a linear problem in one step; tol 1e-10 is the solver's own
        # convergence test, the rest is round-off: 1e-10 relative.
        assert np.abs(res.harmonics[s, 1] - Q1).max() <= 1e-10 * np.abs(Q1).max()
        assert np.abs(res.harmonics[s, [0, 2, 3]]).max() <= 1e-12 * np.abs(Q1).max()


# --- Duffing oscillator (NLvib example) ---------------------------------------------------


def duffing_h1_amplitude_roots(Om, mu=1.0, zeta=0.05, kappa=1.0, gamma=0.1, P=0.18) -> np.ndarray:
    """Real roots a > 0 of (kappa - mu Om^2 + 3/4 gamma a^2)^2 a^2 + (zeta Om a)^2 = P^2 (cubic in a^2)."""
    d = kappa - mu * Om**2
    g = 0.75 * gamma
    # g^2 A^3 + 2 d g A^2 + (d^2 + (zeta Om)^2) A - P^2 = 0
    roots = np.roots([g * g, 2 * d * g, d * d + (zeta * Om) ** 2, -P * P])
    A = np.sort(roots[np.abs(roots.imag) < 1e-9 * np.abs(roots).max()].real)
    return np.sqrt(A[A > 0])


def test_duffing_single_harmonic_closed_form():
    Om = np.array([0.3, 0.8, 1.0, 1.2, 1.5, 2.0])
    res = solve(duffing(Om), harmonics=1)
    assert res.success.all()
    a = np.abs(res.harmonics[:, 1, 0])
    lhs = (1.0 - Om**2 + 0.75 * 0.1 * a**2) ** 2 * a**2 + (0.05 * Om * a) ** 2
    # The + 3/4 gamma a^2 (hardening) confirms the sign convention F_nl = -gamma x^3 ON
    # the structure. N = 4H + 1 = 5 samples make the AFT of x^3 exact at H = 1, so the
    # only error is Newton's (tol 1e-10 on the residual, quadratically converged): 1e-12.
    np.testing.assert_allclose(lhs, 0.18**2, rtol=1e-12)

    # At H = 1, Om = 1.0 is single-valued (the detuning vanishes: one root); Om = 1.2 lies
    # between the folds with three amplitudes. Run-up from 0.5 stays on the upper
    # (resonant) branch, run-down from 1.5 on the lower one; both are roots.
    assert duffing_h1_amplitude_roots(1.0).size == 1
    roots = duffing_h1_amplitude_roots(1.2)
    assert roots.size == 3
    speeds = np.round(np.arange(0.5, 1.5001, 0.05), 10)
    # tol 1e-13: near a fold the Jacobian is nearly singular, so the default tol (1e-10 on
    # the residual) would only give the amplitude to ~1e-11; with 1e-13 round-off rules.
    sweeps = {d: solve_sweep(lambda om, rows: duffing(np.full(len(rows), om)), speeds, 1, direction=d,
                             harmonics=1, tol=1e-13)
              for d in ("up", "down")}

    def at(direction, Om):
        sweep = sweeps[direction]
        return sweep.results[int(np.argmin(np.abs(sweep.rpm - Om)))]

    assert abs(at("up", 1.2).harmonics[0, 1, 0]) == pytest.approx(roots[-1], rel=1e-12)
    assert abs(at("down", 1.2).harmonics[0, 1, 0]) == pytest.approx(roots[0], rel=1e-12)
    assert at("up", 1.2).branch[0] == "run-up" and at("down", 1.2).branch[0] == "run-down"
    # Past the upper fold (1.25 < Om_fold < 1.3: one root left at 1.3) the run-up branch
    # ends. The sweep may report a failure or jump to the remaining branch, but never
    # silently: a success there must be the remaining root and be labelled as a jump.
    remaining = duffing_h1_amplitude_roots(1.3)
    assert remaining.size == 1
    end = at("up", 1.3)
    assert end.message[0]
    if end.success[0]:
        assert "jump" in end.branch[0]
        assert abs(end.harmonics[0, 1, 0]) == pytest.approx(remaining[0], rel=1e-12)
    else:
        assert np.isnan(end.harmonics[0]).all()


# NLvib's Duffing example (mu=1, zeta=0.05, kappa=1, gamma=0.1, P=0.18, H=7), to 9 digits.
NLVIB_H7 = {0.8: 0.474872047, 1.0: 1.305345473}


def test_duffing_h7_reference_amplitudes():
    # Run-up continuation from Om = 0.5 along the resonant branch, as in NLvib (Om = 1.0
    # is near the peak; the multi-valued region at this forcing is about 1.12-1.27).
    speeds = np.round(np.arange(0.5, 1.0001, 0.05), 10)
    sweep = solve_sweep(lambda om, rows: duffing(np.full(len(rows), om)), speeds, 1, harmonics=7)
    for Om, ref in NLVIB_H7.items():
        res = sweep.results[int(np.argmin(np.abs(sweep.rpm - Om)))]
        assert res.success[0]
        # The reference is rounded to 9 decimals (error <= 5e-10): 1e-8 absolute.
        assert abs(res.harmonics[0, 1, 0]) == pytest.approx(ref, abs=1e-8)
        # Only odd harmonics for an odd force with cos forcing (symmetry x(t+T/2) = -x(t)).
        assert np.abs(res.harmonics[0, 0::2, 0]).max() < 1e-14


@pytest.mark.parametrize("block", [256, 2])
def test_sweeps_in_lockstep_equal_their_own_sweeps_jump_included(block, monkeypatch):
    """Per-scenario speeds (one batched sweep over sweeps of different lengths) against each sweep
    solved on its own: the solver treats scenarios independently, so every step of every scenario,
    including the run-up that passes the upper fold (1.25 < Om_fold < 1.3) and jumps, must be the
    same to the bit, labels and messages included, whether the batch is solved whole or in blocks
    (``block`` 2: the 3 scenarios in 2 blocks); a scenario whose sweep has ended is marked so."""
    monkeypatch.setattr(solver_module, "BLOCK", block)
    gammas = np.array([0.1, 0.05, 0.1])
    ramps = [np.round(np.arange(0.5, 1.3001, 0.05), 10), np.round(np.arange(0.6, 1.0001, 0.1), 10),
             np.round(np.arange(0.5, 0.7001, 0.05), 10)]
    speeds = np.full((max(map(len, ramps)), 3), np.nan)
    for s, ramp in enumerate(ramps):
        speeds[: len(ramp), s] = ramp
    lockstep = solve_sweep(lambda om, rows: duffing(om, gamma=gammas[rows]), speeds, 3, harmonics=3)
    assert lockstep.rpm.shape == speeds.shape
    for s, ramp in enumerate(ramps):
        alone = solve_sweep(lambda om, rows: duffing(om, gamma=gammas[s]), ramp, 1, harmonics=3)
        for step, result in enumerate(alone.results):
            mine = lockstep.results[step]
            np.testing.assert_array_equal(mine.harmonics[s], result.harmonics[0])
            assert (mine.success[s], mine.message[s], mine.branch[s]) == (
                result.success[0], result.message[0], result.branch[0])
        for step in range(len(ramp), len(speeds)):
            assert not lockstep.results[step].success[s]
            assert "sweep has ended" in lockstep.results[step].message[s]
    assert "jump between 1.25 and 1.3 RPM" in lockstep.results[len(ramps[0]) - 1].branch[0]


def test_lockstep_sweeps_that_jump_at_different_steps_and_go_on_equal_their_own_sweeps():
    """A sweep's failed continuations wait while the other scenarios go on, and are refined and jumped in one
    batch with those of other steps (``continuation._sweep_pass``): three hardening Duffing oscillators whose upper
    folds lie at different speeds (gamma 0.05, 0.1, 0.2: jumps at 1.2, 1.3 and 1.45) run up together to 1.6,
    each continuing on the lower branch after its jump. Every step of each equals its own sweep to the bit,
    messages and branch labels included."""
    gammas = np.array([0.05, 0.1, 0.2])
    ramp = np.round(np.arange(0.5, 1.6001, 0.05), 10)
    lockstep = solve_sweep(lambda om, rows: duffing(om, gamma=gammas[rows]), ramp, 3, harmonics=3)
    jumps = []
    for s, gamma in enumerate(gammas):
        alone = solve_sweep(lambda om, rows: duffing(om, gamma=gamma), ramp, 1, harmonics=3)
        for step, result in enumerate(alone.results):
            mine = lockstep.results[step]
            np.testing.assert_array_equal(mine.harmonics[s], result.harmonics[0])
            np.testing.assert_array_equal(mine.state[s], result.state[0])
            assert (mine.success[s], mine.message[s], mine.branch[s]) == (
                result.success[0], result.message[0], result.branch[0])
        jumps.append([step for step, r in enumerate(lockstep.results) if "jump" in r.branch[s]])
        assert all(r.success[s] for r in lockstep.results)  # on the lower branch after the jump, to the end
    assert [ramp[j] for (j,) in jumps] == [1.2, 1.3, 1.45]


@pytest.mark.parametrize("speeds, problem", [
    ([[0.5, np.nan], [0.6, 0.7]], "first speed"),
    ([[0.5, 0.5], [np.nan, 0.6], [0.7, 0.7]], "NaN only after"),
    ([[0.5, 0.5], [0.6, 0.4]], "strictly increasing"),
    ([[0.5, 0.5, 0.5]], "shape"),
])
def test_per_scenario_speeds_are_checked(speeds, problem):
    with pytest.raises(ValueError, match=problem):
        solve_sweep(lambda om, rows: duffing(om), np.array(speeds), 2, harmonics=1)


def test_damped_newton_backtracks_at_resonance_and_lands_on_the_reference():
    """From rest (x = 0, where the cubic has no stiffness) the first full Newton step is the linear
    response; at Omega = 1 that is the lightly damped resonance peak, far above the hardened
    response, so the step makes the residual 20x worse and the line search
    (_backtrack) takes over. It must hand back the residual AND the Jacobian of the step it chose
    (the fractions are screened on residuals alone), and the solve must reach NLvib's amplitude."""
    system = duffing([1.0])
    prob = Condensed(system, 7, None)
    screened = []
    evaluate = prob.evaluate

    def spy(x, idx, jacobian=True):
        screened.append(not jacobian)
        return evaluate(x, idx, jacobian)

    prob.evaluate = spy
    one = np.array([0])
    x = np.zeros_like(prob.a)
    r, J = prob.evaluate(x, one)
    step = np.linalg.solve(J, -r.reshape(1, -1, 1)).reshape(r.shape)
    nr = np.linalg.norm(r.ravel())
    trial_r, trial_J = prob.evaluate(x + step, one)
    assert np.linalg.norm(trial_r.ravel()) > 10 * nr  # the full step is far worse: backtracking needed
    alpha = np.ones(1)
    _backtrack(prob, x, one, step, np.array([nr]), alpha, one, trial_r, trial_J)
    assert any(screened) and alpha[0] < 1
    exact_r, exact_J = evaluate(x + alpha[0] * step, one)
    # Same arithmetic on the same state, only the batch layout differs: equal to round-off (observed 0).
    np.testing.assert_allclose(trial_r, exact_r, rtol=0, atol=1e-14 * np.abs(exact_r).max())
    np.testing.assert_allclose(trial_J, exact_J, rtol=0, atol=1e-14 * np.abs(exact_J).max())
    assert np.linalg.norm(trial_r.ravel()) < nr

    res = solve(system, harmonics=7)
    assert res.success[0]
    # The reference is rounded to 9 decimals (error <= 5e-10): 1e-8 absolute.
    assert abs(res.harmonics[0, 1, 0]) == pytest.approx(NLVIB_H7[1.0], abs=1e-8)


@pytest.mark.parametrize("Om", sorted(NLVIB_H7))
def test_duffing_h7_matches_time_integration(Om):
    res = solve(duffing([Om]), harmonics=7)  # direct solve lands on the upper branch at 1.0
    assert res.success[0]
    assert abs(res.harmonics[0, 1, 0]) == pytest.approx(NLVIB_H7[Om], abs=1e-8)
    Q = res.harmonics[0, :, 0]
    h = np.arange(Q.size)
    y0 = [Q.sum().real, (1j * h * Om * Q).sum().real]  # x(0), x'(0) from the HB series

    def rhs(t, y):
        return [y[1], 0.18 * np.cos(Om * t) - 0.05 * y[1] - y[0] - 0.1 * y[0] ** 3]

    T = 2 * np.pi / Om
    n_periods, per_period = 20, 64
    t = np.linspace(0.0, n_periods * T, n_periods * per_period + 1)
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, method="DOP853", rtol=1e-11, atol=1e-13, t_eval=t)
    assert sol.success
    x_hb = res.time_series(t)[0, :, 0]
    # Tolerance: HB with H = 7 drops harmonics 9, 11, ...; with H = 11 the 9X amplitude
    # is 1.1e-9 at Om = 1.0 (checked below) and 8e-13 at Om = 0.8, so the HB orbit is
    # within ~1e-9 of the true one, and the integrator's error (rtol 1e-11) is smaller.
    # A stable orbit keeps that offset bounded over 20 periods: 1e-8 leaves a margin
    # of ~3 over the observed 3e-9, while a wrong amplitude, phase or branch would be
    # off by > 1e-3.
    assert np.abs(sol.y[0] - x_hb).max() < 1e-8
    # The orbit returns to itself after 20 periods (periodicity of the true flow).
    assert np.abs(sol.y[:, -1] - y0).max() < 1e-8
    fine = solve(duffing([Om]), harmonics=11)
    assert abs(fine.harmonics[0, 9, 0]) < 2e-9


# --- exact rotor solution: circular orbit of an isotropic machine -------------------------


def test_isotropic_rotor_has_exact_circular_orbit():
    effects = base_effects() + [linear_spring_bearing(), IsotropicCubic()]
    model = Model(effects)  # a user effect, no change to the package
    values = GEOMETRIC.values({"m_e": 0.0259, "q_x": 0.004, "q_y": 0.004})  # q_x = q_y: isotropic forcing
    values["a_iso"] = np.asarray(2e9)
    rpm = np.array([600.0, 900.0])
    system = model.system(values, rpm)
    res = solve(system, harmonics=5)
    assert res.success.all()
    x, y = SHAFT.translational("x"), SHAFT.translational("y")
    for s in range(rpm.size):
        Q = res.harmonics[s]
        scale = np.abs(Q[1]).max()
        # Exact solution is pure 1X: all other harmonics vanish to round-off.
        assert np.abs(Q[[0, 2, 3, 4, 5]]).max() <= 1e-12 * scale
        # Forward circular whirl at every node: V_1 = -i U_1 (v lags u by 90 degrees).
        np.testing.assert_allclose(Q[1, y], -1j * Q[1, x], rtol=0, atol=1e-12 * scale)

        # Independent reference: on the orbit u^2 + v^2 = r^2 is constant, so the force is
        # the linear spring a_iso r^2 at node 0, with r = |U_0| a root of the scalar equation
        # |[(D_1 + a_iso r^2 B)^-1 F_1]_u0| = r (solved by brentq, no harmonic balance).
        D = dynamic_stiffness(system, s, 1)
        B = np.zeros(SHAFT.n_dof)
        B[[SHAFT.dof("u0"), SHAFT.dof("v0")]] = 1.0

        def circular(r):
            return np.linalg.solve(D + 2e9 * r * r * np.diag(B), system.forcing[1][s])

        r_lin = abs(circular(0.0)[SHAFT.dof("u0")])
        r = brentq(lambda r: abs(circular(r)[SHAFT.dof("u0")]) - r, 0.0, r_lin, xtol=1e-16, rtol=1e-15)
        exact = circular(r)
        # The nonlinearity matters here (otherwise the test would be a linear one):
        assert r < 0.9 * r_lin
        # brentq to 1e-15 on r, then a linear solve: agreement to 1e-10 (cond(D) ~ 1e4).
        assert np.abs(Q[1] - exact).max() <= 1e-10 * np.abs(exact).max()


# --- analytic Jacobian vs finite differences ----------------------------------------------


@pytest.mark.parametrize(
    "variant,overrides",
    [
        ("geometric", {}),
        # Paper's identified values: k2, k4, k5, k6, k7 all nonzero (quadratic, slope,
        # cross terms); k2, k5 larger than identified to make the even terms matter.
        ("expansion", {"k2": -600.0, "k5": 800.0}),
        ("final", {}),
    ],
)
def test_analytic_jacobian_matches_finite_differences(variant, overrides):
    v = builtin_variant(variant)
    H = 3
    rpm = np.array([700.0, 950.0])
    values = v.values({k: np.asarray(x) for k, x in overrides.items()})
    full = v.model.system(values, rpm)
    # Each effect's force alone, then the system's (effects at one node evaluated together):
    # a small term (e.g. the cubic slope force k6 (u')^3, whose share of the total Jacobian
    # is ~1e-4) is checked on its own.
    p = v.model.context(values, rpm).p
    per_effect = [LocalForce(e.name, np.array([SHAFT.dof(d) for d in e.dofs]),
                             lambda q, rows, e=e: e.force(q, p.rows(rows)), e.degree)
                  for e in v.model.effects if e.is_nonlinear]
    subsystems = [[f] for f in per_effect] + [full.forces]
    assert len(subsystems) > 2 or variant == "geometric"
    for forces in subsystems:
        system = System(full.M, full.C, full.K, full.Omega, full.forcing, forces)
        prob = Condensed(system, H, None)
        rng = np.random.default_rng(1)
        # An arbitrary state (all harmonics, including 0 and even ones) of the size of
        # the response, per DOF (slopes and deflections have different magnitudes).
        scale = np.abs(prob.a).max(axis=2, keepdims=True)
        x = prob.a + 0.5 * scale * rng.standard_normal(prob.a.shape)
        idx = np.arange(system.n_scenarios)
        _, J = prob.evaluate(x, idx)
        m = J.shape[1]
        flat = x.reshape(len(idx), m)

        def central(j, step):
            xp, xm = flat.copy(), flat.copy()
            xp[:, j] += step[:, j]
            xm[:, j] -= step[:, j]
            rp, _ = prob.evaluate(xp.reshape(x.shape), idx, jacobian=False)
            rm, _ = prob.evaluate(xm.reshape(x.shape), idx, jacobian=False)
            return (rp - rm).reshape(len(idx), m) / (2 * step[:, j, None])

        # Central differences with one Richardson step (error O(step^4) f^(5): exact up to
        # round-off for the polynomial forces of degree <= 3 here, since the AFT residual is
        # then itself a cubic polynomial of x, for any step). A large step, 0.1 x the
        # amplitude, keeps the round-off of r (~1e-16 |x|, and |r| ~ |x| >> |H G| for weak
        # terms) small against the differences: with 1e-3 x the amplitude the round-off
        # reached 2e-6 of a weak column with numpy 2.4's FFT.
        step = np.broadcast_to(0.1 * scale, x.shape).reshape(len(idx), m)
        J_fd = np.empty_like(J)
        for j in range(m):
            J_fd[:, :, j] = (4.0 * central(j, step) - central(j, 2.0 * step)) / 3.0
        names = [f.name for f in forces]
        for s in idx:
            nonlinear = J[s] - np.eye(m)  # = -H dG/dx: the part that is not trivially exact
            assert np.abs(nonlinear).max() > 0  # the force is really exercised
            # Error relative to each column's own scale (slope and deflection columns differ
            # by orders of magnitude), floored at 1e-3 of the largest column (columns a force
            # does not depend on, e.g. u0 for the slope force, are zero).
            col = np.abs(nonlinear).max(axis=0)
            err = np.abs(J_fd[s] - J[s]).max(axis=0) / np.maximum(col, 1e-3 * col.max())
            # Observed <= 1e-8: round-off of r over the step. 1e-6 catches any wrong term
            # (a wrong factor or sign is O(1); a 0.1 % error in one term is caught).
            assert err.max() < 1e-6, (variant, names, s, err.max())


# --- AFT sample count and harmonic truncation ---------------------------------------------


def test_alias_free_sample_count_matches_oversampling():
    system = geometric_system([450.0, 700.0, 900.0])
    H = 7
    default = solve(system, harmonics=H, tol=1e-14)
    over = solve(system, harmonics=H, n_time=64, tol=1e-14)
    assert default.n_time == 4 * H + 1 and over.n_time == 64
    assert default.success.all() and over.success.all()
    # Both AFT grids are exact for a cubic of an H-harmonic signal (4H + 1 is the
    # alias-free minimum, 64 > 4H), so both solve the same equations: 1e-12.
    for s in range(3):
        scale = np.abs(default.harmonics[s]).max()
        assert np.abs(default.harmonics[s] - over.harmonics[s]).max() <= 1e-12 * scale


def test_harmonic_truncation_converges():
    system = geometric_system(700.0)
    amplitude = {}
    for H in (1, 3, 5, 7):
        res = solve(system, harmonics=H)
        assert res.success[0]
        Q = res.harmonics[0, :, SENSOR_X]
        amplitude[H] = (abs(Q[1]), abs(Q[3]) if H >= 3 else np.nan)
    one = np.array([amplitude[H][0] for H in (1, 3, 5, 7)])
    three = np.array([amplitude[H][1] for H in (3, 5, 7)])
    change_1x = np.abs(np.diff(one)) / one[1:]
    change_3x = np.abs(np.diff(three)) / three[1:]
    # Brief: from H = 5 to H = 7 both amplitudes change by less than 1e-6 relative.
    assert change_1x[-1] < 1e-6 and change_3x[-1] < 1e-6
    # ... and the changes shrink as H grows (spectral convergence of a smooth orbit).
    assert np.all(np.diff(change_1x) < 0), change_1x
    assert np.all(np.diff(change_3x) < 0), change_3x
    # At 700 RPM the response is nearly pure 1X (docs/model.md: 3X/1X ~ 1e-4 .. 1e-2).
    assert 1e-5 < amplitude[7][1] / amplitude[7][0] < 1e-2


# --- power balance ------------------------------------------------------------------------


def test_power_balance_geometric():
    # Direct solves at 450 and 700; 900 RPM (near the peak) by a run-up from 700.
    system = geometric_system([450.0, 700.0])
    direct = solve(system, harmonics=7)
    sweep = solve_sweep(lambda rpm, rows: geometric_system(np.full(len(rows), rpm)),
                        [700.0, 800.0, 900.0], 1, harmonics=7)
    cases = [(system, 0, direct.harmonics[0]), (system, 1, direct.harmonics[1])]
    top = geometric_system(900.0)
    assert sweep.results[-1].success[0]
    cases.append((top, 0, sweep.results[-1].harmonics[0]))
    for sys_, s, Q in cases:
        # K symmetric (Geometric springs' linear part, -Omega^2 M): it stores energy, no power.
        np.testing.assert_allclose(sys_.K[s], sys_.K[s].T, rtol=0, atol=0)
        P_in, P_diss, P_nl, P_K = power_balance(sys_, s, Q)
        assert P_in > 0
        # Geometric springs are conservative (F = -grad V); mean power of d/dt V over a
        # period is zero exactly for a truncated series with alias-free AFT.
        assert abs(P_nl) < 1e-10 * P_in
        # P_K = sum_h 1/2 h Omega Im(Q_h^H K Q_h) is zero for symmetric K; in floating point it is
        # a cancellation of products of size h Omega |Q_h| (|K| |Q_h|) (the usual floating-point
        # bound of a matrix product), so its floor is ~eps times their sum.
        h = np.arange(Q.shape[0])[:, None]
        terms = h * sys_.Omega[s] * np.abs(Q) * (np.abs(Q) @ np.abs(sys_.K[s]).T)
        assert abs(P_K) < 100 * np.finfo(float).eps * terms.sum()
        assert abs(P_K) < 1e-10 * P_in
        # The HB equations are solved to tol 1e-10 (relative): balance to 1e-8.
        assert P_diss == pytest.approx(P_in, rel=1e-8)
        # And the full-DOF HB equations hold (independent FFT residual).
        assert hb_residual(sys_, s, Q) < 1e-9


# --- fixed-point vs Newton ----------------------------------------------------------------


def test_fixed_point_equals_newton():
    system = geometric_system([450.0, 700.0, 900.0])
    newton = solve(system, harmonics=5)
    fixed = solve(system, harmonics=5, method="fixed-point")
    assert newton.success.all() and fixed.success.all()
    # It really is the fixed-point iteration that converged (no Newton fallback).
    assert not any("fallback" in m for m in fixed.message)
    assert np.all(fixed.iterations > newton.iterations)
    for s in range(3):
        scale = np.abs(newton.harmonics[s]).max()
        # Both stop at a relative residual <= 1e-10; the fixed point's error is that
        # divided by (1 - contraction rate) (~0.5 here), so 1e-8 is safe.
        assert np.abs(fixed.harmonics[s] - newton.harmonics[s]).max() <= 1e-8 * scale


# --- failures and batching ----------------------------------------------------------------


def quadratic_oscillator(P0, zeta=0.1) -> System:
    """x'' + zeta x' + x + x^2 = P0 (static load only), force ON the structure F = -x^2."""
    P0 = np.asarray(P0, dtype=float)
    S = P0.size

    def evaluate(q, rows):
        return -q * q, (-2.0 * q)[:, :, None, :]

    return System(np.ones((S, 1, 1)), np.full((S, 1, 1), zeta), np.ones((S, 1, 1)), np.ones(S),
                  {0: P0[:, None].astype(complex)}, [LocalForce("quadratic", np.array([0]), evaluate, 2)])


def test_no_periodic_solution_is_reported_not_garbage():
    """x'' + 0.1 x' + x + x^2 = P0 has no periodic solution at all for P0 < -1/4.

    Proof: with E = x'^2/2 + x^2/2 + x^3/3 - P0 x, dE/dt = -0.1 x'^2, so over a period
    x' = 0: a periodic solution is an equilibrium x + x^2 = P0, and x + x^2 >= -1/4.
    The same power argument holds for the alias-free HB equations (the quadratic force
    is conservative), so the solver has no root to find. Above -1/4 the equilibrium is
    the exact answer. (A softening Duffing under large P is NOT such a case: its HB
    equations and the true system have large-amplitude periodic orbits.)
    """
    P0 = np.array([0.2, -1.0, -0.2, -0.3])
    res = solve(quadratic_oscillator(P0), harmonics=3)
    assert res.success.tolist() == [True, False, True, False]
    for s in np.flatnonzero(res.success):
        x0 = res.harmonics[s, 0, 0].real
        assert abs(x0 + x0**2 - P0[s]) < 1e-12
        assert np.abs(res.harmonics[s, 1:]).max() < 1e-14
    for s in np.flatnonzero(~res.success):
        assert res.status[s] != 0
        assert res.message[s] and "converged in" not in res.message[s]
        assert np.isnan(res.harmonics[s]).all()
        assert np.isnan(res.state[s]).all()
    assert set(res.failures()) == {1, 3}
    # Batched == one by one, failures included.
    for s in range(P0.size):
        alone = solve(quadratic_oscillator(P0[[s]]), harmonics=3)
        assert alone.success[0] == res.success[s] and alone.status[0] == res.status[s]
        np.testing.assert_array_equal(np.isnan(alone.harmonics[0]), np.isnan(res.harmonics[s]))
        if alone.success[0]:
            assert alone.harmonics[0, 0, 0] == pytest.approx(res.harmonics[s, 0, 0], rel=1e-14)


def test_undamped_linear_resonance_is_reported():
    # x'' + x = cos(Omega t) (+ 0 x^3), no damping: at Omega = 1 the response grows
    # without bound. Omega = 0.3 and 2.0 keep 2 Omega away from 1 (no 2X resonance).
    Om = np.array([0.3, 1.0, 2.0])
    system = duffing(Om, gamma=0.0, P=1.0, zeta=0.0)
    res = solve(system, harmonics=2)
    assert res.success.tolist() == [True, False, True]
    assert "singular" in res.message[1]
    assert np.isnan(res.harmonics[1]).all()
    # The others: the closed form 1 / (1 - Omega^2), to round-off.
    np.testing.assert_allclose(res.harmonics[[0, 2], 1, 0], 1.0 / (1.0 - Om[[0, 2]] ** 2), rtol=1e-14)


def test_geometric_failure_near_peak_and_batching():
    """Range-edge parameters at 900 RPM: the direct solve may fail; it must say so cleanly.

    k_b = 2000, zeta_s = 0.01, zeta_bup = 0, q = 0.01 (softest, least damped, largest bow):
    Newton from the linear response does not converge there, while a run-up reaches a
    periodic solution. Either outcome must be honest: failure with NaN and a message, or
    success that satisfies the full HB equations (independent FFT residual).
    """
    edge = dict(k_b=2000.0, zeta_s=0.01, zeta_bup=0.0, q_x=0.01, q_y=0.01)
    nominal = {k: GEOMETRIC.values()[k] for k in edge}
    mixed = {k: np.array([nominal[k], edge[k], nominal[k], edge[k]]) for k in edge}
    rpm = np.array([900.0, 900.0, 700.0, 700.0])
    system = GEOMETRIC.system(rpm, mixed)
    batched = solve(system, harmonics=5)
    assert batched.success[[0, 2, 3]].all()
    for s in range(4):
        if batched.success[s]:
            assert hb_residual(system, s, batched.harmonics[s]) < 1e-9
        else:
            assert batched.message[s] and np.isnan(batched.harmonics[s]).all()
    # (Today scenario 1 fails from the linear start: "Newton did not converge". A future,
    # more robust start that converges is fine too: the residual check above covers it.)

    # Batched == one by one (scenarios do not interact through the batch).
    for s in range(4):
        alone = solve(system.subset(np.array([s])), harmonics=5)
        assert alone.success[0] == batched.success[s]
        assert alone.status[0] == batched.status[s] and alone.iterations[0] == batched.iterations[s]
        if alone.success[0]:
            # Same iterates up to the round-off of batched vs single LAPACK calls.
            scale = np.abs(alone.harmonics[0]).max()
            assert np.abs(alone.harmonics[0] - batched.harmonics[s]).max() <= 1e-12 * scale

    # The failure was "not found from the linear start", not "does not exist": a run-up
    # from 700 RPM reaches a periodic solution at 900 RPM that satisfies the HB equations.
    build = lambda r, rows: GEOMETRIC.system(np.full(len(rows), r), {k: np.full(len(rows), x) for k, x in edge.items()})
    sweep = solve_sweep(build, np.arange(700.0, 901.0, 25.0), 1, harmonics=5)
    end = sweep.results[-1]
    assert end.success[0] and end.branch[0] == "run-up"
    assert hb_residual(build(900.0, np.array([0])), 0, end.harmonics[0]) < 1e-9
