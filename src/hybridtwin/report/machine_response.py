"""A machine's unbalance response before any data, and what API 684 reads off it (``hybridtwin response``).

``unbalance_response(model, values, rpm)``: the sensor harmonics of ``model`` at one parameter set along a run-up
and a run-down over ``rpm`` (harmonic balance by continuation, ``continuation.solve_sweep``; every step's
stability by Floquet), on a grid made fine around each linear critical speed so that the resonance peaks and
their half-power points are resolved. The table has the form of the report's dense response
(``response_plots.columns``: one row per sweep, speed and harmonic, two columns per sensor channel, stable,
branch), so ``response_plots.write_dense`` / ``read_dense`` write and read it back exactly.

``amplification_factors(table)``: every resonance peak of each channel's 1X amplitude, with its half-power points
N1 < N_c < N2 (where the amplitude is the peak's / sqrt 2) and the amplification factor AF = N_c / (N2 - N1)
(API 684's half-power method; ~ 1 / (2 zeta) for a lightly damped mode).

``separation_margins(peaks, operating)``: each peak's separation margin from an operating speed range and the
margin API 617 requires for its AF (ROSS's report computes the same: below the range (N_min - N_c) / N_c, above it
(N_c - N_max) / N_max; required none for AF < 2.5, else min(16, 17 (1 - 1 / (AF - 1.5))) % below the range and
min(26, 10 + 17 (1 - 1 / (AF - 1.5))) % above it).

``bode_figure`` and ``polar_figure``: the response of every channel (Bode: amplitude and phase vs speed; polar),
run-up solid, run-down dashed, unstable stretches dotted, the peaks and their half-power points marked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt  # no backend forced: Agg by itself without a display, or the caller's choice
import numpy as np
import pandas as pd

from .. import tables
from ..model.model import Model, campbell
from ..model.sensor import sensor_channels, sensor_names
from ..solvers.continuation import solve_sweep
from . import machine_plots as mp
from .response_plots import SWEEPS, response_curve, bode_axes, channels_of, columns

Array = np.ndarray
MICRO = 1e6
#: around each linear critical speed c (damping ratio zeta), the sweep's step is at most zeta c / STEPS_PER_ZETA
#: over c (1 +- HALF_WIDTH_ZETA zeta) (at most +- MAX_HALF_WIDTH of c): the half-power band ~ c (1 +- zeta) then
#: holds 2 STEPS_PER_ZETA steps; its ends are interpolated by a parabola through three points (error ~1e-5 of the
#: band on a one-mode peak), and so is the peak's top
STEPS_PER_ZETA, HALF_WIDTH_ZETA, MAX_HALF_WIDTH = 10.0, 2.0, 0.5
#: a peak lower than this fraction of the channel's largest amplitude is round-off (a channel the mode does not
#: move), not a resonance
PEAK_FLOOR = 1e-9
#: ... and one that stands out of its curve (above the higher of the lowest points either side before the curve
#: rises above it again, or ends) by less than this fraction of its height is a shoulder, not a resonance: a mode
#: the probe barely sees, a bump of 0.1 % on a rising curve (the stepped rotor's probe at d1 at 4060 RPM)
PEAK_PROMINENCE = 0.01
#: API 617's amplification factor below which a critical speed is "critically damped" (no margin required)
AF_CRITICALLY_DAMPED = 2.5
HALF_POWER = 1.0 / np.sqrt(2.0)


def sweep_speeds(model: Model, values: Mapping[str, float], rpm: Sequence[float], n_speeds: int = 121) -> Array:
    """``n_speeds`` speeds evenly over [min(rpm), max(rpm)] and, around each linear critical speed inside (1X
    crossings of ``model.campbell``, every branch), speeds zeta c / STEPS_PER_ZETA apart (module constants)."""
    lo, hi = float(np.min(rpm)), float(np.max(rpm))
    grid = np.linspace(lo, hi, n_speeds)
    table = mp.branches(campbell(model, values, np.linspace(lo, hi, max(n_speeds, 61)), n_modes=8))
    extra, done = [], []
    for row in mp.critical_speeds(table).itertuples():
        zeta = float(row.damping_ratio)
        if not (lo < row.rpm < hi and np.isfinite(zeta) and zeta > 0):
            continue
        if any(abs(row.rpm - c) <= 1e-4 * c for c in done):  # a forward and backward pair of one planar mode
            continue
        done.append(row.rpm)
        half = min(HALF_WIDTH_ZETA * zeta, MAX_HALF_WIDTH) * row.rpm
        step = zeta * row.rpm / STEPS_PER_ZETA
        extra.append(np.arange(max(row.rpm - half, lo), min(row.rpm + half, hi), step))
    speeds = np.unique(np.concatenate([grid, *extra])) if extra else grid
    # two refinements overlapping (close modes): speeds closer than 1e-3 of a step dropped, one of each pair
    return speeds[np.append(True, np.diff(speeds) > 1e-6 * max(abs(hi), 1.0))]


def unbalance_response(model: Model, values: Mapping[str, float], rpm: Sequence[float], harmonics: int = 1,
                       n_speeds: int = 121, method: str = "newton") -> pd.DataFrame:
    """The sensor harmonics 1X..HX of ``model`` at parameter values ``values`` (scalars, complete: a variant's
    ``values``) along a run-up and a run-down over ``sweep_speeds(model, values, rpm, n_speeds)``.

    One row per (sweep, speed, harmonic): the columns of ``response_plots.columns`` for the machine's sensors
    (eccentric_mass_g: 1e3 m_e, NaN without one; eccentric_mass_angle_deg: angle_me in degrees; stable: the Floquet check, NaN where the sweep did not
    converge, its branch saying why)."""
    values = {k: np.atleast_1d(np.asarray(v, float)) for k, v in values.items()}
    speeds = sweep_speeds(model, {k: float(v[0]) for k, v in values.items()}, rpm, n_speeds)
    rest = model.at_rest(values, 1)
    channels = sensor_names(model.shaft)
    mass = 1e3 * float(values["m_e"][0]) if "m_e" in values else np.nan
    angle = float(np.degrees(values["angle_me"][0])) if "angle_me" in values else 0.0
    rows = []
    for direction, label in SWEEPS.items():
        with np.errstate(all="ignore"):
            sweep = solve_sweep(lambda speed, which: model.system_at(rest.rows(which), speed), speeds, 1,
                                direction=direction, harmonics=harmonics, method=method)
        for speed, result in zip(sweep.rpm, sweep.results):
            ok = bool(result.success[0])
            radius = float(result.floquet_radius[0])
            stable = (radius < 1.0) if ok and np.isfinite(radius) else np.nan
            Z = sensor_channels(result.harmonics, model.shaft)[0]  # (H+1, C)
            for h in range(1, harmonics + 1):
                z = Z[h] if ok else np.full(len(channels), np.nan + 0j)
                rows.append((mass, angle, label, float(speed), h, *[v for c in z for v in (c.real, c.imag)], stable,
                             str(result.branch[0]) if ok else f"failed: {result.message[0]}"))
    table = pd.DataFrame(rows, columns=columns(channels))
    table["stable"] = table["stable"].astype(object)
    return table


# --- amplification factor and separation margin (API 684) ------------------------------------------------------

PEAK_COLUMNS = ["eccentric_mass_g", "sweep", "channel", "harmonic", "rpm_peak", "amplitude_0pk_m",
                "rpm_half_power_low", "rpm_half_power_high", "amplification_factor", "stable"]


def _peak_top(rpm: Array, a: Array, i: int) -> tuple[float, float]:
    """The top of the parabola through the points i-1, i, i+1 (speed, amplitude): the peak between grid speeds."""
    x, y = rpm[i - 1:i + 2], a[i - 1:i + 2]
    c2, c1, c0 = np.polyfit(x - x[1], y, 2)
    if c2 >= 0:
        return float(rpm[i]), float(a[i])
    dx = float(np.clip(-c1 / (2 * c2), x[0] - x[1], x[2] - x[1]))
    return float(x[1] + dx), float(c0 + c1 * dx + c2 * dx**2)


def _crossing(rpm: Array, a: Array, i: int, level: float, step: int) -> float:
    """The speed where the amplitude, walking from peak index i by ``step`` (-1 left, +1 right), first falls below
    ``level`` (linear interpolation between grid speeds); NaN when it rises above the peak first or never falls
    below it within the sweep."""
    j = i
    while 0 <= j + step < len(a):
        k = j + step
        if a[k] > a[i]:
            return np.nan  # a higher peak before the half-power point: the peaks overlap
        if a[k] < level:
            t = (a[j] - level) / (a[j] - a[k])
            linear = float(rpm[j] + t * (rpm[k] - rpm[j]))
            near = [m for m in (j - step, j, k) if 0 <= m < len(a)]  # j's neighbour towards the peak, j, k
            if len(near) < 3:
                return linear
            c2, c1, c0 = np.polyfit(rpm[near] - rpm[j], a[near] - level, 2)
            roots = np.roots([c2, c1, c0]) if c2 != 0 else np.array([-c0 / c1])
            inside = [r.real + rpm[j] for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12
                      and min(rpm[j], rpm[k]) <= r.real + rpm[j] <= max(rpm[j], rpm[k])]
            return float(inside[0]) if len(inside) == 1 else linear
        j = k
    return np.nan


def _valley(a: Array, i: int, step: int) -> float:
    """The lowest amplitude from peak index i towards ``step`` before the curve rises above a[i] (or ends)."""
    low, k = a[i], i + step
    while 0 <= k < len(a) and a[k] <= a[i]:
        low, k = min(low, a[k]), k + step
    return low


def peaks_of(rpm: Array, amplitude: Array) -> list[tuple[float, float, float, float]]:
    """The resonance peaks of an amplitude curve ``amplitude`` over sorted speeds ``rpm``: (N_c, peak amplitude, N1,
    N2) for each interior local maximum above PEAK_FLOOR of the largest that stands out by PEAK_PROMINENCE of its
    height, N1 and N2 its half-power points (NaN where the curve does not fall to peak / sqrt 2 on that side within
    the speeds, or rises above the peak first)."""
    rpm, a = np.asarray(rpm, float), np.asarray(amplitude, float)
    keep = np.isfinite(a)
    rpm, a = rpm[keep], a[keep]
    if a.size < 3:
        return []
    floor = PEAK_FLOOR * a.max()
    out = []
    for i in np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]) & (a[1:-1] > floor)) + 1:
        if a[i] - max(_valley(a, i, -1), _valley(a, i, +1)) <= PEAK_PROMINENCE * a[i]:
            continue
        top, height = _peak_top(rpm, a, i)
        level = HALF_POWER * height
        out.append((top, height, _crossing(rpm, a, i, level, -1), _crossing(rpm, a, i, level, +1)))
    return out


def amplification_factor(rpm_peak: float, rpm_low: float, rpm_high: float) -> float:
    """API 684's half-power amplification factor AF = N_c / (N2 - N1) (NaN when a half-power point is missing)."""
    return rpm_peak / (rpm_high - rpm_low) if np.isfinite(rpm_low) and np.isfinite(rpm_high) else np.nan


def amplification_factors(table: pd.DataFrame, harmonic: int = 1) -> pd.DataFrame:
    """Every resonance peak of each channel's ``harmonic`` X amplitude in a response table (``unbalance_response``
    or the report's dense response), per eccentric mass and sweep, with its half-power points and amplification
    factor (``PEAK_COLUMNS``, amplitude 0-peak [m]; ``peaks_of``) and the stability of the steady state at the sweep
    speed nearest the peak (True/False, NaN: not assessed; an unstable peak is one the machine does not sit on).
    Unconverged speeds are left out of the curve."""
    rows = []
    part = table[table["harmonic"] == harmonic]
    for (mass, sweep), group in part.groupby(["eccentric_mass_g", "sweep"], sort=True, dropna=False):
        group = group.sort_values("rpm")
        for c in channels_of(group):
            z = tables.complex_values(group, c)
            speeds, stable = group["rpm"].to_numpy(), group["stable"].to_numpy() if "stable" in group else None
            for top, height, low, high in peaks_of(speeds, np.abs(z)):
                at = stable[np.argmin(np.abs(speeds - top))] if stable is not None else np.nan
                rows.append((mass, sweep, c, harmonic, top, height, low, high, amplification_factor(top, low, high),
                             at))
    out = pd.DataFrame(rows, columns=PEAK_COLUMNS)
    out["stable"] = out["stable"].astype(object)
    return out


def required_margin(af: float, above: bool) -> float:
    """API 617's least separation margin [%] for a critical speed of amplification factor ``af`` below (``above``
    False) or above the operating range: none (0) for AF < 2.5 or an unknown AF, else min(16, 17 (1 - 1/(AF -
    1.5))) below and min(26, 10 + 17 (1 - 1/(AF - 1.5))) above."""
    if not np.isfinite(af) or af < AF_CRITICALLY_DAMPED:
        return 0.0
    base = 17.0 * (1.0 - 1.0 / (af - 1.5))
    return min(26.0, 10.0 + base) if above else min(16.0, base)


def separation_margin(rpm_critical: float, operating: tuple[float, float]) -> float:
    """The separation margin [%] of a critical speed from the operating range (N_min, N_max): (N_min - N_c) / N_c
    below it, (N_c - N_max) / N_max above it (as ROSS's report); inside the range negative, minus the distance to
    the nearer end over N_c."""
    lo, hi = operating
    if rpm_critical < lo:
        return 100.0 * (lo - rpm_critical) / rpm_critical
    if rpm_critical > hi:
        return 100.0 * (rpm_critical - hi) / hi
    return -100.0 * min(rpm_critical - lo, hi - rpm_critical) / rpm_critical


def separation_margins(peaks: pd.DataFrame, operating: tuple[float, float]) -> pd.DataFrame:
    """``peaks`` (``amplification_factors``) with the operating range (operating_rpm_low, operating_rpm_high), each
    peak's separation_margin_pct, the required_margin_pct for its AF (API 617) and ``meets`` (the margin at least
    the required one: True/False)."""
    lo, hi = float(min(operating)), float(max(operating))
    out = peaks.copy()
    out["operating_rpm_low"], out["operating_rpm_high"] = lo, hi
    out["separation_margin_pct"] = [separation_margin(r, (lo, hi)) for r in out["rpm_peak"]]
    out["required_margin_pct"] = [
        required_margin(af, r > hi) if not lo <= r <= hi else (0.0 if required_margin(af, False) == 0.0 else np.inf)
        for r, af in zip(out["rpm_peak"], out["amplification_factor"])]
    out["meets"] = out["separation_margin_pct"] >= out["required_margin_pct"]
    return out


# --- figures ---------------------------------------------------------------------------------------------------


def bode_figure(table: pd.DataFrame, peaks: pd.DataFrame | None = None, harmonics: Sequence[int] = (1,),
                title: str = "") -> plt.Figure:
    """Amplitude (0-peak [um], log scale) and phase [deg] against speed of each channel (two rows per channel) and
    harmonic of ``harmonics`` (a column each): the run-up solid, the run-down dashed, unstable stretches dotted
    (``response_plots``' curves); the 1X peaks of ``peaks`` (``amplification_factors``) marked with their
    half-power band and AF."""
    channels = channels_of(table)
    orders = [h for h in harmonics if h in set(table["harmonic"])]
    fig, axes = plt.subplots(2 * len(channels), len(orders), sharex=True, squeeze=False,
                             figsize=(max(5.0 * len(orders), 8.0), 4.2 * len(channels)))
    for col, h in enumerate(orders):
        part = table[table["harmonic"] == h]
        for j, channel in enumerate(channels):
            amp, ph = axes[2 * j, col], axes[2 * j + 1, col]
            z = tables.complex_values(table, channel)
            a = np.hypot(z.real, z.imag) * MICRO
            a = a[np.isfinite(a) & (a > 0)]
            # eight decades below the channel's largest harmonic: a harmonic that is zero shows its round-off nowhere
            floor = 1e-8 * a.max() if a.size else 1e-12
            sweeps = {sweep: rows for sweep, rows in part.groupby("sweep")}
            up = response_curve(amp, ph, sweeps[SWEEPS["up"]], j, "C0", "-", "run-up", floor) \
                if SWEEPS["up"] in sweeps else None
            if SWEEPS["down"] in sweeps:
                response_curve(amp, ph, sweeps[SWEEPS["down"]], j, "C1", "--", "run-down", floor, up)
            if peaks is not None and h == 1:
                for row in peaks[(peaks["channel"] == channel) & (peaks["sweep"] == SWEEPS["up"])].itertuples():
                    amp.plot(row.rpm_peak, row.amplitude_0pk_m * MICRO, "v", color="k", ms=5, gid="peak")
                    if np.isfinite(row.amplification_factor):
                        amp.axvspan(row.rpm_half_power_low, row.rpm_half_power_high, color="0.85", zorder=0)
                        amp.annotate(f"{row.rpm_peak:.0f} RPM\nAF {row.amplification_factor:.3g}",
                                     (row.rpm_peak, row.amplitude_0pk_m * MICRO), xytext=(4, 2),
                                     textcoords="offset points", fontsize=7)
            bode_axes(amp, ph, channel, h, f"|{channel}, {h}X| 0-peak [um]")
        axes[-1, col].set_xlabel("speed [RPM]")
    axes[0, 0].legend(fontsize=8, loc="upper left")
    fig.suptitle(title or "Unbalance response (solid run-up, dashed run-down, dotted unstable; grey: half-power "
                 "band)", fontsize=10)
    fig.tight_layout()
    return fig


def polar_figure(table: pd.DataFrame, harmonic: int = 1, title: str = "") -> plt.Figure:
    """Polar (Nyquist) plot of each channel's ``harmonic`` X (radius 0-peak [um], angle the phase): run-up solid,
    run-down dashed, every ~tenth speed labelled on the run-up."""
    channels = channels_of(table)
    part = table[table["harmonic"] == harmonic]
    fig, axes = plt.subplots(1, len(channels), squeeze=False, subplot_kw={"projection": "polar"},
                             figsize=(4.2 * len(channels), 4.6))
    for j, channel in enumerate(channels):
        ax = axes[0, j]
        for sweep, rows in part.groupby("sweep"):
            rows = rows.sort_values("rpm")
            z = tables.complex_values(rows, channel)
            up = sweep == SWEEPS["up"]
            ax.plot(np.angle(z), np.abs(z) * MICRO, "-" if up else "--", color="C0" if up else "C1", lw=1.2,
                    label=sweep, gid=f"{channel}:{sweep}")
            if up:
                for k in np.linspace(0, len(z) - 1, 11).astype(int)[1:-1]:
                    if np.isfinite(z[k]):
                        ax.annotate(f"{rows['rpm'].iloc[k]:.0f}", (np.angle(z[k]), abs(z[k]) * MICRO), fontsize=6)
        ax.set_title(f"{harmonic}X, {channel} [um]", fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="lower left", bbox_to_anchor=(-0.15, -0.15))
    fig.suptitle(title or "Unbalance response, polar (labels: RPM)", fontsize=10)
    fig.tight_layout()
    return fig
