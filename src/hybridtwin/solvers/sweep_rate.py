"""How fast is too fast: when a run-up or coast-down is no longer quasi-steady (issue 38, item 5).

A swept rotor lags the steady response near a resonance and flattens it. For one mode the rotating-frame
amplitude X of the modal coordinate z = X exp(i theta) obeys, for the model at variable speed (hybridtwin.solvers.sweep:
K - Omega^2 M, the unbalance's inertia a (Omega^2 - i Omega'))::

    X'' + (2 i Omega + c) X' + (i Omega' + D(Omega)) X = Omega^2 - i Omega',   D = omega_n^2 - (1 + s) Omega^2 + i c Omega

with c = 2 zeta omega_n (zeta the damping ratio at rest), s = 1 with the centrifugal softening (the resonance where
Omega = omega_n / sqrt(2)), s = 0 without. Its quasi-steady solution is X0 = Omega^2 / D, and the first
correction in the slow rate (the adiabatic expansion; tests/test_sweep.py checks it against time integration)

    X1 = (-i Omega' - (2 i Omega + c) dX0/dOmega Omega' - i Omega' X0) / D

is the expected difference between the transient and the quasi-steady order vector. ``sweep_rate_check``
gives, per speed band, max |X1| / max |X0| over the record (the vector error relative to the peak) and
compares it with the noise-to-amplitude ratio of the measured order vector: "ok" where the quasi-steady model is
within the noise, "too fast" where it is not (then model the transient, or keep the band out). Near the
resonance |X1| / |X0| ~ Omega' / (zeta^2 Omega_c^2) up to a factor of order one: the classical dimensionless sweep
rate eta = Omega' / omega^2 against zeta^2 (``dimensionless_rate``). First order only: past ~20 % it
underestimates the flattening, and the verdict there is "too fast" anyway.

**Higher orders.** The h-th order of a swept record (a 2X force, a 3X excitation) is a forcing at the frequency
w = h Omega, swept at w' = h Omega': with z = X exp(i h theta) the same equation holds in w (``order`` h). Its
forcing law is that of the effect behind it, unknown to the data: an unbalance-like w^2 - i w' (an inertial 2X
excitation) or a constant amplitude F (a 2X force: X0 = F / D, X1 = (-(2 i w + c) dX0/dw w' - i w' X0) / D).
``sweep_rate_check`` with ``order`` > 1 takes the larger of both relative errors. The h-th order meets the mode
at Omega = omega_n / h: a 2X force crosses at half the critical speed at twice its frequency rate, where a run-up
slow enough for 1X may not be (measured on a time-integrated run-up with a 2X force: the 2X bands at 560-640 RPM,
quasi-steady chi^2 up to 2450 on 4 numbers; tests/test_sweep.py checks the closed form against time integration).

**Second order.** A forward model that carries X1 (``hybridtwin.solvers.sweep_forward``, the run-up's forward
model) still misses X2: at a constant rate (Omega'' = 0) the next order of the same expansion,

    X2 = -(Omega'^2 d^2X0/dOmega^2 + (2 i Omega + c) dX1/dOmega Omega' + i Omega' X1) / D,

relative to the peak ~ (Omega' / (zeta^2 Omega_c^2))^2: ``sweep_rate_check(forward="first_order")`` compares it
with the noise, so that a band is kept out only where even the corrected model is not within the noise.

Measured on the rig (the VARM's default truth, benchmarks/sweep_rate_study.py; table in benchmarks/README.md):
the predicted error against the time-integrated transient's, per rate and band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

Array = np.ndarray


#: the forcing laws of an order (module docstring): an unbalance-like w^2 - i w', or a constant amplitude
FORCINGS = ("unbalance", "constant")
#: the forward models whose sweep error ``sweep_rate_check`` estimates: the steady response, or the one corrected
#: to first order in the rate (module docstring, "Second order")
FORWARD_MODELS = ("quasi_steady", "first_order")


def quasi_steady(Omega: Array, omega_n: float, zeta: float, centrifugal: bool = True,
                 forcing: str = "unbalance") -> Array:
    """X0 = Omega^2 / D(Omega) of a unit unbalance on the mode (module docstring); ``forcing`` "constant": 1 / D,
    a unit force of constant amplitude."""
    Omega = np.asarray(Omega, dtype=float)
    s = 1.0 if centrifugal else 0.0
    D = omega_n ** 2 - (1.0 + s) * Omega ** 2 + 2j * zeta * omega_n * Omega
    return (Omega ** 2 if _forcing(forcing) == "unbalance" else 1.0) / D


def adiabatic_correction(Omega: Array, Omega_dot: Array | float, omega_n: float, zeta: float,
                         centrifugal: bool = True, forcing: str = "unbalance") -> Array:
    """X1, the first-order lag of the swept response (module docstring), for a unit unbalance (or, ``forcing``
    "constant", a unit force of constant amplitude: no -i Omega' term in the forcing)."""
    Omega = np.asarray(Omega, dtype=float)
    Omega_dot = np.broadcast_to(np.asarray(Omega_dot, dtype=float), Omega.shape)
    s = 1.0 if centrifugal else 0.0
    c = 2.0 * zeta * omega_n
    D = omega_n ** 2 - (1.0 + s) * Omega ** 2 + 1j * c * Omega
    dD = -2.0 * (1.0 + s) * Omega + 1j * c
    if _forcing(forcing) == "unbalance":
        X0 = Omega ** 2 / D
        dX0 = (2.0 * Omega * D - Omega ** 2 * dD) / D ** 2
        f1 = -1j * Omega_dot
    else:
        X0, dX0, f1 = 1.0 / D, -dD / D ** 2, 0.0
    return (f1 - (2j * Omega + c) * dX0 * Omega_dot - 1j * Omega_dot * X0) / D


def second_order_correction(Omega: Array, Omega_dot: Array | float, omega_n: float, zeta: float,
                            centrifugal: bool = True, forcing: str = "unbalance") -> Array:
    """X2, the second-order lag of the swept response at a constant rate (module docstring, "Second order"): what a
    forward model corrected to first order (``hybridtwin.solvers.sweep_forward``) still leaves, per unit unbalance
    (or unit constant force)."""
    Omega = np.asarray(Omega, dtype=float)
    Omega_dot = np.broadcast_to(np.asarray(Omega_dot, dtype=float), Omega.shape)
    s = 1.0 if centrifugal else 0.0
    c = 2.0 * zeta * omega_n
    D = omega_n ** 2 - (1.0 + s) * Omega ** 2 + 1j * c * Omega
    step = SECOND_ORDER_STEP * np.maximum(np.abs(Omega), omega_n * 1e-3)

    def X0(w):
        return quasi_steady(w, omega_n, zeta, centrifugal, forcing)

    def X1(w):
        return adiabatic_correction(w, Omega_dot, omega_n, zeta, centrifugal, forcing)

    X0_ww = (X0(Omega + step) - 2.0 * X0(Omega) + X0(Omega - step)) / step ** 2
    X1_w = (X1(Omega + step) - X1(Omega - step)) / (2.0 * step)
    return -(Omega_dot ** 2 * X0_ww + (2j * Omega + c) * X1_w * Omega_dot + 1j * Omega_dot * X1(Omega)) / D


#: the relative step of ``second_order_correction``'s differences in Omega (the laws are rational: round-off
#: eps / step^2 ~ 1e-10 of the value, truncation step^2 ~ 1e-6 of the curvature's scale)
SECOND_ORDER_STEP = 1e-3


def _forcing(forcing: str) -> str:
    if forcing not in FORCINGS:
        raise ValueError(f"forcing {forcing!r}: one of {', '.join(FORCINGS)}")
    return forcing


def crossing_speed(omega_n: float, centrifugal: bool = True) -> float:
    """The speed [rad/s] where the 1X forcing meets the mode: omega_n / sqrt(2) with the centrifugal softening."""
    return omega_n / math.sqrt(2.0) if centrifugal else omega_n


def dimensionless_rate(sweep_rate_rpm_s: float, omega_n: float, zeta: float, centrifugal: bool = True) -> float:
    """eta / zeta^2 = Omega' / (zeta^2 Omega_c^2) at the crossing: << 1 quasi-steady, ~1 and above the peak
    lags and flattens (the classical passage-through-resonance parameter)."""
    Omega_c = crossing_speed(omega_n, centrifugal)
    return abs(sweep_rate_rpm_s) * math.pi / 30.0 / (zeta ** 2 * Omega_c ** 2)


@dataclass(frozen=True)
class BandCheck:
    """One speed band of a record: the expected relative error of the quasi-steady order vector (max |X1| in
    the band over max |X0| in the record, the worst mode), the noise-to-amplitude ratio it is compared with,
    and the verdict."""

    rpm_low: float
    rpm_high: float
    expected_error: float
    noise_to_amplitude: float

    @property
    def ok(self) -> bool:
        return self.expected_error <= self.noise_to_amplitude

    @property
    def verdict(self) -> str:
        return "ok" if self.ok else "too fast"


def sweep_rate_check(modes: list[tuple[float, float]], sweep_rate_rpm_s: float, noise_to_amplitude: float,
                     rpm_low: float, rpm_high: float, band_rpm: float = 50.0, centrifugal: bool = True,
                     points_per_band: int = 50, order: int = 1, forward: str = "quasi_steady") -> list[BandCheck]:
    """Per band of ``band_rpm`` between rpm_low and rpm_high: is the quasi-steady model within the noise?

    modes: (omega_n [rad/s], zeta) of each mode at rest (e.g. ``model.campbell`` at 0 RPM, or the first mode
    of ``Model.at_rest`` with its damping ratio); sweep_rate_rpm_s: the record's rate |rpm'| (its largest, to be
    safe); noise_to_amplitude: the standard deviation of a measured order vector over the record's largest
    order amplitude (e.g. noise sigma sqrt(2 / samples per window) / peak). Each mode is scaled to its own
    peak (the worst case: the record dominated by that mode). ``order`` h: the h-th order vector, a forcing at
    h Omega swept at h Omega' (module docstring, "Higher orders"; h > 1: the larger error of both forcing laws).
    The bands stay in rotor speed; an order above 1 takes ``centrifugal`` False (a mode as the record shows it).
    ``forward``: the model whose error is estimated, "quasi_steady" (the steady response: its error is X1) or
    "first_order" (corrected for the rate, ``hybridtwin.solvers.sweep_forward``: its error is X2, module
    docstring, "Second order"). Returns one ``BandCheck`` per band.
    """
    if not rpm_high > rpm_low > 0:
        raise ValueError(f"sweep_rate_check: needs 0 < rpm_low < rpm_high, got {rpm_low}, {rpm_high}")
    if not band_rpm > 0 or not noise_to_amplitude >= 0:
        raise ValueError("sweep_rate_check: band_rpm must be positive and noise_to_amplitude >= 0")
    if forward not in FORWARD_MODELS:
        raise ValueError(f"sweep_rate_check: forward {forward!r}: one of {', '.join(FORWARD_MODELS)}")
    lag = adiabatic_correction if forward == "quasi_steady" else second_order_correction
    if int(order) != order or order < 1:
        raise ValueError(f"sweep_rate_check: order must be a positive integer, got {order}")
    if order > 1 and centrifugal:  # K - Omega^2 M is a law in Omega, not in h Omega: the mapping holds without it
        raise ValueError("sweep_rate_check: an order above 1 needs centrifugal=False (the record's apparent mode)")
    for omega_n, zeta in modes:
        if not (omega_n > 0 and zeta > 0):
            raise ValueError(f"sweep_rate_check: a mode needs omega_n > 0 and zeta > 0, got ({omega_n}, {zeta})")
    edges = np.arange(rpm_low, rpm_high + 1e-9, band_rpm)
    if edges[-1] < rpm_high - 1e-9:
        edges = np.append(edges, rpm_high)
    h = int(order)
    rate = h * abs(sweep_rate_rpm_s) * math.pi / 30.0  # the order's frequency rate, w' = h Omega'
    fine = h * np.linspace(rpm_low, rpm_high, max(2001, int(points_per_band * (edges.size - 1)))) * math.pi / 30.0
    errors = np.zeros(edges.size - 1)
    for omega_n, zeta in modes:
        for forcing in FORCINGS if h > 1 else ("unbalance",):
            peak = np.abs(quasi_steady(fine, omega_n, zeta, centrifugal, forcing)).max()
            for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
                w = h * np.linspace(a, b, points_per_band) * math.pi / 30.0
                error = lag(w, rate, omega_n, zeta, centrifugal, forcing)
                errors[i] = max(errors[i], float(np.abs(error).max() / peak))
    return [BandCheck(float(a), float(b), float(e), float(noise_to_amplitude))
            for a, b, e in zip(edges[:-1], edges[1:], errors)]


def largest_quasi_steady_rate(modes: list[tuple[float, float]], noise_to_amplitude: float, rpm_low: float,
                              rpm_high: float, centrifugal: bool = True) -> float:
    """The sweep rate [RPM/s] below which every band is "ok": X1 is proportional to the rate, so the rate at
    which the worst band's expected error equals the noise-to-amplitude ratio."""
    worst = max(c.expected_error for c in sweep_rate_check(modes, 1.0, 0.0, rpm_low, rpm_high,
                                                           band_rpm=rpm_high - rpm_low, centrifugal=centrifugal))
    return noise_to_amplitude / worst if worst > 0 else math.inf
