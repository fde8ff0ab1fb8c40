"""The run-up forward model (hybridtwin.solvers.sweep_forward: the steady state corrected to first order in the sweep
rate) against time integration of the same equations (hybridtwin.solvers.sweep.integrate_sweep) on a linear rotor
and on the VARM with its nonlinear bearing; its derivative in the fit (forward.SolverModel); the one-mode
second-order estimate the keep-out rule reads (solvers.sweep_rate.second_order_correction) against integration."""

import math

import numpy as np
import pytest

from hybridtwin.rig.rig import Truth
from hybridtwin.identify.forward import SolverModel, run_up
from hybridtwin.model.effect_base import Effect, Parameter
from hybridtwin.model.model import Model
from hybridtwin.model.sensor import sensor_dofs
from hybridtwin.solvers.solver import solve
from hybridtwin.solvers.sweep import SpeedProfile, SpeedSystem, integrate_sweep
from hybridtwin.solvers.sweep_forward import swept_response

H = 3


class UpperSpring(Effect):
    """A linear isotropic spring at the upper bearing: the VARM made linear (the geometric spring's linear part)."""

    name = "upper_spring"
    meaning = "test: a linear isotropic spring at the upper bearing"
    parameters = (Parameter("k_up", "N/m", (0.0, 1e4), 4822.6, "its stiffness"),)

    def stiffness(self, ctx):
        K = ctx.zeros()
        for dof in ("u0", "v0"):
            K[:, ctx.dof(dof), ctx.dof(dof)] = ctx.p["k_up"]
        return K


def varm_truth():
    """The VARM's default truth (Geometric model + slope spring: a cubic bearing), no added mass (the bow drives it:
    with 25.9 g the run-up jumps at a fold, where no expansion in the rate holds), and the same rotor made linear
    (the springs replaced by ``UpperSpring`` at 2 k_b, the geometric spring's linear stiffness)."""
    truth = Truth.from_spec()
    values = truth.variant.values({**truth.values, "m_e": 0.0})
    model = truth.variant.model
    linear = Model([UpperSpring()] + [e for e in model.effects if e.name not in ("geometric_spring", "slope_spring")],
                   model.shaft)
    linear_values = {k: v for k, v in values.items() if k not in ("k_w", "k_z")} | {"k_up": 2 * 2411.3}
    return truth.variant, values, linear, linear_values


def windows(t, theta, x, revolutions=2):
    """Per window of whole revolutions, the order vectors X_h (h = 1..H) at its centre: least squares of each column
    of x on [1, tau, cos h theta, sin h theta, tau cos h theta, tau sin h theta] (tau the time from the centre), so
    that the amplitude's change across the window leaks into no other order (a fit of one order alone puts ~2 %
    of the 1X peak into the 3X near the resonance). Returns the centres' times and X (W, H, d)."""
    edges = 2 * np.pi * np.arange(np.ceil(theta[0] / (2 * np.pi)), theta[-1] / (2 * np.pi), revolutions)
    index = np.searchsorted(theta, edges)
    times, vectors = [], []
    for a, b in zip(index[:-1], index[1:]):
        th, tau = theta[a:b], t[a:b] - 0.5 * (t[a] + t[b - 1])
        columns = [np.ones_like(tau), tau]
        for h in range(1, H + 1):
            columns += [np.cos(h * th), np.sin(h * th), tau * np.cos(h * th), tau * np.sin(h * th)]
        coef = np.linalg.lstsq(np.column_stack(columns), x[a:b], rcond=None)[0]
        vectors.append([coef[2 + 4 * k] - 1j * coef[3 + 4 * k] for k in range(H)])
        times.append(0.5 * (t[a] + t[b - 1]))
    return np.array(times), np.array(vectors)


def swept_errors(model, values, start, end, rate, steady):
    """A run-up (or, end < start, a coast-down) start -> end RPM at ``rate`` RPM/s integrated in time from the steady
    state at start; its order vectors per
    two revolutions (``windows``) against the model at each window's speed and rate: the steady state alone and
    corrected to first order (``swept_response``). ``steady(rpm)``: the steady states there. Returns, per order
    h = 1..H, the largest vector error of each over the windows of constant rate (the ramps' Omega'' left out) as a
    fraction of the order's largest steady response, and the windows' speeds with the 1X errors."""
    lo, hi = min(start, end), max(start, end)
    profile = SpeedProfile.sweep(start, end, (hi - lo) / rate, dwell_start_s=0.1, ramp_s=0.5)
    dofs = sensor_dofs(model.shaft)
    system = SpeedSystem.from_model(model, values, 1.2 * hi)
    t = np.arange(0.0, profile.t1, 60.0 / (64 * hi))  # 64 samples per revolution at the top speed
    result = integrate_sweep(system, profile, t, dofs, start=solve(model.system(values, start), H))
    centre, X = windows(t, result.theta, result.displacements)
    rpm = profile.rpm(centre)
    keep = (rpm > lo + rate) & (rpm < hi - rate)  # a ramp's time (0.5 s) and more away from both ends
    centre, X, rpm = centre[keep], X[keep], rpm[keep]
    states = steady(rpm)
    response = swept_response(model, values, rpm, profile.omega_dot(centre) * 30 / math.pi, states.state, H,
                              states.n_time)
    out = {}
    for h in range(1, H + 1):
        Q0, Q = response.quasi_steady[:, h][:, dofs], response.harmonics[:, h][:, dofs]
        peak = np.abs(Q0).max()
        if peak == 0:
            continue
        e0 = np.abs(X[:, h - 1] - Q0).max(axis=1) / peak
        e1 = np.abs(X[:, h - 1] - Q).max(axis=1) / peak
        out[h] = (e0, e1)
    return out, rpm


@pytest.fixture(scope="module")
def rotors():
    return varm_truth()


def test_linear_rotor_swept_response_matches_time_integration(rotors):
    """The VARM made linear, driven by its bow (resonance ~950 RPM), run up 840 -> 990 RPM at 10 and 20 RPM/s.
    Measured (1X, fraction of the steady peak): the steady state misses by 0.091 and 0.175 (first order in the rate:
    x 1.93), the corrected one by 0.024 and 0.088 (x 3.6: second order; the expansion's parameter, |X1| / |X0|, is
    ~0.1 and ~0.2 at the peak, so the third order shows at 20 RPM/s). Away from the peak (where the steady state's
    error is below half its largest) the corrected error is at most 0.16 of the steady one at 10 RPM/s. Asserted:
    the corrected error below 0.45 times the steady one at 10 RPM/s, below 0.25 times it away from the peak, and
    growing with the rate faster than the steady one's (x 2.5 or more, where the steady one's stays within
    x 1.6-2.2 of first order). A coast-down 990 -> 840 RPM at 10 RPM/s (a negative rate): measured 0.090 -> 0.024,
    asserted as the run-up at 10 RPM/s.
    """
    _, _, model, values = rotors

    def steady(rpm):
        return solve(model.system(values, rpm), H)

    worst = {}
    for rate in (10.0, 20.0):
        errors, rpm = swept_errors(model, values, 840.0, 990.0, rate, steady)
        e0, e1 = errors[1]
        worst[rate] = (e0.max(), e1.max())
        assert e0.max() > 0.05 * rate / 10  # the sweep is visibly not quasi-steady (measured 0.091, 0.175)
        if rate == 10.0:
            away = e0 < 0.5 * e0.max()
            assert away.sum() > 10 and (e1[away] < 0.25 * e0[away]).all(), (e1[away] / e0[away]).max()
    assert worst[10.0][1] < 0.45 * worst[10.0][0], worst
    assert 1.6 < worst[20.0][0] / worst[10.0][0] < 2.2, worst  # the steady state's error: first order in the rate
    assert worst[20.0][1] / worst[10.0][1] > 2.5, worst  # the corrected one's: of higher order
    # a coast-down through the same resonance (a negative rate: the lag is on the other side of the peak)
    errors, _ = swept_errors(model, values, 990.0, 840.0, 10.0, steady)
    e0, e1 = errors[1]
    assert e0.max() > 0.05 and e1.max() < 0.45 * e0.max(), (e0.max(), e1.max())


def test_varm_with_its_nonlinear_bearing_swept_response_matches_time_integration(rotors):
    """The VARM's truth (cubic geometric and slope springs, the bow driving it) run up 880 -> 1040 RPM at 10 RPM/s
    through its hardening resonance (~990 RPM), the steady states by run-up (the branch the rotor follows), the
    correction linearised about them (the Newton Jacobian of the bearing). Measured (fraction of each order's steady
    peak): 1X 0.085 -> 0.029, 3X (the bearing's own order) 0.244 -> 0.061; away from the peak (the steady state's 1X
    error below half its largest) the corrected 1X error is at most 0.23 of the steady one. Asserted: the corrected
    error below 0.45 times the steady one at 1X and at 3X, and below 0.3 times it at 1X away from the peak."""
    variant, values, _, _ = rotors

    def steady(rpm):
        from hybridtwin.solvers.solver import SteadyState

        return SteadyState.concatenate(run_up(variant, rpm, values, H))

    errors, rpm = swept_errors(variant.model, values, 880.0, 1040.0, 10.0, steady)
    (e0, e1), (f0, f1) = errors[1], errors[3]
    assert e0.max() > 0.05 and f0.max() > 0.1  # not quasi-steady at 1X nor 3X (measured 0.085, 0.244)
    assert e1.max() < 0.45 * e0.max(), (e1.max(), e0.max())
    assert f1.max() < 0.45 * f0.max(), (f1.max(), f0.max())
    away = e0 < 0.5 * e0.max()
    assert away.sum() > 10 and (e1[away] < 0.3 * e0[away]).all(), (e1[away] / e0[away]).max()


def test_the_fits_swept_model_and_its_derivative(rotors):
    """forward.SolverModel with a band's sweep rate: its response is the steady state plus ``swept_response``'s
    correction, its Jacobian (forward differences of the correction along the steady state's own sensitivities)
    against central differences of ``evaluate`` itself (each a run-up and a new correction): measured 2e-6 of the
    largest entry; 1e-4 allows for the differences' truncation (steps of 1e-4 of the range)."""
    variant, values, _, _ = rotors
    names = ["zeta_s", "zeta_bup", "k_b"]
    lower, upper = np.array([0.01, 0.005, 2000.0]), np.array([0.04, 0.03, 2800.0])
    x = np.array([[0.1, -0.2, 0.05]])
    steady = SolverModel(variant, "b0960", 960.0, 0.0, names, lower, upper, H, warm=False)
    swept = SolverModel(variant, "b0960", 960.0, 0.0, names, lower, upper, H, warm=False, sweep_rpm_s=10.0)
    M0, _ = steady.evaluate(x)
    M, J = swept.evaluate(x)
    at = swept._values(x)  # the parameter set at x: the variant's nominal values, x's and the run's mass
    state = run_up(variant, [960.0], at, H)[0]
    expected = swept_response(variant.model, at, [960.0], [10.0], state.state, H, state.n_time).harmonics
    from hybridtwin.model.sensor import sensor_channels

    assert np.allclose(M[0], sensor_channels(expected, variant.model.shaft)[0, 1:], rtol=0, atol=1e-9 * np.abs(M).max())
    assert np.abs(M - M0).max() > 0.01 * np.abs(M0).max()  # the correction is not negligible at the resonance
    h = 1e-3
    for j in range(len(names)):
        step = np.zeros_like(x)
        step[0, j] = h
        numeric = (swept.evaluate(x + step, jacobian=False)[0] - swept.evaluate(x - step, jacobian=False)[0]) / (2 * h)
        assert np.abs(J[0, ..., j] - numeric[0]).max() < 2e-3 * np.abs(numeric).max(), names[j]


def test_second_order_estimate_against_time_integration():
    """The one-mode second order X2 (sweep_rate.second_order_correction), what the swept model still misses and what
    the keep-out rule compares with the noise, against the Jeffcott rotor integrated in time (the closed-form
    equation of sweep_rate's docstring, m = 1, unbalance a): zeta 0.05 swept 390 -> 460 RPM at 5 RPM/s. Measured
    (fraction of the steady peak, largest over the windows): X - X0 - X1 0.033, X2 0.036, X - X0 - X1 - X2 0.017
    (the series' parameter, |X1| / |X0| ~ 0.3 at the peak, makes the third order visible). Asserted: X2 halves what
    the first order leaves (the rest below 0.6 of it), and as an estimate of that rest it is right to a factor 2
    wherever the rest is a tenth of its largest or more (measured 0.64-1.33)."""
    from hybridtwin.solvers.sweep_rate import adiabatic_correction, quasi_steady, second_order_correction

    wn, zeta, a, rate = 2 * np.pi * 10.0, 0.05, 1e-4, 5.0
    c = 2 * zeta * wn
    system = SpeedSystem(np.eye(2), {0: np.eye(2) * wn**2, 2: -np.eye(2)}, {0: np.eye(2) * c}, {},
                         {1: a * np.array([1.0, -1.0j])})
    profile = SpeedProfile.sweep(390, 460, 70.0 / rate, dwell_start_s=1.0, ramp_s=0.5)
    t = np.arange(0.0, profile.t1, 5e-4)
    O0 = profile.omega0
    Z = a * quasi_steady(O0, wn, zeta) * np.exp(1j * profile.theta(0.0))
    result = integrate_sweep(system, profile, t, [0, 1], start=np.array([Z.real, Z.imag, (1j * O0 * Z).real,
                                                                         (1j * O0 * Z).imag]))
    centre, X = windows(t, result.theta, result.displacements[:, :1], 1)  # x = Re(z) = Re(X e^{i theta})
    Omega, Omega_dot = profile.omega(centre), profile.omega_dot(centre)
    inside = (Omega * 30 / np.pi > 395) & (Omega * 30 / np.pi < 455)  # the constant rate (no ramp's Omega'')
    Xz = X[inside, 0, 0]
    X0 = a * quasi_steady(Omega[inside], wn, zeta)
    X1 = a * adiabatic_correction(Omega[inside], Omega_dot[inside], wn, zeta)
    X2 = a * second_order_correction(Omega[inside], Omega_dot[inside], wn, zeta)
    peak = np.abs(X0).max()
    rest = np.abs(Xz - X0 - X1) / peak
    assert rest.max() > 0.01, rest.max()  # the first order leaves a visible rest (measured 0.033)
    assert (np.abs(Xz - X0 - X1 - X2) / peak).max() < 0.6 * rest.max()
    visible = rest > 0.1 * rest.max()
    ratio = np.abs(X2[visible]) / peak / rest[visible]
    assert visible.sum() >= 5 and 0.5 < ratio.min() and ratio.max() < 2.0, ratio
