"""Preprocessing of measured runs: true speed, synchronous (order) analysis, nuisances.

What a rotordynamics engineer does with a displacement record before comparing
it with a steady-state model (u(t) = Re(sum_h U_h exp(i h Omega t)), 0-peak):

1. Speed. The nominal RPM is only a set point. ``refine_speed`` finds the
   rotation frequency as the maximum-likelihood frequency of a harmonic
   series in white Gaussian noise: a coarse search of the summed power of
   1X..HX of every channel within +-2 % of nominal (grid finer than a quarter
   of the HX line width), then variable projection (the linear harmonic
   amplitudes solved exactly for each trial Omega, Omega minimising
   sum_ch log RSS_ch, the profile likelihood with an unknown noise level per
   channel). Its uncertainty is the Cramer-Rao / Gauss-Newton one,
   1 / sigma_Omega^2 = sum_ch |(I - P_A) dm_ch/dOmega|^2 / sigma_ch^2.
2. Phase origin. Without a keyphasor the rotor angle at any instant is
   unknown: harmonics are referred to a revolution boundary near the middle
   of the analysed span (``phase_reference`` = "arbitrary"), where the phase
   is least affected by the speed's uncertainty. With a keyphasor the origin
   is the mark (the unbalance on +x, docs/measurement-format.md): the marks' times
   are fitted as t_k = t_c + k T_kp, and the origin is the fitted mark nearest
   the middle ("keyphasor"). A mark lands on the sample nearest to the event
   (the virtual rig does so), so its time error is the rounding
   dt (round(u + k f) - (u + k f)), f = T / dt, u the unknown sub-sample
   position of mark 0. These errors are not independent: along the sequence
   k f mod 1 they largely cancel in the regression. Its uncertainty is
   therefore the RMS, over u uniform in [0, 1), of the regression's error
   for the record's own f and mark numbers (``quantisation_sigma``), plus
   the regression's share of any scatter beyond the rounding (jitter).
   Measured on 66 virtual-rig records: (origin error / sigma) has an RMS of
   0.50 with an independent-error formula, about 1 with this one.
3. Order analysis over whole revolutions. The record is cut into the K whole
   revolutions [t_ref + k T, t_ref + (k+1) T) it contains; in each the DC and
   1X..HX of x and y are fitted by least squares (exact, no resampling);
   the estimate is their mean (synchronous averaging) and its standard
   uncertainty the revolution-to-revolution standard deviation / sqrt(K)
   (per real and imaginary part, reported as their RMS), plus with a
   keyphasor the origin's share h Omega sigma_t |X_h| / sqrt(2). The noise
   level is the residual standard deviation about the averaged waveform.
4. DC. The 0X term is the sensor's offset plus the response's own mean; one
   channel cannot tell them apart, so it is reported (offset_x_m, ...) and is
   a nuisance.

Nuisances, and how a comparison stays invariant to them. A per-run phase
phi (no keyphasor) turns every measured harmonic into X_h exp(i h phi) and
the DC offsets shift only h = 0. A comparison with a model (``fit_phase``,
``phase_aligned_residuals``) therefore (a) never uses h = 0 and (b) compares
X_h with M_h exp(i h phi*) where phi* minimises the weighted misfit for that
run: the result is the same whatever the record's time origin and offsets.
Neither phi* nor the offsets are model parameters. With a keyphasor the
absolute phases are physical and can be compared directly.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

from .measurements import DataError, DataWarning, check_coverage, read_runs
from .plausibility import SPEED_TOLERANCE, Flag, check_magnitudes, check_speed, response_flags
from .record_columns import (  # noqa: F401 (harmonic_column, harmonic_stem re-exported)
    carried_columns as _carried, harmonic_column, harmonic_columns, harmonic_stem, keyphasor_marks,
)
from .records import (MIN_REVOLUTIONS, SENSOR_RANGE_MM, SENSOR_RESOLUTION_MM, Record, Saturation, Sensor, check_length,
                      check_sampling, detect_saturation, read_record)
from .run_kinds import is_transient_row
from ..model.sensor import DEFAULT_CHANNELS
from ..solvers.solver import DEFAULT_HARMONICS
from ..tables import MEASURED
from .transient import summary_row, track_record

Array = np.ndarray
CHANNELS = DEFAULT_CHANNELS  # the VARM's channels (a record's own: ``Record.names``)
#: the true speed is sought within this fraction of the nominal speed (beyond it: plausibility.check_speed's error)
SPEED_SEARCH = SPEED_TOLERANCE


@dataclass(frozen=True)
class SpeedEstimate:
    """Refined rotation speed [RPM] and its standard uncertainty."""

    rpm: float
    sigma_rpm: float

    @property
    def omega(self) -> float:
        """Omega [rad/s]."""
        return self.rpm * 2.0 * np.pi / 60.0

    @property
    def period_s(self) -> float:
        return 60.0 / self.rpm


@dataclass(frozen=True)
class PhaseOrigin:
    """The instant (record time) the harmonics' phases refer to.

    source: "keyphasor" (the unbalance points to +x there: phases are absolute)
    or "arbitrary" (a revolution boundary near the record's middle).
    """

    time_s: float
    sigma_s: float
    source: str
    rpm_keyphasor: float = float("nan")
    n_marks: int = 0


@dataclass
class OrderAnalysis:
    """Synchronous averages of one record.

    harmonics: (C, H+1) complex [m] for the record's channels (x, y on the
    VARM), h = 0..H, with x(t) ~ Re(sum_h X_h exp(i h Omega (t - origin)));
    sigma: (C, H+1) standard uncertainty of each of the real and imaginary
    parts [m]; per_revolution: (K, C, H+1) the individual revolutions'
    estimates; noise_m: (C,) residual standard deviation about the averaged
    waveform. One speed and one phase origin for all channels of a run.
    """

    harmonics: Array
    sigma: Array
    per_revolution: Array
    noise_m: Array
    start_s: float  # first analysed revolution's start (record time)
    n_samples_used: int

    @property
    def n_revolutions(self) -> int:
        return self.per_revolution.shape[0]

    @property
    def H(self) -> int:
        return self.harmonics.shape[1] - 1


@dataclass
class RunAnalysis:
    """Everything the preprocessing learns about one run.

    findings: what keeps the run out of the fit (``Saturation``: flat or
    clipped channels; ``plausibility.Flag``: noise only, backward whirl,
    spikes), each already warned about (``DataWarning``).
    """

    record: Record
    rpm_nominal: float
    findings: list[Saturation | Flag] = field(default_factory=list)
    speed: SpeedEstimate | None = None
    origin: PhaseOrigin | None = None
    orders: OrderAnalysis | None = None

    @property
    def flat(self) -> bool:
        return any(f.kind == "flat" for f in self.findings)

    @property
    def saturated(self) -> bool:
        return any(f.kind == "clipped" for f in self.findings)

    @property
    def usable(self) -> bool:
        """Fit for comparison with a model: analysed, and nothing found against it."""
        return self.orders is not None and not self.findings

    @property
    def note(self) -> str:
        """"ok", or "excluded..." with the findings in a few words (the run is kept out of the fit)."""
        if self.flat:
            return "excluded: " + "; ".join(f.short for f in self.findings if f.kind == "flat")
        if self.saturated:
            return "excluded (saturated, harmonics biased): " + "; ".join(f.short for f in self.findings)
        if self.findings:
            return "excluded: " + "; ".join(f.short for f in self.findings)
        return "ok"


# --- step 1: speed ----------------------------------------------------------------------


def design_matrix(t: Array, omega: float, harmonics: int) -> Array:
    """[1, cos(h Omega t), sin(h Omega t) for h = 1..H] (N, 2H+1)."""
    phase = np.outer(t, omega * np.arange(1, harmonics + 1))
    out = np.empty((t.size, 2 * harmonics + 1))
    out[:, 0] = 1.0
    out[:, 1::2], out[:, 2::2] = np.cos(phase), np.sin(phase)
    return out


#: the largest block of the speed search's (frequency x sample) matrices, complex values (16 MiB each)
_SPEED_BLOCK_VALUES = 1 << 20


def refine_speed(record: Record, rpm_nominal: float, harmonics: int = DEFAULT_HARMONICS,
                 channels: tuple[str, ...] | None = None, search: float = SPEED_SEARCH) -> SpeedEstimate:
    """Maximum-likelihood rotation speed from the record (module docstring, step 1).

    Raises ``DataError`` when the best frequency lies at the edge of the
    +-``search`` band around the nominal speed (the true speed is elsewhere
    or the record holds no periodic signal).
    """
    t = record.time_s - record.time_s.mean()
    data = record.data if channels is None else np.column_stack([record.channel(c) for c in channels])
    data = data - data.mean(0)
    f0 = rpm_nominal / 60.0
    step = 0.25 / (harmonics * record.duration_s)
    grid = f0 + np.arange(-np.ceil(search * f0 / step), np.ceil(search * f0 / step) + 1) * step
    power = np.zeros(grid.size)
    # the grid in blocks of about _SPEED_BLOCK_VALUES complex values (G x N grows with the record's duration
    # squared: 481 x 600 000, 4.3 GiB a matrix, for 60 s at 10 kHz); each frequency's power is its own row's
    for rows in np.array_split(np.arange(grid.size), -(-grid.size * t.size // _SPEED_BLOCK_VALUES)):
        first = np.exp(-2j * np.pi * np.outer(grid[rows], t))  # (g, N), exp(-i 2 pi f t)
        kernel = first.copy()
        for _ in range(harmonics):  # kernel = first^h: exp(-i 2 pi h f t)
            power[rows] += (np.abs(kernel @ data) ** 2).sum(1)
            kernel *= first
    best = int(np.argmax(power))
    if best in (0, grid.size - 1):
        raise DataError(f"{record.path}: no rotation frequency found within +-{100 * search:g} % of the nominal "
                        f"{rpm_nominal:g} RPM (the strongest synchronous response lies at the edge of the search, "
                        f"{grid[best] * 60:.1f} RPM): wrong nominal speed or no periodic signal")

    energy = (data**2).sum(0)

    def objective(f: float) -> float:
        A = design_matrix(t, 2 * np.pi * f, harmonics)
        projected = A.T @ data
        rss = energy - (projected * np.linalg.solve(A.T @ A, projected)).sum(0)
        return float(np.log(rss).sum())

    found = minimize_scalar(objective, bounds=(grid[best] - step, grid[best] + step), method="bounded",
                            options={"xatol": 1e-9 * f0})
    omega = 2 * np.pi * found.x
    sigma_omega = _speed_sigma(t, data, omega, harmonics)
    return SpeedEstimate(omega * 60 / (2 * np.pi), sigma_omega * 60 / (2 * np.pi))


def _speed_sigma(t: Array, data: Array, omega: float, harmonics: int) -> float:
    """Gauss-Newton standard uncertainty of Omega with the harmonic amplitudes profiled out."""
    A = design_matrix(t, omega, harmonics)
    gram = A.T @ A
    coef = np.linalg.solve(gram, A.T @ data)  # (2H+1, C)
    residual = data - A @ coef
    dof = t.size - A.shape[1] - 1
    sigma2 = (residual**2).sum(0) / dof
    h = np.arange(1, harmonics + 1)
    phase = np.outer(t, omega * h)
    # d/dOmega of sum_h a_h cos(h Omega t) + b_h sin(h Omega t)
    d = (t[:, None] * ((-np.sin(phase) * h) @ coef[1::2] + (np.cos(phase) * h) @ coef[2::2]))  # (N, C)
    d_perp = d - A @ np.linalg.solve(gram, A.T @ d)
    information = ((d_perp**2).sum(0) / sigma2).sum()
    return float(1.0 / np.sqrt(information))


# --- step 2: phase origin ---------------------------------------------------------------


def phase_origin(record: Record, speed: SpeedEstimate) -> PhaseOrigin:
    """The phase reference: the keyphasor mark nearest the middle, else a revolution boundary there.

    The marks are the rising edges of ``record.keyphasor`` (``keyphasor_marks``: the first sample of each
    pulse, however wide); a missed mark is tolerated (the sequence is fitted over the mark numbers k), two
    marks within one revolution or one more than a quarter period off the sequence are a ``DataError``.
    """
    t, period = record.time_s, speed.period_s
    if record.keyphasor is None:
        whole = int(np.floor((t[-1] + record.dt_s - t[0]) / period))
        return PhaseOrigin(float(t[0] + (whole // 2) * period), 0.0, "arbitrary")
    index = np.flatnonzero(keyphasor_marks(record.keyphasor))  # a pulse wider than a sample is one mark
    marks = t[index]
    k = np.round((marks - marks[0]) / period).astype(int)
    repeated = np.flatnonzero(np.diff(k) == 0)
    if repeated.size:
        first, second = record.line(index[repeated[0]]), record.line(index[repeated[0] + 1])
        raise DataError(f"{record.path}: column keyphasor: two marks within one revolution at lines {first} and "
                        f"{second} (period {period:.5f} s)")
    if k.size < 2:
        raise DataError(f"{record.path}: column keyphasor: only one mark; a phase reference needs a mark per "
                        "revolution")
    slope, intercept = np.polyfit(k, marks, 1)
    residual = marks - (intercept + slope * k)
    off = np.flatnonzero(np.abs(residual) > 0.25 * period)
    if off.size:
        raise DataError(f"{record.path}: column keyphasor: mark at line {record.line(index[off[0]])} is "
                        f"{residual[off[0]]:+.4f} s off the once-per-turn sequence (period {slope:.5f} s)")
    k_c = int(np.round((0.5 * (t[0] + t[-1]) - intercept) / slope))
    t_c = intercept + slope * k_c
    s2 = (residual**2).sum() / max(k.size - 2, 1)
    lever = 1.0 / k.size + (k_c - k.mean()) ** 2 / ((k - k.mean()) ** 2).sum()
    weights = 1.0 / k.size + (k_c - k.mean()) * (k - k.mean()) / ((k - k.mean()) ** 2).sum()  # t_c = w . t_k
    jitter2 = max(s2 - record.dt_s**2 / 12.0, 0.0)  # scatter beyond the rounding's
    sigma = np.sqrt(quantisation_sigma(weights, k, slope / record.dt_s, record.dt_s) ** 2 + jitter2 * lever)
    return PhaseOrigin(float(t_c), float(sigma), "keyphasor", 60.0 / slope, int(k.size))


def quantisation_sigma(weights: Array, k: Array, f: float, dt: float, n_positions: int = 512) -> float:
    """RMS error [s] of the estimate w . t_k when each mark t_k is rounded to the sample grid (step 2).

    Mark k sits at u + k f samples, u the unknown sub-sample position of mark 0: the estimate errs by
    dt sum_k w_k (round(u + k f) - (u + k f)) (an exact linear estimator, sum w = 1, is blind to the
    events' own linear trend); its mean square over u uniform in [0, 1), on a grid of ``n_positions``.
    """
    u = (np.arange(n_positions) + 0.5) / n_positions
    position = u[:, None] + np.mod(k * f, 1.0)[None, :]
    error = dt * ((np.round(position) - position) @ weights)
    return float(np.sqrt(np.mean(error * error)))


# --- step 3: order analysis -------------------------------------------------------------


def order_analysis(record: Record, speed: SpeedEstimate, origin: PhaseOrigin, harmonics: int = DEFAULT_HARMONICS) -> OrderAnalysis:
    """Synchronous averages of DC and 1X..HX of every channel over whole revolutions (module docstring, step 3)."""
    t, period, omega = record.time_s, speed.period_s, speed.omega
    first = int(np.ceil((t[0] - origin.time_s) / period - 1e-9))
    start = origin.time_s + first * period
    K = int(np.floor((t[-1] + record.dt_s - start) / period + 1e-9))
    if K < 2:
        raise DataError(f"{record.path}: only {K} whole revolution(s) at {speed.rpm:.2f} RPM; the synchronous "
                        "analysis needs at least 2")
    revolution = np.floor((t - start) / period).astype(int)
    used = (revolution >= 0) & (revolution < K)
    data = record.data[used]
    A = design_matrix(t[used] - origin.time_s, omega, harmonics)
    bounds = np.searchsorted(revolution[used], np.arange(K))  # first sample of each revolution
    normal = np.add.reduceat(np.einsum("np,nq->npq", A, A), bounds, axis=0)  # (K, p, p)
    rhs = np.add.reduceat(np.einsum("np,nc->npc", A, data), bounds, axis=0)  # (K, p, C)
    coef = np.linalg.solve(normal, rhs)  # (K, p, C)
    per_rev = _to_complex(np.moveaxis(coef, 2, 1))  # (K, C, H+1)
    mean = per_rev.mean(0)
    scatter = np.sqrt(0.5 * (per_rev.real.var(0, ddof=1) + per_rev.imag.var(0, ddof=1)) / K)
    sigma = np.sqrt(scatter**2 + origin_share(mean, omega, origin.sigma_s) ** 2)
    residual = data - A @ _to_real(mean).T
    noise = np.sqrt((residual**2).sum(0) / (used.sum() - A.shape[1]))
    return OrderAnalysis(mean, sigma, per_rev, noise, float(start), int(used.sum()))


def origin_share(harmonics: Array, omega: float, sigma_t: float) -> Array:
    """The phase origin's share of each harmonic's sigma, h Omega sigma_t |X_h| / sqrt(2) (step 3).

    harmonics: (..., H+1) over h = 0..H; a timing error delta_t rotates X_h by h Omega delta_t, the same
    for every harmonic and channel of a record (one common rotation, not independent noise).
    """
    h = np.arange(np.shape(harmonics)[-1])
    return h * omega * sigma_t * np.abs(harmonics) / np.sqrt(2.0)


def _to_complex(coef: Array) -> Array:
    """[c0, a1, b1, ..., aH, bH] (cos, sin coefficients) -> X_h = a_h - i b_h, X_0 = c0 (last axis)."""
    out = np.empty(coef.shape[:-1] + ((coef.shape[-1] + 1) // 2,), complex)
    out[..., 0] = coef[..., 0]
    out[..., 1:] = coef[..., 1::2] - 1j * coef[..., 2::2]
    return out


def _to_real(X: Array) -> Array:
    """Inverse of ``_to_complex``."""
    out = np.empty(X.shape[:-1] + (2 * X.shape[-1] - 1,))
    out[..., 0] = X[..., 0].real
    out[..., 1::2], out[..., 2::2] = X[..., 1:].real, -X[..., 1:].imag
    return out


# --- a whole run ------------------------------------------------------------------------


def analyse_record(record: Record, rpm_nominal: float, harmonics: int = DEFAULT_HARMONICS, sensor_range_m: float | None = None,
                   min_revolutions: float = MIN_REVOLUTIONS, sensor_resolution_m: float | None = None,
                   whirl=None) -> RunAnalysis:
    """Checks and steps 1-3 for one record (docs/data-checks.md).

    Errors (``DataError``): too short or too coarsely sampled, values the
    sensor cannot have written (units, offsets beyond its range), a record
    turning at another speed than ``rpm_nominal`` (``hybridtwin.data.plausibility``).
    Flags (``findings``, each warned about as a ``DataWarning``; the run is not
    ``usable``): a flat channel (returned unanalysed), a clipped one (flat tops
    or the noisy rail of the sensor's range), a channel of noise only, a
    backward 1X whirl, spikes. The sensor: +-``sensor_range_m`` (default 14 mm)
    and ``sensor_resolution_m`` (default 1 um). whirl: the machine's model of the 1X whirl
    (``hybridtwin.model.whirl.WhirlModel``): backward whirl is flagged only where it predicts forward
    (``plausibility.response_flags``); None: the model-free rule.
    """
    sensor = Sensor(SENSOR_RANGE_MM * 1e-3 if sensor_range_m is None else sensor_range_m,
                    SENSOR_RESOLUTION_MM * 1e-3 if sensor_resolution_m is None else sensor_resolution_m)
    check_magnitudes(record, sensor)
    check_speed(record, rpm_nominal, harmonics=harmonics)  # first: a wrong rpm named so, not a record too short
    check_length(record, rpm_nominal, min_revolutions)
    check_sampling(record, rpm_nominal * (1 + SPEED_SEARCH), harmonics)
    analysis = RunAnalysis(record, rpm_nominal, detect_saturation(record, sensor.range_m, sensor.resolution_m))
    if analysis.flat:
        return analysis
    analysis.speed = refine_speed(record, rpm_nominal, harmonics)
    analysis.origin = phase_origin(record, analysis.speed)
    analysis.orders = order_analysis(record, analysis.speed, analysis.origin, harmonics)
    orders = analysis.orders
    A = design_matrix(record.time_s - analysis.origin.time_s, analysis.speed.omega, orders.H)
    residual = record.data - A @ _to_real(orders.harmonics).T
    clipped = tuple(f.channel for f in analysis.findings if f.kind == "clipped")
    analysis.findings += response_flags(record, orders.harmonics, orders.sigma, residual, skip=clipped,
                                        rpm=analysis.speed.rpm, whirl=whirl)
    return analysis


def table_channels(table: pd.DataFrame) -> tuple[str, ...]:
    """The channels of a harmonics table (``run_row``'s columns), in order: the names c with a column
    noise_<c>_m and the 1X of c (its real part or amplitude); ("x", "y") for the VARM's, also for a table
    with x1_re_m and y1_re_m but no noise columns (one written by hand)."""
    out = []
    for column in table.columns:
        if column.startswith("noise_") and column.endswith("_m"):
            name = column[len("noise_"):-len("_m")]
            if name and any(harmonic_column(name, 1, part) in table for part in ("re", "amp")):
                out.append(name)
    if not out and all(harmonic_column(c, 1, "re") in table for c in CHANNELS):
        return CHANNELS
    return tuple(out)


def run_row(analysis: RunAnalysis, harmonics: int, complex_parts: bool = True) -> dict:
    """The tidy per-run result (one row, SI, units in the column names); NaN where not analysed.

    Per channel c of the record (x, y on the VARM): noise_<c>_m, offset_<c>_m, offset_<c>_sigma_m, then per
    harmonic h its real and imaginary part, amplitude and sigma (``harmonic_column``: x1_re_m, ...)."""
    record = analysis.record
    nan = float("nan")
    row = {"n_samples": record.n_samples, "duration_s": record.duration_s, "sample_rate_hz": record.sample_rate_hz,
           "unit": record.unit, "keyphasor": record.keyphasor is not None}
    speed, origin, orders = analysis.speed, analysis.origin, analysis.orders
    row["rpm_true"] = speed.rpm if speed else nan
    row["rpm_true_sigma"] = speed.sigma_rpm if speed else nan
    row["speed_deviation_rel"] = speed.rpm / analysis.rpm_nominal - 1 if speed else nan
    row["rpm_keyphasor"] = origin.rpm_keyphasor if origin else nan
    row["phase_reference"] = origin.source if origin else ""
    row["phase_origin_s"] = origin.time_s if origin else nan
    row["phase_origin_sigma_s"] = origin.sigma_s if origin else nan
    row["n_revolutions"] = orders.n_revolutions if orders else 0
    row |= harmonic_columns(record.names, harmonics, orders.harmonics if orders else None,
                            orders.sigma if orders else None, orders.noise_m if orders else None, complex_parts)
    row["flat"], row["saturated"], row["usable"], row["note"] = (
        analysis.flat, analysis.saturated, analysis.usable, analysis.note)
    row["flags"] = ",".join(dict.fromkeys(f.kind for f in analysis.findings))
    return row


def waveforms(analysis: RunAnalysis, cycles: int = 2) -> pd.DataFrame:
    """Two (``cycles``) revolutions from the phase origin, for plotting.

    time_s: time since the phase origin (the record's own samples, dt = 1/fs);
    angle_rad: Omega time_s; per channel c (x, y on the VARM): <c>_m, the
    synchronous average 1X..HX (DC and noise removed), and <c>_raw_m, the
    recorded samples minus the DC offset.
    """
    names = analysis.record.names
    columns = ["time_s", "angle_rad", *(f"{c}_m" for c in names), *(f"{c}_raw_m" for c in names)]
    if analysis.orders is None:
        return pd.DataFrame(columns=columns)
    record, orders, speed = analysis.record, analysis.orders, analysis.speed
    period, start = speed.period_s, analysis.origin.time_s
    while start + cycles * period > record.time_s[-1] + record.dt_s and start - period >= record.time_s[0]:
        start -= period
    take = (record.time_s >= start) & (record.time_s < start + cycles * period)
    tau = record.time_s[take] - analysis.origin.time_s
    A = design_matrix(tau, speed.omega, orders.H)
    clean = A[:, 1:] @ _to_real(orders.harmonics)[:, 1:].T
    raw = record.data[take] - orders.harmonics[:, 0].real
    out = {"time_s": tau, "angle_rad": speed.omega * tau}
    out |= {f"{c}_m": clean[:, i] for i, c in enumerate(names)}
    out |= {f"{c}_raw_m": raw[:, i] for i, c in enumerate(names)}
    return pd.DataFrame(out, columns=columns)


def spectrum(record: Record, rpm: float, max_order: float = 10.0) -> pd.DataFrame:
    """A record's full amplitude spectrum up to ``max_order`` times the speed (the cascade plot's rows): each
    channel's mean removed, a Hann window, |FFT| scaled so that a sinusoid at a bin's frequency shows its
    0-peak amplitude [m] (2 |X_k| / sum(w)); ``order``: frequency over the rotation frequency rpm / 60.
    Unlike the order analysis it keeps everything between the harmonics: subharmonics, natural frequencies
    excited by noise, the mains, a rub's broadband."""
    n = record.n_samples
    window = np.hanning(n)
    f = np.fft.rfftfreq(n, record.dt_s)
    keep = f <= max_order * rpm / 60.0
    out = {"frequency_hz": f[keep], "order": f[keep] * 60.0 / rpm}
    for name in record.names:
        z = record.channel(name)
        out[f"{name}_amplitude_m"] = 2.0 * np.abs(np.fft.rfft((z - z.mean()) * window))[keep] / window.sum()
    return pd.DataFrame(out)


def preprocess_run(sheet_row: Mapping, harmonics: int = DEFAULT_HARMONICS, sensor_range_m: float | None = None,
                   sensor_resolution_m: float | None = None, record: Record | None = None, sensors=None,
                   whirl=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One runs-sheet row (with its resolved ``record`` path) -> (one-row tidy table, waveforms).

    The sensor: the row's sensor_range_mm / sensor_resolution_mm, else the
    given defaults [m], else the built-in ones (``records.Sensor``).
    record: the row's record already read (``read_record``), e.g. for its ``spectrum`` too; else read here,
    its channels named after ``sensors`` (the machine's, ``records.record_channels``; None: x, y).
    whirl: the machine's model of the 1X whirl, as in ``analyse_record``.
    """
    sensor = Sensor.for_run(sheet_row, sensor_range_m, sensor_resolution_m)
    record = read_record(sheet_row["record"], sensors, sheet_row.get("channels")) if record is None else record
    analysis = analyse_record(record, float(sheet_row["rpm"]), harmonics, sensor.range_m,
                              sensor_resolution_m=sensor.resolution_m, whirl=whirl)
    analysed = run_row(analysis, harmonics)
    return pd.DataFrame([_carried(sheet_row, analysed) | analysed]), waveforms(analysis)


def summarise_runs(runs: pd.DataFrame, harmonics: int = DEFAULT_HARMONICS, sensor_range_m: float | None = None,
                   min_revolutions: float = MIN_REVOLUTIONS, sensor_resolution_m: float | None = None, sensors=None,
                   whirl=None) -> tuple[pd.DataFrame, dict[str, str]]:
    """check-data: every run of a validated sheet analysed; (summary table, {run: error message}).

    The summary has the sheet's columns, then the per-run figures of
    ``run_row`` without the complex parts (amplitudes and uncertainties only)
    and ``status`` ("ok", "excluded: ...", or "invalid: <error>"). Runs whose
    record is invalid keep their row (status invalid) and their error is
    returned, so nothing is dropped silently. The sensor, ``sensors`` and ``whirl`` as in ``preprocess_run``.
    """
    rows, errors = [], {}
    for _, sheet_row in runs.iterrows():
        sensor = Sensor.for_run(sheet_row, sensor_range_m, sensor_resolution_m)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("always", DataWarning)  # every flagged run is reported, not just the first
                record = read_record(sheet_row["record"], sensors, sheet_row.get("channels"))
                if is_transient_row(sheet_row):  # a run-up or coast-down: its speed bands (data/transient.py)
                    tracked = track_record(record, sheet_row, harmonics, sensor.range_m)
                    analysed = summary_row(tracked, record.names)
                    rows.append(_carried(sheet_row, analysed) | analysed)
                    continue
                analysis = analyse_record(record, float(sheet_row["rpm"]), harmonics, sensor.range_m,
                                          min_revolutions, sensor.resolution_m, whirl)
            analysed = run_row(analysis, harmonics, complex_parts=False) | {"status": analysis.note}
            rows.append(_carried(sheet_row, analysed) | analysed)
        except DataError as err:
            errors[str(sheet_row["run"])] = str(err)
            analysed = {"status": f"invalid: {str(err).splitlines()[0]}", "usable": False}
            rows.append(_carried(sheet_row, analysed) | analysed)
    return pd.DataFrame(rows), errors


# --- nuisance-free comparison -----------------------------------------------------------


def fit_phase(measured: Array, model: Array, sigma: Array | None = None) -> float:
    """The per-run phase phi* minimising sum_{ch, h>=1} |X_h - M_h exp(i h phi)|^2 / sigma_h^2.

    measured, model: (..., H+1) complex (h = 0 ignored); sigma: same shape or
    None (unit weights). The misfit is const - 2 sum_h Re(c_h exp(i h phi)),
    c_h = sum_ch conj(X_h) M_h / sigma_h^2: maximised on a grid of 64 H phases,
    then refined by Newton's method on its derivative.
    """
    measured, model = np.atleast_2d(measured), np.atleast_2d(model)
    weight = 1.0 if sigma is None else 1.0 / np.atleast_2d(sigma) ** 2
    c = (np.conj(measured) * model * weight)[..., 1:].reshape(-1, measured.shape[-1] - 1).sum(0)
    h = np.arange(1, c.size + 1)

    def gain(phi: float | Array) -> Array:
        return (c[None, :] * np.exp(1j * np.outer(np.atleast_1d(phi), h))).real.sum(1)

    grid = np.linspace(0.0, 2 * np.pi, 64 * h.size, endpoint=False)
    phi = grid[np.argmax(gain(grid))]
    for _ in range(30):  # Newton on d gain / d phi = 0 from the best grid phase (quadratic convergence)
        rotated = c * np.exp(1j * h * phi)
        slope, curvature = -(h * rotated.imag).sum(), -(h**2 * rotated.real).sum()
        if curvature >= 0:  # not a maximum: keep the grid phase (degenerate, e.g. model = 0)
            break
        step = -slope / curvature
        phi += step
        if abs(step) < 1e-15:
            break
    return float(np.mod(phi, 2 * np.pi))


def phase_aligned_residuals(measured: Array, sigma: Array, model: Array) -> tuple[Array, float]:
    """Normalised residuals (X_h - M_h exp(i h phi*)) / sigma_h for h >= 1, real and imaginary parts.

    Invariant to the record's phase origin and DC offsets (module docstring):
    returns (residuals (..., 2H) flattened per channel, phi*).
    """
    phi = fit_phase(measured, model, sigma)
    h = np.arange(measured.shape[-1])
    aligned = model * np.exp(1j * h * phi)
    r = ((measured - aligned) / sigma)[..., 1:]
    return np.concatenate([r.real, r.imag], axis=-1), phi


def write_tsv(table: pd.DataFrame, path: str | Path) -> None:
    """TSV with enough digits for metres (the format of every preprocessing output); ``read_tsv`` reads it."""
    MEASURED.write(table, path)


def read_tsv(path: str | Path) -> pd.DataFrame | None:
    """A table written by ``write_tsv`` (a run's spectrum.tsv, a record's speed.tsv and runout.tsv); None for one
    written without columns (a record without a slow-roll runout). The harmonics tables have their own reader
    (``measured.read_harmonics``)."""
    if Path(path).stat().st_size <= 1:
        return None
    return MEASURED.read(path)


# --- check-data: the whole data set -----------------------------------------------------


def check_data(sheet: str | Path, harmonics: int = DEFAULT_HARMONICS, rpm_range: tuple[float, float] | None = None,
               mass_range_g: tuple[float, float] | None = None, sensor_range_m: float | None = None,
               min_revolutions: float = MIN_REVOLUTIONS, sensor_resolution_m: float | None = None,
               range_names: tuple[str, str] = ("--rpm-range", "--mass-range-g"), sensors=None, whirl=None
               ) -> tuple[pd.DataFrame, dict[str, str]]:
    """Validate a runs sheet and every record; (summary table, {run: error}).

    The sheet is read as the workflow reads it (``read_runs`` with every mass
    required) and must be valid, like its coverage (``check_coverage``): both
    raise ``DataError``; record problems are collected per run (``summarise_runs``). sensors: the machine
    whose sensors name the records' channels (``records.record_channels``; None: the VARM's x, y). whirl: the
    machine's model of the 1X whirl (``analyse_record``; ``config.whirl_model``).
    """
    runs = read_runs(sheet, require_mass=True)
    check_coverage(runs, rpm_range, mass_range_g, sheet, range_names)
    return summarise_runs(runs, harmonics, sensor_range_m, min_revolutions, sensor_resolution_m, sensors, whirl)


def has_usable_fit_run(summary: pd.DataFrame) -> bool:
    """Whether ``check_data``'s summary holds a usable run with role fit: without one nothing can be identified
    (check-data and the workflow's check_data stop)."""
    return bool((summary["usable"].astype(bool) & (summary["role"] == "fit")).any())


def format_summary(summary: pd.DataFrame, harmonics: int) -> str:
    """The check-data printout: one line per run (figures in mm), then the harmonic amplitudes."""
    sweeps = ""
    if "n_bands" in summary:  # run-ups and coast-downs: their own lines (data/transient.summary_row)
        rows = summary[summary["n_bands"].notna()]
        summary = summary[summary["n_bands"].isna()]
        sweeps = "\n\nrun-ups and coast-downs (speed bands, data/transient.py):\n" + pd.DataFrame({
            "run": rows["run"], "kind": rows["kind"], "rpm_low": rows["rpm_measured_low"].round(1),
            "rpm_high": rows["rpm_measured_high"].round(1), "revs": rows["n_revolutions"],
            "bands_usable": rows["n_bands_usable"].astype(int).astype(str) + "/" + rows["n_bands"].astype(int).astype(str),
            "status": rows["status"]}).to_string(index=False)
        if summary.empty:
            return sweeps.lstrip("\n")
    if "rpm_true" not in summary:
        return summary[["run", "rpm", "status"]].to_string(index=False) + sweeps
    mm = 1e3
    channels = table_channels(summary)
    view = pd.DataFrame({
        "run": summary["run"], "rpm": summary["rpm"], "rpm_true": summary["rpm_true"].round(2),
        "dev_%": (100 * summary["speed_deviation_rel"]).round(3), "samples": summary["n_samples"],
        "duration_s": summary["duration_s"].round(3), "fs_hz": summary["sample_rate_hz"].round(1),
        "revs": summary["n_revolutions"],
        **{f"noise_{c}_mm": (mm * summary[f"noise_{c}_m"]).round(4) for c in channels},
        **{f"offset_{c}_mm": (mm * summary[f"offset_{c}_m"]).round(4) for c in channels},
        "phase": summary["phase_reference"], "saturated": summary["saturated"], "status": summary["status"],
    })
    amplitudes = pd.DataFrame({"run": summary["run"]})
    for name in channels:
        for h in range(1, harmonics + 1):
            amplitudes[f"{harmonic_stem(name, h)}X_mm"] = (
                mm * summary[harmonic_column(name, h, "amp")]).map(lambda v: f"{v:.4f}")
    sigma = mm * summary[[harmonic_column(c, 1, "sigma") for c in channels]].max(axis=1)
    amplitudes["sigma_1X_mm"] = sigma.map(lambda v: f"{v:.1e}")
    return (view.to_string(index=False, na_rep="-") + "\n\nharmonic amplitudes, 0-peak [mm] (sigma_1X_mm: standard "
            "uncertainty of the 1X real/imaginary parts):\n" + amplitudes.to_string(index=False, na_rep="-") + sweeps)
