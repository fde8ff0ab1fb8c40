"""Transient records (run-ups and coast-downs) as speed bands: what the rest of the method reads (issue 38).

A runs-sheet row of kind ``runup`` or ``coastdown`` is one record through a speed range, with a keyphasor
(docs/measurement-format.md). The twin compares it with the model along the sweep, quasi-steadily: the sweep is
cut into speed **bands** of ``band_rpm`` (a sheet column, default DEFAULT_BAND_RPM), and each band becomes a
*pseudo-run*, a row of the harmonics table like a steady run's, at the band's measured mean speed. Everything
downstream (libraries, identification, validation, diagnosis, report) then reads a band as it reads a run; the
model's response at a band is the steady state reached by continuation, as the rotor reaches it along the sweep.

- **Bands are known from the sheet alone** (``expand_bands``): ids ``<run>_b<centre RPM>``, centres from the top
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
- **Slow-roll runout** (``slowroll_runout``): in the slow-roll band (the lowest speeds of the record, below
  ``slowroll_rpm``, default the lowest SLOWROLL_SHARE of the sweep's span) the 1X and 2X vectors are runout (a
  mechanical or electrical mark on the shaft, turning with it, of constant size) plus the dynamic response, which
  at low speed grows as Omega^2. Fitting R + b (Omega / Omega_top)^2 separates them; the b term is kept only where
  it is significant (beyond 3 sigma: then the band holds dynamics, reported per probe), and R is subtracted as a
  vector from every band's 1X and 2X, its uncertainty added to theirs in quadrature. Off with ``slowroll`` False.

SI inside; rpm at the boundary. Conventions as everywhere: u(t) = Re(sum_h U_h exp(i h theta)), 0-peak.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.interpolate import PchipInterpolator

from .measurements import DataError, Record
from .record_columns import keyphasor_marks

Array = np.ndarray

KINDS = ("steady", "runup", "coastdown")
TRANSIENT_KINDS = ("runup", "coastdown")
#: speed band of a pseudo-run [RPM] unless the sheet's band_rpm says otherwise: narrow enough that the response
#: changes nearly linearly across it (the VARM's resonance is ~36 RPM wide at half power; the band fit carries a
#: linear term), wide enough to hold >= MIN_BAND_REVOLUTIONS at the sweep rates of a rig (10-20 RPM/s)
DEFAULT_BAND_RPM = 20.0
#: the slow-roll band, unless the sheet's slowroll_rpm gives its top: the lowest 10 % of the sweep's span
SLOWROLL_SHARE = 0.1
#: fewest whole revolutions a band (or the slow-roll band) must hold to be fitted
MIN_BAND_REVOLUTIONS = 5
#: fewest keyphasor marks a transient record must hold
MIN_MARKS = 20
#: a revolution this much longer (shorter) than its neighbours' median is a missed (double) mark
MISSED_MARK, DOUBLE_MARK = 1.6, 0.625
#: runout harmonics (1X, 2X): what a mark on the shaft writes, turning with it
RUNOUT_HARMONICS = (1, 2)


def is_transient(row: Mapping) -> bool:
    """Whether a runs-sheet row is a run-up or coast-down (its ``kind``; steady when absent or empty)."""
    kind = row.get("kind", "steady")
    return isinstance(kind, str) and kind.strip().lower() in TRANSIENT_KINDS


def _number(row: Mapping, key: str, default: float) -> float:
    value = row.get(key, default)
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return default if math.isnan(value) else value


@dataclass(frozen=True)
class BandPlan:
    """A transient row's speed bands [RPM]: the slow-roll band and the fitted bands (lo, hi) in rising order."""

    run: str
    slowroll: tuple[float, float]
    bands: tuple[tuple[float, float], ...]

    @staticmethod
    def band_id(run: str, lo: float, hi: float) -> str:
        return f"{run}_b{int(round(0.5 * (lo + hi))):04d}"

    @property
    def ids(self) -> list[str]:
        return [self.band_id(self.run, lo, hi) for lo, hi in self.bands]

    @classmethod
    def of(cls, row: Mapping) -> "BandPlan":
        """From a transient row: rpm_start, rpm_end, and optionally band_rpm and slowroll_rpm."""
        start, end = _number(row, "rpm_start", math.nan), _number(row, "rpm_end", math.nan)
        lo, hi = min(start, end), max(start, end)
        width = _number(row, "band_rpm", DEFAULT_BAND_RPM)
        top = _number(row, "slowroll_rpm", lo + SLOWROLL_SHARE * (hi - lo))
        if not (math.isfinite(lo) and hi > lo and width > 0 and lo <= top < hi):
            raise ValueError(f"run {row.get('run')}: no speed bands in rpm_start {start}, rpm_end {end}, "
                             f"band_rpm {width}, slowroll_rpm {top}")
        n = int(math.floor((hi - top) / width + 1e-9))
        bands = tuple((top + k * width, top + (k + 1) * width) for k in range(n))
        return cls(str(row["run"]), (lo, top), bands)


def expand_bands(sheet: pd.DataFrame) -> pd.DataFrame:
    """The runs the workflow plans: steady rows as they are, each transient row replaced by its speed bands.

    A band row keeps the sheet row's columns (mass, role, path, record, extras), with ``run`` its id, ``rpm`` its
    centre, and ``parent_run``, ``band_lo_rpm``, ``band_hi_rpm`` added; steady rows get empty ones. A band id
    that is also a run of the sheet is an error."""
    if "kind" not in sheet or not sheet.apply(is_transient, axis=1).any():
        return sheet
    rows = []
    for _, row in sheet.iterrows():
        row = row.to_dict()
        if not is_transient(row):
            rows.append(row | {"parent_run": "", "band_lo_rpm": math.nan, "band_hi_rpm": math.nan})
            continue
        plan = BandPlan.of(row)
        for (lo, hi), run in zip(plan.bands, plan.ids):
            rows.append(row | {"run": run, "rpm": 0.5 * (lo + hi), "parent_run": row["run"], "band_lo_rpm": lo,
                               "band_hi_rpm": hi})
    out = pd.DataFrame(rows)
    clash = sorted(set(out["run"][out["parent_run"] != ""]) & set(sheet["run"]))
    if clash:
        raise DataError(f"run(s) {clash} of the runs sheet have the id of a transient record's speed band "
                        "(<run>_b<RPM>): rename them")
    out.attrs = dict(sheet.attrs)
    return out


# --- the speed profile ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SpeedProfile:
    """theta(t) and Omega(t) of a record from its keyphasor: marks (K,) [s], revolutions' mean rpm (K-1,),
    theta (N,) [rad] and omega (N,) [rad/s] at the record's samples (NaN outside the first and last mark)."""

    marks_s: Array
    rev_rpm: Array
    theta: Array
    omega: Array

    @property
    def rev_mid_s(self) -> Array:
        return 0.5 * (self.marks_s[1:] + self.marks_s[:-1])


def speed_profile(record: Record, kind: str) -> SpeedProfile:
    """The speed profile of a transient record from its keyphasor (module docstring), checked."""
    where = str(record.path)
    if record.keyphasor is None:
        raise DataError(f"{where}: a {kind} record needs a keyphasor column (the speed and the phase come from it); "
                        "add it, or give the row kind steady if the speed is constant")
    marks = np.flatnonzero(keyphasor_marks(record.keyphasor))
    if marks.size < MIN_MARKS:
        raise DataError(f"{where}: only {marks.size} keyphasor marks; a {kind} record needs at least {MIN_MARKS}")
    t = record.time_s[marks]
    period = np.diff(t)
    # a revolution against its neighbours (median of 7 around it): a missed mark doubles one, a double halves it
    ref = pd.Series(period).rolling(7, center=True, min_periods=1).median().to_numpy()
    lines = record.lines if record.lines is not None else np.arange(record.time_s.size) + 2
    for test, word in ((period > MISSED_MARK * ref, "a missed keyphasor mark (a revolution ~2x its neighbours)"),
                       (period < DOUBLE_MARK * ref, "a double keyphasor mark (a revolution ~1/2 its neighbours)")):
        if test.any():
            k = np.flatnonzero(test)
            at = ", ".join(f"lines {lines[marks[i]]}-{lines[marks[i + 1]]}" for i in k[:3])
            raise DataError(f"{where}: {word} at {at}{' ...' if k.size > 3 else ''} ({k.size} in all)")
    rpm = 60.0 / period
    smooth = pd.Series(rpm).rolling(9, center=True, min_periods=1).median().to_numpy()
    rising = kind == "runup"
    drift = np.maximum.accumulate(smooth) - smooth if rising else smooth - np.minimum.accumulate(smooth)
    span = smooth.max() - smooth.min()
    if drift.max() > max(0.02 * span, 2.0):
        i = int(np.argmax(drift))
        raise DataError(f"{where}: the speed profile reverses: a {kind} whose speed {'falls' if rising else 'rises'} "
                        f"by {drift.max():.1f} RPM (to {smooth[i]:.1f} RPM at t = {t[i]:.2f} s)")
    theta_at = PchipInterpolator(t, 2.0 * np.pi * np.arange(t.size))
    inside = (record.time_s >= t[0]) & (record.time_s <= t[-1])
    theta = np.full(record.time_s.shape, np.nan)
    omega = np.full(record.time_s.shape, np.nan)
    theta[inside] = theta_at(record.time_s[inside])
    omega[inside] = theta_at.derivative()(record.time_s[inside])
    return SpeedProfile(t, rpm, theta, omega)


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
    revs = np.flatnonzero((profile.rev_rpm >= lo) & (profile.rev_rpm < hi))
    if revs.size == 0:
        return np.zeros(time_s.shape, bool), 0
    starts, stops = profile.marks_s[revs], profile.marks_s[revs + 1]
    k = np.searchsorted(starts, time_s, side="right") - 1
    take = (k >= 0) & (time_s < stops[np.clip(k, 0, None)])
    return take, int(revs.size)


def fit_band(data: Array, time_s: Array, profile: SpeedProfile, take: Array, harmonics: int,
             speed_order: int = 2) -> BandFit:
    """Least-squares harmonics of the samples ``take`` of ``data`` (N, C) [m] (module docstring)."""
    t, theta, omega, y = time_s[take], profile.theta[take], profile.omega[take], data[take]
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
    rpm = 30.0 * omega / np.pi
    slope = np.polyfit(t - t.mean(), rpm, 1)[0] if t.size > 2 else math.nan
    return BandFit(X, sigma, noise, float(rpm.mean()), float(rpm.std() / math.sqrt(max(t.size, 1))), float(slope),
                   0, int(t.size), float(t[0]), float(t[-1]))


@dataclass(frozen=True)
class Runout:
    """Slow-roll runout per channel: R (C, 2) complex [m] for 1X and 2X, its sigma (C, 2), the dynamic part at the
    band's top speed D (C, 2) complex [m] (0 where not significant), the band [RPM] and its revolutions."""

    R: Array
    sigma: Array
    dynamic: Array
    band_rpm: tuple[float, float]
    n_revolutions: int

    def table(self, channels: Sequence[str]) -> pd.DataFrame:
        rows = []
        for i, name in enumerate(channels):
            for j, hh in enumerate(RUNOUT_HARMONICS):
                rows.append({"channel": name, "harmonic": hh, "runout_re_m": self.R[i, j].real,
                             "runout_im_m": self.R[i, j].imag, "runout_amp_m": abs(self.R[i, j]),
                             "runout_sigma_m": self.sigma[i, j], "dynamic_amp_m": abs(self.dynamic[i, j]),
                             "band_lo_rpm": self.band_rpm[0], "band_hi_rpm": self.band_rpm[1],
                             "n_revolutions": self.n_revolutions})
        return pd.DataFrame(rows)


def slowroll_runout(data: Array, time_s: Array, profile: SpeedProfile, band: tuple[float, float],
                    harmonics: int, where: str) -> Runout:
    """The runout vector in the slow-roll band (module docstring): R + b (Omega / Omega_top)^2 per 1X and 2X, the
    b term kept where it is significant."""
    lo = min(band[0], float(profile.rev_rpm.min())) - 1e-9
    take, n_rev = _revolution_samples(profile, time_s, lo, band[1])
    if n_rev < MIN_BAND_REVOLUTIONS:
        raise DataError(f"{where}: the slow-roll band (below {band[1]:.0f} RPM) holds {n_rev} whole revolution(s); "
                        f"at least {MIN_BAND_REVOLUTIONS} are needed (a record shorter than its slow-roll band?); "
                        "set slowroll_rpm in the runs sheet, or record from a lower speed")
    t, theta, omega, y = time_s[take], profile.theta[take], profile.omega[take], data[take]
    q = (omega / omega.max()) ** 2
    h = np.arange(1, harmonics + 1)
    c, s = np.cos(np.outer(theta, h)), np.sin(np.outer(theta, h))
    n_run = len(RUNOUT_HARMONICS)
    tau = (t - t.mean()) / max(np.ptp(t), 1e-12)
    base = [np.ones_like(t), tau, c, s]
    dyn = [q[:, None] * c[:, :n_run], q[:, None] * s[:, :n_run]]
    C = y.shape[1]
    R, sig, D = (np.zeros((C, n_run), complex), np.zeros((C, n_run)), np.zeros((C, n_run), complex))
    for i in range(C):
        for with_dynamics in (True, False):
            A = np.column_stack(base + (dyn if with_dynamics else []))
            coef, *_ = np.linalg.lstsq(A, y[:, i], rcond=None)
            dof = max(A.shape[0] - A.shape[1], 1)
            noise = math.sqrt(float(np.sum((y[:, i] - A @ coef) ** 2)) / dof)
            err = noise * np.sqrt(np.diag(np.linalg.pinv(A.T @ A)))
            H = harmonics
            Rc = coef[2:2 + n_run] - 1j * coef[2 + H:2 + H + n_run]
            Rs = np.sqrt(0.5 * (err[2:2 + n_run] ** 2 + err[2 + H:2 + H + n_run] ** 2))
            if with_dynamics:
                k = 2 + 2 * H
                Dc = coef[k:k + n_run] - 1j * coef[k + n_run:k + 2 * n_run]
                Ds = np.sqrt(0.5 * (err[k:k + n_run] ** 2 + err[k + n_run:k + 2 * n_run] ** 2))
                if np.any(np.abs(Dc) > 3.0 * Ds):  # dynamics in the band: keep the Omega^2 term
                    R[i], sig[i], D[i] = Rc, Rs, np.where(np.abs(Dc) > 3.0 * Ds, Dc, 0.0)
                    break
            else:
                R[i], sig[i] = Rc, Rs
    return Runout(R, sig, D, (float(band[0]), float(band[1])), n_rev)


# --- a transient record as rows of the harmonics table --------------------------------------------------------


@dataclass(frozen=True)
class TrackedRecord:
    """A transient record analysed: one row per speed band (``bands``: the harmonics table's columns, as a steady
    run's ``preprocessing.run_row`` with the sheet's columns carried), the runout removed (``runout``, None when
    off) and the per-revolution speed (``speed``: t_s, rpm)."""

    bands: pd.DataFrame
    runout: Runout | None
    speed: pd.DataFrame


def band_row(fit: BandFit | None, names: Sequence[str], harmonics: int, note: str, sample_rate_hz: float,
             unit: str) -> dict:
    """A band's row in the columns of ``preprocessing.run_row`` (NaN where not fitted), plus the band's own."""
    from .preprocessing import harmonic_column

    nan = math.nan
    row = {"n_samples": fit.n_samples if fit else 0,
           "duration_s": (fit.t_end_s - fit.t_start_s) if fit else nan, "sample_rate_hz": sample_rate_hz,
           "unit": unit, "keyphasor": True, "rpm_true": fit.rpm if fit else nan,
           "rpm_true_sigma": fit.rpm_sigma if fit else nan, "speed_deviation_rel": nan,
           "rpm_keyphasor": fit.rpm if fit else nan, "phase_reference": "keyphasor" if fit else "",
           "phase_origin_s": fit.t_start_s if fit else nan,
           # the marks are sample instants: their timing error is uniform over a sample (dt / sqrt(12))
           "phase_origin_sigma_s": 1.0 / (sample_rate_hz * math.sqrt(12.0)), "n_revolutions": fit.n_revolutions if fit
           else 0}
    for i, name in enumerate(names):
        row[f"noise_{name}_m"] = fit.noise[i] if fit else nan
    for i, name in enumerate(names):
        row[f"offset_{name}_m"] = fit.X[i, 0].real if fit else nan
        row[f"offset_{name}_sigma_m"] = fit.sigma[i, 0] if fit else nan
    for i, name in enumerate(names):
        for h in range(1, harmonics + 1):
            X = fit.X[i, h] if fit else complex(nan, nan)
            row[harmonic_column(name, h, "re")], row[harmonic_column(name, h, "im")] = X.real, X.imag
            row[harmonic_column(name, h, "amp")] = abs(X)
            row[harmonic_column(name, h, "sigma")] = fit.sigma[i, h] if fit else nan
    usable = fit is not None and note == "ok"
    row |= {"flat": False, "saturated": note.startswith("clipped"), "usable": usable, "note": note,
            "flags": "" if usable else note.split(":")[0].replace(" ", "_"),
            "t_start_s": fit.t_start_s if fit else nan, "t_end_s": fit.t_end_s if fit else nan,
            "sweep_rpm_per_s": fit.sweep_rpm_s if fit else nan}
    return row


def track_record(record: Record, sheet_row: Mapping, harmonics: int, sensor_range_m: float | None = None,
                 slowroll: bool = True) -> TrackedRecord:
    """A transient sheet row's record -> its bands' rows (module docstring); ``DataError`` for a record that
    cannot be tracked (no keyphasor, missed or double marks, reversal, too short for its slow-roll band, a sweep
    that never leaves one speed)."""
    from .preprocessing import _carried

    kind = str(sheet_row.get("kind", "")).strip().lower()
    where = str(record.path)
    plan = BandPlan.of(sheet_row)
    profile = speed_profile(record, kind)
    names = record.names
    data = np.column_stack([record.channels[n] for n in names])
    span = float(np.ptp(profile.rev_rpm))
    nominal = plan.bands[-1][1] - plan.slowroll[0]
    if span < 0.1 * nominal:
        raise DataError(f"{where}: the sweep never leaves one speed: the keyphasor gives {profile.rev_rpm.min():.1f}-"
                        f"{profile.rev_rpm.max():.1f} RPM, against the sheet's {sheet_row.get('rpm_start')}-"
                        f"{sheet_row.get('rpm_end')}; is this a steady run (kind steady)?")
    runout = slowroll_runout(data, record.time_s, profile, plan.slowroll, harmonics, where) if slowroll else None
    clipped = np.zeros(record.time_s.shape, bool)
    if sensor_range_m:
        clipped = np.any(np.abs(data) >= 0.999 * sensor_range_m, axis=1)
    rows = []
    for (lo, hi), run in zip(plan.bands, plan.ids):
        take, n_rev = _revolution_samples(profile, record.time_s, lo, hi)
        fit, note = None, "ok"
        if n_rev < MIN_BAND_REVOLUTIONS:
            reached = profile.rev_rpm.min() <= hi and profile.rev_rpm.max() >= lo
            note = (f"only {n_rev} whole revolution(s) in {lo:.0f}-{hi:.0f} RPM (at least {MIN_BAND_REVOLUTIONS}): "
                    "the sweep is too fast for its bands; widen band_rpm" if reached else
                    f"not reached: the record's speed spans {profile.rev_rpm.min():.0f}-"
                    f"{profile.rev_rpm.max():.0f} RPM")
        else:
            fit = fit_band(data, record.time_s, profile, take, harmonics)
            fit = BandFit(**{**fit.__dict__, "n_revolutions": n_rev})
            if runout is not None:
                for j, h in enumerate(RUNOUT_HARMONICS):
                    if h <= harmonics:
                        fit.X[:, h] -= runout.R[:, j]
                        fit.sigma[:, h] = np.hypot(fit.sigma[:, h], runout.sigma[:, j])
            if clipped[take].any():
                note = f"clipped: {int(clipped[take].sum())} sample(s) at the sensor's range in this band"
        analysed = band_row(fit, names, harmonics, note, record.sample_rate_hz, record.unit)
        carried = {k: v for k, v in sheet_row.items() if k not in ("record",)}
        base = _carried(carried | {"run": run, "rpm": 0.5 * (lo + hi)}, analysed)
        rows.append(base | {"parent_run": sheet_row["run"], "band_lo_rpm": lo, "band_hi_rpm": hi,
                            "slowroll_compensated": runout is not None} | analysed)
    speed = pd.DataFrame({"t_s": profile.rev_mid_s, "rpm": profile.rev_rpm})
    return TrackedRecord(pd.DataFrame(rows), runout, speed)
