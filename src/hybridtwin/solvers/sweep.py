"""Time integration of the equations of motion along a speed profile: run-ups and coast-downs (issue 38).

The model at variable speed is the steady model (``Model.system``, eq. 29) with the speed a function of
time, Omega(t), and the rotor angle theta(t) = integral of Omega dt (theta = 2 pi k when the unbalance points
to +x; the shaft turns from +x towards +y)::

    M q'' + C(Omega) q' + K(Omega) q = f(t) + F_nl(q)

- K(Omega), C(Omega) are the steady model's at the instantaneous speed: K - Omega^2 M from the centrifugal
  term (and any other speed term an effect declares), C with alpha_d, omega_1, Phi_1 of (K, M) at rest, so
  they do not change with speed (the steady model's own definition; ``Model.at_rest``).
- A harmonic forcing term F_h(Omega) of the steady model becomes Re(F_h(Omega(t)) exp(i h theta(t))): it reads
  the instantaneous speed and angle, with no Omega' term (a force law written with Omega and Omega t).
- The inertia of a rotating mass, declared by its effect (``Effect.inertial``: the unbalance and the shaft
  bow), also gets the tangential term: its Omega^2 coefficient A_h becomes A_h (Omega^2 - i Omega' / h), i.e.
  for h = 1 f_x = A_x (Omega^2 cos theta + Omega' sin theta), f_y = A_y (Omega^2 sin theta - Omega' cos
  theta), the inertia of a mass at angle theta. With Omega' = 0 and theta = Omega t this is the steady forcing.
- The local nonlinear forces do not depend on the speed (``Effect.force`` reads q only).
- Not modelled (the project's definition): a gyroscopic disk's spin-acceleration term Omega' G q.

How the speed dependence is read from the System, generically (no effect-specific code here):
``SpeedSystem.from_model`` evaluates the model at POLY_NODES speeds and fits K, C and every forcing harmonic
(the inertial effects' apart) as polynomials of degree <= POLY_DEGREE in Omega, and checks the fit at
POLY_CHECKS other speeds to POLY_TOLERANCE of the largest entry. The built-in effects are polynomials of degree
<= 2 (Omega^2 M, Omega G, 2 zeta_v Omega M, m_e r_me Omega^2, e Omega^2, constant forces), so the fit is exact to
round-off. An effect whose law is not such a polynomial makes the check fail, and the system is then
evaluated at the instantaneous speed at every right-hand side (``Model.system_at``, exact but about 100 times
slower; ``SpeedSystem.polynomial`` False says so).

Integration (``integrate_sweep``): Radau with the exact Jacobian dy'/dy = [[0, I], [-M^-1 (K(Omega) - dF_nl/dq),
-M^-1 C(Omega)]] (as ``hybridtwin.solvers.transient``), tolerances as ``transient.settle``'s (atol relative to the start
orbit's amplitude, velocities scaled), sampled by Radau's dense output. The start is the periodic steady state at
the start speed: settled by time integration (``transient.settle``, no harmonic-balance code: the rig's truth) or
given (a harmonic-balance ``SteadyState`` or a state vector).

``SpeedProfile``: Omega(t) as a C2 piecewise polynomial (its derivative and integral exact), constant before its
first and after its last breakpoint; ``SpeedProfile.sweep`` builds a run-up or coast-down with dwells, a smooth
onset of the acceleration, a linear or exponential-approach shape and a seeded wobble of the rate.
``order_vectors``: a per-revolution least-squares fit of one order, for checks (the real order tracker is the
data side's).
"""

from __future__ import annotations

import bisect
import cmath
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.integrate import Radau
from scipy.interpolate import CubicSpline, PPoly

from ..model.model import LocalForce, Model, System, rpm_to_rad_s
from .transient import (ATOL_FLOOR, DEFAULT_ATOL_RELATIVE, DEFAULT_RTOL, DEFAULT_VELOCITY_SCALE, RESOLVED_HARMONICS,
                        FirstOrder, NotSettledError, PolynomialForce, local_forces, settle, state_tolerance)

Array = np.ndarray

#: speed laws are fitted as polynomials of this degree in Omega (the built-in effects need 2) ...
POLY_DEGREE = 4
#: ... at these fractions of the highest speed (Chebyshev-Lobatto points on [0, 1]) ...
POLY_NODES = 0.5 * (1.0 - np.cos(np.pi * np.arange(POLY_DEGREE + 1) / POLY_DEGREE))
#: ... checked at these, to this fraction of the largest entry over the speeds (else: evaluated at every speed)
POLY_CHECKS = np.array([0.31, 0.77, 1.0 + 1.0 / 3.0])
POLY_TOLERANCE = 1e-9
#: terms whose contribution at the highest speed is below this fraction of the largest are dropped (round-off)
POLY_DROP = 1e-13


# --- the speed profile ------------------------------------------------------------------------------------


class SpeedProfile:
    """Omega(t) [rad/s], Omega'(t) and theta(t) [rad] of a C1 (or smoother) piecewise polynomial ``omega``
    (a scipy ``PPoly`` on [t0, t1]), constant (Omega(t0), Omega(t1)) outside; theta(t0) = ``theta0``.

    ``at(t)`` gives the three at one instant (fast, for the right-hand side); ``omega``, ``omega_dot``,
    ``theta`` are vectorised. ``steady_until``: the last instant before which the speed is constant
    (t0 unless the first pieces are constant).
    """

    def __init__(self, omega: PPoly, theta0: float = 0.0):
        if not isinstance(omega, PPoly):
            raise TypeError("SpeedProfile: omega must be a scipy PPoly")
        self._omega = omega
        self._omega_dot = omega.derivative()
        theta = omega.antiderivative()
        self.t0, self.t1 = float(omega.x[0]), float(omega.x[-1])
        self.theta0 = float(theta0)
        self._theta = theta
        self._theta_t0 = float(theta(self.t0))
        self.omega0, self.omega1 = float(omega(self.t0)), float(omega(self.t1))
        self._theta_t1 = self.theta0 + float(theta(self.t1)) - self._theta_t0
        # a fast scalar evaluator: breakpoints, and each piece's coefficients for Horner (highest power first)
        self._x = omega.x.tolist()
        self._c = [omega.c[:, j].tolist() for j in range(omega.c.shape[1])]
        self._cd = [self._omega_dot.c[:, j].tolist() for j in range(omega.c.shape[1])]
        self._ct = [theta.c[:, j].tolist() for j in range(omega.c.shape[1])]
        self._shift = self.theta0 - self._theta_t0
        varying = np.flatnonzero(np.any(omega.c[:-1] != 0.0, axis=0) | (omega.c[-1] != omega.c[-1, 0]))
        self.steady_until = float(omega.x[varying[0]]) if varying.size else self.t1

    # scalar, for the integrator
    def at(self, t: float) -> tuple[float, float, float]:
        """(Omega, Omega', theta) at the instant t."""
        if t <= self.t0:
            return self.omega0, 0.0, self.theta0 + self.omega0 * (t - self.t0)
        if t >= self.t1:
            return self.omega1, 0.0, self._theta_t1 + self.omega1 * (t - self.t1)
        j = min(bisect.bisect_right(self._x, t) - 1, len(self._c) - 1)
        s = t - self._x[j]
        w = 0.0
        for c in self._c[j]:
            w = w * s + c
        wd = 0.0
        for c in self._cd[j]:
            wd = wd * s + c
        th = 0.0
        for c in self._ct[j]:
            th = th * s + c
        return w, wd, th + self._shift

    # vectorised
    def omega(self, t: Array) -> Array:
        t = np.asarray(t, dtype=float)
        return np.where(t <= self.t0, self.omega0,
                        np.where(t >= self.t1, self.omega1, self._omega(np.clip(t, self.t0, self.t1))))

    def omega_dot(self, t: Array) -> Array:
        t = np.asarray(t, dtype=float)
        inside = (t > self.t0) & (t < self.t1)
        return np.where(inside, self._omega_dot(np.clip(t, self.t0, self.t1)), 0.0)

    def theta(self, t: Array) -> Array:
        t = np.asarray(t, dtype=float)
        mid = self._shift + self._theta(np.clip(t, self.t0, self.t1))
        return np.where(t <= self.t0, self.theta0 + self.omega0 * (t - self.t0),
                        np.where(t >= self.t1, self._theta_t1 + self.omega1 * (t - self.t1), mid))

    def rpm(self, t: Array) -> Array:
        return self.omega(t) * 30.0 / math.pi

    def times_at_angles(self, angles: Array) -> Array:
        """The instants at which theta reaches each of ``angles`` (theta increasing: Omega > 0 throughout)."""
        angles = np.asarray(angles, dtype=float)
        grid = np.linspace(self.t0, self.t1, max(2, int((self.t1 - self.t0) * 200) + 2))
        th = self.theta(grid)
        if np.any(np.diff(th) <= 0) or self.omega0 <= 0 or self.omega1 <= 0:
            raise ValueError("speed profile: the rotor angle must increase (Omega > 0 throughout)")
        t = np.interp(angles, th, grid)
        before, after = angles < th[0], angles > th[-1]
        t[before] = self.t0 + (angles[before] - self.theta0) / self.omega0
        t[after] = self.t1 + (angles[after] - self._theta_t1) / self.omega1
        for _ in range(4):  # Newton on theta(t) = angle
            t = t - (self.theta(t) - angles) / self.omega(t)
        return t

    @classmethod
    def constant(cls, rpm: float, t0: float = 0.0, t1: float = 1.0, theta0: float = 0.0) -> "SpeedProfile":
        """A constant speed (theta = theta0 + Omega (t - t0))."""
        omega = float(rpm_to_rad_s(rpm))
        return cls(PPoly(np.array([[omega]]), np.array([t0, t1])), theta0)

    @classmethod
    def sweep(cls, rpm_start: float, rpm_end: float, sweep_s: float, *, dwell_start_s: float = 0.0,
              dwell_end_s: float = 0.0, ramp_s: float = 0.5, shape: str = "linear", wobble: float = 0.0,
              rng: np.random.Generator | None = None, theta0: float = 0.0,
              knot_spacing_s: float | None = None) -> "SpeedProfile":
        """A run-up (rpm_end > rpm_start) or coast-down from rpm_start to rpm_end, starting at t = 0.

        Speed constant for ``dwell_start_s``, then a sweep of ``sweep_s`` seconds, then constant for
        ``dwell_end_s``. The sweep's acceleration a(t) = onset(t) shape(t) (1 + wobble g(t)), normalised so
        that the speed ends exactly at rpm_end: onset rises from 0 to 1 over ``ramp_s`` at the start and falls
        back over the end (C2 smoothstep 10 s^3 - 15 s^4 + 6 s^5: no jerk steps that would ring the high
        modes); shape 1 ("linear": a constant rate between the ramps) or exp(-2 t / sweep_s) ("exponential": an
        exponential approach to the end speed, the rate at the end 13.5 % of the start's); g a smooth random
        curve with |g| <= 1 (three sines of 0.1-1 Hz with random phases, from ``rng``), so the rate wobbles by
        +-wobble of itself and never reverses (0 <= wobble < 1). a(t) is a clamped cubic spline through its
        samples every ``knot_spacing_s`` (default min(ramp_s / 8, 0.02 s)): that spline is the profile, exactly.
        """
        if shape not in ("linear", "exponential"):
            raise ValueError(f"speed profile: shape must be 'linear' or 'exponential', got {shape!r}")
        if not 0.0 <= wobble < 1.0:
            raise ValueError(f"speed profile: wobble must be in [0, 1) (a fraction of the rate), got {wobble}")
        if not (rpm_start > 0 and rpm_end > 0 and rpm_start != rpm_end):
            raise ValueError(f"speed profile: a sweep needs two different positive speeds, got {rpm_start} -> "
                             f"{rpm_end} RPM")
        if not (sweep_s > 0 and 0 < ramp_s <= sweep_s / 2 and dwell_start_s >= 0 and dwell_end_s >= 0):
            raise ValueError(f"speed profile: needs sweep_s > 0, 0 < ramp_s <= sweep_s / 2, dwells >= 0; got "
                             f"sweep_s {sweep_s}, ramp_s {ramp_s}, dwells {dwell_start_s}, {dwell_end_s}")
        spacing = knot_spacing_s or min(ramp_s / 8.0, 0.02)
        m = max(int(math.ceil(sweep_s / spacing)), 16)
        t = np.linspace(0.0, sweep_s, m + 1)
        onset = _smoothstep(t / ramp_s) * _smoothstep((sweep_s - t) / ramp_s)
        a = onset * (np.exp(-2.0 * t / sweep_s) if shape == "exponential" else 1.0)
        if wobble > 0:
            rng = np.random.default_rng() if rng is None else rng
            freq, phase, size = rng.uniform(0.1, 1.0, 3), rng.uniform(0, 2 * np.pi, 3), rng.uniform(0.5, 1.0, 3)
            g = (size[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase[:, None])).sum(0) / size.sum()
            a = a * (1.0 + wobble * g)
        spline = CubicSpline(t, a, bc_type="clamped")
        speed = spline.antiderivative()  # integral of a from 0, a PPoly of degree 4
        d_omega = float(rpm_to_rad_s(rpm_end - rpm_start))
        scale = d_omega / float(speed(sweep_s))
        fine = np.linspace(0.0, sweep_s, 20 * m + 1)
        if np.min(spline(fine)) < -1e-9 * np.max(np.abs(spline(fine))):
            raise ValueError("speed profile: the acceleration changes sign (the speed would reverse); lower the "
                             "wobble")
        coeffs = speed.c * scale
        coeffs[-1] += float(rpm_to_rad_s(rpm_start))
        breaks = speed.x + dwell_start_s
        k = coeffs.shape[0]
        if dwell_start_s > 0:
            first = np.zeros((k, 1))
            first[-1] = float(rpm_to_rad_s(rpm_start))
            coeffs, breaks = np.hstack([first, coeffs]), np.concatenate([[0.0], breaks])
        if dwell_end_s > 0:
            last = np.zeros((k, 1))
            last[-1] = float(rpm_to_rad_s(rpm_end))
            coeffs, breaks = np.hstack([coeffs, last]), np.concatenate([breaks, [breaks[-1] + dwell_end_s]])
        return cls(PPoly(coeffs, breaks), theta0)

    def summary(self) -> dict:
        """Start and end speeds [RPM], duration, sweep rate (mean over the changing part, smallest and largest
        |rpm'|) [RPM/s]: the answer key's profile summary."""
        t = np.linspace(self.steady_until, self.t1, 2001)
        rate = np.abs(self.omega_dot(t)) * 30.0 / math.pi
        changing = self._changing_span()
        return {"rpm_start_true": self.omega0 * 30 / math.pi, "rpm_end_true": self.omega1 * 30 / math.pi,
                "sweep_start_s": changing[0], "sweep_end_s": changing[1],
                "sweep_rate_mean_rpm_s": abs(self.omega1 - self.omega0) * 30 / math.pi / max(
                    changing[1] - changing[0], 1e-300),
                "sweep_rate_max_rpm_s": float(rate.max())}

    def _changing_span(self) -> tuple[float, float]:
        c = self._omega.c
        varying = np.flatnonzero(np.any(c[:-1] != 0.0, axis=0))
        if not varying.size:
            return self.t0, self.t0
        return float(self._omega.x[varying[0]]), float(self._omega.x[varying[-1] + 1])


def _smoothstep(s: Array) -> Array:
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


# --- the equations of motion at variable speed ------------------------------------------------------------


@dataclass
class SpeedSystem:
    """The equations of motion of ONE scenario as functions of the speed (module docstring).

    K(Omega) = sum_k Omega^k K[k], C(Omega) likewise; forcing {h: {k: F_hk}} the harmonics' polynomial
    coefficients (no Omega' term); inertia {h: A_h} the Omega^2 coefficient of the inertial effects'
    forcing (with the Omega' term); forces: the local nonlinear forces (speed-independent), rows: their
    scenario. ``polynomial`` False: the laws are not polynomials of degree <= POLY_DEGREE and
    ``evaluate(Omega)`` (K, C, {h: F_h non-inertial}) assembles the model at each speed instead.
    """

    M: Array
    K: dict[int, Array]
    C: dict[int, Array]
    forcing: dict[int, dict[int, Array]]
    inertia: dict[int, Array]
    forces: list[LocalForce] = field(default_factory=list)
    rows: Array = field(default_factory=lambda: np.arange(1))
    polynomial: bool = True
    evaluate: Callable[[float], tuple[Array, Array, dict[int, Array]]] | None = None
    problems: str = ""

    @property
    def n(self) -> int:
        return self.M.shape[0]

    def matrices(self, Omega: float) -> tuple[Array, Array, dict[int, Array]]:
        """K, C and the non-inertial forcing harmonics at the speed Omega [rad/s]."""
        if not self.polynomial:
            return self.evaluate(Omega)
        K = sum((Omega ** k * v for k, v in self.K.items()), np.zeros_like(self.M))
        C = sum((Omega ** k * v for k, v in self.C.items()), np.zeros_like(self.M))
        F = {h: sum(Omega ** k * v for k, v in terms.items()) for h, terms in self.forcing.items()}
        return K, C, F

    def system(self, rpm: float) -> System:
        """The steady System (eq. 29) at a constant speed: what ``Model.system`` gives (to round-off)."""
        Omega = float(rpm_to_rad_s(rpm))
        K, C, F = self.matrices(Omega)
        forcing = {h: np.asarray(f, complex)[None].copy() for h, f in F.items()}
        for h, A in self.inertia.items():
            forcing[h] = forcing.get(h, np.zeros((1, self.n), complex)) + A[None] * Omega ** 2
        return System(self.M[None].copy(), C[None], K[None], np.array([Omega]), forcing, self.forces,
                      np.asarray(self.rows), np.array([self.problems], dtype=object))

    @classmethod
    def from_model(cls, model: Model, values: Mapping[str, float | Array], rpm_max: float) -> "SpeedSystem":
        """The speed laws of ``model`` with ``values`` (one scenario), fitted over 0..``rpm_max`` (module
        docstring); effects with ``inertial`` True give ``inertia``, the rest ``forcing``."""
        scale = float(rpm_to_rad_s(rpm_max))
        if not scale > 0:
            raise ValueError(f"SpeedSystem: rpm_max must be positive, got {rpm_max}")
        fractions = np.concatenate([POLY_NODES, POLY_CHECKS])
        one = {k: np.asarray(v, dtype=float).reshape(-1)[:1] for k, v in values.items()}
        rest = model.at_rest(one, fractions.size)
        rpm = fractions * rpm_max
        system = model.system_at(rest, rpm)
        ctx = replace(rest, Omega=system.Omega)
        inertial_effects = [e for e in model.effects if getattr(e, "inertial", False)]
        n = system.n_dof
        inert: dict[int, Array] = {}
        for effect in inertial_effects:
            for h, f in effect.forcing(ctx).items():
                inert[h] = inert.get(h, 0) + np.broadcast_to(f, (fractions.size, n))
        other = {h: system.forcing[h] - inert.get(h, 0) for h in system.forcing}
        u = fractions[: POLY_NODES.size]
        V = np.vander(u, POLY_DEGREE + 1, increasing=True)  # (nodes, degree+1)
        V_check = np.vander(fractions[POLY_NODES.size:], POLY_DEGREE + 1, increasing=True)
        ok = True

        def fit(values: Array) -> dict[int, Array]:
            nonlocal ok
            flat = values.reshape(values.shape[0], -1)
            coef = np.linalg.solve(V, flat[: POLY_NODES.size])  # in u = Omega / scale
            largest = np.abs(flat).max()
            if largest == 0:
                return {}
            if np.abs(V_check @ coef - flat[POLY_NODES.size:]).max() > POLY_TOLERANCE * largest:
                ok = False
            out = {}
            for k in range(POLY_DEGREE + 1):
                if np.abs(coef[k]).max() > POLY_DROP * largest:
                    out[k] = (coef[k] / scale ** k).reshape(values.shape[1:])
            return out

        K, C = fit(system.K), fit(system.C)
        forcing = {h: fit(f) for h, f in other.items()}
        inertia_fit = {h: fit(f) for h, f in inert.items()}
        inertia = {}
        for h, terms in inertia_fit.items():
            if set(terms) - {2}:  # an inertial effect's force must be m r Omega^2: any other power is a plain force
                for k, v in terms.items():
                    if k != 2:
                        forcing.setdefault(h, {})[k] = forcing.get(h, {}).get(k, 0) + v
            if 2 in terms:
                inertia[h] = terms[2]
        M = system.M[0]
        problems = str(system.problems[0])
        out = cls(M, K, C, {h: t for h, t in forcing.items() if t}, inertia, system.forces, system.rows[:1], ok,
                  problems=problems)
        if not ok:
            rest1 = model.at_rest(one, 1)
            inertial_names = {e.name for e in inertial_effects}

            def evaluate(Omega: float) -> tuple[Array, Array, dict[int, Array]]:
                s = model.system_at(rest1, Omega * 30.0 / math.pi)
                c1 = replace(rest1, Omega=s.Omega)
                F = {h: f[0].copy() for h, f in s.forcing.items()}
                for effect in model.effects:
                    if effect.name in inertial_names:
                        for h, f in effect.forcing(c1).items():
                            F[h] = F[h] - np.broadcast_to(f, (1, n))[0]
                return s.K[0], s.C[0], F

            out.evaluate = evaluate
        return out


class SweepFirstOrder:
    """y' = f(t, y) of a ``SpeedSystem`` along a ``SpeedProfile``, y = [q, q'], with the exact Jacobian."""

    def __init__(self, system: SpeedSystem, profile: SpeedProfile, fast_forces: bool = True):
        self.system, self.profile = system, profile
        n = system.n
        self.n = n
        Minv = np.linalg.inv(system.M)
        self._Minv = Minv
        self.MK = {k: Minv @ v for k, v in system.K.items()}
        self.MC = {k: Minv @ v for k, v in system.C.items()}
        terms, columns = [], []
        for h, coeffs in sorted(system.forcing.items()):
            for k, F in sorted(coeffs.items()):
                terms.append((h, k, False))
                columns.append(Minv @ np.asarray(F, complex))
        for h, A in sorted(system.inertia.items()):
            terms.append((h, 2, True))
            columns.append(Minv @ np.asarray(A, complex))
        self._terms = terms
        self._h = np.array([t[0] for t in terms], float)
        self._k = np.array([t[1] for t in terms], float)
        self._inertial = np.array([t[2] for t in terms], bool)
        self.G = np.stack(columns, axis=1) if columns else np.zeros((n, 0), complex)
        forces = system.forces
        self.dofs = np.unique(np.concatenate([f.dofs for f in forces])) if forces else np.array([], int)
        self.B = Minv[:, self.dofs]
        self.local = [np.searchsorted(self.dofs, f.dofs) for f in forces]
        self.polynomials = ([PolynomialForce.identify(f, system.rows) for f in forces] if fast_forces
                            else [None] * len(forces))
        self.n_rhs = 0

    def _linear(self, Omega: float) -> tuple[Array, Array, dict | None]:
        """M^-1 K(Omega), M^-1 C(Omega) and, off the polynomial path, the forcing columns at Omega."""
        if self.system.polynomial:
            MK = sum((Omega ** k * v for k, v in self.MK.items()), np.zeros((self.n, self.n)))
            MC = sum((Omega ** k * v for k, v in self.MC.items()), np.zeros((self.n, self.n)))
            return MK, MC, None
        K, C, F = self.system.evaluate(Omega)
        G = {h: self._Minv @ np.asarray(f, complex) for h, f in F.items()}
        return self._Minv @ K, self._Minv @ C, G

    def excitation(self, t: float) -> Array:
        """M^-1 f(t) (module docstring)."""
        Omega, Omega_dot, theta = self.profile.at(t)
        G_other = None if self.system.polynomial else self._linear(Omega)[2]
        return self._excitation(Omega, Omega_dot, theta, G_other)

    def _excitation(self, Omega: float, Omega_dot: float, theta: float, G_other: dict | None) -> Array:
        if G_other is None:
            if not self._terms:
                return np.zeros(self.n)
            coef = [(Omega * Omega - 1j * Omega_dot / h if inertial else Omega ** k) * cmath.exp(1j * h * theta)
                    for h, k, inertial in self._terms]
            return (self.G @ np.array(coef)).real
        out = np.zeros(self.n)
        for (h, _, inertial), g in zip(self._terms, self.G.T):
            if inertial:
                out += ((Omega * Omega - 1j * Omega_dot / h) * cmath.exp(1j * h * theta) * g).real
        for h, g in G_other.items():
            out += (g * cmath.exp(1j * h * theta)).real
        return out

    def local_force(self, q: Array, jacobian: bool) -> tuple[Array, Array | None]:
        return local_forces(self.system, self.local, self.polynomials, len(self.dofs), q, jacobian)

    def rhs(self, t: float, y: Array) -> Array:
        self.n_rhs += 1
        n = self.n
        Omega, Omega_dot, theta = self.profile.at(t)
        q, v = y[:n], y[n:]
        if self.system.polynomial:
            acc = self._excitation(Omega, Omega_dot, theta, None)
            for k, MK in self.MK.items():
                acc -= (Omega ** k) * (MK @ q)
            for k, MC in self.MC.items():
                acc -= (Omega ** k) * (MC @ v)
        else:
            MK, MC, G_other = self._linear(Omega)
            acc = self._excitation(Omega, Omega_dot, theta, G_other) - MK @ q - MC @ v
        if len(self.dofs):
            F, _ = self.local_force(q, jacobian=False)
            acc += self.B @ F
        return np.concatenate([v, acc])

    def jacobian(self, t: float, y: Array) -> Array:
        n = self.n
        Omega, _, _ = self.profile.at(t)
        MK, MC, _ = self._linear(Omega)
        J = np.zeros((2 * n, 2 * n))
        J[:n, n:] = np.eye(n)
        J[n:, :n] = -MK
        J[n:, n:] = -MC
        if len(self.dofs):
            _, dF = self.local_force(y[:n], jacobian=True)
            J[n:, self.dofs] += self.B @ dF
        return J


@dataclass
class SweepResult:
    """Samples of a sweep: t (N,), displacements (N, d) at the requested DOFs [m, rad], theta (N,) [rad],
    Omega (N,) [rad/s]; state: [q, q'] at the last instant; steps, n_rhs: Radau's; start: how the start
    state was obtained; atol: the displacement tolerance used [m]."""

    t: Array
    displacements: Array
    theta: Array
    Omega: Array
    state: Array
    steps: int
    n_rhs: int
    start: str
    atol: float

    @property
    def rpm(self) -> Array:
        return self.Omega * 30.0 / math.pi


def start_state(system: SpeedSystem, rpm: float, dofs: Sequence[int], *, harmonics: int = RESOLVED_HARMONICS,
                fast_forces: bool = True, **settle_options) -> tuple[Array, float, str]:
    """The periodic steady state at the constant speed ``rpm`` by time integration from rest
    (``transient.settle``): the state [q, q'] at rotor angle 0, the orbit's amplitude at ``dofs`` and a
    description. NotSettledError when it does not settle."""
    first_order = FirstOrder.from_system(system.system(rpm), 0, fast_forces)
    period = settle(first_order, dofs, harmonics, **settle_options)
    return period.state, period.amplitude, (f"settled by time integration at {rpm:.3f} RPM after "
                                            f"{period.n_periods} periods")


def integrate_sweep(system: SpeedSystem, profile: SpeedProfile, t_eval: Array, dofs: Sequence[int], *,
                    start: object = None, harmonics: int = RESOLVED_HARMONICS, rtol: float = DEFAULT_RTOL,
                    atol_relative: float = DEFAULT_ATOL_RELATIVE, atol: float | None = None,
                    velocity_scale: float = DEFAULT_VELOCITY_SCALE, max_displacement: float = 1.0,
                    fast_forces: bool = True, settle_options: Mapping | None = None) -> SweepResult:
    """Integrate the equations of motion along ``profile`` (module docstring); samples at ``t_eval`` (sorted).

    start (the state at t_eval[0]):
    - None: the periodic steady state at the profile's speed at t_eval[0], settled by time integration
      (``start_state``); the integration then starts where theta = 0 (mod 2 pi) at most one revolution
      before t_eval[0], which must lie where the speed is still constant (``profile.steady_until``, e.g. a
      dwell, or the constant extension before the profile's first breakpoint);
    - an object with ``harmonics`` (S, H+1, n) (a harmonic-balance ``SteadyState`` at that speed, scenario 0):
      q = Re(sum_h Q_h exp(i h theta)), q' = Re(sum_h i h Omega Q_h exp(i h theta)) at t_eval[0];
    - a state vector [q, q'] (2n,) at t_eval[0].

    Tolerances: rtol; atol [m] on displacements (default ``atol_relative`` x the start orbit's largest
    displacement at ``dofs``, at least transient.ATOL_FLOOR), ``velocity_scale`` x that on velocities
    (``transient.state_tolerance``). Raises NotSettledError when Radau fails or a displacement exceeds
    ``max_displacement`` [m], ValueError on a start that does not fit.
    """
    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval.ndim != 1 or t_eval.size == 0 or np.any(np.diff(t_eval) < 0):
        raise ValueError("integrate_sweep: t_eval must be a non-empty sorted 1-D array")
    dofs = np.asarray(dofs, dtype=int).reshape(-1)
    n = system.n
    t_first = float(t_eval[0])
    Omega0, _, theta0 = profile.at(t_first)
    if start is None:
        t_a = t_first - (theta0 % (2 * math.pi)) / Omega0
        if t_first > max(profile.steady_until, profile.t0) + 1e-12:
            raise ValueError(f"integrate_sweep: the speed changes before t = {t_first:.6g} s (from "
                             f"{profile.steady_until:.6g} s): give the start state, or sample from the dwell")
        y0, amplitude, how = start_state(system, Omega0 * 30.0 / math.pi, dofs, harmonics=harmonics,
                                         fast_forces=fast_forces, **dict(settle_options or {}))
    elif hasattr(start, "harmonics"):
        Q = np.asarray(start.harmonics)[0]
        if Q.shape[-1] != n or not np.all(np.isfinite(Q)):
            raise ValueError("integrate_sweep: the start steady state has the wrong size or failed")
        h = np.arange(Q.shape[0])[:, None]
        rotation = np.exp(1j * h * theta0)
        y0 = np.concatenate([(Q * rotation).sum(0).real, (1j * h * Omega0 * Q * rotation).sum(0).real])
        t_a, amplitude, how = t_first, float(np.abs(Q[:, dofs]).sum(0).max()), "harmonic balance"
    else:
        y0 = np.asarray(start, dtype=float).reshape(-1)
        if y0.shape != (2 * n,):
            raise ValueError(f"integrate_sweep: the start state has {y0.size} entries, expected {2 * n}")
        t_a, amplitude, how = t_first, float(np.abs(y0[dofs]).max()), "given"
    if atol is None:
        atol = max(atol_relative * amplitude, ATOL_FLOOR) if amplitude > 0 else DEFAULT_ATOL_RELATIVE
    first_order = SweepFirstOrder(system, profile, fast_forces)
    tol = state_tolerance(n, atol, velocity_scale)
    out = np.empty((t_eval.size, dofs.size))
    t_end = float(t_eval[-1])
    j = 0
    if t_end <= t_a:
        out[:] = y0[dofs]
        return _result(t_eval, out, profile, y0, 0, 0, how, atol)
    solver = Radau(first_order.rhs, t_a, y0.copy(), t_end, rtol=rtol, atol=tol, jac=first_order.jacobian)
    while j < t_eval.size and t_eval[j] <= t_a:
        out[j] = y0[dofs]
        j += 1
    steps = 0
    while solver.status == "running":
        message = solver.step()
        steps += 1
        largest = np.abs(solver.y[:n]).max()
        if solver.status == "failed" or not largest <= max_displacement:
            reason = (f"Radau failed ({message})" if solver.status == "failed" else
                      f"a displacement reached {largest:.3g} m (> {max_displacement:g} m)")
            raise NotSettledError(f"sweep: {reason} at t = {solver.t:.6g} s "
                                  f"({profile.at(solver.t)[0] * 30 / math.pi:.1f} RPM)")
        k = j
        while k < t_eval.size and t_eval[k] <= solver.t:
            k += 1
        if k > j:
            out[j:k] = solver.dense_output()(t_eval[j:k])[dofs].T
            j = k
    return _result(t_eval, out, profile, solver.y.copy(), steps, first_order.n_rhs, how, atol)


def _result(t: Array, out: Array, profile: SpeedProfile, state: Array, steps: int, n_rhs: int, how: str,
            atol: float) -> SweepResult:
    return SweepResult(t, out, profile.theta(t), profile.omega(t), state, steps, n_rhs, how, float(atol))


# --- order vectors, per revolution -----------------------------------------------------------------------


def order_vectors(t: Array, theta: Array, x: Array, order: int = 1, revolutions: int = 1,
                  theta_start: float | None = None) -> tuple[Array, Array]:
    """Per window of ``revolutions`` whole revolutions (theta from 2 pi k to 2 pi (k + revolutions), windows
    not overlapping): the least-squares fit x = c + Re(X exp(i order theta)) of each column of x (N, d).
    Returns the windows' mean speed [RPM] (their angle over their time) and X (W, d) complex [x's unit].
    A check, not an order tracker (no uncertainty, no overlap)."""
    t, theta = np.asarray(t, float), np.asarray(theta, float)
    x = np.asarray(x, float).reshape(len(t), -1)
    first = math.ceil((theta[0] if theta_start is None else theta_start) / (2 * math.pi) - 1e-9)
    edges = 2 * math.pi * np.arange(first, theta[-1] / (2 * math.pi) + 1e-12, revolutions)
    index = np.searchsorted(theta, edges)
    rpm, vectors = [], []
    for a, b in zip(index[:-1], index[1:]):
        if b - a < 2 * order + 2:
            continue
        th = theta[a:b]
        design = np.column_stack([np.ones(b - a), np.cos(order * th), np.sin(order * th)])
        coef = np.linalg.lstsq(design, x[a:b], rcond=None)[0]
        vectors.append(coef[1] - 1j * coef[2])
        rpm.append((theta[b - 1] - theta[a]) / (t[b - 1] - t[a]) * 30.0 / math.pi)
    return np.array(rpm), np.array(vectors).reshape(len(rpm), x.shape[1])
