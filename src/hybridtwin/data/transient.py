"""Transient records (run-ups and coast-downs) as speed bands: what the rest of the method reads (issue 38).

A runs-sheet row of kind ``runup`` or ``coastdown`` is one record through a speed range, with a keyphasor
(docs/measurement-format.md). The twin compares it with the model along the sweep: the sweep is
cut into speed **bands** of ``band_rpm`` (a sheet column, default DEFAULT_BAND_RPM), and each band becomes a
*pseudo-run*, a row of the harmonics table like a steady run's, at the band's measured mean speed. Everything
downstream (libraries, identification, validation, diagnosis, report) then reads a band as it reads a run; the
model's response at a band is the steady state reached by continuation, as the rotor reaches it along the sweep,
corrected to first order for the band's measured sweep rate (the sheet's ``sweep_model``, default "first_order":
``hybridtwin.solvers.sweep_forward``; "quasi_steady": the steady state alone), and a band is kept out only where
that model's own sweep error exceeds the noise (``check_sweep_rate``).

- **Bands are known from the sheet alone** (``run_kinds.expand_bands``): ids ``<run>_b<centre RPM>``, centres from the top
  of the slow-roll band to the sweep's highest nominal speed. The workflow plans its jobs from them before any
  record is read; a band the record never reaches is written unusable with its reason, never dropped.
- **The speed and the phase come from the keyphasor** (``speed_profile``): the rotor angle theta(t) interpolates
  2 pi k at the marks (monotone cubic, PCHIP), so that every harmonic is referred to theta = 0 at a mark, the
  instant the unbalance points to +x. Missed or double marks, a profile that reverses, a sweep that never leaves
  one speed: an error naming the file.
- **A band's harmonics** (``fit_band``): least squares of each channel, over the whole revolutions whose speed
  lies in the band, on [1, t, cos h theta, sin h theta, d^k cos h theta, d^k sin h theta] (h = 1..H, k = 1, 2,
  d the relative speed deviation from the band's mean): the response may change across the band (near a
  resonance it does, by its curvature too), and the estimate is the one at the band's mean speed. Each part's 1-sigma uncertainty is the residual's
  standard deviation through (A^T A)^-1 (white noise; the bands hold disjoint samples, so their errors are
  independent and the identification's weights need no correlation).
- **Slow-roll runout** (``hybridtwin.data.slow_roll`` on the order vectors of ``order_tracking``): in the slow-roll
  band (the lowest speeds of the record, below ``slowroll_rpm``; by default the lowest SLOWROLL_SHARE of the
  sweep's span and as many windows above as the estimate needs, ``slow_roll.MIN_WINDOWS``: on a fast sweep it then
  overlaps the first bands, a correlation of their errors with the runout's that is not modelled) the 1X and 2X
  vectors are runout (a mark on the shaft, turning with it, of constant size) plus the dynamic response, which at
  low speed grows as Omega^2: the runout is the intercept of R + b Omega^2, subtracted as a vector from every
  band's 1X and 2X, its uncertainty added in quadrature; a band holding dynamics is reported per probe. Off with
  ``slowroll`` False. That uncertainty is one error common to all of a record's bands: each band also carries it
  as ``<channel><h>_runout_sigma_m`` (``slow_roll.runout_sigma_column``) and its record in ``parent_run``, from
  which the identification fits it as one offset per record (``measured.RunData.record``).

SI inside; rpm at the boundary. Conventions as everywhere: u(t) = Re(sum_h U_h exp(i h theta)), 0-peak.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from ..solvers.sweep_rate import sweep_rate_check
from .measurements import DataError
from .records import Record
from .record_columns import carried_columns, harmonic_column, harmonic_columns, highest_harmonic
from .run_kinds import BandPlan
from .order_tracking import SpeedProfile, TrackingError, speed_profile, track_orders
from .slow_roll import SlowRollWarning, compensate, runout as slow_roll_runout, with_runout_sigma

Array = np.ndarray

#: fewest whole revolutions a band must hold to be fitted
MIN_BAND_REVOLUTIONS = 5


# --- harmonics of a band -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BandFit:
    """Harmonics of one speed band: X (C, H+1) complex [m] (h = 0 the offset), sigma (C, H+1) [m] per real and
    imaginary part, noise (C,) [m], rpm (mean), sweep rate [RPM/s], revolutions, samples and the band's time span."""

    X: Array
    sigma: Array
    noise: Array
    rpm: float
    rpm_sigma: float
    sweep_rpm_s: float
    n_revolutions: int
    n_samples: int
    t_start_s: float
    t_end_s: float


def _revolution_samples(profile: SpeedProfile, time_s: Array, lo: float, hi: float) -> tuple[Array, int]:
    """Samples of the whole revolutions whose mean speed lies in [lo, hi) RPM, and how many revolutions."""
    revs = np.flatnonzero((profile.rpm >= lo) & (profile.rpm < hi))
    if revs.size == 0:
        return np.zeros(time_s.shape, bool), 0
    starts, stops = profile.marks_s[revs], profile.marks_s[revs + 1]
    k = np.searchsorted(starts, time_s, side="right") - 1
    take = (k >= 0) & (time_s < stops[np.clip(k, 0, None)])
    return take, int(revs.size)


def fit_band(data: Array, time_s: Array, profile: SpeedProfile, take: Array, harmonics: int,
             speed_order: int = 2, n_revolutions: int = 0) -> BandFit:
    """Least-squares harmonics of the samples ``take`` of ``data`` (N, C) [m] (module docstring)."""
    sigma_t_s = float(profile.sigma_t_s)
    t, y = time_s[take], data[take]
    theta, omega = profile.theta(t), profile.rpm_at(t) * np.pi / 30.0
    omega_c = float(np.mean(omega))
    d = omega / omega_c - 1.0
    h = np.arange(1, harmonics + 1)
    c, s = np.cos(np.outer(theta, h)), np.sin(np.outer(theta, h))
    tau = (t - t.mean()) / max(np.ptp(t), 1e-12)
    columns = [np.ones_like(t), tau, c, s]
    for k in range(1, speed_order + 1):  # the response's change across the band (module docstring)
        columns += [d[:, None] ** k * c, d[:, None] ** k * s]
    A = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    dof = max(A.shape[0] - A.shape[1], 1)
    noise = np.sqrt(np.sum((y - A @ coef) ** 2, axis=0) / dof)
    cov = np.linalg.pinv(A.T @ A)
    H = harmonics
    X = np.empty((y.shape[1], H + 1), complex)
    X[:, 0] = coef[0]
    X[:, 1:] = coef[2:2 + H].T - 1j * coef[2 + H:2 + 2 * H].T  # u = Re(X e^{ih theta}) = Re X cos - Im X sin
    unit = np.sqrt(0.5 * (np.diag(cov)[2:2 + H] + np.diag(cov)[2 + H:2 + 2 * H]))
    sigma = np.empty(X.shape)
    sigma[:, 0] = noise * math.sqrt(cov[0, 0])
    sigma[:, 1:] = noise[:, None] * unit[None, :]
    if sigma_t_s > 0 and n_revolutions > 0:
        # the keyphasor's timing noise: each mark off by e_k puts theta off by Omega e_k, independently per mark;
        # over the band's n revolutions the mean phase error (Omega sigma_t / sqrt(n)) turns U_h by h phi, and its
        # per-revolution scatter leaks the strongest order, the 1X, into the others by the same factor (order
        # tracking's exact propagation, order_tracking._jitter_variance, for windows; here to first order)
        phi = omega_c * sigma_t_s / math.sqrt(n_revolutions)
        leak = np.abs(X[:, 1:2]) ** 2
        sigma[:, 1:] = np.sqrt(sigma[:, 1:] ** 2 + 0.5 * phi**2 * ((h * np.abs(X[:, 1:])) ** 2 + leak))
    rpm = 30.0 * omega / np.pi
    slope = np.polyfit(t - t.mean(), rpm, 1)[0] if t.size > 2 else math.nan
    return BandFit(X, sigma, noise, float(rpm.mean()), float(rpm.std() / math.sqrt(max(t.size, 1))), float(slope),
                   0, int(t.size), float(t[0]), float(t[-1]))


# --- a transient record as rows of the harmonics table --------------------------------------------------------


@dataclass(frozen=True)
class TrackedRecord:
    """A transient record analysed: one row per speed band (``bands``: the harmonics table's columns, as a steady
    run's ``preprocessing.run_row`` with the sheet's columns carried), the runout removed (``runout``: the slow-roll
    runout table of ``hybridtwin.data.slow_roll``, empty when off), the per-revolution speed (``speed``) and the
    order vectors of windows of a few revolutions (``orders``, ``hybridtwin.data.order_tracking``: the Bode and
    polar plots' points)."""

    bands: pd.DataFrame
    runout: pd.DataFrame
    speed: pd.DataFrame
    orders: pd.DataFrame
    warnings: tuple[str, ...] = ()


#: a band's outcome (``track_record``): fitted and kept, too few revolutions, a speed the record never reached, or
#: samples clipped at the sensor's range; the band's ``note`` is the sentence
BAND_OK, BAND_TOO_FEW, BAND_NOT_REACHED, BAND_CLIPPED = "ok", "too_few_revolutions", "not_reached", "clipped"


def band_row(fit: BandFit | None, names: Sequence[str], harmonics: int, note: str, sample_rate_hz: float,
             unit: str, sigma_t_s: float, outcome: str = BAND_OK) -> dict:
    """A band's row in the columns of ``preprocessing.run_row`` (NaN where not fitted), plus the band's own
    (``outcome``: a ``BAND_*`` code, ``note`` its sentence)."""
    nan = math.nan
    row = {"n_samples": fit.n_samples if fit else 0,
           "duration_s": (fit.t_end_s - fit.t_start_s) if fit else nan, "sample_rate_hz": sample_rate_hz,
           "unit": unit, "keyphasor": True, "rpm_true": fit.rpm if fit else nan,
           "rpm_true_sigma": fit.rpm_sigma if fit else nan, "speed_deviation_rel": nan,
           "rpm_keyphasor": fit.rpm if fit else nan, "phase_reference": "keyphasor" if fit else "",
           "phase_origin_s": fit.t_start_s if fit else nan,
           # the band's phase origin: the mean of its n marks, each with the marks' timing noise (order_tracking.
           # SpeedProfile.sigma_t_s, at least dt / sqrt(12)), independent: sigma_t / sqrt(n), the share fit_band
           # adds to the sigmas and measured.run_data takes out again for the phase prior
           "phase_origin_sigma_s": sigma_t_s / math.sqrt(fit.n_revolutions) if fit and fit.n_revolutions > 0
           else nan, "n_revolutions": fit.n_revolutions if fit else 0}
    row |= harmonic_columns(names, harmonics, fit.X if fit else None, fit.sigma if fit else None,
                            fit.noise if fit else None)
    usable = fit is not None and outcome == BAND_OK
    row |= {"flat": False, "saturated": outcome == BAND_CLIPPED, "usable": usable, "note": note,
            "flags": "" if usable else note.split(":")[0].replace(" ", "_"),
            "t_start_s": fit.t_start_s if fit else nan, "t_end_s": fit.t_end_s if fit else nan,
            "sweep_rpm_per_s": fit.sweep_rpm_s if fit else nan}
    return row


def track_record(record: Record, sheet_row: Mapping, harmonics: int, sensor_range_m: float | None = None,
                 slowroll: bool = True) -> TrackedRecord:
    """A transient sheet row's record -> its bands' rows (module docstring); ``DataError`` naming the file for a
    record that cannot be tracked (no keyphasor, missed or double marks, a reversing profile, a record too short for
    its slow-roll band, a sweep that never leaves one speed)."""
    kind = str(sheet_row.get("kind", "")).strip().lower()
    where = str(record.path)
    plan = BandPlan.of(sheet_row)
    caught: list[str] = []
    try:
        profile = speed_profile(record, kind)
        span = float(np.ptp(profile.rpm))
        nominal = plan.bands[-1][1] - plan.slowroll[0]
        if span < 0.1 * nominal:
            raise DataError(f"{where}: the sweep never leaves one speed: the keyphasor gives {profile.rpm.min():.1f}-"
                            f"{profile.rpm.max():.1f} RPM, against the sheet's {sheet_row.get('rpm_start')}-"
                            f"{sheet_row.get('rpm_end')}; is this a steady run (kind steady)?")
        orders = track_orders(record, harmonics, direction=kind)
        runout = pd.DataFrame()
        if slowroll:
            with warnings.catch_warnings(record=True) as found:
                warnings.simplefilter("always", SlowRollWarning)
                runout = slow_roll_runout(orders, band_rpm=(min(plan.slowroll[0], float(profile.rpm.min())),
                                                            plan.slowroll[1]), mode=record_mode(orders, record.names),
                                          extend=not plan.slowroll_given)
            caught = [str(w.message) for w in found]
            orders = compensate(orders, runout)
    except TrackingError as err:
        raise DataError(str(err)) from None
    names = record.names
    data = np.column_stack([record.channels[n] for n in names])
    clipped = np.zeros(record.time_s.shape, bool)
    if sensor_range_m:  # on what the probes read (before a rotated pair is turned into x, y)
        seen = record.readings or record.channels
        clipped = np.any(np.abs(np.column_stack([seen[n] for n in names])) >= 0.999 * sensor_range_m, axis=1)
    rows = []
    for (lo, hi), run in zip(plan.bands, plan.ids):
        take, n_rev = _revolution_samples(profile, record.time_s, lo, hi)
        fit, note, outcome = None, "ok", BAND_OK
        if n_rev < MIN_BAND_REVOLUTIONS:
            reached = profile.rpm.min() <= hi and profile.rpm.max() >= lo
            outcome = BAND_TOO_FEW if reached else BAND_NOT_REACHED
            note = (f"only {n_rev} whole revolution(s) in {lo:.0f}-{hi:.0f} RPM (at least {MIN_BAND_REVOLUTIONS}): "
                    "the sweep is too fast for its bands; widen band_rpm" if reached else
                    f"not reached: the record's speed spans {profile.rpm.min():.0f}-{profile.rpm.max():.0f} RPM")
        else:
            fit = fit_band(data, record.time_s, profile, take, harmonics, n_revolutions=n_rev)
            fit = BandFit(**{**fit.__dict__, "n_revolutions": n_rev})
            if clipped[take].any():
                note = f"clipped: {int(clipped[take].sum())} sample(s) at the sensor's range in this band"
                outcome = BAND_CLIPPED
        analysed = band_row(fit, names, harmonics, note, record.sample_rate_hz, record.unit, profile.sigma_t_s,
                            outcome)
        carried = {k: v for k, v in sheet_row.items() if k != "record"}
        base = carried_columns(carried | {"run": run, "rpm": 0.5 * (lo + hi)}, analysed)
        rows.append(base | {"parent_run": sheet_row["run"], "band_lo_rpm": lo, "band_hi_rpm": hi,
                            "slowroll_compensated": bool(slowroll)} | analysed)
    bands = pd.DataFrame(rows)
    if slowroll and not runout.empty:
        bands = with_runout_sigma(compensate(bands, runout), runout)
    bands = check_sweep_rate(bands, names, plan, plan.sweep_model)
    bands["sweep_model"] = plan.sweep_model
    return TrackedRecord(bands, runout, profile.table(), orders, tuple(caught))


#: a band is too fast for the quasi-steady model where the sweep's expected lag exceeds this many of its sigmas
SWEEP_LAG_SIGMAS = 2.0
#: an order above 1 is checked where its resonance improves the chi^2 of a constant by this many sigmas squared
ORDER_SIGNIFICANCE = 3.0
#: ... and where its damping ratio in rotor speed is at least this share of the 1X's (``_resonances``)
ORDER_ZETA_SHARE = 0.5


def check_sweep_rate(bands: pd.DataFrame, names: Sequence[str], plan: BandPlan, forward: str = "quasi_steady"
                     ) -> pd.DataFrame:
    """The bands where the sweep is too fast for the forward model kept out, with a note (issue 38 item 5; issue 51).

    ``forward``: the model the bands are fitted with (``run_kinds.SWEEP_MODELS``). "quasi_steady", the steady state:
    its error is the first-order lag below. "first_order", the steady state corrected for the sweep rate
    (``hybridtwin.solvers.sweep_forward``, the default of a record): its error is the second-order lag
    (``sweep_rate_check(forward="first_order")``, ~ the square of the first relative to the peak), so only the bands
    where the correction itself is no longer small are kept out, and the bands at the resonances are fitted.

    The modes are the record's own (``one_mode_fit``: the strongest channel's 1X over the bands, a resonance seen
    whole or only on its flank); the expected lag of the swept response per band is the first-order adiabatic
    correction (``solvers.sweep_rate.sweep_rate_check``, measured against time integration on the rig:
    benchmarks/README.md, "Sweep rate") at the record's fastest rate, scaled to the mode's peak, and a band is
    kept out where it exceeds SWEEP_LAG_SIGMAS of the band's sigma. Every order of the table is checked: the h-th
    order sweeps its mode at h times the frequency rate (``sweep_rate_check(order=h)``), at its own resonance and
    scaled to its own resonant part (``_order_modes``: a 2X force's response peaks where 2X meets the mode, where 1X
    is quiet); an order without a resonance in sight is not checked. Every resonance an order shows is checked, not
    only its strongest (``_resonances``: each found in what the ones before leave): a 3X force meets the VARM's
    first mode at ~425 RPM and its second at ~640 RPM, and the bands at the second, left unchecked, carried a
    quasi-steady error of up to 3.4 sigma (benchmarks/README.md, "Why the fits' own intervals missed on run-ups").
    Columns added: sweep_lag_m (the expected lag of the order and mode that decide, the largest against its
    sigma, for ``forward``'s error), sweep_check ("ok", "too fast", or "no mode found" where no resonance is in
    sight)."""
    out = bands.copy()
    amp = np.column_stack([np.hypot(out[harmonic_column(c, 1, "re")], out[harmonic_column(c, 1, "im")]) for c in names])
    sigma = np.column_stack([out[harmonic_column(c, 1, "sigma")] for c in names])
    usable = out["usable"].astype(bool).to_numpy() & np.isfinite(amp).all(1)
    out["sweep_lag_m"], out["sweep_check"] = math.nan, "no resonance crossed"
    if usable.sum() < 5:
        return out
    rpm = out["rpm_true"].to_numpy(float)
    c = int(np.argmax(np.nanmax(np.where(usable[:, None], amp, -np.inf), axis=0)))  # the strongest channel
    X1 = (out[harmonic_column(names[c], 1, "re")] + 1j * out[harmonic_column(names[c], 1, "im")]).to_numpy()
    mode = one_mode_fit(rpm[usable] * math.pi / 30.0, X1[usable], sigma[usable, c])
    if mode is None:
        out["sweep_check"] = "no mode found"
        return out
    omega_n, zeta, gain = mode
    rate = float(np.nanmax(np.abs(out["sweep_rpm_per_s"].to_numpy(float))))
    width_rpm = plan.bands[0][1] - plan.bands[0][0]
    fine = np.linspace(plan.bands[0][0], plan.bands[-1][1], 4001) * math.pi / 30.0
    ratio, lag, order, which = np.zeros(len(out)), np.zeros(len(out)), np.ones(len(out), int), np.zeros(len(out), int)
    first = _resonances(rpm[usable] * math.pi / 30.0, X1[usable], sigma[usable, c], ORDER_ZETA_SHARE * zeta, mode)
    modes = {1: [(w, z, g * _peak(w, z, fine)) for w, z, g in first]}
    for h in range(2, highest_harmonic(out, names) + 1):
        found = _order_modes(out, names, h, usable, fine, zeta)
        if found:
            modes[h] = found
    for h, found in modes.items():
        sigma_h = np.column_stack([out[harmonic_column(name, h, "sigma")] for name in names])
        sigma_h = np.where(np.isfinite(sigma_h), sigma_h, 0.0).max(axis=1)  # a band not fitted: 0 (never marked)
        for k, (omega_h, zeta_h, peak) in enumerate(found):
            # sweep_rate_check scales each band's lag to the order's largest response over the record's bands
            checks = sweep_rate_check([(omega_h, zeta_h)], rate, 0.0, plan.bands[0][0], plan.bands[-1][1],
                                      band_rpm=width_rpm, centrifugal=False, order=h, forward=forward)
            lag_h = np.array([ch.expected_error for ch in checks])[: len(out)] * peak
            ratio_h = np.divide(lag_h, sigma_h, out=np.zeros_like(lag_h), where=sigma_h > 0)
            worse = ratio_h > ratio
            ratio[worse], lag[worse], order[worse], which[worse] = ratio_h[worse], lag_h[worse], h, k
    too_fast = usable & (ratio > SWEEP_LAG_SIGMAS)
    out["sweep_lag_m"] = lag
    out["sweep_check"] = np.where(too_fast, "too fast", "ok")
    for i in np.flatnonzero(too_fast):
        h, (omega_h, zeta_h, _) = int(order[i]), modes[int(order[i])][int(which[i])]
        out.loc[i, "usable"] = False
        what = ("a quasi-steady model: expected" if forward == "quasi_steady" else
                "the swept model (the steady state corrected to first order in the rate): expected second-order")
        out.loc[i, "note"] = (f"sweep too fast for {what} {h}X lag {1e6 * lag[i]:.1f} um "
                              f"against a {h}X sigma of {1e6 * lag[i] / ratio[i]:.2f} um at {rate:.1f} RPM/s near "
                              f"the {h}X resonance at {omega_h * 30 / math.pi / h:.0f} RPM (zeta "
                              f"{zeta_h:.3f}, fitted to the record): kept out")
        out.loc[i, "flags"] = "sweep_too_fast"
    return out


#: at most this many resonances of one order are checked (``_resonances``)
MAX_ORDER_MODES = 3


def _peak(omega_n: float, zeta: float, fine: Array) -> float:
    """The largest modulus over ``fine`` [rad/s] of the one-mode shape Omega^2 / (omega_n^2 - Omega^2 + 2 i zeta
    omega_n Omega) (``one_mode_fit``'s, unit gain)."""
    return float(np.abs(fine**2 / (omega_n**2 - fine**2 + 2j * zeta * omega_n * fine)).max())


def _resonances(Omega: Array, X: Array, s: Array, zeta_floor: float,
                first: tuple[float, float, float] | None = None) -> list[tuple[float, float, float]]:
    """The resonances one order shows over the bands, strongest first: [(Omega_n [rad/s, rotor speed], zeta,
    gain [m])]. Each is the one-mode fit (``one_mode_fit``) of what the ones before leave (their resonant parts
    A shape subtracted), so a second mode the strongest hides is found in its own bands; ``first``: the first one,
    when already fitted (the 1X's, which is kept without the tests below). A further one counts where its fit
    beats a constant on the same rest by ORDER_SIGNIFICANCE^2 in chi^2 (otherwise the noise, scaled to a resonance
    no band shows, would keep bands out) and its damping ratio is at least ``zeta_floor`` (a band or two fitted as
    a needle-sharp peak between the bands is no mode: ``_order_modes``); at most MAX_ORDER_MODES."""
    found: list[tuple[float, float, float]] = []
    rest = np.asarray(X, complex)
    while len(found) < MAX_ORDER_MODES:
        given = first is not None and not found
        mode = first if given else one_mode_fit(Omega, rest, s)
        if mode is None:
            break
        Omega_n, zeta, gain = mode
        if not given and zeta < zeta_floor:
            break
        shape = Omega**2 / (Omega_n**2 - Omega**2 + 2j * zeta * Omega_n * Omega)
        A = np.column_stack([shape, np.ones_like(shape)]) / s[:, None]
        coef, *_ = np.linalg.lstsq(A, rest / s, rcond=None)
        chi2_mode = float(np.sum(np.abs(A @ coef - rest / s) ** 2))
        mean = np.sum(rest / s**2) / np.sum(1 / s**2)
        chi2_constant = float(np.sum(np.abs((rest - mean) / s) ** 2))
        if not given and chi2_constant - chi2_mode < ORDER_SIGNIFICANCE**2:
            break
        found.append((Omega_n, zeta, gain))
        rest = rest - coef[0] * shape
    return found


def _order_modes(bands: pd.DataFrame, names: Sequence[str], h: int, usable: Array, fine: Array, zeta_1: float
                 ) -> list[tuple[float, float, float]]:
    """[(omega_h [rad/s], zeta_h, peak [m])] of the h-th order's own resonances (``_resonances`` of the strongest
    probe's h-th order over the usable bands, in rotor speed): the order crosses a mode at Omega_h, and omega_h =
    h Omega_h is the mode's frequency as that order drives it. Its own, not the 1X mode's
    divided by h: a speed-dependent stiffness moves the crossings apart (the VARM's centrifugal softening
    K - Omega^2 M puts 1X at omega_0 / sqrt(2) and 2X at omega_0 / sqrt(5), 950 and 600 RPM, not 950 / 2).
    peak: the fitted resonant part's largest modulus over ``fine`` [rad/s]. Empty where the order shows no
    resonance of a mode: the fit no better than a constant by ORDER_SIGNIFICANCE^2 in chi^2 (otherwise the
    noise, scaled to a resonance no band shows, would keep bands out of a record with no such order), no mode
    found, or a damping ratio below ORDER_ZETA_SHARE of the 1X's ``zeta_1``: the same mode driven by the h-th
    order shows in rotor speed a damping ratio zeta_0 h / sqrt(s + h^2) for a stiffness K - s Omega^2 M, at 2X
    0.9-1.3 times the 1X's for s in [0, 1]; a narrower one is a band or two fitted as a needle-sharp peak
    between the bands (measured on a time-integrated run-up with no 2X force: zeta 0.001, a 2X "peak" of 16 um
    where the bands show 1 um, which kept two bands out that the quasi-steady model fits to the noise)."""
    Omega = bands["rpm_true"].to_numpy(float) * math.pi / 30.0
    X = np.column_stack([(bands[harmonic_column(n, h, "re")] + 1j * bands[harmonic_column(n, h, "im")]).to_numpy()
                         for n in names])
    s = np.column_stack([bands[harmonic_column(n, h, "sigma")].to_numpy(float) for n in names])
    keep = usable & np.isfinite(X).all(1) & np.isfinite(s).all(1) & (s > 0).all(1)
    if keep.sum() < 6:
        return []
    c = int(np.argmax(np.abs(X[keep]).max(axis=0)))
    X, s, Omega = X[keep, c], s[keep, c], Omega[keep]
    return [(h * Omega_h, zeta, gain * _peak(Omega_h, zeta, fine))
            for Omega_h, zeta, gain in _resonances(Omega, X, s, ORDER_ZETA_SHARE * zeta_1)]


def summary_row(tracked: TrackedRecord, names: Sequence[str]) -> dict:
    """check-data's line for a transient record: its measured speed range, how many bands are usable, the noise
    (median over the bands) and the runout removed per probe (1X), and the status ("ok" or why it is kept out)."""
    bands = tracked.bands
    usable = bands["usable"].astype(bool)
    out = {"n_revolutions": int(bands["n_revolutions"].sum()), "rpm_measured_low": float(tracked.speed["rpm"].min()),
           "rpm_measured_high": float(tracked.speed["rpm"].max()), "n_bands": len(bands),
           "n_bands_usable": int(usable.sum()), "keyphasor": True}
    for name in names:
        out[f"noise_{name}_m"] = float(bands[f"noise_{name}_m"].median())
    if not tracked.runout.empty:
        for row in tracked.runout[tracked.runout["harmonic"] == 1].itertuples():
            out[f"runout_{row.channel}1_amp_m"] = row.runout_amp_m
    kept = bands.loc[~usable, "note"]
    status = "ok" if usable.all() else (f"{int((~usable).sum())} of {len(bands)} bands kept out: "
                                        + "; ".join(dict.fromkeys(n.split(":")[0] for n in kept)))
    if not usable.any():
        status = "excluded: no usable band (" + status + ")"
    return out | {"usable": bool(usable.any()), "note": status, "status": status,
                  "warnings": " | ".join(tracked.warnings)}


def record_mode(orders: pd.DataFrame, names: Sequence[str]) -> tuple[float, float] | None:
    """(omega_n [rad/s], zeta) of a record's first resonance from its order table before the runout is removed
    (``one_mode_fit`` of the strongest channel's 1X over the windows: its constant term takes the runout), for the
    slow-roll estimate's dynamic shape (``slow_roll.runout``); None where no resonance is in sight."""
    amp = [np.nanmax(np.hypot(orders[harmonic_column(c, 1, "re")], orders[harmonic_column(c, 1, "im")])) for c in names]
    c = names[int(np.argmax(amp))]
    X = (orders[harmonic_column(c, 1, "re")] + 1j * orders[harmonic_column(c, 1, "im")]).to_numpy()
    sigma = orders[harmonic_column(c, 1, "sigma")].to_numpy(float)
    keep = np.isfinite(X) & np.isfinite(sigma) & (sigma > 0)
    mode = one_mode_fit(orders["rpm"].to_numpy(float)[keep] * math.pi / 30.0, X[keep], sigma[keep])
    return None if mode is None else mode[:2]


def one_mode_fit(omega: Array, X: Array, sigma: Array) -> tuple[float, float, float] | None:
    """(omega_n [rad/s], zeta, |A| [m]) of the one-mode quasi-steady 1X that best fits the bands:
    X = A Omega^2 / (omega_n^2 - Omega^2 + 2 i zeta omega_n Omega) + B, complex A and B by linear least squares
    for each (omega_n, zeta) (variable projection), weighted by sigma. The mode may lie up to 1.5 times beyond
    the highest band (a record ending on the resonance's flank). None where no resonance is in sight (the best
    zeta at its bound, or omega_n beyond that reach): then no band is kept out."""
    if omega.size < 6:
        return None
    w = 1.0 / sigma

    def residual(p):
        wn, z = p
        basis = omega**2 / (wn**2 - omega**2 + 2j * z * wn * omega)
        A = np.column_stack([basis, np.ones_like(basis)]) * w[:, None]
        coef, *_ = np.linalg.lstsq(A, X * w, rcond=None)
        r = A @ coef - X * w
        return np.concatenate([r.real, r.imag])

    hi = 1.5 * omega.max()
    # the starts: the best point of a grid over (omega_n, zeta), its cost in closed form (the 2 x 2 weighted
    # normal equations of A and B for every point at once), then one least-squares refinement from there
    grid_wn = np.linspace(omega.min(), hi, 121)[1:]
    grid_z = np.geomspace(1.5e-3, 0.45, 24)
    wn_g, z_g = (g.ravel() for g in np.meshgrid(grid_wn, grid_z, indexing="ij"))
    basis = omega**2 / (wn_g[:, None] ** 2 - omega**2 + 2j * z_g[:, None] * wn_g[:, None] * omega)  # (G, n)
    w2 = w**2
    s_bb, s_b1, s_11 = (np.abs(basis) ** 2) @ w2, basis.conj() @ w2, w2.sum()
    s_bx, s_1x = (basis.conj() * X) @ w2, (X * w2).sum()
    det = s_bb * s_11 - np.abs(s_b1) ** 2
    a = (s_11 * s_bx - s_b1 * s_1x) / det
    b = (s_bb * s_1x - s_b1.conj() * s_bx) / det
    cost = np.sum(np.abs((a[:, None] * basis + b[:, None] - X) * w) ** 2, axis=1)
    cost[~np.isfinite(cost)] = np.inf
    k = int(np.argmin(cost))
    best = least_squares(residual, [wn_g[k], z_g[k]], bounds=([omega.min(), 1e-3], [hi, 0.5]))
    wn, z = best.x
    if z >= 0.49 or wn >= 0.99 * hi:
        return None
    basis = omega**2 / (wn**2 - omega**2 + 2j * z * wn * omega)
    A = np.column_stack([basis, np.ones_like(basis)]) * w[:, None]
    coef, *_ = np.linalg.lstsq(A, X * w, rcond=None)
    return float(wn), float(z), float(abs(coef[0]))
