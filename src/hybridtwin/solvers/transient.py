"""Independent time integration of the equations of motion (paper eq. 29).

For ONE scenario of a ``System``::

    M q'' + C q' + K q = Re(sum_h F_h exp(i h Omega t)) + F_nl(q)      (eq. 29)

is written in first-order form y = [q, q'],

    y' = A y + [0; M^-1 (f(t) + B F_nl(q))],   A = [[0, I], [-M^-1 K, -M^-1 C]],

and integrated with ``scipy.integrate.solve_ivp``. This module is a reference
for the harmonic-balance solver and deliberately shares no code with it
(``hybridtwin.solvers.solver``): only the assembled matrices, the forcing harmonics and
the local forces' ``evaluate`` of the ``System`` are used. Time origin and
sign conventions are those of the ``System`` (t = 0 with the unbalance on +x).

Integrator and tolerances (measured on the Geometric model with paper-like
parameters, 450 and 900 RPM, rtol = 1e-10, on a loaded 2-CPU machine):

- The beam's highest natural frequency is about 1.1e5 rad/s, and the
  mass-proportional damping of eq. 31 gives every mode the same slow decay
  rate zeta_s omega_1 (about 3.3 1/s). DOP853 is stability-limited to steps
  of 2.5-5e-5 s whatever rtol: 1400-2700 steps (2-4 s of CPU) per forcing period.
- Radau (implicit, L-stable) with the exact Jacobian steps over those modes as
  far as its error control lets it. Started on the periodic orbit it takes
  30-140 steps per period (0.03-0.15 s): 13 to 130 times faster than DOP853.
  Started from rest, the forcing switched on at t = 0 sets the high modes
  ringing (for seconds: they decay at 3.3 1/s too), and the error control
  resolves that ringing as long as it exceeds atol: 330-870 steps per period
  over the first 10 periods (0.4-1 s), 2.5 to 12 times faster than DOP853.
- Hence the tolerances: ``atol`` (default 1e-8) on displacements [m, rad] and
  ``atol * velocity_scale`` (velocity_scale = 1e4 rad/s, i.e. 1.6 kHz, above
  the sensors' 1 kHz Nyquist frequency) on velocities, so that the error
  control ignores vibration above about 1e4 rad/s whose displacement is below
  atol. With atol = 1e-9 Radau needs about 1000 steps per period from rest;
  with atol = 1e-5 x the response amplitude it needs about 50 at 900 RPM and
  still reaches a node-1 error below 5e-5 of the amplitude. rtol matters little
  here (atol dominates for displacements below 1 m); 1e-8 is the default.
- Tolerances below the round-off of this stiff problem make Radau's Newton
  iteration fail step after step (rtol = 1e-10 with atol = 1e-11 on every
  component took minutes per period): keep atol >= 1e-10.

Periodic steady state period by period (``settle``, ``run_up_harmonics``; the
virtual rig's "time" integrator), measured on the rig's default truth and plan:

- Switching the forcing on (from rest) or the speed (in a run-up) abruptly sets
  the high modes ringing: 260-2000 Radau steps per period at atol = 1e-6 x the
  amplitude, 200 s for a run-up through one mass's 7 runs. Switched over one period with a
  C2 ramp (``_Transition``) they stay quasi-static: 55-65 steps per period,
  22 s for the same runs, and the same harmonics (to 1e-6).
- The bearing force's generic ``evaluate`` took 85 % of a right-hand side
  (~280 us of ~320 us); its identified monomials (``PolynomialForce``, on in
  ``run_up_harmonics``) make the right-hand side 3.5 times cheaper.
- Each speed settles in 16-46 periods (the transient decays at 3.3 1/s); the
  rig's 22 runs (run-up and run-down, 50 speeds settled) take 79 s of CPU,
  their harmonics within 2.1e-6 of harmonic balance (``settle``,
  DEFAULT_ATOL_RELATIVE).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import Radau, solve_ivp

from ..model.model import System

Array = np.ndarray

#: default integrator (see the module docstring for the measurements behind it)
DEFAULT_METHOD = "Radau"
#: default relative tolerance
DEFAULT_RTOL = 1e-8
#: the highest harmonic H of a steady state resolved in time (a settled period compared harmonic by harmonic, a
#: run-up's harmonics) and of the virtual rig's truth (config ``rig: NAME: harmonics``, which has no schema default:
#: hybridtwin.rig.rig.RigSpec): beyond the analysis's (the config's ``harmonics``, solver.DEFAULT_HARMONICS)
RESOLVED_HARMONICS = 7
#: default absolute tolerance on displacements [m, rad]
DEFAULT_ATOL = 1e-8
#: velocities get the absolute tolerance atol * velocity_scale [rad/s]
DEFAULT_VELOCITY_SCALE = 1e4


@dataclass
class FirstOrder:
    """The first-order form of eq. 29 for one scenario, with its exact Jacobian.

    A: (2n, 2n) linear part; G: (n, n_h) M^-1 F_h (complex) for the harmonics
    ``h``; B: (n, c) columns of M^-1 at the nonlinear DOFs ``dofs``.
    ``monitor``, if set, is called with t at every right-hand-side evaluation
    (e.g. to time how fast the integration advances). ``polynomials``, if set
    (``from_system(..., fast_forces=True)``), evaluates each local force from
    its identified monomials (``PolynomialForce``) instead of its ``evaluate``.
    """

    system: System
    A: Array
    G: Array
    h: Array
    B: Array
    dofs: Array
    local: list[Array]
    monitor: Callable[[float], None] | None = None
    polynomials: list | None = None

    @classmethod
    def from_system(cls, system: System, scenario: int = 0, fast_forces: bool = False) -> "FirstOrder":
        """Build for scenario ``scenario`` of ``system`` (eq. 29).

        fast_forces: evaluate polynomial local forces from their monomial coefficients, identified once from
        their ``evaluate`` (``PolynomialForce``; a force that is not a polynomial of its declared degree
        keeps ``evaluate``).
        """
        one = system.subset(np.array([scenario]))
        n = one.n_dof
        M, C, K = one.M[0], one.C[0], one.K[0]
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        A[n:, :n] = -np.linalg.solve(M, K)
        A[n:, n:] = -np.linalg.solve(M, C)
        harmonics = sorted(one.forcing)
        F = (np.stack([np.asarray(one.forcing[k][0], complex) for k in harmonics], axis=1)
             if harmonics else np.zeros((n, 0), complex))
        G = np.linalg.solve(M.astype(complex), F)
        dofs = np.unique(np.concatenate([f.dofs for f in one.forces])) if one.forces else np.array([], int)
        B = np.linalg.solve(M, np.eye(n)[:, dofs])
        local = [np.searchsorted(dofs, f.dofs) for f in one.forces]
        polynomials = [PolynomialForce.identify(f, one.rows) for f in one.forces] if fast_forces else None
        return cls(one, A, G, np.array(harmonics, dtype=float), B, dofs, local, polynomials=polynomials)

    @property
    def n(self) -> int:
        return self.system.n_dof

    @property
    def Omega(self) -> float:
        return float(self.system.Omega[0])

    @property
    def period(self) -> float:
        """Forcing period T = 2 pi / Omega [s]."""
        return 2.0 * math.pi / self.Omega

    def local_force(self, q: Array, jacobian: bool) -> tuple[Array, Array | None]:
        """F_nl (c,) at the nonlinear DOFs and dF_nl/dq (c, c), from the forces' ``evaluate``."""
        return local_forces(self.system, self.local, self.polynomials, len(self.dofs), q, jacobian)

    def excitation(self, t: float) -> Array:
        """M^-1 f(t), f(t) = Re(sum_h F_h exp(i h Omega t))."""
        return (self.G @ np.exp(1j * self.h * self.Omega * t)).real

    def rhs(self, t: float, y: Array) -> Array:
        """y' of the first-order form of eq. 29."""
        if self.monitor is not None:
            self.monitor(t)
        n = self.n
        dy = self.A @ y
        dy[n:] += self.excitation(t)
        if len(self.dofs):
            F, _ = self.local_force(y[:n], jacobian=False)
            dy[n:] += self.B @ F
        return dy

    def jacobian(self, t: float, y: Array) -> Array:
        """dy'/dy: A plus M^-1 dF_nl/dq in the (velocity, displacement) block."""
        J = self.A.copy()
        if len(self.dofs):
            n = self.n
            _, dF = self.local_force(y[:n], jacobian=True)
            J[n:, self.dofs] += self.B @ dF
        return J


def local_forces(system, local: Sequence[Array], polynomials: Sequence | None, c: int, q: Array,
                 jacobian: bool) -> tuple[Array, Array | None]:
    """F_nl (c,) at the c nonlinear DOFs and dF_nl/dq (c, c) of one scenario's ``system.forces`` at q: each force's
    identified monomials (``PolynomialForce``) where there are, else its ``evaluate``; ``local`` places each
    force's DOFs among the c. Shared by the steady (``FirstOrder``) and swept (``solvers.sweep``) integrations."""
    F = np.zeros(c)
    J = np.zeros((c, c)) if jacobian else None
    for i, (force, loc) in enumerate(zip(system.forces, local)):
        polynomial = polynomials[i] if polynomials else None
        if polynomial is not None:
            f, j = polynomial(q[force.dofs], jacobian)
        else:
            f, j = force.evaluate(q[force.dofs][None, :, None], system.rows)
            f, j = f[0, :, 0], j[0, :, :, 0]
        F[loc] += f
        if jacobian:
            J[loc[:, None], loc[None, :]] += j
    return F, J


class PolynomialForce:
    """A local force that is a polynomial of degree d in its c DOFs, F_k(q) = sum_m C_km prod_j q_j^E_mj.

    ``identify`` finds the coefficients C (c, m) of all monomials of degree <= d
    (of degree >= 2 if the force and its Jacobian vanish at q = 0)
    by least squares from one batched ``evaluate`` at 3 m random points
    (|q_j| <= ``scale``, in scaled variables q / scale), and keeps them only if
    they reproduce ``evaluate``'s force and Jacobian at other random points at
    that scale and at 1/100 of it to ``check`` of the largest value there. The
    same force, 8-17 times cheaper per call than the generic ``evaluate`` on the
    VARM's bearing (35 / 16 us with / without the Jacobian, against ~280 us);
    Radau calls it ~7 times per step.
    """

    def __init__(self, exponents: Array, coefficients: Array):
        self.E = exponents  # (m, c)
        self.C = coefficients  # (c, m)
        c = exponents.shape[1]
        self._columns = np.arange(c)
        # exponents of dF/dq_j: E - e_j (clipped at 0; the factor E_mj zeroes the clipped ones), (c, m, c)
        self._E_derivative = np.maximum(exponents[None, :, :] - np.eye(c, dtype=int)[:, None, :], 0)
        self._factor = exponents.T.astype(float)  # (c, m)
        self._degree = int(exponents.max())

    @classmethod
    def identify(cls, force, rows: Array, scale: float = 1e-2, check: float = 1e-9,
                 seed: int = 0) -> "PolynomialForce | None":
        """The polynomial form of ``force`` (a ``LocalForce``) for scenario ``rows``, or None."""
        if force.degree is None:
            return None
        c, d = len(force.dofs), int(force.degree)
        F0, J0 = force.evaluate(np.zeros((1, c, 1)), rows)
        lowest = 2 if not np.any(F0) and not np.any(J0) else 0  # purely nonlinear: no constant or linear term
        exponents = np.array([e for e in itertools.product(range(d + 1), repeat=c) if lowest <= sum(e) <= d],
                             dtype=int)
        if exponents.size == 0:
            return None
        rng = np.random.default_rng(seed)
        z = rng.uniform(-1.0, 1.0, (3 * len(exponents), c))
        F, _ = force.evaluate(scale * z.T[None], rows)
        design = np.prod(z[:, None, :] ** exponents[None, :, :], axis=-1)  # (P, m)
        a = np.linalg.lstsq(design, F[0].T, rcond=None)[0]  # (m, c) in scaled variables
        polynomial = cls(exponents, (a / scale ** exponents.sum(1)[:, None]).T)
        for size in (scale, scale / 100.0):
            q = size * rng.uniform(-1.0, 1.0, (c, 16))
            F_ref, J_ref = force.evaluate(q[None], rows)
            for k in range(q.shape[1]):
                f, j = polynomial(q[:, k], True)
                if (np.abs(f - F_ref[0, :, k]).max() > check * max(np.abs(F_ref[0]).max(), 1e-300)
                        or np.abs(j - J_ref[0, :, :, k]).max() > check * max(np.abs(J_ref[0]).max(), 1e-300)):
                    return None
        return polynomial

    def __call__(self, q: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """F (c,) and, if asked, dF/dq (c, c) at q (c,)."""
        powers = np.ones((len(q), self._degree + 1))
        for k in range(1, self._degree + 1):
            powers[:, k] = powers[:, k - 1] * q
        F = self.C @ np.prod(powers[self._columns, self.E], axis=1)
        if not jacobian:
            return F, None
        derivative = self._factor * np.prod(powers[self._columns, self._E_derivative], axis=-1)  # (c, m)
        return F, self.C @ derivative.T


def state_tolerance(n: int, atol: float | Array = DEFAULT_ATOL,
                    velocity_scale: float = DEFAULT_VELOCITY_SCALE) -> Array:
    """Absolute tolerance of the state [q, q'] (2n,): ``atol`` on q, ``atol * velocity_scale`` on q'.

    An ``atol`` of 2n entries is returned unchanged.
    """
    atol = np.asarray(atol, dtype=float)
    if atol.size == 2 * n:
        return atol.reshape(-1)
    if atol.size == n:
        return np.concatenate([atol.reshape(-1), velocity_scale * atol.reshape(-1)])
    if atol.size != 1:
        raise ValueError(f"atol has {atol.size} entries, expected 1, {n} or {2 * n}")
    return np.concatenate([np.full(n, float(atol)), np.full(n, velocity_scale * float(atol))])


def run(first_order: FirstOrder, q0: Array | None, v0: Array | None, t_span: tuple[float, float],
        t_eval: Array | None = None, *, method: str = DEFAULT_METHOD, rtol: float = DEFAULT_RTOL,
        atol: float | Array | None = None) -> tuple[Array, Array]:
    """solve_ivp on a prepared ``FirstOrder``; returns t and the state y (len(t), 2n) = [q, q']."""
    n = first_order.n
    y0 = np.concatenate([_vector(q0, n, "q0"), _vector(v0, n, "v0")])
    atol = state_tolerance(n) if atol is None else atol
    options = {"jac": first_order.jacobian} if method in ("Radau", "BDF", "LSODA") else {}
    sol = solve_ivp(first_order.rhs, t_span, y0, method=method, t_eval=t_eval, rtol=rtol, atol=atol, **options)
    if not sol.success:
        raise RuntimeError(f"time integration ({method}) over t = {t_span[0]:.4g}..{t_span[1]:.4g} s "
                           f"failed: {sol.message}")
    return sol.t, sol.y.T


def _vector(x: Array | None, n: int, name: str) -> Array:
    if x is None:
        return np.zeros(n)
    x = np.asarray(x, dtype=float).reshape(-1)
    if x.shape != (n,):
        raise ValueError(f"{name} has {x.size} entries, expected {n}")
    return x


def harmonic_initial_state(harmonics: Array, Omega: float) -> tuple[Array, Array]:
    """q(0) and q'(0) of q(t) = Re(sum_h Q_h exp(i h Omega t)); harmonics (H+1, n) complex."""
    Q = np.asarray(harmonics)
    h = np.arange(Q.shape[0])[:, None]
    return Q.sum(axis=0).real, (1j * h * Omega * Q).sum(axis=0).real


def fourier_series(harmonics: Array, Omega: float, t: Array) -> Array:
    """q(t) = Re(sum_h Q_h exp(i h Omega t)) at times t, (len(t), n); harmonics (H+1, n)."""
    Q = np.asarray(harmonics)
    h = np.arange(Q.shape[0])
    return (np.exp(1j * Omega * np.outer(np.asarray(t, dtype=float), h)) @ Q).real


def decay_time(system: System, scenario: int = 0) -> float:
    """1 / (slowest decay rate) of eq. 29 linearised at q = 0 [s] (about 0.3 s for the VARM)."""
    return _decay_time(FirstOrder.from_system(system, scenario))


@dataclass
class Periodic:
    """The last period of a long integration: times t (N,) [s], displacements q (N, n)."""

    t: Array
    q: Array
    n_periods: int
    Omega: float

    def at(self, dofs: Sequence[int]) -> Array:
        """q at the given DOFs, (N, len(dofs))."""
        return self.q[:, list(dofs)]


def periodic_response(
    system: System,
    start: object | tuple[Array, Array] | None = None,
    n_periods: int | None = None,
    *,
    scenario: int = 0,
    n_decay: float = 10.0,
    samples_per_period: int = 64,
    method: str = DEFAULT_METHOD,
    rtol: float = DEFAULT_RTOL,
    atol: float | Array = DEFAULT_ATOL,
    velocity_scale: float = DEFAULT_VELOCITY_SCALE,
) -> Periodic:
    """Periodic steady state of eq. 29 by brute-force time integration.

    start: a ``SteadyState`` (its scenario ``scenario`` gives q(0), q'(0) from
    the Fourier series at t = 0, e.g. the harmonic-balance solution to check),
    a (q0, v0) pair, or None (rest). Integrates ``n_periods`` forcing periods
    T = 2 pi / Omega (default: enough for ``n_decay`` decay times of eq. 29
    linearised at rest, see ``decay_time``) and returns the last period sampled
    at ``samples_per_period`` points, t in [(n_periods - 1) T, n_periods T)
    (absolute time, the origin of eq. 29's forcing).
    """
    first_order = FirstOrder.from_system(system, scenario)
    T = first_order.period
    q0, v0 = _start_state(start, scenario, first_order.Omega)
    if n_periods is None:
        n_periods = max(1, math.ceil(n_decay * decay_time(system, scenario) / T))
    t_eval = (n_periods - 1 + np.arange(samples_per_period) / samples_per_period) * T
    t, y = run(first_order, q0, v0, (0.0, n_periods * T), t_eval, method=method, rtol=rtol,
               atol=state_tolerance(first_order.n, atol, velocity_scale))
    return Periodic(t, y[:, : first_order.n], n_periods, first_order.Omega)


def _start_state(start: object, scenario: int, Omega: float) -> tuple[Array | None, Array | None]:
    if start is None:
        return None, None
    if hasattr(start, "harmonics"):  # a SteadyState, duck-typed to keep this module free of the solver
        Q = np.asarray(start.harmonics)[scenario]
        if not np.all(np.isfinite(Q)):
            raise ValueError(f"no steady state for scenario {scenario} (the solver failed there)")
        return harmonic_initial_state(Q, Omega)
    q0, v0 = start
    return q0, v0


def relative_error(reference: Array, other: Array) -> float:
    """max |other - reference| / max |reference| over all samples and columns."""
    reference, other = np.asarray(reference), np.asarray(other)
    return float(np.max(np.abs(other - reference)) / np.max(np.abs(reference)))


# --- periodic steady state, period by period ---------------------------------------------------------------

#: settled when the watched DOFs' harmonics of two successive periods (twice in a row) differ by less than
#: this fraction of their largest
DEFAULT_SETTLE_TOLERANCE = 1e-6
#: absolute tolerance on displacements as a fraction of the response amplitude at the watched DOFs. Measured at
#: the default rig truth's 22 runs and 3 run-down starts (0.27-9.9 mm at the sensor, 350-1200 RPM), 16 periods
#: from the harmonic-balance orbit: 3e-6 -> 40-61 Radau steps per period, harmonics' period-to-period change
#: (integration noise) <= 1.8e-8, error vs harmonic balance <= 1.2e-7; 1e-5 -> 30-49 steps, noise <= 1.7e-7
#: (too close to DEFAULT_SETTLE_TOLERANCE), error <= 4e-7
DEFAULT_ATOL_RELATIVE = 3e-6
#: smallest absolute tolerance used on displacements [m, rad] (see the module docstring: keep atol >= 1e-10)
ATOL_FLOOR = 1e-10
#: the forcing (from rest) or the previous speed's equations (at a speed change) fade over this many periods
DEFAULT_RAMP_PERIODS = 1
#: ``settle`` gives up after this many decay times of eq. 29 linearised at rest (``decay_time``)
DEFAULT_MAX_DECAY_TIMES = 40.0


class NotSettledError(RuntimeError):
    """No periodic steady state reached: the period budget ran out, the response diverged or Radau failed.

    ``settled`` holds the speeds a run-up had settled before (``run_up_harmonics``); ``budget`` is True when the
    period budget ran out with the response bounded (the harmonics still changing above the tolerance), False when
    it diverged or Radau failed.
    """

    def __init__(self, message: str, settled: list | None = None, budget: bool = False):
        super().__init__(message)
        self.settled = list(settled or [])
        self.budget = bool(budget)


@dataclass
class SettledPeriod:
    """The periodic steady state of eq. 29 at one speed, reached by time integration (``settle``).

    harmonics: (H+1, d) complex X_h at the watched DOFs with x(t) = Re(sum_h X_h exp(i h Omega t))
    [m, rad], the harmonic-balance solver's convention (t = 0 with the unbalance on +x);
    samples: (N, d) the last period at t_j = j T / N from its start (rotor angle 2 pi j / N);
    state: (2n,) [q, q'] at the end of the last period (rotor angle 0), where a next speed starts;
    n_periods: periods integrated at this speed (ramp included); change: the last relative
    period-to-period change of the harmonics (``settle``); steps, n_rhs: Radau steps and right-hand-side
    evaluations at this speed.
    """

    harmonics: Array
    samples: Array
    state: Array
    Omega: float
    n_periods: int
    change: float
    steps: int
    n_rhs: int

    @property
    def amplitude(self) -> float:
        """Largest |x(t)| over the last period at the watched DOFs [m, rad]."""
        return float(np.abs(self.samples).max())

    @property
    def rpm(self) -> float:
        return self.Omega * 30.0 / math.pi


class _Transition:
    """Eq. 29 of ``new`` switched on smoothly over ``duration`` [s] from t = 0.

    y' = w(t) rhs_new(t, y) + (1 - w(t)) rhs_old(t, y) with the C2 ramp
    w = 10 s^3 - 15 s^4 + 6 s^5, s = t / duration; ``old`` None stands for
    ``new`` without its forcing (a start from rest). Both speeds' forcing
    starts at rotor angle 0 at t = 0, so the old orbit continues seamlessly.
    A step in the forcing would set the beam's high modes ringing (they decay
    at only zeta_s omega_1, see the module docstring) and Radau would resolve
    that ringing for seconds; the ramp leaves them quasi-static.
    """

    def __init__(self, new: FirstOrder, old: FirstOrder | None, duration: float):
        if old is not None and old.n != new.n:
            raise ValueError(f"the previous system has {old.n} DOFs, this one {new.n}")
        self.new, self.old, self.duration = new, old, duration

    def weight(self, t: float) -> float:
        s = min(max(t / self.duration, 0.0), 1.0)
        return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)

    def rhs(self, t: float, y: Array) -> Array:
        w = self.weight(t)
        dy = self.new.rhs(t, y)
        if w == 1.0:
            return dy
        if self.old is None:
            dy[self.new.n:] -= (1.0 - w) * self.new.excitation(t)
            return dy
        return w * dy + (1.0 - w) * self.old.rhs(t, y)

    def jacobian(self, t: float, y: Array) -> Array:
        J = self.new.jacobian(t, y)
        w = self.weight(t)
        if self.old is None or w == 1.0:
            return J
        return w * J + (1.0 - w) * self.old.jacobian(t, y)


def settle(
    first_order: FirstOrder,
    dofs: Sequence[int],
    harmonics: int = RESOLVED_HARMONICS,
    start: tuple[Array, Array] | Array | None = None,
    previous: FirstOrder | None = None,
    *,
    tolerance: float = DEFAULT_SETTLE_TOLERANCE,
    atol_relative: float = DEFAULT_ATOL_RELATIVE,
    scale: float | None = None,
    ramp_periods: int = DEFAULT_RAMP_PERIODS,
    max_periods: int | None = None,
    samples_per_period: int | None = None,
    rtol: float = DEFAULT_RTOL,
    velocity_scale: float = DEFAULT_VELOCITY_SCALE,
    max_displacement: float = 1.0,
) -> SettledPeriod:
    """Integrate eq. 29 period after period until its periodic steady state; harmonics at ``dofs``.

    start: the state at t = 0 (rotor angle 0), a (q0, v0) pair or the state
    [q, q'] (2n,), None for rest; previous: the system that state belongs to
    (the previous speed of a run-up) or None. Over the first ``ramp_periods``
    periods T = 2 pi / Omega the equations switch smoothly from ``previous``
    (or from no forcing) to ``first_order`` (``_Transition``). Each period is
    one Radau integration over [k T, (k + 1) T] (exact Jacobian, the previous
    period's largest step as first step), sampled at ``samples_per_period``
    instants t_j = k T + j T / N (default max(64, 4 (H + 1))) at ``dofs``.

    Each period's harmonics are its DFT,
    X_0 = mean, X_h = (2 / N) sum_j x_j exp(-i h 2 pi j / N), h = 1..H
    (x(t) = Re(sum_h X_h exp(i h Omega t)), the rotor angle is 0 at k T).
    Settled: after the ramp, the harmonics of two successive periods differ by
    less than ``tolerance`` times their largest, max |X^k - X^(k-1)| <
    tolerance max |X^k| over h and ``dofs``, twice in a row. A transient
    decaying by a factor rho per period then leaves at most change / (1 - rho);
    rho = exp(-T / tau) with tau = ``decay_time`` (0.3 s on the VARM) gives
    1 / (1 - rho) = 2.8 at 450 RPM and 5.5 at 1000 RPM (tau of eq. 29
    linearised at rest; near a fold an orbit's transient decays more slowly,
    rho is closer to 1 and the same change leaves more). The harmonics, not the
    samples, are compared: the samples between steps come from Radau's dense
    output, whose error changes from period to period with the step pattern
    (25.9 g at 850 RPM, atol_relative 1e-5: the samples of a settled orbit
    alternate by 2.1e-6 of the amplitude for ever, its harmonics by 1.7e-7).

    Tolerances: rtol, and atol = ``atol_relative`` x the amplitude at ``dofs``
    of the period before (``scale`` or DEFAULT_ATOL for the first, at least
    ATOL_FLOOR) on displacements, ``velocity_scale`` times that on velocities.
    Measured on the default rig truth (its 22 runs, started on the
    harmonic-balance orbit): see ``DEFAULT_ATOL_RELATIVE``.

    Raises NotSettledError when ``max_periods`` (default: ``ramp_periods`` +
    DEFAULT_MAX_DECAY_TIMES decay times) pass without settling, when the
    response exceeds ``max_displacement`` [m] or when Radau fails.
    """
    n, T, H = first_order.n, first_order.period, int(harmonics)
    dofs = np.asarray(dofs, dtype=int).reshape(-1)
    N = int(samples_per_period or max(64, 4 * (H + 1)))
    if N < 2 * H + 1:
        raise ValueError(f"samples_per_period = {N} is too few for H = {H} (need >= {2 * H + 1})")
    y = _start_vector(start, n)
    rpm = first_order.Omega * 30.0 / math.pi
    if max_periods is None:
        try:
            max_periods = ramp_periods + math.ceil(DEFAULT_MAX_DECAY_TIMES * _decay_time(first_order) / T)
        except ValueError as err:
            raise NotSettledError(f"{rpm:.2f} RPM: {err} (no period budget; give max_periods)") from None
    transition = _Transition(first_order, previous, ramp_periods * T) if ramp_periods > 0 else None
    previous_X, change, below, first_step, steps, n_rhs = None, np.inf, 0, None, 0, 0
    for k in range(max_periods):
        ramping = k < ramp_periods
        fun, jac = (transition.rhs, transition.jacobian) if ramping else (first_order.rhs, first_order.jacobian)
        atol = DEFAULT_ATOL if scale is None else max(atol_relative * scale, ATOL_FLOOR)
        try:
            samples, y_end, first_step, period_steps, period_rhs = _one_period(
                fun, jac, y, k * T, T, dofs, N, rtol, state_tolerance(n, atol, velocity_scale), first_step,
                max_displacement)
        except NotSettledError as err:
            raise NotSettledError(f"{rpm:.2f} RPM, period {k + 1}: {err}") from None
        steps, n_rhs = steps + period_steps, n_rhs + period_rhs
        amplitude = float(np.abs(samples).max())
        X = _dft(samples, H)
        if not ramping and previous_X is not None:
            largest = np.abs(X).max()
            change = float(np.abs(X - previous_X).max() / largest) if largest > 0 else 0.0
            below = below + 1 if change < tolerance else 0
            if below >= 2:
                return SettledPeriod(X, samples, y_end, first_order.Omega, k + 1, change, steps, n_rhs)
        previous_X = None if ramping else X
        y, scale = y_end, (amplitude if amplitude > 0 else scale)
    raise NotSettledError(f"{rpm:.2f} RPM: no periodic steady state after {max_periods} periods "
                          f"({max_periods * T:.3g} s): the last period-to-period change of the harmonics is "
                          f"{change:.2e} of the largest, tolerance {tolerance:.1e}", budget=True)


def run_up_harmonics(systems: Sequence[System], dofs: Sequence[int], harmonics: int = RESOLVED_HARMONICS, *,
                     scenario: int = 0,
                     fast_forces: bool = True, **options) -> list[SettledPeriod]:
    """A quasi-static run-up (or run-down) in time through ``systems``, one speed each, in the given order.

    The first speed starts from rest (forcing ramped on over the first
    periods); each next speed starts from the previous one's settled state at
    rotor angle 0 (the end of a whole period, so the forcing's phase is
    continuous) with the previous equations faded out smoothly (``settle``,
    whose keyword ``options`` are passed on). Which periodic steady state is
    reached thus depends on the history, as on a rig: give the systems by
    increasing speed for a run-up, by decreasing speed for a run-down.
    ``fast_forces``: polynomial local forces from their identified monomials
    (``PolynomialForce``; 3.5 times faster right-hand sides on the VARM).
    Returns one ``SettledPeriod`` per system; raises NotSettledError (with the
    speeds settled so far in ``settled``) at the first speed that does not settle.
    """
    results: list[SettledPeriod] = []
    previous, state, scale = None, None, None
    for system in systems:
        first_order = FirstOrder.from_system(system, scenario, fast_forces)
        try:
            result = settle(first_order, dofs, harmonics, state, previous, scale=scale, **options)
        except (NotSettledError, RuntimeError) as err:
            raise NotSettledError(str(err), results) from None
        results.append(result)
        previous, state, scale = first_order, result.state, result.amplitude
    return results


def _one_period(fun: Callable, jac: Callable, y0: Array, t0: float, T: float, dofs: Array, N: int, rtol: float,
                atol: Array, first_step: float | None,
                max_displacement: float = np.inf) -> tuple[Array, Array, float, int, int]:
    """One Radau integration over [t0, t0 + T]: samples (N, d) at t0 + j T / N, the end state, the largest
    step (the next period's first step), the steps and the right-hand-side evaluations. NotSettledError
    when Radau fails or a displacement exceeds ``max_displacement``."""
    n = y0.size // 2
    solver = Radau(fun, t0, y0, t0 + T, rtol=rtol, atol=atol, jac=jac, first_step=first_step)
    times = t0 + T * np.arange(N) / N
    samples = np.empty((N, dofs.size))
    samples[0] = y0[dofs]
    j, largest, steps = 1, 0.0, 0
    while solver.status == "running":
        message = solver.step()
        steps += 1
        largest_q = np.abs(solver.y[:n]).max()
        if solver.status == "failed" or not largest_q <= max_displacement:
            reason = (f"Radau failed ({message}) with displacements up to {largest_q:.3g} m"
                      if solver.status == "failed" else
                      f"a displacement reached {largest_q:.3g} m (> {max_displacement:g} m)")
            raise NotSettledError(f"{reason} at t = {solver.t:.6g} s: the response diverges")
        largest = max(largest, solver.t - solver.t_old)
        if j < N and times[j] <= solver.t:
            dense = solver.dense_output()
            while j < N and times[j] <= solver.t:
                samples[j] = dense(times[j])[dofs]
                j += 1
    return samples, solver.y.copy(), min(largest, T), steps, solver.nfev


def _dft(samples: Array, H: int) -> Array:
    """X_h (H+1, d) of x(t_j) = Re(sum_h X_h exp(i h 2 pi j / N)) from one period's N samples."""
    X = np.fft.rfft(samples, axis=0)[: H + 1] / samples.shape[0]
    X[1:] *= 2.0
    return X


def _start_vector(start: tuple[Array, Array] | Array | None, n: int) -> Array:
    if start is None:
        return np.zeros(2 * n)
    if isinstance(start, tuple):
        return np.concatenate([_vector(start[0], n, "q0"), _vector(start[1], n, "v0")])
    y = np.asarray(start, dtype=float).reshape(-1)
    if y.shape != (2 * n,):
        raise ValueError(f"start state has {y.size} entries, expected {2 * n}")
    return y.copy()


def _decay_time(first_order: FirstOrder) -> float:
    rates = -np.linalg.eigvals(first_order.jacobian(0.0, np.zeros(2 * first_order.n))).real
    slowest = rates.min()
    if slowest <= 0:
        raise ValueError(f"eq. 29 linearised at rest is not asymptotically stable (decay rate {slowest:.3g} 1/s)")
    return 1.0 / slowest
