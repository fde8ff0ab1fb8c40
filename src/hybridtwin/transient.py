"""Independent time integration of the equations of motion (paper eq. 29).

For ONE scenario of a ``System``::

    M q'' + C q' + K q = Re(sum_h F_h exp(i h Omega t)) + F_nl(q)      (eq. 29)

is written in first-order form y = [q, q'],

    y' = A y + [0; M^-1 (f(t) + B F_nl(q))],   A = [[0, I], [-M^-1 K, -M^-1 C]],

and integrated with ``scipy.integrate.solve_ivp``. This module is a reference
for the harmonic-balance solver and deliberately shares no code with it
(``hybridtwin.solver``): only the assembled matrices, the forcing harmonics and
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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from .model import System

Array = np.ndarray

#: default integrator (see the module docstring for the measurements behind it)
DEFAULT_METHOD = "Radau"
#: default relative tolerance
DEFAULT_RTOL = 1e-8
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
    (e.g. to time how fast the integration advances).
    """

    system: System
    A: Array
    G: Array
    h: Array
    B: Array
    dofs: Array
    local: list[Array]
    monitor: Callable[[float], None] | None = None

    @classmethod
    def from_system(cls, system: System, scenario: int = 0) -> "FirstOrder":
        """Build for scenario ``scenario`` of ``system`` (eq. 29)."""
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
        return cls(one, A, G, np.array(harmonics, dtype=float), B, dofs, local)

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
        c = len(self.dofs)
        F = np.zeros(c)
        J = np.zeros((c, c)) if jacobian else None
        for force, loc in zip(self.system.forces, self.local):
            f, j = force.evaluate(q[force.dofs][None, :, None], self.system.rows)
            F[loc] += f[0, :, 0]
            if jacobian:
                J[loc[:, None], loc[None, :]] += j[0, :, :, 0]
        return F, J

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


def integrate(
    system: System,
    q0: Array | None = None,
    v0: Array | None = None,
    t_end: float = 1.0,
    t_eval: Array | None = None,
    *,
    scenario: int = 0,
    t_start: float = 0.0,
    method: str = DEFAULT_METHOD,
    rtol: float = DEFAULT_RTOL,
    atol: float | Array = DEFAULT_ATOL,
    velocity_scale: float = DEFAULT_VELOCITY_SCALE,
) -> tuple[Array, Array]:
    """Integrate eq. 29 for one scenario from q(t_start) = q0, q'(t_start) = v0 (default: rest).

    Returns the sample times t and the displacements q (len(t), n) at ``t_eval``
    (default: the integrator's own steps). Tolerances: see ``state_tolerance``
    and the module docstring. Raises RuntimeError when the integrator fails
    (e.g. the response grows without bound).
    """
    first_order = FirstOrder.from_system(system, scenario)
    t, y = run(first_order, q0, v0, (t_start, t_end), t_eval, method=method, rtol=rtol,
               atol=state_tolerance(first_order.n, atol, velocity_scale))
    return t, y[:, : first_order.n]


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
    first_order = FirstOrder.from_system(system, scenario)
    rates = -np.linalg.eigvals(first_order.jacobian(0.0, np.zeros(2 * first_order.n))).real
    slowest = rates.min()
    if slowest <= 0:
        raise ValueError(f"eq. 29 linearised at rest is not asymptotically stable (decay rate {slowest:.3g} 1/s)")
    return 1.0 / slowest


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
