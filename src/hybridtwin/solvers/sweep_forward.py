"""The run-up forward model: the steady response corrected for the sweep rate, to first order (issue 51, item 1).

A run-up's band is compared with the model at the band's speed. The steady state (harmonic balance) is what the
rotor reaches at a constant speed; swept, it lags behind and, near a resonance, flattens. The equations of the
integrator (``hybridtwin.solvers.sweep``)::

    M q'' + C(Omega) q' + K(Omega) q = Re(sum_h F_h(Omega) e^{i h theta}) + Re(sum_h A_h (Omega^2 - i Omega'/h)
                                       e^{i h theta}) + F_nl(q),   theta' = Omega,

(A_h the Omega^2 coefficient of the inertial effects' forcing: unbalance, bow) with the response sought as
q(t) = Re(sum_h Q_h(t) e^{i h theta(t)}), slowly varying amplitudes Q_h. Then q' = Re sum (Q_h' + i h Omega Q_h)
e^{i h theta} and q'' = Re sum (Q_h'' + 2 i h Omega Q_h' + i h Omega' Q_h - h^2 Omega^2 Q_h) e^{i h theta}, and
the harmonic balance of the slow amplitudes reads, per harmonic h,

    D_h(Omega) Q_h - B G_h(B^T Q) + M (Q_h'' + 2 i h Omega Q_h' + i h Omega' Q_h) + C Q_h'
        = F_h(Omega) + A_h (Omega^2 - i Omega' / h),     D_h = K + i h Omega C - (h Omega)^2 M.

Q = Q0 + Q1 + ..., ordered by the slow rate: Q0(Omega) is the steady state at the instantaneous speed, and with
Q0' = Omega' dQ0/dOmega the first order is the harmonic balance linearised about Q0 (the Newton Jacobian)::

    D_h Q1_h - B (dG/dx x1)_h = -Omega' [ (2 i h Omega M + C) dQ0_h/dOmega + i h M Q0_h ] - i (Omega' / h) A_h

(h = 0: -Omega' C dQ0_0/dOmega). dQ0/dOmega is the steady state's sensitivity to the speed, by the implicit
function theorem as the parameters' (``solver.sensitivity``): D_h dQ0_h - B (dG/dx dx)_h = -(dD_h/dOmega Q0_h -
dF_h/dOmega), dD_h/dOmega = dK/dOmega + i h C + i h Omega dC/dOmega - 2 h^2 Omega M - (h Omega)^2 dM/dOmega, the
assembly's own Omega-derivatives by central differences (SPEED_STEP; exact to round-off for laws of degree <= 2 in
Omega, as every built-in effect's). Both are the solver's linearised solve (``solver.linearised_response``): no
new steady state, a few linear solves per band. For one mode of a Jeffcott rotor this is the closed form of
``hybridtwin.solvers.sweep_rate`` (``adiabatic_correction``), which the data side uses to say where the first
order itself is no longer enough (its second order, ``sweep_rate.second_order_correction``).

What it does not hold, as the integrator: the spin-acceleration term Omega' G q of a gyroscopic disk. Second-order
terms (Omega'^2, Omega'') are left out: measured against time integration in tests/test_sweep_forward.py.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from ..model.model import rpm_to_rad_s
from .solver import Condensed, linearised_response

Array = np.ndarray

#: the relative step in Omega of the assembly's central differences (module docstring)
SPEED_STEP = 1e-3


@dataclass(frozen=True)
class SweptResponse:
    """The swept response of S scenarios, all (S, H+1, n) complex [m]: the steady state Q0 (``quasi_steady``), its
    speed derivative dQ0/dOmega [m s/rad] and the first-order correction Q1 (``correction``) for the sweep rate."""

    quasi_steady: Array
    speed_derivative: Array
    correction: Array

    @property
    def harmonics(self) -> Array:
        """Q0 + Q1: the order vectors a record swept at the given rate shows (to first order in the rate)."""
        return self.quasi_steady + self.correction


def inertial_forcing(model, rest, system) -> dict[int, Array]:
    """{h: A_h (S, n)} the Omega^2 coefficients of the inertial effects' forcing (``Effect.inertial``: unbalance,
    bow) at the speeds of ``system`` (> 0), their forcing divided by Omega^2 (the integrator's law,
    ``sweep.SpeedSystem``)."""
    ctx = replace(rest, Omega=system.Omega)
    n = system.n_dof
    out: dict[int, Array] = {}
    for effect in model.effects:
        if getattr(effect, "inertial", False):
            for h, f in effect.forcing(ctx).items():
                term = np.broadcast_to(f, (system.n_scenarios, n)) / system.Omega[:, None] ** 2
                out[h] = out.get(h, 0) + term
    return out


def swept_response(model, values: Mapping[str, Array | float], rpm: Array, rate_rpm_s: Array, state: Array,
                   harmonics: int, n_time: int | None = None) -> SweptResponse:
    """The first-order swept response (module docstring) of ``model`` with parameter ``values`` (complete, each
    (S,) or scalar) at speeds ``rpm`` (S,) > 0 swept at ``rate_rpm_s`` (S,) [RPM/s, signed: negative on a
    coast-down], about the converged condensed steady states ``state`` (S, c, 2H+1) (``SteadyState.state`` of the
    same scenarios; ``n_time`` its AFT samples)."""
    rpm = np.asarray(rpm, float).reshape(-1)
    S, H = rpm.size, int(harmonics)
    rate = np.broadcast_to(np.asarray(rate_rpm_s, float), (S,))
    if not np.all(rpm > 0):
        raise ValueError("swept_response: the speeds must be positive")
    values = {k: np.broadcast_to(np.asarray(v, float), (S,)) for k, v in values.items()}
    rest = model.at_rest(values, S)
    system = model.system_at(rest, rpm)
    step = SPEED_STEP * rpm
    up, down = model.system_at(rest, rpm + step), model.system_at(rest, rpm - step)
    width = rpm_to_rad_s(2.0 * step)

    def d_dOmega(a: Array, b: Array) -> Array:
        return (a - b) / width.reshape((S,) + (1,) * (np.ndim(a) - 1))

    dK, dC, dM = d_dOmega(up.K, down.K), d_dOmega(up.C, down.C), d_dOmega(up.M, down.M)
    prob = Condensed(system, H, n_time)
    state = np.asarray(state, float)
    Q0 = prob.full_harmonics(state, np.arange(S))  # (S, H+1, n)
    Omega, M, C = system.Omega, system.M, system.C
    n = system.n_dof
    rhs = np.zeros((S, 1, H + 1, n), complex)
    for h in range(H + 1):
        w = (h * Omega)[:, None, None]
        dD = dK + 1j * h * C + 1j * w * dC - 2.0 * h * w * M - w * w * dM
        rhs[:, 0, h] = -(dD @ Q0[:, h, :, None])[..., 0]
        if h in system.forcing:
            rhs[:, 0, h] += d_dOmega(up.forcing[h], down.forcing[h])
    dQ0 = linearised_response(prob, state, rhs)[0][:, 0]
    Omega_dot = rpm_to_rad_s(rate)[:, None]
    inertia = inertial_forcing(model, rest, system)
    rhs = np.zeros((S, 1, H + 1, n), complex)
    for h in range(H + 1):
        lag = (2j * h * Omega[:, None, None] * M + C) @ dQ0[:, h, :, None] + 1j * h * (M @ Q0[:, h, :, None])
        rhs[:, 0, h] = -Omega_dot * lag[..., 0]
        if h > 0 and h in inertia:
            rhs[:, 0, h] -= 1j * Omega_dot / h * inertia[h]
    Q1 = linearised_response(prob, state, rhs)[0][:, 0]
    return SweptResponse(Q0, dQ0, Q1)
