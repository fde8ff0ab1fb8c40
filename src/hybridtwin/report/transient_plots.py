"""The pictures engineers read of a run-up or coast-down (issue 38, item 7): Bode and polar plots of the tracked
order vectors with the fitted twin on top and the residual in units of the noise, the waterfall of the record,
and its orbits at chosen speeds (docs/method.md, "Transient records: the pictures").

**The points** are the order vectors of ``order_tracking`` as ``track_record`` wrote them (orders.tsv: one
window of a few whole revolutions each, slow-roll runout removed, each part with its 1-sigma), not re-analysed.
Each window is marked with the speed band of bands.tsv it falls in (``window_status``): "used" where that band is
one the fit or the validation reads, else the band's flag (sweep_too_fast, clipped, ...) or "slow_roll" below the
first band: such windows are drawn hollow, their band shaded, never left out.

**The model** is the fitted twin's steady response by continuation (``response_plots.dense_response``, the
report's Bode curves: the joint fit's values, the bow from its law over the fit runs) at every window's own speed,
along the record's own sweep direction (a run-up on the run-up branch, a coast-down on the run-down one), so the
residual z = (measured - model) / sigma is exact at each point, not read off an interpolated curve; compensated
for slow roll as the record was (``compensated_like_the_data``), as the fit compares them. The residual
panel shows |z|: for a complex vector with independent parts of sigma each, |z| is Rayleigh-distributed, below
RAYLEIGH_95 = 2.45 in 95 % of the windows where the model explains the record.

**Frame and display** (``Display``; config ``report: transient:``): the records' probes may stand at angles
(``model.probes``); the order table and the model hold the plane's x and y. frame "probes" (default) shows each
probe as it reads (p = x cos a + y sin a, measured and model alike; sigma_p^2 = cos^2 a sigma_x^2 + sin^2 a
sigma_y^2, exact for orthogonal probes of equal noise, as the x and y noise is then independent); frame "model"
shows x and y. Amplitudes 0-peak or peak-to-peak, phases as a lag (the keyphasor to the probe's positive peak,
-arg U_h: the proximity-probe systems' convention) or a lead (arg U_h, the rest of the report's): every axis
says which. SI inside; um on the axes.

**The waterfall** (``waterfall``) is the record's short-time spectrum (``scipy.signal.spectrogram``, Hann
segments, 50 % overlap) against the speed of each segment (the keyphasor's profile, speed.tsv), per probe as it
reads (before any rotation to x, y), with the orders 1X..5X drawn: what lies off them (a natural frequency, a
subharmonic, a rub) shows. **The orbits** (``plot_orbits``) at chosen speeds: the record's samples over the
window nearest each speed (offset, drift and runout removed), the orbit its order vectors 1X..HX describe, and
the model's, each with its keyphasor dot (theta = 0: the mark passes), in the plane's x, y (the probes' axes
drawn).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .. import tables
from ..data import measured  # noqa: E402
from ..data.records import probe_angles, record_channels  # noqa: E402
from ..data.order_tracking import order_vector, table_channels  # noqa: E402
from ..data.record_columns import harmonic_column  # noqa: E402
from ..model.probes import DEFAULT_ANGLE_DEG, cos_sin_deg  # noqa: E402
from .report_plots import MICRO, ORDERS  # noqa: E402
from .response_plots import SWEEPS, channels_of, dense_response  # noqa: E402

Array = np.ndarray

#: 95 % quantile of |z| for a complex residual with independent N(0, 1) parts: sqrt(-2 ln 0.05)
RAYLEIGH_95 = float(np.sqrt(-2 * np.log(0.05)))
#: the waterfall's frequency axis reaches this order of the record's top speed
WATERFALL_MAX_ORDER = 5.5
#: the waterfall's segments hold this many revolutions at the record's lowest speed (frequency resolution a
#: quarter of the lowest 1X), at most 1/MIN_SEGMENTS of the record
SEGMENT_REVOLUTIONS, MIN_SEGMENTS = 4, 20


@dataclass(frozen=True)
class Display:
    """How amplitudes and phases are shown (never how they are stored): amplitude "0-peak" or "peak-to-peak",
    phase "lag" (-arg U) or "lead" (arg U), or None for a figure that shows no phase (the waterfall). Every label
    says which."""

    amplitude: str
    phase: str | None

    def __post_init__(self):
        if self.amplitude not in ("0-peak", "peak-to-peak") or self.phase not in ("lag", "lead", None):
            raise ValueError(f"display: amplitude must be 0-peak or peak-to-peak, phase lag or lead; got "
                             f"{self.amplitude!r}, {self.phase!r}")

    @classmethod
    def of(cls, options: Mapping) -> Display:
        """The display of config ``report: transient:`` (``hybridtwin.settings.TransientSettings``, its defaults
        the schema's), as a rule's params carry it (the waterfall's carry no phase: it shows none)."""
        return cls(options["amplitude"], options.get("phase"))

    @property
    def factor(self) -> float:
        """um per metre of 0-peak amplitude, as shown."""
        return MICRO * (2.0 if self.amplitude == "peak-to-peak" else 1.0)

    @property
    def unit(self) -> str:
        return "um pk-pk" if self.amplitude == "peak-to-peak" else "um 0-pk"

    def amp(self, z) -> Array:
        return np.abs(z) * self.factor

    def angle(self, z) -> Array:
        """The shown phase [rad] of complex vectors: -arg for a lag, arg for a lead."""
        if self.phase is None:
            raise ValueError("display: no phase convention given (phase lag or lead)")
        a = np.angle(z)
        return -a if self.phase == "lag" else a

    def amp_label(self, channel: str, h: int) -> str:
        return f"|{channel}, {h}X| [{self.unit}]"

    def phase_label(self, channel: str, h: int) -> str:
        return f"{channel}, {h}X: phase {self.phase} [deg]"


# --- frames -------------------------------------------------------------------------------------------------


def probe_matrix(channels: Sequence[str], sensors=None, frame: str = "probes") -> Array:
    """(C, C) real matrix P: the shown channels = P @ the order table's (the plane's x and y). Frame "model": the
    identity. Frame "probes": for each x, y pair of ``sensors`` (``record_channels``: the machine's planes; None,
    the VARM's x, y), the probes' rows [cos a, sin a] at their angles (``probe_angles``; defaults 0 and 90 deg:
    the identity again)."""
    C = len(channels)
    P = np.eye(C)
    if frame == "model":
        return P
    if frame != "probes":
        raise ValueError(f"frame must be 'probes' or 'model', got {frame!r}")
    names, pairs = record_channels(sensors)
    angles = probe_angles(sensors)
    index = {name: channels.index(name) for name in names if name in channels}
    for i, j in pairs or ():  # no machine: the VARM's x, y at 0 and 90 deg, the identity
        a, b = names[i], names[j]
        if a not in index or b not in index:
            continue
        for name, default in ((a, DEFAULT_ANGLE_DEG["x"]), (b, DEFAULT_ANGLE_DEG["y"])):
            row = np.zeros(C)
            row[index[a]], row[index[b]] = cos_sin_deg(angles.get(name, default))
            P[index[name]] = row
    return P


def project(P: Array, Z: Array, sigma: Array | None = None) -> tuple[Array, Array | None]:
    """Z (..., C) complex in the table's channels -> the shown channels (P @ Z); sigma (..., C) per part ->
    sqrt(P^2 @ sigma^2) (the parts of different channels independent, module docstring)."""
    shown = Z @ P.T
    return shown, None if sigma is None else np.sqrt((sigma**2) @ (P**2).T)


# --- the points: measured windows, their status, the model at their speeds ----------------------------------------


def window_status(rpm: Sequence[float], bands: pd.DataFrame) -> list[str]:
    """Each window's status from the speed band its speed falls in (bands.tsv: band_lo_rpm, band_hi_rpm, usable,
    flags): "used" (a band the fit or validation reads), the band's flag (e.g. sweep_too_fast), "slow_roll"
    below the first band, "beyond_bands" above the last."""
    lo, hi = bands["band_lo_rpm"].to_numpy(float), bands["band_hi_rpm"].to_numpy(float)
    usable = measured.flags(bands["usable"]).to_numpy()
    flags = bands["flags"].fillna("").astype(str).to_numpy()
    out = []
    for r in np.asarray(rpm, float):
        inside = np.flatnonzero((lo <= r) & (r < hi))
        if inside.size:
            k = inside[0]
            out.append("used" if usable[k] else (flags[k] or "kept_out"))
        else:
            out.append("slow_roll" if r < lo.min() else "beyond_bands")
    return out


def model_response(variant, joint: pd.DataFrame, runs: pd.DataFrame, speeds: Sequence[float], harmonics: int,
                   law: str = "law") -> pd.DataFrame:
    """The fitted model at ``speeds`` by continuation, both sweep directions, one per eccentric mass of ``runs``
    (``response_plots.dense_response``: the report's Bode curves, the same values and bow law)."""
    return dense_response(variant, joint, runs, np.unique(np.asarray(speeds, float)), harmonics, law)


def model_at(dense: pd.DataFrame, mass_g: float, kind: str, rpm: Sequence[float], harmonics: int,
             angle_deg: float = 0.0) -> Array:
    """(W, H, C) complex: the model of ``dense`` for this trial mass (``mass_g`` at ``angle_deg``) along the
    record's sweep (kind runup: the run-up branch; coastdown: the run-down one) at each of ``rpm`` (speeds of the
    table, matched to 1e-9; NaN where the table has none or the sweep did not converge)."""
    sweep = SWEEPS["down"] if str(kind).strip().lower() == "coastdown" else SWEEPS["up"]
    channels = channels_of(dense)
    part = dense[(dense["sweep"] == sweep) & np.isclose(dense["eccentric_mass_g"], mass_g)
                 & np.isclose(dense["eccentric_mass_angle_deg"], np.mod(angle_deg, 360.0))]
    rpm = np.asarray(rpm, float)
    out = np.full((rpm.size, harmonics, len(channels)), np.nan + 0j)
    for h in range(1, harmonics + 1):
        rows = part[part["harmonic"] == h].sort_values("rpm")
        speeds = rows["rpm"].to_numpy(float)
        if not speeds.size:
            continue
        k = np.clip(np.searchsorted(speeds, rpm), 0, speeds.size - 1)
        k = np.where((k > 0) & (np.abs(speeds[k - 1] - rpm) < np.abs(speeds[k] - rpm)), k - 1, k)
        match = np.abs(speeds[k] - rpm) <= 1e-9 * np.maximum(np.abs(rpm), 1.0)
        for j, c in enumerate(channels):
            z = tables.complex_values(rows, c)
            out[:, h - 1, j] = np.where(match, z[k], np.nan)
    return out


def compensated_like_the_data(dense: pd.DataFrame, model: Array, mass_g: float, kind: str,
                              runout: pd.DataFrame | None, angle_deg: float = 0.0) -> Array:
    """The model (W, H, C) of ``model_at`` compensated as the record was: where its slow-roll runout was subtracted
    (``runout``: the record's runout table, None or empty when compensation was off), the model's own response at
    ``forward.SLOW_ROLL_RPM`` (a speed of ``dense``) subtracted from the runout's harmonics, as the fit's model
    (``forward.SolverModel``'s ``slow_roll_harmonics``). A response that does not vanish at slow roll (a 2X force's
    static deflection) then lies on the record's curve, not beside it; unbalance and bow responses are unchanged
    (~1e-5 of their value at 1000 RPM)."""
    from ..identify.forward import SLOW_ROLL_RPM

    if runout is None or runout.empty:
        return model
    out = model.copy()
    reference = model_at(dense, mass_g, kind, [SLOW_ROLL_RPM], model.shape[1], angle_deg)[0]  # (H, C)
    for h in sorted(set(int(v) for v in runout["harmonic"])):
        if 1 <= h <= model.shape[1]:
            out[:, h - 1, :] -= reference[h - 1]
    return out


def points(orders: pd.DataFrame, model: Array, P: Array, record: Mapping, bands: pd.DataFrame,
           frame: str = "probes") -> pd.DataFrame:
    """The points table of one record (tables.TRANSIENT.columns; transient.tsv): per window, shown channel and harmonic the
    measured vector and its sigma (``project``ed from the order table), the model's (``model_at``: (W, H, C) in
    the table's channels), z = (measured - model) / sigma per part and |z|, the window's status.
    record: run, kind, role, eccentric_mass_g."""
    channels = table_channels(orders)
    H = model.shape[1]
    status = window_status(orders["rpm"], bands)
    rows = []
    for h in range(1, H + 1):
        parts = [order_vector(orders, c, h) for c in channels]
        Z, S = project(P, np.stack([p[0] for p in parts], 1), np.stack([p[1] for p in parts], 1))
        M, _ = project(P, model[:, h - 1, :])
        z = (Z - M) / S
        for j, c in enumerate(channels):
            for w in range(len(orders)):
                rows.append((record["run"], record.get("kind"), record.get("role"), float(record["eccentric_mass_g"]),
                             w, orders["t_start_s"].iat[w], orders["t_end_s"].iat[w], orders["rpm"].iat[w], frame, c,
                             h, Z[w, j].real, Z[w, j].imag, S[w, j], M[w, j].real, M[w, j].imag, z[w, j].real,
                             z[w, j].imag, abs(z[w, j]), status[w], status[w] == "used"))
    return pd.DataFrame(rows, columns=tables.TRANSIENT.columns)


def table_harmonics(orders: pd.DataFrame) -> int:
    """The highest harmonic of an order table (every channel has it)."""
    channels, h = table_channels(orders), 0
    while all(harmonic_column(c, h + 1, "re") in orders for c in channels):
        h += 1
    return h


def _complex(table: pd.DataFrame, what: str) -> Array:
    return tables.complex_values(table, what)


def _kept_spans(table: pd.DataFrame) -> list[tuple[float, float, str]]:
    """(rpm from, rpm to, status) of each run of consecutive windows (in speed) not used."""
    one = table.drop_duplicates("window").sort_values("rpm")
    spans, current = [], None
    for rpm, status in zip(one["rpm"].to_numpy(float), one["status"]):
        if current is not None and status != current[2]:  # a used window, or another reason, closes the span
            spans.append(tuple(current))
            current = None
        if status != "used":
            current = [rpm, rpm, status] if current is None else [current[0], rpm, status]
    if current is not None:
        spans.append(tuple(current))
    return spans


# --- the figures ---------------------------------------------------------------------------------------------


def _title(table: pd.DataFrame, what: str, variant: str, display: Display,
           marks: str = "points, 2 sigma bars; hollow: kept out of the fit, shaded") -> str:
    r = table.iloc[0]
    frame = "each probe as it reads (at its angle)" if r["frame"] == "probes" else "the plane's x and y"
    return (f"{r['run']} ({r['kind']}, {r['eccentric_mass_g']:g} g, {r['role']}): {what}, variant {variant}\n"
            f"measured order vectors ({marks}) vs the twin along "
            f"the {'run-down' if str(r['kind']) == 'coastdown' else 'run-up'} (line); {frame}; "
            f"{display.amplitude}, phase {display.phase}")


def plot_bode(table: pd.DataFrame, variant: str, display: Display, orders: Sequence[int] = ORDERS
              ) -> plt.Figure:
    """Bode plot of one record's points table: per shown channel three rows (amplitude, phase, |z| on a log
    scale with 1 and RAYLEIGH_95 marked), a column per order; measured with 2 sigma bars (phase only where the
    amplitude stands above 2 sigma), the model's curve through the windows' speeds."""
    channels = list(dict.fromkeys(table["channel"]))
    orders = [h for h in orders if h <= int(table["harmonic"].max())]
    fig, axes = plt.subplots(3 * len(channels), len(orders), sharex=True, squeeze=False,
                             figsize=(max(4.8 * len(orders), 10.0), 7.5 * len(channels)),
                             gridspec_kw={"height_ratios": [3, 2, 1.4] * len(channels)})
    spans = _kept_spans(table)
    for col, h in enumerate(orders):
        for j, c in enumerate(channels):
            amp, ph, res = axes[3 * j, col], axes[3 * j + 1, col], axes[3 * j + 2, col]
            part = table[(table["channel"] == c) & (table["harmonic"] == h)].sort_values("rpm")
            rpm, Z, M = part["rpm"].to_numpy(), _complex(part, "measured"), _complex(part, "model")
            sigma, used = part["sigma_m"].to_numpy(), part["used"].to_numpy(bool)
            model_phase = _unwrapped(display.angle(M), np.isfinite(M) & (np.abs(M) > 0.2 * np.nanmin(sigma)))
            amp.plot(rpm, display.amp(M), "-", color="k", lw=1.2, label="twin (fitted), quasi-steady")
            ph.plot(rpm, np.degrees(model_phase), "-", color="k", lw=1.2)
            strong = np.abs(Z) > 2 * sigma
            near = np.where(np.isfinite(model_phase), model_phase, _unwrapped(display.angle(Z), strong))
            shown_phase = near + _wrap(display.angle(Z) - near)
            for mask, style in ((used, {"fmt": "o", "mfc": "C0"}), (~used, {"fmt": "o", "mfc": "none"})):
                label = "measured, used" if style["mfc"] == "C0" else "measured, kept out"
                amp.errorbar(rpm[mask], display.amp(Z[mask]), yerr=2 * sigma[mask] * display.factor, ms=3,
                             color="C0", elinewidth=0.8, label=label, **style)
                m = mask & strong
                ph.errorbar(rpm[m], np.degrees(shown_phase[m]), yerr=np.degrees(2 * sigma[m] / np.abs(Z[m])),
                            ms=3, color="C0", elinewidth=0.8, **style)
                res.plot(rpm[mask], part["z_abs"].to_numpy()[mask], "o", ms=3, color="C3", mfc=style["mfc"]
                         if style["mfc"] == "none" else "C3")
            amp.plot(rpm, 2 * sigma * display.factor, ":", color="0.5", label="noise (2 sigma)")
            res.axhline(1.0, color="0.5", lw=0.8)
            res.axhline(RAYLEIGH_95, color="0.3", ls="--", lw=0.8, label="|z| 95 % (2.45)")
            res.set_yscale("log")
            amp.set_ylabel(display.amp_label(c, h), fontsize=8)
            ph.set_ylabel(display.phase_label(c, h), fontsize=8)
            res.set_ylabel("|measured - twin|\n/ sigma", fontsize=8)
            amp.set_title(f"{h}X, {c}", fontsize=9)
            for ax in (amp, ph, res):
                ax.grid(alpha=0.3, which="both")
                for lo, hi, label in spans:
                    ax.axvspan(lo, hi, color="0.85", zorder=0)
            for lo, hi, label in spans:  # each kept-out span named, upright along its left edge
                amp.annotate(label.replace("_", " "), (lo, 0.98), xycoords=("data", "axes fraction"), rotation=90,
                             ha="left", va="top", fontsize=7, color="0.35")
            res.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            res.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        axes[-1, col].set_xlabel("speed [RPM]")
    _legend(fig, [axes[0, 0], axes[2, 0]])
    fig.suptitle(_title(table, "Bode plot", variant, display), fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 0.96))
    return fig


def plot_polar(table: pd.DataFrame, variant: str, display: Display, orders: Sequence[int] = ORDERS
               ) -> plt.Figure:
    """Polar plot of one record's points table: a row per shown channel, a column per order; angle the shown
    phase (lag or lead), radius the shown amplitude; measured points coloured by speed (hollow: kept out), the
    twin's curve, the noise circle (2 sigma, median over the windows)."""
    channels = list(dict.fromkeys(table["channel"]))
    orders = [h for h in orders if h <= int(table["harmonic"].max())]
    fig, axes = plt.subplots(len(channels), len(orders), squeeze=False, subplot_kw={"projection": "polar"},
                             figsize=(max(5.6 * len(orders), 10.0), 5.2 * len(channels)))
    fig.subplots_adjust(wspace=0.45, hspace=0.35, left=0.04, right=0.86, bottom=0.1, top=0.86)
    lo, hi = float(table["rpm"].min()), float(table["rpm"].max())
    scatter = None
    for col, h in enumerate(orders):
        for j, c in enumerate(channels):
            ax = axes[j, col]
            part = table[(table["channel"] == c) & (table["harmonic"] == h)].sort_values("rpm")
            Z, M, used = _complex(part, "measured"), _complex(part, "model"), part["used"].to_numpy(bool)
            ax.plot(display.angle(M), display.amp(M), "-", color="k", lw=1.1, label="twin (fitted)")
            speed = part["rpm"].to_numpy()
            scatter = ax.scatter(display.angle(Z[used]), display.amp(Z[used]), c=speed[used], cmap="viridis",
                                 vmin=lo, vmax=hi, s=10, label="measured, used")
            colours = scatter.cmap(scatter.norm(speed[~used]))
            ax.scatter(display.angle(Z[~used]), display.amp(Z[~used]), s=10, facecolors="none", edgecolors=colours,
                       label="measured, kept out")
            noise = 2 * float(np.median(part["sigma_m"])) * display.factor
            ax.plot(np.linspace(0, 2 * np.pi, 90), np.full(90, noise), ":", color="0.4", lw=1, label="noise (2 sigma)")
            ax.set_title(f"{h}X, {c}: radius [{display.unit}], angle phase {display.phase} [deg]", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.set_rlabel_position(100)
    if scatter is not None:
        fig.colorbar(scatter, cax=fig.add_axes((0.9, 0.3, 0.015, 0.45)), label="speed [RPM]")
    _legend(fig, [axes[0, 0]])
    fig.suptitle(_title(table, "polar plot", variant, display, "points coloured by speed; hollow: kept out of the "
                        "fit"), fontsize=9)
    return fig


def _unwrapped(angle: Array, shown: Array) -> Array:
    out = np.full(angle.shape, np.nan)
    if shown.any():
        out[shown] = np.unwrap(angle[shown])
    return out


def _wrap(a: Array) -> Array:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _legend(fig: plt.Figure, axes: Sequence[plt.Axes]) -> None:
    unique = {}
    for ax in axes:
        handles, labels = ax.get_legend_handles_labels()
        unique |= dict(zip(labels, handles))
    fig.legend(unique.values(), unique.keys(), loc="lower center", ncol=min(len(unique), 5), fontsize=8)


# --- the waterfall ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Waterfall:
    """A record's short-time spectra: frequency_hz (F,), rpm (S,) and t_s (S,) of each segment (its mean speed
    and middle), amplitude {channel: (S, F) [m], 0-peak}."""

    frequency_hz: Array
    t_s: Array
    rpm: Array
    amplitude: dict


def waterfall(time_s: Array, channels: Mapping[str, Array], speed: pd.DataFrame, segment_s: float | None = None
              ) -> Waterfall:
    """Short-time amplitude spectra of each channel (``scipy.signal.spectrogram``: Hann segments of
    ``segment_s``, by default SEGMENT_REVOLUTIONS revolutions at the lowest speed of ``speed`` and at most
    1/MIN_SEGMENTS of the record, 50 % overlap, each segment's mean removed), scaled to 0-peak amplitude (a line
    of amplitude A at a bin reads A); each segment's speed from the per-revolution profile (speed.tsv: t_start_s,
    t_end_s, rpm) at its middle."""
    from scipy.signal import spectrogram

    t = np.asarray(time_s, float)
    fs = 1.0 / float(np.median(np.diff(t)))
    if segment_s is None:
        segment_s = min(SEGMENT_REVOLUTIONS * 60.0 / float(speed["rpm"].min()), (t[-1] - t[0]) / MIN_SEGMENTS)
    n = int(max(16, round(segment_s * fs)))
    out, f, middle = {}, None, None
    for name, x in channels.items():
        f, tt, S = spectrogram(np.asarray(x, float), fs=fs, window="hann", nperseg=n, noverlap=n // 2,
                               detrend="constant", scaling="spectrum", mode="magnitude")
        out[name] = 2.0 * S.T  # one-sided: a sine of amplitude A reads A / 2 in either half of the spectrum
        middle = t[0] + tt
    mid = 0.5 * (speed["t_start_s"].to_numpy(float) + speed["t_end_s"].to_numpy(float))
    rpm = np.interp(middle, mid, speed["rpm"].to_numpy(float))
    return Waterfall(f, middle, rpm, out)


def plot_waterfall(fall: Waterfall, run: str, display: Display, orders: int = 5) -> plt.Figure:
    """The waterfall as a colour map per channel: frequency [Hz] across, speed [RPM] up, colour the amplitude in
    dB re 1 um (the display's 0-peak or peak-to-peak), 80 dB below the strongest line; the orders 1X..``orders``X
    dashed (f = h rpm / 60)."""
    names = list(fall.amplitude)
    fig, axes = plt.subplots(1, len(names), figsize=(6.5 * len(names), 6.5), squeeze=False, sharey=True)
    top_f = WATERFALL_MAX_ORDER * float(fall.rpm.max()) / 60.0
    keep = fall.frequency_hz <= top_f
    levels = {c: 20 * np.log10(np.maximum(a[:, keep] * display.factor, 1e-12)) for c, a in fall.amplitude.items()}
    vmax = max(float(v.max()) for v in levels.values())
    order = np.argsort(fall.rpm)
    mesh = None
    for ax, name in zip(axes[0], names):
        mesh = ax.pcolormesh(fall.frequency_hz[keep], fall.rpm[order], levels[name][order], shading="nearest",
                             vmin=vmax - 80.0, vmax=vmax, cmap="viridis")
        for h in range(1, orders + 1):
            ax.plot(h * fall.rpm[order] / 60.0, fall.rpm[order], "--", color="w", lw=0.7, alpha=0.8)
            ax.annotate(f"{h}X", (h * fall.rpm[order][-1] / 60.0, fall.rpm[order][-1]), color="w", fontsize=8,
                        ha="center", va="top")
        ax.set_xlim(0, top_f)
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(f"probe {name}: amplitude [dB re 1 {display.unit}]", fontsize=9)
    axes[0, 0].set_ylabel("speed [RPM] (keyphasor)")
    if mesh is not None:
        fig.colorbar(mesh, ax=axes.ravel().tolist(), shrink=0.8, label=f"dB re 1 {display.unit}")
    fig.suptitle(f"{run}: waterfall of the record (Hann segments, 50 % overlap; dashed: orders 1X-{orders}X)",
                 fontsize=10)
    return fig


# --- the orbits -----------------------------------------------------------------------------------------------


def orbit_speeds(orders: pd.DataFrame, bands: pd.DataFrame, requested: Sequence[float] | None = None
                 ) -> tuple[list[int], list[str]]:
    """(indexes of the order table's windows whose speed is nearest each requested speed, notes on the speeds
    the record does not reach). None: three speeds, the lowest band's, the record's largest 1X (over every
    channel; the middle of the two others where that is within 10 % of the span from the top) and its top
    speed."""
    rpm = orders["rpm"].to_numpy(float)
    notes = []
    if requested is None:
        channels = table_channels(orders)
        first = np.abs(np.stack([order_vector(orders, c, 1)[0] for c in channels], 1)).max(1)
        picks = [float(bands["band_lo_rpm"].min()), float(rpm[int(np.nanargmax(first))]), float(rpm.max())]
        if abs(picks[1] - picks[2]) < 0.1 * np.ptp(rpm):  # the largest 1X at the top: the middle instead
            picks[1] = 0.5 * (picks[0] + picks[2])
    else:
        picks = []
        for r in requested:
            if rpm.min() - 10 <= float(r) <= rpm.max() + 10:
                picks.append(float(r))
            else:
                notes.append(f"orbit at {float(r):g} RPM: the record spans {rpm.min():.0f}-{rpm.max():.0f} RPM")
    return sorted(dict.fromkeys(int(np.argmin(np.abs(rpm - r))) for r in picks), key=lambda w: rpm[w]), notes


def orbit_samples(time_s: Array, xy: Array, theta: Array, window: pd.Series, channels: Sequence[str],
                  runout: pd.DataFrame | None = None) -> tuple[Array, Array]:
    """The samples of one window (t_start_s <= t < t_end_s) of ``xy`` (N, C) [m] less the window's offset and
    drift (the order table's offset_<c>_m, drift_<c>_m over tau = (t - middle) / length) and the slow-roll
    runout (runout.tsv: Re(R_h exp(i h theta)) per channel and harmonic); returns (samples (n, C), theta (n,))."""
    a, b = float(window["t_start_s"]), float(window["t_end_s"])
    take = (time_s >= a) & (time_s < b)
    tau = (time_s[take] - 0.5 * (a + b)) / (b - a)
    out = xy[take].copy()
    th = theta[take]
    for j, c in enumerate(channels):
        out[:, j] -= float(window[f"offset_{c}_m"]) + float(window[f"drift_{c}_m"]) * tau
        if runout is not None and len(runout):
            for r in runout[runout["channel"] == c].itertuples():
                out[:, j] -= (complex(r.runout_re_m, r.runout_im_m) * np.exp(1j * r.harmonic * th)).real
    return out, th


def record_orbits(time_s: Array, xy: Array, theta: Array, orders: pd.DataFrame, bands: pd.DataFrame,
                  runout: pd.DataFrame | None, model: Array, requested: Sequence[float] | None = None
                  ) -> tuple[list[dict], list[str]]:
    """The orbits of one record at the requested speeds (``orbit_speeds``) for ``plot_orbits``, and the notes on
    speeds it does not reach. xy (N, C): the record's channels in the order table's order (the plane's x, y);
    theta (N,): the shaft angle (NaN outside the marks); model (W, H, C): ``model_at``."""
    channels = table_channels(orders)
    picks, notes = orbit_speeds(orders, bands, requested)
    status = window_status(orders["rpm"], bands)
    out = []
    for w in picks:
        samples, _ = orbit_samples(time_s, xy, theta, orders.iloc[w], channels, runout)
        measured = np.array([[order_vector(orders, c, h)[0][w] for c in channels]
                             for h in range(1, model.shape[1] + 1)])
        out.append({"rpm": float(orders["rpm"].iat[w]), "t_start_s": float(orders["t_start_s"].iat[w]),
                    "samples": samples, "measured": measured, "model": model[w], "channels": channels,
                    "status": status[w]})
    return out, notes


def _orbit(vectors: Array, n: int = 181) -> tuple[Array, Array]:
    """x, y over one turn (theta 0..2 pi) of order vectors (H, 2)."""
    theta = np.linspace(0, 2 * np.pi, n)
    h = np.arange(1, vectors.shape[0] + 1)
    e = np.exp(1j * np.outer(theta, h))
    return (e @ vectors[:, 0]).real, (e @ vectors[:, 1]).real


def plot_orbits(orbits: Sequence[dict], run: str, variant: str, pair_names: Sequence[tuple[str, str]],
                angles: Mapping[str, float]) -> plt.Figure:
    """A column per chosen speed, a row per x, y plane: the record's samples (grey), the orbit of its order
    vectors (blue) and the twin's (black dashed), each keyphasor dot (theta = 0) marked; um 0-peak axes in the
    plane's x and y, the probes' axes drawn. orbits: dicts with rpm, t_start_s, samples (n, C), measured (H, C),
    model (H, C) complex, channels (names), status."""
    n_rows = max(len(pair_names), 1)
    fig, axes = plt.subplots(n_rows, max(len(orbits), 1), figsize=(4.3 * max(len(orbits), 1), 4.6 * n_rows),
                             squeeze=False)
    for col, o in enumerate(orbits):
        for row, (a, b) in enumerate(pair_names):
            ax = axes[row, col]
            i, j = o["channels"].index(a), o["channels"].index(b)
            s = o["samples"] * MICRO
            ax.plot(s[:, i], s[:, j], "-", color="0.7", lw=0.4, label="record (offset, runout removed)")
            for vectors, style, label in ((o["measured"], "-", "order vectors 1X..HX"),
                                          (o["model"], "--", "twin (fitted)")):
                v = vectors[:, [i, j]] * MICRO
                if not np.isfinite(v).all():
                    continue
                x, y = _orbit(v)
                colour = "C0" if style == "-" else "k"
                ax.plot(x, y, style, color=colour, lw=1.3, label=label)
                ax.plot(x[0], y[0], "o", color=colour, ms=5, mfc="w" if style == "--" else colour)
            reach = np.nanmax(np.abs(s[:, [i, j]])) if s.size else 1.0
            for name, default in ((a, DEFAULT_ANGLE_DEG["x"]), (b, DEFAULT_ANGLE_DEG["y"])):
                c, si = cos_sin_deg(angles.get(name, default))
                ax.annotate("", (1.05 * reach * c, 1.05 * reach * si), (0, 0),
                            arrowprops={"arrowstyle": "->", "color": "C2", "lw": 0.8})
                ax.annotate(f"probe {name}", (1.1 * reach * c, 1.1 * reach * si), color="C2", fontsize=7)
            ax.set_aspect("equal", "datalim")
            ax.grid(alpha=0.3)
            ax.set_xlabel(f"x (plane {a}/{b}) [um 0-pk]")
            ax.set_ylabel("y [um 0-pk]")
            kept = "" if o["status"] == "used" else f"; kept out: {o['status'].replace('_', ' ')}"
            ax.set_title(f"{o['rpm']:.0f} RPM (t = {o['t_start_s']:.1f} s{kept})", fontsize=9)
    _legend(fig, [axes[0, 0]])
    fig.suptitle(f"{run}: orbits at chosen speeds, variant {variant} (dots: keyphasor, theta = 0; "
                 "the shaft turns from +x towards +y)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    return fig
