"""Order tracking of a transient record (a run-up or coast-down): the speed profile from the keyphasor and the
1X..HX vectors of every channel as functions of speed (docs/measurement-format.md, docs/data-checks.md).

**Speed profile** (``speed_profile``). The keyphasor's marks are its rising edges (``record_columns.
keyphasor_marks``: the first high sample of each pulse), and each mark's instant is that sample's time: the sample
where the once-per-turn mark passes (docs/measurement-format.md), as a steady run's phase origin reads it
(``preprocessing.phase_origin``), so that a steady run and a sweep of the same machine agree to the phase. A
keyphasor written on the sample nearest the mark is then within +-dt/2 of it, unbiased; one latched on the first
sample after the mark is late by dt/2 on average (a phase lag of h Omega dt / 2, 0.01 rad at 1000 RPM and 5 kHz).
Revolution k runs from mark k to mark k+1, its speed 60 / (t_{k+1} - t_k) RPM; the
shaft angle theta(t) is the monotone (PCHIP) interpolation of theta(t_k) = 2 pi k, so theta = 0 at the first
mark and every mark is a whole turn (the unbalance points to +x there). Refused, with a message naming the file
and the keyphasor's lines: a missed mark (a revolution MISSED_RATIO or more times the median of its neighbours,
~2x), a double mark (DOUBLE_RATIO or less, ~0.5x), a speed profile that reverses (a run-up that slows down, a
coast-down that speeds up, by more than REVERSAL_SIGMAS times the tracking noise over REVERSAL_SPAN revolutions),
fewer than MIN_REVOLUTIONS whole revolutions, no keyphasor.

**Order vectors** (``track_orders``, ``order_vectors``). The marks are cut into windows of N whole revolutions
(``revolutions``, default DEFAULT_REVOLUTIONS; why 6: ``benchmarks/order_tracking_window.py``), NOT overlapping:
each window's samples are its own, so the windows' noise is independent and each window is one independent
measurement of the vectors at its mean speed (no correlation between windows to carry into the weights; two
adjacent windows share only the keyphasor mark between them, whose timing error moves both phases by at most
1/(4 (N - 1/2)) of their phase-jitter variance: a correlation of 0.05 at N = 6, left out). Revolutions after the
last whole window, and samples before the first mark or after the last, are left out (``attrs``: left_out_s).
In each window every channel is fitted in least squares on [1, tau, cos(h theta), sin(h theta), h = 1..H]
(tau: time from the window's middle over its length, a linear drift), giving U_h = A_h - i B_h, so that
u(t) = Re(sum_h U_h exp(i h theta(t))) (0-peak amplitudes, the steady harmonics' convention), and its 1-sigma
uncertainty per part from that window's own residual (white noise: s^2 (X^T X)^-1, s^2 = RSS / (n - p)) plus the
keyphasor's timing noise (each mark within +-dt/2, ``SpeedProfile.sigma_t_s``) propagated through the fit
(``_jitter_variance``: the window-mean phase error turns U_h by h phi; the per-revolution scatter of the marks
leaks a strong order into its neighbours, a 1X of 125 um at a resonance into the 2X by ~0.5 um at 5 kHz; the
mean of the two parts' variances is the sigma). A vector that changes within the window (through a resonance)
leaks too, as a bias ~ its change / (pi N) into the neighbouring orders: the whiteness flag below marks such
windows, and N is the trade-off (``benchmarks/order_tracking_window.py``). The residual is
checked for content the model does not resolve (a line that is not an order, orders above H, coloured noise):
its variance against half the mean square of its first differences (both the noise variance for white noise);
a ratio above 1 + 5 sqrt(5 / n) (5 standard errors) sets ``unresolved_<c>``: the sigma of that window and
channel then understates the error.

The table (``order_columns``): t_start_s, t_end_s, rpm (the window's mean speed: N turns over its duration),
rpm_start, rpm_end (the profile's speed at its ends), n_rev, n_samples; then per channel c: noise_<c>_m (the
residual's standard deviation), noise_ratio_<c> (the whiteness ratio above), unresolved_<c> (bool),
offset_<c>_m (the mean level), drift_<c>_m (its change over the window); then per channel and harmonic h the
steady harmonics table's columns (``harmonic_column``): <c>h_re_m, <c>h_im_m, <c>h_amp_m, <c>h_sigma_m (x1_re_m;
x1_1_re_m for a channel x1). ``write_orders`` / ``read_orders`` store it as TSV and read it back exactly.

Imports numpy, scipy and pandas only: a record is anything with ``time_s``, ``keyphasor`` (marks or levels, or
None), ``channels`` ({name: (N,) [m]}), ``path`` and optionally ``line(index)`` (``records.Record``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

from .record_columns import harmonic_column
from ..solvers.solver import DEFAULT_HARMONICS  # the order vectors' default highest harmonic (the steady analysis's)
from ..tables import ORDERS
from scipy.interpolate import PchipInterpolator

Array = np.ndarray

#: windows of this many whole revolutions by default (benchmarks/order_tracking_window.py: the smallest
#: total error of the 1X through a resonance of a 300 -> 1000 RPM run-up, bias against noise)
DEFAULT_REVOLUTIONS = 6
#: fewest whole revolutions between the first and the last mark
MIN_REVOLUTIONS = 5
#: a revolution this many times the median of its neighbours holds a missed mark (two turns: ~2x) ...
MISSED_RATIO = 1.5
#: ... and this fraction of it or less a double mark (one turn cut in two: the shorter piece <= 0.5x)
DOUBLE_RATIO = 0.67
#: neighbours on each side whose median a revolution is judged against
NEIGHBOURS = 2
#: a run-up slowing (a coast-down speeding up) by more than this many sigmas of the tracking noise reverses ...
REVERSAL_SIGMAS = 5.0
#: ... judged on the mean speed over this many revolutions (the marks' timing noise shrinks as 1 / span)
REVERSAL_SPAN = 5
#: the whiteness ratio's threshold is 1 + UNRESOLVED_SIGMAS sqrt(5 / n) (its standard error for white noise
#: is about sqrt(5 / n): the two variance estimates' relative errors, sqrt(2 / n) and sqrt(3 / n))
UNRESOLVED_SIGMAS = 5.0
#: the marks' scatter replaces the quantisation's dt / sqrt(12) as their timing noise beyond this factor
JITTER_FACTOR = 2.0
_MAX_LISTED = 6


class TrackingError(ValueError):
    """A transient record whose keyphasor or speed profile cannot be tracked; the message names the file."""


def _lines(record, index: Array) -> Array:
    index = np.asarray(index, int)
    return record.line(index) if hasattr(record, "line") else index + 2


def _listed(what: str, items: list[str]) -> str:
    more = f" ... and {len(items) - _MAX_LISTED} more" if len(items) > _MAX_LISTED else ""
    return f"{what} ({len(items)}): {'; '.join(items[:_MAX_LISTED])}{more}"


# --- the speed profile ---------------------------------------------------------------------------


def mark_instants(time_s: Array, keyphasor: Array) -> tuple[Array, Array]:
    """(instants [s], sample index of each mark's first high sample) of a keyphasor.

    keyphasor: (N,) bool marks (True on the first high sample of each pulse, as ``Record.keyphasor``) or the
    two-level signal itself (numbers): its rising crossings of the half level between its lowest and highest
    value. Each instant is the time of the mark's first high sample (module docstring: the sample where the mark
    passes, the steady runs' convention). A mark on the record's first sample has no low sample before it (the
    record may start inside a pulse): it is not a mark."""
    t = np.asarray(time_s, float)
    kp = np.asarray(keyphasor)
    if kp.dtype == bool:
        index = np.flatnonzero(kp)
    else:
        level = kp.astype(float)
        high = level > 0.5 * (np.nanmin(level) + np.nanmax(level))
        index = np.flatnonzero(high[1:] & ~high[:-1]) + 1
    index = index[index > 0]
    return t[index], index


@dataclass(frozen=True)
class SpeedProfile:
    """A record's speed profile from its keyphasor marks (``speed_profile``).

    marks_s: (K+1,) the mark instants [s] (theta = 2 pi k there); index: (K+1,) each mark's first high sample;
    dt_s: the sampling step; sigma_t_s: the marks' timing noise [s] (the quantisation's dt / sqrt(12), or the
    scatter of the marks' 4th differences when it exceeds that JITTER_FACTOR times); direction: "runup" or
    "coastdown".
    """

    marks_s: Array
    index: Array
    dt_s: float
    sigma_t_s: float
    direction: str

    @property
    def n_revolutions(self) -> int:
        return int(self.marks_s.size - 1)

    @property
    def rpm(self) -> Array:
        """(K,) each revolution's mean speed [RPM]."""
        return 60.0 / np.diff(self.marks_s)

    @cached_property
    def _interpolant(self) -> PchipInterpolator:
        return PchipInterpolator(self.marks_s, 2 * np.pi * np.arange(self.marks_s.size), extrapolate=False)

    def theta(self, t: Array) -> Array:
        """The shaft angle [rad] at times t (NaN outside the first and last mark)."""
        return self._interpolant(np.asarray(t, float))

    def rpm_at(self, t: Array) -> Array:
        """The speed [RPM] at times t, the derivative of theta (NaN outside the marks)."""
        return self._interpolant.derivative()(np.asarray(t, float)) * 60.0 / (2 * np.pi)

    def table(self) -> pd.DataFrame:
        """One row per revolution: revolution, t_start_s, t_end_s, period_s, rpm."""
        return pd.DataFrame({"revolution": np.arange(self.n_revolutions), "t_start_s": self.marks_s[:-1],
                             "t_end_s": self.marks_s[1:], "period_s": np.diff(self.marks_s), "rpm": self.rpm})


def speed_profile(record, direction: str | None = None, min_revolutions: int = MIN_REVOLUTIONS) -> SpeedProfile:
    """The speed profile of a transient record from its keyphasor (module docstring), or ``TrackingError``.

    record: ``time_s``, ``keyphasor`` (marks or levels), ``path`` (and ``line`` for the messages); direction:
    "runup" or "coastdown" (the sheet's kind), None to take it from the record (its last revolution faster
    than its first: a run-up). Refused, naming the file: no keyphasor; fewer than ``min_revolutions`` whole
    revolutions; missed or double marks (each listed with its line and time); a record whose overall change
    contradicts ``direction``; a speed that reverses."""
    path = getattr(record, "path", "record")
    if record.keyphasor is None:
        raise TrackingError(f"{path}: no keyphasor column: a runup or coastdown record needs the once-per-turn "
                            "marks (column keyphasor) to track its speed and the orders' phases; the run is refused")
    t = np.asarray(record.time_s, float)
    dt = float(np.median(np.diff(t)))
    marks, index = mark_instants(t, record.keyphasor)
    n_rev = marks.size - 1
    if n_rev < min_revolutions:
        raise TrackingError(f"{path}: column keyphasor: {marks.size} mark(s), {max(n_rev, 0)} whole revolution(s) "
                            f"between the first and the last; order tracking needs at least {min_revolutions}")
    period = np.diff(marks)
    padded = np.concatenate([np.full(NEIGHBOURS, np.nan), period, np.full(NEIGHBOURS, np.nan)])
    neighbours = np.stack([padded[NEIGHBOURS + d:NEIGHBOURS + d + n_rev]
                           for d in range(-NEIGHBOURS, NEIGHBOURS + 1) if d != 0])
    ratio = period / np.nanmedian(neighbours, axis=0)
    problems = []
    for kind, bad, meaning in (("missed mark(s)", ratio >= MISSED_RATIO, "a mark not recorded"),
                               ("double mark(s)", ratio <= DOUBLE_RATIO, "two marks in one turn")):
        k = np.flatnonzero(bad)
        if k.size:
            items = [f"line {_lines(record, index[i])}-{_lines(record, index[i + 1])}, t = {marks[i]:.4f} s: "
                     f"{ratio[i]:.2f}x its neighbours" for i in k]
            problems.append(_listed(f"column keyphasor: {kind}, a revolution ~{2 if 'missed' in kind else 0.5}x "
                                    f"its neighbours ({meaning})", items))
    if problems:
        raise TrackingError(f"{path}: " + "; ".join(problems))
    second = marks[2:] - 2 * marks[1:-1] + marks[:-2]  # smooth speed change + the marks' timing noise (var 6 s^2)
    if second.size >= 5:
        rough = second[2:] - 2 * second[1:-1] + second[:-2]  # the smooth part removed (var 70 s^2)
        scatter = 1.4826 * float(np.median(np.abs(rough - np.median(rough)))) / np.sqrt(70.0)
    else:
        scatter = 0.0
    # the marks' own scatter counts when it clearly exceeds the quantisation's (jitter of the keyphasor itself):
    # the quantisation errors of a slowly changing period are a sawtooth in k, not independent, and their 4th
    # differences overstate dt / sqrt(12) by up to ~1.3 (measured on tests/swept_signals.py records)
    quantisation = dt / np.sqrt(12.0)
    sigma_t = scatter if scatter > JITTER_FACTOR * quantisation else quantisation
    rising = period[-1] < period[0]
    if direction is None:
        direction = "runup" if rising else "coastdown"
    elif direction not in ("runup", "coastdown"):
        raise ValueError(f"direction must be 'runup', 'coastdown' or None, got {direction!r}")
    rpm = 60.0 / period
    if rising != (direction == "runup") and abs(rpm[-1] - rpm[0]) > REVERSAL_SIGMAS * np.hypot(
            *(r * np.sqrt(2) * sigma_t / p for r, p in ((rpm[0], period[0]), (rpm[-1], period[-1])))):
        raise TrackingError(f"{path}: a {direction} that {'slows down' if direction == 'runup' else 'speeds up'} "
                            f"overall, from {rpm[0]:.1f} to {rpm[-1]:.1f} RPM (first and last revolution): the "
                            f"record is a {'coastdown' if direction == 'runup' else 'runup'}, or of another run")
    span = min(REVERSAL_SPAN, n_rev)
    duration = marks[span:] - marks[:-span]
    speed = 60.0 * span / duration
    sigma = speed * np.sqrt(2.0) * sigma_t / duration
    sign = 1.0 if direction == "runup" else -1.0
    best = np.maximum.accumulate(sign * speed)
    at_best = np.maximum.accumulate(np.where(sign * speed == best, np.arange(best.size), 0))  # where it was set
    drop = best - sign * speed
    limit = REVERSAL_SIGMAS * np.hypot(sigma, sigma[at_best])
    bad = np.flatnonzero(drop > limit)
    if bad.size:
        j = bad[np.argmax(drop[bad] / limit[bad])]
        i = at_best[j]
        raise TrackingError(
            f"{path}: the speed profile reverses: a {direction} that {'slows down' if sign > 0 else 'speeds up'} "
            f"from {speed[i]:.2f} RPM (revolutions from t = {marks[i]:.3f} s, line {_lines(record, index[i])}) to "
            f"{speed[j]:.2f} RPM (from t = {marks[j]:.3f} s, line {_lines(record, index[j])}), "
            f"{drop[j] / (limit[j] / REVERSAL_SIGMAS):.1f} times the tracking noise ({sigma[j]:.3g} RPM over "
            f"{span} revolutions); order tracking needs a monotone sweep")
    return SpeedProfile(marks, index, dt, float(sigma_t), direction)


# --- the order vectors ---------------------------------------------------------------------------


def order_columns(channels, harmonics: int = DEFAULT_HARMONICS) -> list[str]:
    """The columns of an order table (module docstring) for these channel names."""
    from_steady = harmonic_column
    out = ["t_start_s", "t_end_s", "rpm", "rpm_start", "rpm_end", "n_rev", "n_samples"]
    for c in channels:
        out += [f"noise_{c}_m", f"noise_ratio_{c}", f"unresolved_{c}", f"offset_{c}_m", f"drift_{c}_m"]
    for c in channels:
        for h in range(1, harmonics + 1):
            out += [from_steady(c, h, part) for part in ("re", "im", "amp", "sigma")]
    return out


def track_orders(record, harmonics: int = DEFAULT_HARMONICS, revolutions: int = DEFAULT_REVOLUTIONS,
                 direction: str | None = None) -> pd.DataFrame:
    """The order table of a transient record (module docstring): ``speed_profile`` then ``order_vectors``.
    ``attrs``: path, harmonics, revolutions, direction, sigma_t_s, left_out_s."""
    profile = speed_profile(record, direction, max(MIN_REVOLUTIONS, revolutions))
    return order_vectors(record.time_s, record.channels, profile, harmonics, revolutions,
                         getattr(record, "path", "record"))


def order_vectors(time_s: Array, channels: Mapping[str, Array], profile: SpeedProfile,
                  harmonics: int = DEFAULT_HARMONICS, revolutions: int = DEFAULT_REVOLUTIONS,
                  path="record") -> pd.DataFrame:
    """One row per window of ``revolutions`` whole revolutions (module docstring); channels {name: (N,) [m]}."""
    if revolutions < 1 or harmonics < 1:
        raise ValueError(f"revolutions ({revolutions}) and harmonics ({harmonics}) must be >= 1")
    t = np.asarray(time_s, float)
    names = list(channels)
    data = np.column_stack([np.asarray(channels[c], float) for c in names])
    n_win = profile.n_revolutions // revolutions
    if n_win < 1:
        raise TrackingError(f"{path}: {profile.n_revolutions} whole revolution(s), fewer than one window of "
                            f"{revolutions}")
    bounds = profile.marks_s[::revolutions][:n_win + 1]
    first, last = np.searchsorted(t, [bounds[0], bounds[-1]])
    theta = np.full(t.size, np.nan)
    theta[first:last] = profile.theta(t[first:last])
    z = np.exp(1j * theta[first:last])
    powers = np.empty((harmonics, last - first), complex)
    powers[0] = z
    for h in range(1, harmonics):
        powers[h] = powers[h - 1] * z
    p = 2 + 2 * harmonics
    rows = []
    for w in range(n_win):
        a, b = bounds[w], bounds[w + 1]
        i0, i1 = np.searchsorted(t, [a, b])
        n = i1 - i0
        if n <= p + 2:
            raise TrackingError(f"{path}: window {a:.3f}-{b:.3f} s holds {n} samples, too few for {harmonics} "
                                f"harmonics (sampling too slow for {60 * revolutions / (b - a):.0f} RPM)")
        X = np.empty((n, p))
        X[:, 0] = 1.0
        X[:, 1] = (t[i0:i1] - 0.5 * (a + b)) / (b - a)
        block = powers[:, i0 - first:i1 - first]
        X[:, 2::2], X[:, 3::2] = block.real.T, block.imag.T
        Y = data[i0:i1]
        # normal equations: the columns are O(1) and nearly orthogonal over whole turns (X^T X ~ n diag(1, 1/12,
        # 1/2, ...)), so nothing is lost against an SVD, which took 100 times longer
        inverse = np.linalg.inv(X.T @ X)
        coef = inverse @ (X.T @ Y)
        residual = Y - X @ coef
        dof = n - p
        s2 = (residual**2).sum(0) / dof
        diag = np.diag(inverse)
        rpm = 60.0 * revolutions / (b - a)
        jitter = _jitter_variance(t[i0:i1], X, coef, inverse, profile, w * revolutions, revolutions, harmonics)
        diff2 = (np.diff(residual, axis=0) ** 2).mean(0) / 2.0
        ratio = residual.var(0) / np.where(diff2 > 0, diff2, np.inf)
        threshold = 1.0 + UNRESOLVED_SIGMAS * np.sqrt(5.0 / n)
        row = {"t_start_s": a, "t_end_s": b, "rpm": rpm, "rpm_start": float(profile.rpm_at(a)),
               "rpm_end": float(profile.rpm_at(b)), "n_rev": revolutions, "n_samples": n}
        for i, c in enumerate(names):
            row[f"noise_{c}_m"] = float(np.sqrt(s2[i]))
            row[f"noise_ratio_{c}"] = float(ratio[i])
            row[f"unresolved_{c}"] = bool(ratio[i] > threshold)
            row[f"offset_{c}_m"] = float(coef[0, i])
            row[f"drift_{c}_m"] = float(coef[1, i])
        for i, c in enumerate(names):
            for h in range(1, harmonics + 1):
                A, B = coef[2 * h, i], coef[2 * h + 1, i]
                U = complex(A, -B)
                var = s2[i] * 0.5 * (diag[2 * h] + diag[2 * h + 1]) + 0.5 * (jitter[i, 2 * h] + jitter[i, 2 * h + 1])
                row[harmonic_column(c, h, "re")], row[harmonic_column(c, h, "im")] = U.real, U.imag
                row[harmonic_column(c, h, "amp")] = abs(U)
                row[harmonic_column(c, h, "sigma")] = float(np.sqrt(var))
        rows.append(row)
    table = pd.DataFrame(rows, columns=order_columns(names, harmonics))
    left_out = (profile.marks_s[-1] - bounds[-1]) + (profile.marks_s[0] - t[0]) + (t[-1] - profile.marks_s[-1])
    table.attrs.update(path=str(path), harmonics=harmonics, revolutions=revolutions, direction=profile.direction,
                       sigma_t_s=profile.sigma_t_s, left_out_s=float(left_out))
    return table


def _jitter_variance(t: Array, X: Array, coef: Array, inverse: Array, profile: SpeedProfile, first: int,
                     revolutions: int, harmonics: int) -> Array:
    """(C, p) variance of each fitted coefficient from the keyphasor's timing noise (module docstring).

    A mark off by e_k [s] puts theta off by phi_k = Omega_k e_k there, and between the marks by their
    interpolation (linear: the hat functions of the window's N + 1 marks, PCHIP's response to small knot
    shifts to first order); the channel then reads f(theta - phi) ~ f(theta) - f'(theta) phi, f' the fitted
    waveform's derivative, and the fit's coefficients move by (X^T X)^-1 X^T (f' phi): the window-mean phase
    error turns U_h by h phi, and the per-revolution scatter of phi leaks a strong order into its neighbours
    (a 1X at a resonance into the 2X). Variance: sigma_t^2 sum_k (M Omega_k)^2, M = (X^T X)^-1 X^T diag(f') B."""
    knots = profile.marks_s[first:first + revolutions + 1]
    omega = 2 * np.pi / np.diff(profile.marks_s[first:first + revolutions + 1])
    omega_k = np.concatenate([[omega[0]], 0.5 * (omega[1:] + omega[:-1]), [omega[-1]]])
    seg = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, revolutions - 1)
    lam = (t - knots[seg]) / (knots[seg + 1] - knots[seg])
    out = np.empty((coef.shape[1], X.shape[1]))
    for i in range(coef.shape[1]):
        h = np.arange(1, harmonics + 1)
        slope = X[:, 2::2] @ (h * coef[3::2, i]) - X[:, 3::2] @ (h * coef[2::2, i])  # f'(theta)
        B = np.zeros((t.size, revolutions + 1))
        rows = np.arange(t.size)
        B[rows, seg], B[rows, seg + 1] = slope * (1 - lam), slope * lam
        M = inverse @ (X.T @ B) * omega_k  # (p, N + 1)
        out[i] = profile.sigma_t_s**2 * (M**2).sum(1)
    return out


def order_vector(table: pd.DataFrame, channel: str, h: int) -> tuple[Array, Array]:
    """(U_h complex (W,), sigma per part (W,)) of one channel and harmonic from an order table."""
    re, im = table[harmonic_column(channel, h, "re")], table[harmonic_column(channel, h, "im")]
    return re.to_numpy(float) + 1j * im.to_numpy(float), table[harmonic_column(channel, h, "sigma")].to_numpy(float)


def table_channels(table: pd.DataFrame) -> list[str]:
    """The channels of an order table, in order (those with a noise_<c>_m and a noise_ratio_<c> column)."""
    return [c[len("noise_ratio_"):] for c in table.columns if c.startswith("noise_ratio_")]


# --- on disk ---------------------------------------------------------------------------------------


def write_orders(table: pd.DataFrame, path: str | Path) -> None:
    """An order table as TSV (every float to its shortest exact repr; ``read_orders`` reads it back exactly)."""
    ORDERS.write(table, path)


def read_orders(path: str | Path) -> pd.DataFrame:
    """An order table written by ``write_orders``: the same columns, values and dtypes (bool flags, int counts)."""
    table = ORDERS.read(path, engine="python")  # the python parser reads floats exactly
    for c in table.columns:
        if c.startswith("unresolved_"):
            table[c] = table[c].astype(bool)
    return table
