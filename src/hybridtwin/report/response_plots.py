"""The fitted model's response as dense curves through the resonances, with the measurements on top (report stage).

Between the run speeds a model is not a straight line: near a resonance its amplitude rises and its phase turns
by 180 degrees within a few RPM, and a nonlinear bearing can make the response multi-valued (the run-up and the
run-down reach different steady states over a band of speeds, with a jump at each end). So the curves here are
harmonic-balance sweeps by continuation (``continuation.solve_sweep``), one run-up and one run-down per eccentric
mass of the fit runs, on a dense speed grid over the runs' range; the values are the joint fit's estimates, each
per-run parameter (the bow) from its law over the fitted runs (``validation.values_at``, as for the validation
runs). Unstable stretches (a Floquet multiplier outside the unit circle: the machine cannot stay there) are
drawn dotted.

``dense_response`` -> a long table (``write_dense`` / ``read_dense``, exact inverses) with two columns per
sensor channel (``<channel>_re_m``, ``<channel>_im_m``: x, y on the VARM, every sensor of a machine in its
order); ``plot_bode`` and ``plot_polar`` draw every channel with the fit and validation runs
(``report.RunComparison``, the model's frame; its channels in the same order). The cascade
(``plot_cascade``) has a panel per channel too.
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .. import tables  # noqa: E402
from ..identify import validation as val  # noqa: E402
from ..data.measurements import trial_angles  # noqa: E402
from ..identify.arrow_problem import wrap  # noqa: E402
from ..model.effects import trial_mass_values  # noqa: E402
from .report import RunComparison  # noqa: E402
from .report_plots import MICRO, ORDERS, VALIDATION_STYLE, mass_colours  # noqa: E402
from ..model.sensor import sensor_channels, sensor_names  # noqa: E402
from ..solvers.continuation import solve_sweep  # noqa: E402

Array = np.ndarray
SWEEPS = {"up": "run-up", "down": "run-down"}
MIN_WIDTH_IN = 10.0  # the Bode and polar figures' width with one harmonic (H = 1): room for the title and legend
TITLE_IN = 0.5  # the Bode and polar figures' two-line title: kept clear of the first row's panel titles


#: a trial (eccentric) mass as the dense table keys its curves: the mass [g] and its angle [deg, from +x towards +y
#: at the keyphasor mark; the runs sheet's eccentric_mass_angle_deg, 0 where not given]
TRIAL = ["eccentric_mass_g", "eccentric_mass_angle_deg"]


def columns(channels: Sequence[str]) -> list[str]:
    """The dense table's columns for sensor ``channels`` (the machine's order)."""
    return (TRIAL + ["sweep", "rpm", "harmonic"] + [tables.part_column(c, part) for c in channels for part in ("re", "im")]
            + ["stable", "branch"])


def trials_of(runs: pd.DataFrame) -> list[tuple[float, float]]:
    """The (mass [g], angle [deg in [0, 360)]) trials of ``runs`` (rows: eccentric_mass_g and, when the sheet has
    it, eccentric_mass_angle_deg; an empty angle is 0), sorted."""
    angles = trial_angles(runs)
    return sorted({(float(m), float(np.mod(a, 360.0))) for m, a in zip(runs["eccentric_mass_g"], angles)})


def trial_label(mass_g: float, angle_deg: float = 0.0) -> str:
    """How a figure names a trial: "7.6 g", or "7.6 g at 120 deg" when the mass sits at an angle."""
    return f"{mass_g:g} g" if not angle_deg else f"{mass_g:g} g at {angle_deg:g} deg"


def trial_key(c: RunComparison) -> tuple[float, float]:
    """A run's trial (mass, angle in [0, 360)), as ``trials_of`` keys the curves."""
    return float(c.eccentric_mass_g), float(np.mod(c.eccentric_mass_angle_deg, 360.0))


#: the VARM's (probes x, y)
COLUMNS = columns(("x", "y"))


def channels_of(table: pd.DataFrame) -> list[str]:
    """The sensor channels of a dense table, in its column order."""
    return [c[:-len("_re_m")] for c in table.columns if c.endswith("_re_m")]


def dense_speeds(run_rpm: Sequence[float], n_speeds: int = 121, margin: float = 0.08) -> Array:
    """The sweep's speeds [RPM]: ``n_speeds`` evenly spaced over the runs' range widened by ``margin`` of it on
    each side (not below 1 % of the highest run speed)."""
    lo, hi = float(np.min(run_rpm)), float(np.max(run_rpm))
    pad = margin * max(hi - lo, 0.1 * hi)
    return np.linspace(max(lo - pad, 0.01 * hi), hi + pad, n_speeds)


#: around each critical speed c (damping ratio zeta) of the grid's range, the dense grid's step is at most
#: zeta c / PEAK_STEPS_PER_ZETA over c (1 +- PEAK_HALF_WIDTH_ZETA zeta) (the half-power band is c (1 +- zeta)): a
#: lightly damped peak between two grid speeds 29 RPM apart was drawn 4 % low (a stepped rotor's, half-power
#: width 60 RPM); sampled at most zeta c / 8 from its top, a one-mode peak is drawn at most 0.8 % low
#: (1 / sqrt(1 + 1/64))
PEAK_STEPS_PER_ZETA, PEAK_HALF_WIDTH_ZETA = 4.0, 3.0


def refined_speeds(speeds: Sequence[float], criticals: Sequence[tuple[float, float]]) -> Array:
    """``speeds`` (sorted, evenly spaced) and, around each critical speed c with damping ratio zeta inside their
    range where the grid is coarser than zeta c / PEAK_STEPS_PER_ZETA, speeds that fine over c (1 +-
    PEAK_HALF_WIDTH_ZETA zeta), at most +- 10 % of c: the dense curves then resolve the resonance peaks
    (``critical_speeds``). A grid already that fine is returned as it is."""
    speeds = np.asarray(speeds, float)
    step = float(np.max(np.diff(speeds))) if speeds.size > 1 else 0.0
    extra = []
    for rpm, zeta in criticals:
        fine = max(zeta, 0.0) * rpm / PEAK_STEPS_PER_ZETA
        if not speeds[0] < rpm < speeds[-1] or not 0 < fine < step:
            continue
        half = min(PEAK_HALF_WIDTH_ZETA * zeta * rpm, 0.1 * rpm)
        extra.append(np.arange(max(rpm - half, speeds[0]), min(rpm + half, speeds[-1]), fine))
    return np.unique(np.concatenate([speeds, *extra])) if extra else speeds


def critical_speeds(variant, joint: pd.DataFrame, rpm: Sequence[float], eccentric_mass_g: float = 0.0
                    ) -> list[tuple[float, float]]:
    """The fitted model's linear critical speeds in ``rpm``'s range (1X crossings of its Campbell diagram, every
    mode's branch, forward and backward whirl) with each mode's damping ratio there: (rpm, zeta) pairs. The values:
    the joint fit's estimates (per-run ones at their median), as the Campbell diagram of the report."""
    from . import machine_plots as mp
    from ..model.model import campbell

    values = variant.values(mp.fitted_values(joint) | {"m_e": 1e-3 * eccentric_mass_g})
    values = {name: float(value) for name, value in values.items()}
    grid = np.linspace(float(np.min(rpm)), float(np.max(rpm)), 61)
    table = mp.branches(campbell(variant.model, values, grid, n_modes=6))
    out = []
    for row in mp.critical_speeds(table).itertuples():
        branch = table[(table["whirl"] == row.whirl) & (table["branch"] == row.branch)].sort_values("rpm")
        out.append((float(row.rpm), float(np.interp(row.rpm, branch["rpm"], branch["damping_ratio"]))))
    return out


def dense_response(variant, joint: pd.DataFrame, runs: pd.DataFrame, rpm: Sequence[float], harmonics: int,
                   law: str = "law") -> pd.DataFrame:
    """Sensor harmonics 1X..HX of the fitted ``variant`` along a run-up and a run-down over ``rpm``, one sweep per
    trial mass of ``runs`` (rows: run, rpm, eccentric_mass_g and, where the sheet gives one, eccentric_mass_angle_deg;
    the fit runs; ``trials_of``), all trials in one batched sweep. joint: the joint parameter table
    (parameters.tsv). One row per (mass, angle, sweep, speed, harmonic) (``columns`` of the machine's sensors;
    ``stable``: the Floquet check, NaN where the sweep did not converge)."""
    trials = trials_of(runs)
    names = list(variant.model.parameters)
    shaft = variant.model.shaft
    channels = sensor_names(shaft)
    values_at = val.values_along(joint, law, runs)  # the bow's law fitted once, evaluated at every step

    def build(speed: Array, rows: Array):
        sets = [variant.values(values_at(float(s), trials[r][0]) | trial_mass_values(*trials[r]))
                for s, r in zip(speed, rows)]
        return variant.model.system({k: np.array([float(v[k]) for v in sets]) for k in names}, speed)

    frames = []
    for direction, label in SWEEPS.items():
        sweep = solve_sweep(build, np.asarray(rpm, float), len(trials), direction=direction, harmonics=harmonics)
        for speed, result in zip(sweep.rpm, sweep.results):
            Z = sensor_channels(result.harmonics, shaft)  # (S, H+1, C)
            ok = np.asarray(result.success, bool)
            radius = np.asarray(result.floquet_radius, float)
            for s, (mass, angle) in enumerate(trials):
                stable = bool(radius[s] < 1.0) if ok[s] and np.isfinite(radius[s]) else np.nan
                for h in range(1, harmonics + 1):
                    z = Z[s, h] if ok[s] else np.full(len(channels), np.nan + 0j)
                    parts = [v for c in z for v in (c.real, c.imag)]
                    frames.append((mass, angle, label, float(speed), h, *parts, stable, str(result.branch[s])))
    table = pd.DataFrame(frames, columns=columns(channels))
    table["stable"] = table["stable"].astype(object)  # True, False, or NaN (not assessed)
    return table


def write_dense(table: pd.DataFrame, path) -> None:
    """``dense_response``'s table as TSV, every float to full precision (``read_dense`` is its exact inverse)."""
    tables.RESPONSE.write(table, path)


def read_dense(path) -> pd.DataFrame:
    """The table ``write_dense`` wrote (``stable`` back to True/False/NaN; a table written before trial angles
    were, without eccentric_mass_angle_deg, read with the angle 0)."""
    table = tables.RESPONSE.read(path)
    if "eccentric_mass_angle_deg" not in table:
        table.insert(1, "eccentric_mass_angle_deg", 0.0)
    table["stable"] = table["stable"].map({True: True, False: False, "True": True, "False": False}).astype(object)
    table.loc[table["stable"].isna(), "stable"] = np.nan
    return table[columns(channels_of(table))]


def channel_values(table: pd.DataFrame, j: int) -> Array:
    """The j-th sensor channel's complex harmonic (the machine's order)."""
    c = channels_of(table)[j]
    return tables.complex_values(table, c)


def response_curve(ax_amp, ax_phase, part: pd.DataFrame, j: int, colour: str, style: str, label: str | None,
           floor: float, reference: tuple[Array, Array] | None = None) -> tuple[Array, Array]:
    """One sweep's amplitude (stable stretches ``style``, unstable ones dotted) and unwrapped phase, in order of
    speed; the phase is drawn where the amplitude stands above ``floor`` (a vanishing harmonic has none) and
    shifted by whole turns to meet ``reference`` ((rpm, phase) of the other sweep) where both exist. Returns
    (rpm, phase [rad])."""
    part = part.sort_values("rpm")
    z = channel_values(part, j)
    rpm = part["rpm"].to_numpy()
    amplitude = np.maximum(np.abs(z) * MICRO, floor)
    unstable = part["stable"].to_numpy() == False  # noqa: E712 (object column: True/False/NaN)
    ax_amp.plot(rpm, np.where(unstable, np.nan, amplitude), style, color=colour, lw=1.3, label=label)
    if unstable.any():
        ax_amp.plot(rpm, np.where(unstable, amplitude, np.nan), ":", color=colour, lw=1.0)
    phase = np.full(len(z), np.nan)
    shown = np.isfinite(z) & (np.abs(z) * MICRO > floor)
    phase[shown] = np.unwrap(np.angle(z[shown]))
    if reference is not None:
        other = np.interp(rpm, reference[0], reference[1], left=np.nan, right=np.nan)
        both = np.flatnonzero(np.isfinite(phase) & np.isfinite(other))
        if both.size:
            phase -= 2 * np.pi * np.round((phase[both[0]] - other[both[0]]) / (2 * np.pi))
    ax_phase.plot(rpm, np.degrees(np.where(unstable, np.nan, phase)), style, color=colour, lw=1.3)
    return rpm, phase


def by_channel(comparisons: Sequence[RunComparison], channels: Sequence[str]) -> list[RunComparison]:
    """The runs' columns in the dense table's channel order, matched by name; a run whose channels are not the
    table's is a ValueError naming both."""
    for c in comparisons:
        if sorted(c.channels) != sorted(channels):
            raise ValueError(f"run {c.run}: channels {', '.join(c.channels)}, but the model's response has "
                             f"{', '.join(channels)}")
    return [c.select(channels) for c in comparisons]


def plot_bode(dense: pd.DataFrame, comparisons: Sequence[RunComparison], variant: str,
              orders: Sequence[int] = ORDERS) -> plt.Figure:
    """Amplitude (0-peak) and phase (model frame) of harmonics ``orders`` vs speed, every channel (two rows each: x, y
    on the VARM; every probe of a machine, the runs' channels matched by name): the model's run-up
    (solid) and run-down (dashed) per eccentric mass, unstable stretches dotted; the fit runs measured (points, 2
    sigma bars), the validation runs measured (stars) and predicted (crosses); the noise (2 sigma, grey)."""
    H = min([int(dense["harmonic"].max())] + [c.H for c in comparisons])
    orders = [h for h in orders if h <= H]
    colours = trial_colours(dense)
    channels = channels_of(dense)
    comparisons = by_channel(comparisons, channels)
    fig, axes = plt.subplots(2 * len(channels), len(orders), sharex=True, squeeze=False,
                             figsize=(max(4.6 * len(orders), MIN_WIDTH_IN), 6 * len(channels)))
    for col, h in enumerate(orders):
        for j, channel in enumerate(channels):
            amp, ph = axes[2 * j, col], axes[2 * j + 1, col]
            sigmas = [c.sigma[h - 1, j] for c in comparisons] or [float(np.nanmax(np.abs(channel_values(dense, j))))]
            floor = 0.2 * min(sigmas) * MICRO
            ups = {}  # each trial's run-up curve (rpm, unwrapped phase): the branch of 2 pi a run's phase is drawn on
            for trial, both in dense[dense["harmonic"] == h].groupby(TRIAL, sort=True):
                sweeps = {sweep: part for sweep, part in both.groupby("sweep")}
                name = trial_label(*trial)
                up = response_curve(amp, ph, sweeps[SWEEPS["up"]], j, colours[trial], "-", f"{name} model, run-up",
                                    floor)
                response_curve(amp, ph, sweeps[SWEEPS["down"]], j, colours[trial], "--", f"{name} model, run-down",
                       floor, up)
                ups[trial] = up
                for c in comparisons:
                    if c.role == "fit" and trial_key(c) == trial:
                        measured_points(amp, ph, c, h, j, colours[trial], floor, near_speed(ups, c), f"{name} measured")
            for c in comparisons:
                if c.role == "validate":
                    validation_points(amp, ph, c, h, j, floor, near_speed(ups, c))
            ordered = sorted(comparisons, key=lambda c: c.rpm)
            if ordered:
                amp.plot([c.rpm for c in ordered], [2 * c.sigma[h - 1, j] * MICRO for c in ordered], ":",
                         color="0.5", label="noise (2 sigma)")
            bode_axes(amp, ph, channel, h, f"|{channel}, {h}X| [um]")
            amp.set_ylim(bottom=floor)
        axes[-1, col].set_xlabel("speed [RPM]")
    _legend(fig, axes[0, 0])
    fig.suptitle(f"variant {variant}: Bode plots, model by continuation (solid run-up, dashed run-down, dotted "
                 "unstable)\nvs measured (points, 2 sigma bars); magenta: validation runs measured (stars) and "
                 "predicted (crosses)", fontsize=10)
    fig.tight_layout(rect=(0, 0.035 * 2 / len(channels), 1, 1 - TITLE_IN / fig.get_figheight()))
    return fig


def bode_axes(amp: plt.Axes, ph: plt.Axes, channel: str, h: int, amp_label: str) -> None:
    """One Bode pair's styling (the report's and the machine view's): log amplitude with ``amp_label``, phase in
    degrees, the panel named by harmonic and channel, light grids."""
    amp.set_yscale("log")
    amp.set_ylabel(amp_label)
    ph.set_ylabel(f"phase of {channel}, {h}X [deg]")
    amp.set_title(f"{h}X, {channel}", fontsize=9)
    for ax in (amp, ph):
        ax.grid(alpha=0.3, which="both")


def measured_points(amp, ph, c: RunComparison, h: int, j: int, colour: str, floor: float, near: float, label: str
              ) -> None:
    z, s = c.measured[h - 1, j], c.sigma[h - 1, j]
    level = max(abs(z) * MICRO, floor)
    amp.errorbar([c.rpm], [level], yerr=[[min(2 * s * MICRO, level - floor)], [2 * s * MICRO]], fmt="o", ms=4,
                 color=colour, label=label)
    if abs(z) > 2 * s:  # a phase means something only above the noise
        phase = near + wrap(np.angle(z) - near)
        ph.errorbar([c.rpm], [np.degrees(phase)], yerr=[np.degrees(2 * s / abs(z))], fmt="o", ms=4, color=colour)


def near_speed(ups: dict, c: RunComparison) -> float:
    """The model curve's unwrapped phase at run ``c``'s speed, on the run-up of its trial (or the nearest mass
    drawn, then the nearest angle): a run's phase is drawn within pi of it, on the curve's branch of 2 pi."""
    if not ups:
        return 0.0
    mass, angle = trial_key(c)
    rpm, phase = ups[min(ups, key=lambda t: (abs(t[0] - mass), abs(wrap(np.deg2rad(t[1] - angle)))))]
    finite = np.isfinite(phase)
    return float(np.interp(c.rpm, rpm[finite], phase[finite])) if finite.any() else 0.0


def validation_points(amp, ph, c: RunComparison, h: int, j: int, floor: float, near: float) -> None:
    z, m, s = c.measured[h - 1, j], c.model[h - 1, j], c.sigma[h - 1, j]
    predicted = near + wrap(np.angle(m) - near)  # on the curve's branch, as the fit runs (``measured_points``)
    style = {"color": VALIDATION_STYLE["color"], "ms": VALIDATION_STYLE["ms"], "ls": "none"}
    amp.plot(c.rpm, max(abs(z) * MICRO, floor), marker=VALIDATION_STYLE["marker"], mfc="none",
             label="validation measured", **style)
    amp.plot(c.rpm, max(abs(m) * MICRO, floor), marker="x", label="validation predicted", **style)
    if abs(z) > 2 * s:
        ph.plot(c.rpm, np.degrees(predicted + wrap(np.angle(z) - predicted)), marker=VALIDATION_STYLE["marker"],
                mfc="none", **style)
    if abs(m) > 0.1 * s:
        ph.plot(c.rpm, np.degrees(predicted), marker="x", **style)


def plot_polar(dense: pd.DataFrame, comparisons: Sequence[RunComparison], variant: str,
               orders: Sequence[int] = ORDERS) -> plt.Figure:
    """Polar (Nyquist) plots of harmonics ``orders``, a row per channel (x and y on the VARM; model frame, radius in
    um): the model's run-up
    (solid) and run-down (dashed) per mass, the measured fit runs (points, 1X labelled with the speed), the
    validation runs (stars measured, crosses predicted), the noise circle (2 sigma)."""
    H = min([int(dense["harmonic"].max())] + [c.H for c in comparisons])
    orders = [h for h in orders if h <= H]
    colours = trial_colours(dense)
    channels = channels_of(dense)
    comparisons = by_channel(comparisons, channels)
    fig, axes = plt.subplots(len(channels), len(orders), squeeze=False, subplot_kw={"projection": "polar"},
                             figsize=(max(4.8 * len(orders), MIN_WIDTH_IN), 4.8 * len(channels)))
    for col, h in enumerate(orders):
        for j, channel in enumerate(channels):
            ax = axes[j, col]
            for (mass, angle, sweep), part in dense[dense["harmonic"] == h].groupby(TRIAL + ["sweep"]):
                z = channel_values(part, j)
                ax.plot(np.angle(z), np.abs(z) * MICRO, "-" if sweep == SWEEPS["up"] else "--",
                        color=colours[(mass, angle)], lw=1.2, label=f"{trial_label(mass, angle)} model, {sweep}")
            for c in comparisons:
                z = c.measured[h - 1, j]
                if c.role == "fit":
                    colour = colours.get(trial_key(c), "k")
                    ax.plot(np.angle(z), abs(z) * MICRO, "o", ms=4, color=colour,
                            label=f"{trial_label(*trial_key(c))} measured")
                    if h == 1:
                        ax.annotate(f"{c.rpm:.0f}", (np.angle(z), abs(z) * MICRO), fontsize=6, color=colour)
                else:
                    m = c.model[h - 1, j]
                    style = {"color": VALIDATION_STYLE["color"], "ls": "none"}
                    ax.plot(np.angle(z), abs(z) * MICRO, marker=VALIDATION_STYLE["marker"], mfc="none",
                            ms=VALIDATION_STYLE["ms"], label="validation measured", **style)
                    ax.plot(np.angle(m), abs(m) * MICRO, marker="x", label="validation predicted", **style)
            if comparisons:
                noise = 2 * np.median([c.sigma[h - 1, j] for c in comparisons]) * MICRO
                ax.plot(np.linspace(0, 2 * np.pi, 90), np.full(90, noise), ":", color="0.4", lw=1,
                        label="noise (2 sigma)")
            ax.set_title(f"{h}X, {channel} [um]; dotted: noise (2 sigma)", fontsize=9)
            ax.tick_params(labelsize=7)
    _legend(fig, axes[0, 0])
    fig.suptitle(f"variant {variant}: polar plots, model by continuation (solid run-up, dashed run-down)\nvs "
                 "measured (points), model's frame; magenta: validation runs", fontsize=10)
    fig.tight_layout(rect=(0, 0.05 * 2 / len(channels), 1, 1 - TITLE_IN / fig.get_figheight()))
    return fig


def _legend(fig: plt.Figure, ax: plt.Axes) -> None:
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    fig.legend(unique.values(), unique.keys(), loc="lower center", ncol=min(len(unique), 5), fontsize=8)


def multivalued(dense: pd.DataFrame, rtol: float = 0.02) -> pd.DataFrame:
    """Per trial mass, the speed band where run-up and run-down differ (1X amplitude at either sensor channel
    by more than ``rtol`` of the larger): columns eccentric_mass_g, eccentric_mass_angle_deg, rpm_from, rpm_to
    (NaN: single-valued)."""
    rows = []
    first = dense[dense["harmonic"] == 1]
    for (mass, angle), part in first.groupby(TRIAL):
        up = part[part["sweep"] == SWEEPS["up"]].set_index("rpm")
        down = part[part["sweep"] == SWEEPS["down"]].set_index("rpm")
        common = up.index.intersection(down.index)
        differ = np.zeros(len(common), bool)
        for j in range(len(channels_of(part))):
            a, b = np.abs(channel_values(up.loc[common], j)), np.abs(channel_values(down.loc[common], j))
            differ |= np.abs(a - b) > rtol * np.maximum(np.maximum(a, b), 1e-300)
        speeds = np.asarray(common)[differ]
        rows.append({"eccentric_mass_g": mass, "eccentric_mass_angle_deg": angle,
                     "rpm_from": speeds.min() if speeds.size else np.nan,
                     "rpm_to": speeds.max() if speeds.size else np.nan})
    return pd.DataFrame(rows, columns=TRIAL + ["rpm_from", "rpm_to"])


def trial_colours(dense: pd.DataFrame) -> dict[tuple[float, float], str]:
    """One colour per trial of a dense table (``mass_colours``: the heaviest first, then by angle)."""
    return mass_colours(map(tuple, dense[TRIAL].drop_duplicates().to_numpy(float).tolist()))


def plot_cascade(spectra: dict[str, pd.DataFrame], runs: pd.DataFrame, orders: Sequence[int] = ORDERS
                 ) -> plt.Figure:
    """Cascade of the measured full spectra (``preprocessing.spectrum``): one row per run, sorted by eccentric
    mass then speed, x the frequency [Hz], colour the amplitude in dB re 1 um (0-peak), one panel per channel
    (the spectra's <channel>_amplitude_m columns: x, y on the VARM, every sensor of a machine);
    the orders 1X..3X joined across the runs of each mass (dashed): what lies off them (a natural frequency
    excited by the noise, a subharmonic, a rub's broadband) is what the harmonics alone do not show.
    runs: run, rpm (the refined speed), eccentric_mass_g."""
    ordered = runs[runs["run"].isin(list(spectra))].sort_values(["eccentric_mass_g", "rpm"]).reset_index(drop=True)
    suffix = "_amplitude_m"
    channels = list(dict.fromkeys(c[:-len(suffix)] for s in spectra.values() for c in s.columns
                                  if c.endswith(suffix))) or ["x", "y"]
    n_columns = min(len(channels), 2)  # two panels a row: x, y of the VARM side by side, a row per further pair
    n_rows = -(-len(channels) // n_columns)
    fig, axes = plt.subplots(n_rows, n_columns, figsize=(13, n_rows * (0.28 * len(ordered) + 2.5)), sharey=True,
                             squeeze=False)
    levels = np.concatenate([20 * np.log10(np.maximum(spectra[r][f"{c}_amplitude_m"].to_numpy() * MICRO, 1e-12))
                             for r in ordered["run"] for c in channels]) if len(ordered) else np.zeros(1)
    top = float(np.nanmax(levels))
    vmin, vmax = top - 80.0, top  # 80 dB below the largest line: the noise floor and everything above it
    mesh = None
    for j, channel in enumerate(channels):
        ax = axes[j // n_columns, j % n_columns]
        for i, r in enumerate(ordered.itertuples()):
            s = spectra[r.run]
            f = s["frequency_hz"].to_numpy()
            if f.size < 2:
                continue
            edges = np.concatenate([[f[0]], 0.5 * (f[1:] + f[:-1]), [f[-1]]])
            level = 20 * np.log10(np.maximum(s[f"{channel}_amplitude_m"].to_numpy() * MICRO, 1e-12))
            mesh = ax.pcolormesh(edges, [i - 0.5, i + 0.5], level[None, :], vmin=vmin, vmax=vmax,
                                 cmap="viridis", shading="flat")
        for _, group in ordered.groupby("eccentric_mass_g"):
            rows = group.index.to_numpy()
            for h in orders:
                ax.plot(h * group["rpm"].to_numpy() / 60.0, rows, "--", color="w", lw=0.7, alpha=0.8)
        for h in orders if len(ordered) else ():  # no steady run (only run-ups / coast-downs): an empty cascade
            ax.annotate(f"{h}X", (h * ordered["rpm"].iloc[-1] / 60.0, len(ordered) - 0.5), color="k", fontsize=8,
                        ha="center", va="bottom", annotation_clip=False)
        if not len(ordered):
            ax.text(0.5, 0.5, "no steady run: a run-up's or coast-down's orders are in\n"
                    "results/data/records/<run>/orders.tsv", transform=ax.transAxes, ha="center", va="center")
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(f"{channel}: amplitude [dB re 1 um, 0-peak]", fontsize=9)
    for row in range(n_rows):
        axes[row, 0].set_yticks(range(len(ordered)))
        axes[row, 0].set_yticklabels([f"{r.rpm:.0f} RPM, {r.eccentric_mass_g:g} g" for r in ordered.itertuples()],
                                     fontsize=7)
    for j in range(len(channels), n_rows * n_columns):  # an odd number of channels: the last panel unused
        axes[j // n_columns, j % n_columns].set_visible(False)
    if mesh is not None:
        fig.colorbar(mesh, ax=axes.ravel().tolist(), shrink=0.8, label="dB re 1 um")
    fig.suptitle("Cascade of the measured spectra (one row per run; dashed: 1X-3X)", fontsize=10)
    return fig
