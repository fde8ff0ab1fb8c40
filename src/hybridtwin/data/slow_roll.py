"""Slow-roll compensation of an order table (``order_tracking``): the runout read at the lowest speeds and
subtracted as a vector from every window (docs/data-checks.md, "Transient records").

At slow roll the rotor barely responds: what a probe reads at 1X and 2X there is runout (mechanical: a bent or
eccentric journal; electrical: the probe track's conductivity), a vector fixed to the shaft that every speed
carries unchanged. ``runout`` estimates it per channel and harmonic from the windows of the slow-roll band and
``compensate`` subtracts it; ``slow_roll_compensation`` does both and can be switched off.

- **The band** holds what the estimate needs: MIN_WINDOWS (3) windows, i.e. MIN_WINDOWS times the windows'
  revolutions at the record's slowest speeds (18 revolutions with windows of 6), whatever share of the sweep
  that is; a fast sweep crosses many RPM in them (1200 RPM/min from 300 RPM: ~70 RPM). By default the band is
  the slowest windows up to the record's lowest window speed + BAND_FRACTION (10 %) of its speed span, or up to
  ``band_rpm``'s top when that is the sheet's default (``extend``), and in either case over as many of the next
  windows as it takes to hold MIN_WINDOWS. A band the user gave (the runs sheet's ``slowroll_rpm``) is taken as
  given. A record with fewer windows than that, or a given band holding fewer, is a ``TrackingError`` naming the
  file and the remedy (the ``slowroll_rpm`` the record would need, or a record longer at slow roll).
- **The estimate**: per channel and harmonic the weighted (1/sigma^2) least-squares fit a + b Omega^2 of the
  band's vectors (complex a, b); the runout is a, the vector at Omega -> 0, free of the dynamic response's
  leading Omega^2 part (an unbalance response grows as Omega^2 well below the first critical speed; a plain
  mean of the band would carry about half of it). Its sigma per part from the fit's covariance.
- **The check** that what is there is runout, not dynamics: the dynamic part at the band's top,
  |b| Omega_top^2, is flagged when it is both significant (above DYNAMIC_SIGMAS times its own sigma) and not
  small against the runout (above DYNAMIC_FRACTION of |a|): then the band reaches speeds where the rotor
  responds, the runout rests on the extrapolation, and a lower band (or a slower start) is better. Not flagged
  when either is small (a dynamic part within the noise says nothing; against a runout near zero any dynamic
  part is a large fraction). The flag names the probe and is emitted as a ``SlowRollWarning``.
- **The subtraction**: U_h - a from every window, sigma^2 + sigma_a^2 per part. The runout's own error is then
  common to every window of the record (a correlation between windows of sigma_a^2 / (sigma^2 + sigma_a^2); the
  table's attrs carry the runout table so the caller can weigh it).

The runout table (``RUNOUT_COLUMNS``): channel, harmonic, runout_re_m, runout_im_m, runout_amp_m,
runout_sigma_m (per part), band_rpm_low, band_rpm_high, n_windows, dynamic_m (|b| Omega_top^2), dynamic_sigma_m,
flagged (bool), note (the flag's message, or "").
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd

from .order_tracking import TrackingError, table_channels
from .record_columns import harmonic_column

#: the default band: up to the lowest window speed + this fraction of the record's speed span ...
BAND_FRACTION = 0.10
#: ... and at least this many windows
MIN_WINDOWS = 3
#: the runout's harmonics by default (1X and 2X)
RUNOUT_HARMONICS = (1, 2)
#: the dynamic part at the band's top is flagged above this fraction of |runout| ...
DYNAMIC_FRACTION = 0.10
#: ... when it is also above this many of its own sigmas
DYNAMIC_SIGMAS = 3.0
RUNOUT_COLUMNS = ["channel", "harmonic", "runout_re_m", "runout_im_m", "runout_amp_m", "runout_sigma_m",
                  "band_rpm_low", "band_rpm_high", "n_windows", "dynamic_m", "dynamic_sigma_m", "flagged", "note"]


class SlowRollWarning(UserWarning):
    """A slow-roll band whose response looks like dynamics, not runout (the message names the probe)."""


def _windows_remedy(table: pd.DataFrame, min_windows: int) -> str:
    """What the record would need: the ``slowroll_rpm`` that holds ``min_windows`` of its slowest windows, or a
    record longer at slow roll when it has fewer windows than that."""
    rpm = np.sort(table["rpm"].to_numpy(float))
    revolutions = table.attrs.get("revolutions", "?")
    if rpm.size >= min_windows:
        return (f"set the runs sheet's slowroll_rpm to at least {math.ceil(rpm[min_windows - 1] + 0.5):g} RPM (the "
                f"record's {min_windows} slowest windows of {revolutions} revolutions), or leave it empty for the "
                "default, which takes the windows the estimate needs")
    return (f"the estimate needs {min_windows} windows of {revolutions} revolutions at the slowest speeds: record "
            "longer at slow roll (start the run-up lower or hold its first speed, let the coast-down run out), or "
            "use the record with the slow-roll compensation off")


def slow_roll_band(table: pd.DataFrame, band_rpm: Sequence[float] | None = None,
                   min_windows: int = MIN_WINDOWS, extend: bool = False) -> np.ndarray:
    """The indexes (rows) of the windows of the slow-roll band (module docstring), or ``TrackingError``.

    band_rpm None: the default band (the slowest windows up to BAND_FRACTION of the span, at least
    ``min_windows``); ``extend`` True: ``band_rpm`` is a default too (the sheet's plan), extended to
    ``min_windows`` windows the same way; else ``band_rpm`` is the user's, taken as given."""
    path = table.attrs.get("path", "record")
    rpm = table["rpm"].to_numpy(float)
    if rpm.size < min_windows:
        raise TrackingError(f"{path}: {rpm.size} window(s) of {table.attrs.get('revolutions', '?')} revolutions, "
                            f"fewer than the {min_windows} a slow-roll band needs: the record is too short for "
                            f"the slow-roll compensation; {_windows_remedy(table, min_windows)}")
    if band_rpm is None or extend:
        top = rpm.min() + BAND_FRACTION * (rpm.max() - rpm.min()) if band_rpm is None else float(band_rpm[1])
        inside = np.flatnonzero(rpm <= top)
        if inside.size < min_windows:
            inside = np.argsort(rpm, kind="stable")[:min_windows]
        return np.sort(inside)
    low, high = (float(v) for v in band_rpm)
    if not low < high:
        raise ValueError(f"slow-roll band {list(band_rpm)} RPM is not [low, high] with low < high")
    inside = np.flatnonzero((rpm >= low) & (rpm <= high))
    if inside.size < min_windows:
        remedy = (_windows_remedy(table, min_windows) if low <= rpm.min() else
                  "the band misses the record's slowest speeds: lower its bottom to the record's")
        raise TrackingError(f"{path}: {inside.size} window(s) in the slow-roll band [{low:g}, {high:g}] RPM (the "
                            f"record's windows span {rpm.min():.1f}-{rpm.max():.1f} RPM), fewer than {min_windows}: "
                            f"{remedy}")
    return inside


def runout(table: pd.DataFrame, band_rpm: Sequence[float] | None = None,
           harmonics: Sequence[int] = RUNOUT_HARMONICS, min_windows: int = MIN_WINDOWS,
           mode: tuple[float, float] | None = None, extend: bool = False) -> pd.DataFrame:
    """The runout table of an order table (module docstring): one row per channel and harmonic; ``band_rpm`` and
    ``extend`` as ``slow_roll_band``'s.

    mode: (omega_n [rad/s], zeta) of the record's first resonance (``transient.one_mode_fit``), when known: the
    dynamic part's shape is then the one-mode response g_h = Omega^2 omega_n^2 / (omega_n^2 - (h Omega)^2 + 2 i zeta
    omega_n h Omega) instead of Omega^2. With Omega^2 alone the next term of the response, ~ Omega^4 / omega_n^2,
    leaks into the intercept: a band reaching a fifth of the critical speed with a 100 um response at its top
    puts ~1 um of the dynamics into the runout (measured on the run-up example's coast-down), an error common to
    every speed of the record."""
    path = table.attrs.get("path", "record")
    rows = table.iloc[slow_roll_band(table, band_rpm, min_windows, extend)]
    omega = 2 * np.pi * rows["rpm"].to_numpy(float) / 60.0
    low, high = float(rows["rpm"].min()), float(rows["rpm"].max())
    out = []
    for channel in table_channels(table):
        for h in harmonics:
            shape = omega**2 + 0j
            if mode is not None:
                wn, zeta = mode
                shape = omega**2 * wn**2 / (wn**2 - (h * omega) ** 2 + 2j * zeta * wn * h * omega)
            top = shape[np.argmax(np.abs(shape))]
            X = np.column_stack([np.ones_like(shape), shape / top])  # b scaled to the band's top: b' = b g_top
            U = (rows[harmonic_column(channel, h, "re")].to_numpy(float)
                 + 1j * rows[harmonic_column(channel, h, "im")].to_numpy(float))
            sigma = rows[harmonic_column(channel, h, "sigma")].to_numpy(float)
            w = 1.0 / sigma**2
            cov = np.linalg.inv(X.conj().T @ (w[:, None] * X))  # per part (X real without a mode: the same)
            a, dynamic = cov @ (X.conj().T @ (w * U))
            cov = cov.real
            sigma_a, sigma_dyn = np.sqrt(np.diag(cov))
            # |b'|: for a complex b' of per-part sigma s, its modulus has sigma ~ s (both parts' errors project)
            flagged = bool(abs(dynamic) > DYNAMIC_SIGMAS * sigma_dyn and abs(dynamic) > DYNAMIC_FRACTION * abs(a))
            note = ""
            if flagged:
                note = (f"{path}: probe {channel}, {h}X: the slow-roll band {low:.0f}-{high:.0f} RPM holds a dynamic "
                        f"response, {abs(dynamic) * 1e6:.3g} um at its top ({abs(dynamic) / sigma_dyn:.1f} sigma, "
                        f"{100 * abs(dynamic) / max(abs(a), 1e-300):.0f} % of the runout {abs(a) * 1e6:.3g} um): "
                        "not runout alone; the runout is its Omega -> 0 extrapolation (a lower band is safer)")
                warnings.warn(note, SlowRollWarning, stacklevel=2)
            out.append({"channel": channel, "harmonic": int(h), "runout_re_m": a.real, "runout_im_m": a.imag,
                        "runout_amp_m": abs(a), "runout_sigma_m": float(sigma_a), "band_rpm_low": low,
                        "band_rpm_high": high, "n_windows": int(len(rows)), "dynamic_m": abs(dynamic),
                        "dynamic_sigma_m": float(sigma_dyn), "flagged": flagged, "note": note})
    return pd.DataFrame(out, columns=RUNOUT_COLUMNS)


def compensate(table: pd.DataFrame, runout_table: pd.DataFrame) -> pd.DataFrame:
    """The order table less the runout: U_h - a for each row of ``runout_table``, sigma combined in quadrature,
    amplitude recomputed; other columns unchanged. attrs: the table's, plus ``runout`` (the runout table)."""
    out = table.copy()
    for row in runout_table.itertuples(index=False):
        re, im = harmonic_column(row.channel, row.harmonic, "re"), harmonic_column(row.channel, row.harmonic, "im")
        out[re] = table[re] - row.runout_re_m
        out[im] = table[im] - row.runout_im_m
        out[harmonic_column(row.channel, row.harmonic, "amp")] = np.hypot(out[re], out[im])
        sigma = harmonic_column(row.channel, row.harmonic, "sigma")
        out[sigma] = np.hypot(table[sigma], row.runout_sigma_m)
    out.attrs.update(table.attrs)
    out.attrs["runout"] = runout_table
    return out


def runout_sigma_column(channel: str, h: int) -> str:
    """The bands table's column of the runout's sigma [m] that ``compensate`` added in quadrature to channel
    ``channel``'s harmonic ``h`` (x1_runout_sigma_m): the identification models that part as one offset per record
    (``hybridtwin.identify.arrow_problem``, "runout offsets"), common to the record's bands, not as independent."""
    return harmonic_column(channel, h, "runout_sigma")


def with_runout_sigma(table: pd.DataFrame, runout_table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (a record's bands, already ``compensate``d) with one ``runout_sigma_column`` per row of
    ``runout_table``: the sigma its estimate added to every band, the same for all bands of the record."""
    out = table.copy()
    for row in runout_table.itertuples(index=False):
        out[runout_sigma_column(row.channel, row.harmonic)] = float(row.runout_sigma_m)
    out.attrs.update(table.attrs)
    return out


def slow_roll_compensation(table: pd.DataFrame, enabled: bool = True, band_rpm: Sequence[float] | None = None,
                           harmonics: Sequence[int] = RUNOUT_HARMONICS,
                           min_windows: int = MIN_WINDOWS) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the compensated order table, the runout table); ``enabled`` False: (the table unchanged, an empty runout
    table), nothing estimated or subtracted."""
    if not enabled:
        return table, pd.DataFrame(columns=RUNOUT_COLUMNS)
    found = runout(table, band_rpm, harmonics, min_windows)
    return compensate(table, found), found
