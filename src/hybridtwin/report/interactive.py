"""The report's main figures, interactive (issue 39, item 2): plotly figures to zoom, read values on hover (with
their units) and show or hide runs and probes from the legend, each written as one self-contained HTML file
(plotly.js embedded: it opens offline) beside its PNG, which stays for documents.

One function per figure, taking what the PNG's function takes:

=====================  ============================================  ==========================================
figure                 PNG                                           here
=====================  ============================================  ==========================================
comparison per run     ``report_plots.plot_run`` (one run)           ``runs_figure`` (every run in one file)
Bode                   ``response_plots.plot_bode``                  ``bode_figure``
polar                  ``response_plots.plot_polar``                 ``polar_figure``
Campbell               ``machine_plots.campbell_figure``             ``interactive_machine.campbell_figure``
mode shapes            ``machine_plots.mode_shape_figure``           ``interactive_machine.mode_shapes_figure``
summary                ``summary.plot_summary``                      ``summary_figure``
diagnosis              ``diagnosis_report.plot``                     ``diagnosis_figure``
=====================  ============================================  ==========================================

The numbers are the PNGs' own, by their code: the signals and whirl spectra from ``report.waveform`` and
``report.whirl``, the Bode curves' phases (unwrapped, each sweep's turned to meet the run-up's, each run's drawn on
the curve's branch of 2 pi) by the Bode PNG's drawing helpers pointed at a recorder (``_Recorder``), the
Campbell diagram's and the mode shapes' tables from the PNG's figure itself (``fig.campbell``, ``fig.modes``).
SI inside; shown in the PNGs' units: a displacement in mm (orbits, signals) or um (harmonic amplitudes,
residuals), a phase in deg, a speed in RPM, a frequency in Hz; every hover label says its unit.

Legend groups: a click on an entry hides or shows its group, a double click shows it alone. Per run (and, in the
comparison per run, per probe: ``<run>: <probe>``), per eccentric mass's model sweep, per branch of the Campbell
diagram. ``write_html`` writes a figure (its own page, plotly.js inside); the report shows them all in one page
with one copy of plotly.js (``interactive_pages.write_gallery``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from matplotlib.colors import to_hex
from plotly.subplots import make_subplots
from scipy import stats

from ..diagnose.diagnosis_status import verdict_colour
from . import interactive_pages as pages
from . import response_plots as rp
from . import summary as sm
from ..identify.uncertainty import ALPHA
from .report import NOISE_FLOOR, RunComparison, waveform, waveform_noise, whirl, whirl_noise
from .report_plots import MICRO, MILLI, ORDERS, VALIDATION_STYLE, probe_pairs

#: the plotly.js options of every file: no plotly logo; the camera button saves a PNG of the current view
CONFIG = pages.CONFIG
#: the validation runs' colour, as in the PNGs
VALIDATION = to_hex(VALIDATION_STYLE["color"])
#: matplotlib line styles -> plotly dashes
DASH = {"-": "solid", "--": "dash", ":": "dot", "-.": "dashdot", "": "solid"}


# --- shared pieces ----------------------------------------------------------------------------------------


def colour(name: str) -> str:
    """A matplotlib colour ("C0", "tab:green", "0.55", "m") as plotly takes it, '#rrggbb'."""
    return to_hex(name)


def number(value: float, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits without an exponent, as the hover's "%{y:.4~r}" writes it."""
    return np.format_float_positional(float(value), precision=digits, unique=False, fractional=False, trim="-")


def hover(*lines: str) -> str:
    """A hover template of ``lines`` (plotly's %{...} fields allowed), without the trace-name box."""
    return "<br>".join(lines) + "<extra></extra>"


def finish_figure(fig: go.Figure, title: str, height: float, width: float | None = None) -> go.Figure:
    """The layout every figure shares: the title, hover on the closest point, a white background, the legend on
    the right (scrolls when long)."""
    fig.update_layout(title={"text": title, "font": {"size": 13}, "x": 0.01}, hovermode="closest",
                      template="plotly_white", height=int(height), width=None if width is None else int(width),
                      legend={"groupclick": "togglegroup", "font": {"size": 10}}, margin={"t": 80, "l": 70, "r": 20})
    fig.update_annotations(font_size=11)  # the panels' titles
    return fig


def write_html(fig: go.Figure, path: str | Path) -> None:
    """``fig`` as one self-contained HTML file at ``path``: plotly.js embedded, packed (opens offline, no network
    needed), the same figure giving the same bytes (the workflow's reruns compare results);
    ``interactive_pages.write_figure``, read back by ``interactive_pages.read_figure``. The report embeds these figures in one page instead
    (``interactive_pages.write_gallery``: plotly.js once)."""
    pages.write_figure(fig, path, title=fig.layout.title.text or "figure")


class LegendGroups:
    """Which legend groups already have their entry: the first trace of a group shows it, the others follow."""

    def __init__(self):
        self.groups: set[str] = set()

    def __call__(self, group: str) -> bool:
        first = group not in self.groups
        self.groups.add(group)
        return first


def speeds_line(rpm: Sequence[float], top: float) -> tuple[list, list]:
    """x, y of vertical lines at each speed of ``rpm`` from 0 to ``top``, in one trace (gaps between them)."""
    x, y = [], []
    for r in sorted(set(float(v) for v in rpm)):
        x += [r, r, None]
        y += [0.0, top, None]
    return x, y


# --- the comparison per run -------------------------------------------------------------------------------


def runs_figure(comparisons: Sequence[RunComparison], variant: str,
                pairs: Sequence[tuple[str, str]] | None = None) -> go.Figure:
    """Every run of ``comparisons`` as ``report_plots.plot_run`` draws one (a row per plane: the orbit, x and y over two
    revolutions with the residual and its +-2 sigma noise band, the whirl spectrum), in one figure: a legend group
    per run and probe (``<run>: <probe>``; ``<run>: orbit, whirl`` per plane), the worst run (largest chi^2/dof)
    shown, the others one click away. pairs: as ``plot_run``'s."""
    planes = {c.run: probe_pairs(c, pairs) for c in comparisons}
    n = max((len(p) for p in planes.values()), default=1)
    specs = [[{"rowspan": 2}, {}, {"rowspan": 2}], [None, {}, None]] * n
    titles = []
    for _ in range(n):
        titles += ["orbit (h = 1..H, DC removed); circle: t = 0", "two revolutions (model frame)",
                   "whirl spectrum of z = x + i y", "measured - model; bands: +-2 sigma of the noise"]
    fig = make_subplots(rows=2 * n, cols=3, specs=specs, column_widths=[1.0, 1.5, 1.3],
                        row_heights=[1.4, 1.0] * n, subplot_titles=titles, horizontal_spacing=0.07,
                        vertical_spacing=0.08 / n)
    worst = max(comparisons, key=lambda c: c.chi2_dof).run if comparisons else None
    for c in comparisons:
        visible = True if c.run == worst else "legendonly"
        head = (f"{c.run} ({'validation, predicted' if c.role == 'validate' else 'fit'}), {c.rpm:.1f} RPM, "
                f"{c.eccentric_mass_g:g} g, chi^2/dof {c.chi2_dof:.3g}")
        for k, pair in enumerate(planes[c.run]):
            _run_plane(fig, pair, 2 * k + 1, head, visible)
    for k in range(n):
        orbit = fig.get_subplot(2 * k + 1, 1).xaxis.plotly_name.replace("axis", "")  # "x", "x5", ...
        fig.update_yaxes(scaleanchor=orbit, row=2 * k + 1, col=1)  # the orbit's true shape
        fig.update_xaxes(title_text="revolutions (Omega t / 2 pi)", row=2 * k + 2, col=2)
        fig.update_yaxes(title_text="displacement [mm]", row=2 * k + 1, col=2)
        fig.update_yaxes(title_text="residual [um]", row=2 * k + 2, col=2)
        fig.update_yaxes(type="log", title_text="|component| [um]", row=2 * k + 1, col=3)
    fig.update_layout(barmode="group")
    return finish_figure(fig, f"variant {variant}: measured vs model per run. Shown: the worst run, {worst}; a legend "
                   "entry shows or hides a run's probe (double click: that one alone)", 560 * n + 120)


#: samples of a run's orbit (one revolution) and of its signals (two): 20 and 16 per period of the 6X, smooth to the
#: eye, half and four fifths of the PNGs' 240 (the main job's four runs figures in float32: 2.7 -> 2.1 MB)
_ORBIT_SAMPLES, _SIGNAL_SAMPLES = 121, 193


def _run_plane(fig: go.Figure, c: RunComparison, row: int, head: str, visible) -> None:
    """One plane's traces of one run (``c``: its x, y channels) from row ``row`` on."""
    shown = LegendGroups()
    x_name, y_name = c.channels[:2]
    group = f"{c.run}: orbit, whirl ({x_name}, {y_name})"
    common = {"legendgroup": group, "visible": visible}
    for Z, label, style in ((c.measured, "measured", {"color": "#000000", "width": 2.2}),
                            (c.model, "model", {"color": colour("C3"), "width": 1.3, "dash": "dash"})):
        angle, xy = waveform(Z, 1.0, _ORBIT_SAMPLES)
        fig.add_trace(go.Scatter(
            x=xy[:, 0] * MILLI, y=xy[:, 1] * MILLI, mode="lines", line=style, name=group, showlegend=shown(group),
            customdata=angle / (2 * np.pi), **common,
            hovertemplate=hover(head, f"orbit, {label}", f"{x_name} %{{x:.4~r}} mm, {y_name} %{{y:.4~r}} mm",
                                "revolution %{customdata:.3f}")), row=row, col=1)
        fig.add_trace(go.Scatter(x=xy[:1, 0] * MILLI, y=xy[:1, 1] * MILLI, mode="markers", showlegend=False,
                                 marker={"color": style["color"], "size": 7}, hoverinfo="skip", **common),
                      row=row, col=1)
    fig.update_xaxes(title_text=f"{x_name} [mm]", row=row, col=1)
    fig.update_yaxes(title_text=f"{y_name} [mm]", row=row, col=1)
    angle, measured = waveform(c.measured, 2.0, _SIGNAL_SAMPLES)
    _, model = waveform(c.model, 2.0, _SIGNAL_SAMPLES)
    turns = angle / (2 * np.pi)
    noise = waveform_noise(c.sigma) * MICRO
    for j, channel in enumerate((x_name, y_name)):
        group_j = f"{c.run}: {channel}"
        line = colour(f"C{j}")
        for values, label, style in ((measured[:, j], "measured", {"color": line, "width": 2}),
                                     (model[:, j], "model", {"color": "#000000", "width": 1,
                                                             "dash": "dash" if j == 0 else "dot"})):
            fig.add_trace(go.Scatter(
                x=turns, y=values * MILLI, mode="lines", line=style, name=group_j, legendgroup=group_j,
                showlegend=shown(group_j), visible=visible,
                hovertemplate=hover(head, f"{channel} {label} %{{y:.4~r}} mm", "revolution %{x:.3f}")),
                row=row, col=2)
        fig.add_trace(go.Scatter(
            x=turns, y=(measured[:, j] - model[:, j]) * MICRO, mode="lines", line={"color": line, "width": 1.3},
            legendgroup=group_j, showlegend=False, visible=visible, name=group_j,
            hovertemplate=hover(head, f"{channel} residual %{{y:.4~r}} um (2 sigma: {2 * noise[j]:.3g} um)",
                                "revolution %{x:.3f}")), row=row + 1, col=2)
        fig.add_trace(go.Scatter(
            x=[0, turns[-1], turns[-1], 0, 0], y=[-2 * noise[j], -2 * noise[j], 2 * noise[j], 2 * noise[j],
                                                  -2 * noise[j]],
            fill="toself", mode="none", fillcolor=line, opacity=0.12, legendgroup=group_j, showlegend=False,
            visible=visible, hoverinfo="skip"), row=row + 1, col=2)
    _whirl_bars(fig, c, row, head, group, common)


def _whirl_bars(fig: go.Figure, c: RunComparison, row: int, head: str, group: str, common: Mapping) -> None:
    """The whirl spectrum of ``report_plots._spectrum``: |measured|, |model|, |residual| per component, backward (-hX)
    then forward (+hX), and the noise-only RMS (``report.whirl_noise``)."""
    H = c.H
    order = [f"{h:+d}X" for h in np.concatenate([-np.arange(H, 0, -1), np.arange(1, H + 1)])]

    def signed(Z):
        forward, backward = whirl(Z)
        return np.abs(np.concatenate([backward[::-1], forward])) * MICRO

    noise = whirl_noise(c.sigma)
    noise = np.concatenate([noise[::-1], noise]) * MICRO
    for Z, label, bar in ((c.measured, "measured", "0.55"), (c.model, "model", "C3"), (c.residual, "residual", "C2")):
        fig.add_trace(go.Bar(x=order, y=signed(Z), name=group, showlegend=False, marker_color=colour(bar),
                             offsetgroup=label, hovertemplate=hover(head, f"%{{x}} {label}: %{{y:.4~r}} um"),
                             **common), row=row, col=3)
    fig.add_trace(go.Scatter(x=order, y=noise, mode="markers", marker={"symbol": "line-ew-open", "size": 24,
                                                                       "color": "#000000", "line": {"width": 2}},
                             showlegend=False, name=group, hovertemplate=hover(head, "%{x} noise RMS %{y:.3g} um"),
                             **common), row=row, col=3)


# --- Bode and polar ----------------------------------------------------------------------------------------


class _Recorder:
    """Stands in for a matplotlib Axes to the Bode PNG's drawing helpers (``response_plots.response_curve``,
    ``measured_points``, ``validation_points``): keeps each line they draw, (x, y, line style, y error, style
    keywords), so that the interactive figure shows the PNG's numbers from the PNG's own code."""

    def __init__(self):
        self.lines: list[tuple[np.ndarray, np.ndarray, str, object, dict]] = []

    def plot(self, x, y, fmt: str = "", **style) -> None:
        self.lines.append((np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float)), fmt, None,
                           style))

    def errorbar(self, x, y, yerr=None, fmt: str = "", **style) -> None:
        self.lines.append((np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float)), fmt, yerr,
                           style))


def _error(yerr) -> dict:
    """A recorded error bar as plotly's error_y: [[below], [above]] or [both]."""
    if yerr is None:
        return {"visible": False}
    below, above = (yerr[0], yerr[1]) if len(yerr) == 2 else (yerr, yerr)
    return {"type": "data", "symmetric": False, "array": np.ravel(above), "arrayminus": np.ravel(below),
            "thickness": 1, "width": 2}


def _run_label(c: RunComparison) -> str:
    return (f"{c.run} ({'validation' if c.role == 'validate' else 'fit'}, {rp.trial_label(*rp.trial_key(c))}, "
            f"{c.rpm:.1f} RPM)")


def bode_figure(dense: pd.DataFrame, comparisons: Sequence[RunComparison], variant: str,
                orders: Sequence[int] = ORDERS) -> go.Figure:
    """``response_plots.plot_bode`` interactive: amplitude (0-peak, um, log) and phase (deg, model frame) of
    harmonics ``orders`` against speed, two rows per channel; the model's run-up (solid) and run-down (dashed) per
    eccentric mass, unstable stretches dotted (a legend entry per mass and sweep); each run's measured point (2
    sigma bars) a legend entry of its own; validation runs measured (stars) and predicted (crosses); the noise
    (2 sigma)."""
    H = min([int(dense["harmonic"].max())] + [c.H for c in comparisons])
    orders = [h for h in orders if h <= H]
    colours = {trial: colour(c) for trial, c in rp.trial_colours(dense).items()}
    channels = rp.channels_of(dense)
    comparisons = rp.by_channel(comparisons, channels)
    fig = make_subplots(rows=2 * len(channels), cols=len(orders), shared_xaxes=True, vertical_spacing=0.04,
                        horizontal_spacing=0.06, subplot_titles=[f"{h}X, {channel}" if r % 2 == 0 else ""
                                                                 for channel in channels for r in range(2)
                                                                 for h in orders])
    shown = LegendGroups()
    for col, h in enumerate(orders, start=1):
        for j, channel in enumerate(channels):
            row = 2 * j + 1
            cell = {"amp": (row, col), "phase": (row + 1, col)}
            sigmas = [c.sigma[h - 1, j] for c in comparisons] or [float(np.nanmax(np.abs(rp.channel_values(dense, j))))]
            floor = 0.2 * min(sigmas) * MICRO  # plot_bode's: a vanishing harmonic's phase is not drawn
            # the hover gives the true amplitude (customdata): the line drawn stops at the floor
            amp_unit = f"|{channel}, {h}X| %{{customdata:.4~r}} um"
            ups = {}
            for trial, both in dense[dense["harmonic"] == h].groupby(rp.TRIAL, sort=True):
                sweeps = {sweep: part for sweep, part in both.groupby("sweep")}
                for key, style in (("up", "-"), ("down", "--")):
                    amp, ph, part = _Recorder(), _Recorder(), sweeps[rp.SWEEPS[key]]
                    up = rp.response_curve(amp, ph, part, j, "", style, None, floor, ups.get(trial))
                    ups.setdefault(trial, up)
                    group = f"{rp.trial_label(*trial)} model, {rp.SWEEPS[key]}"
                    # response_curve's order: by speed
                    true = np.abs(rp.channel_values(part.sort_values("rpm"), j)) * MICRO
                    for k, (x, y, fmt, _, _) in enumerate(amp.lines + ph.lines):
                        phase = k >= len(amp.lines)
                        fig.add_trace(go.Scatter(
                            x=x, y=y, mode="lines", name=group, legendgroup=group,
                            showlegend=not phase and shown(group), customdata=None if phase else true,
                            line={"color": colours[trial], "dash": DASH[fmt], "width": 1.3 if fmt != ":" else 1.0},
                            hovertemplate=hover(group + (" (unstable)" if fmt == ":" else ""),
                                                "%{x:.1f} RPM", f"phase of {channel}, {h}X %{{y:.4~r}} deg"
                                                if phase else amp_unit)), *cell["phase" if phase else "amp"])
                for c in comparisons:
                    if c.role == "fit" and rp.trial_key(c) == trial:
                        amp, ph = _Recorder(), _Recorder()
                        rp.measured_points(amp, ph, c, h, j, "", floor, rp.near_speed(ups, c), "")
                        _points(fig, c, h, j, amp, ph, cell, colours[trial], "circle", "measured", shown)
            for c in comparisons:
                if c.role == "validate":
                    amp, ph = _Recorder(), _Recorder()
                    rp.validation_points(amp, ph, c, h, j, floor, rp.near_speed(ups, c))
                    _points(fig, c, h, j, amp, ph, cell, VALIDATION, None, None, shown)
            ordered = sorted(comparisons, key=lambda c: c.rpm)
            if ordered:
                fig.add_trace(go.Scatter(
                    x=[c.rpm for c in ordered], y=[2 * c.sigma[h - 1, j] * MICRO for c in ordered], mode="lines",
                    line={"color": colour("0.5"), "dash": "dot", "width": 1}, name="noise (2 sigma)",
                    legendgroup="noise", showlegend=shown("noise"),
                    hovertemplate=hover("noise (2 sigma)", "%{x:.1f} RPM", f"{channel}, {h}X %{{y:.3g}} um")),
                    *cell["amp"])
            fig.update_yaxes(type="log", title_text=f"|{channel}, {h}X| [um]", row=row, col=col)
            fig.update_yaxes(title_text="phase [deg]", row=row + 1, col=col)
        fig.update_xaxes(title_text="speed [RPM]", row=2 * len(channels), col=col)
    return finish_figure(fig, f"variant {variant}: Bode plots, model by continuation (solid run-up, dashed run-down, "
                   "dotted unstable) vs measured (2 sigma bars); magenta: validation runs measured (stars) and "
                   "predicted (crosses)", 520 * len(channels) + 100)


def _points(fig: go.Figure, c: RunComparison, h: int, j: int, amp: _Recorder, ph: _Recorder, cell: Mapping,
            line: str, symbol: str | None, kind: str | None, shown: LegendGroups) -> None:
    """A run's recorded points in one Bode panel pair, in the run's own legend group; the hover gives the true
    amplitude (the drawn one stops at the panel's floor) and phase, and the 2 sigma of the noise."""
    channel = c.channels[j]
    group = _run_label(c)
    z, m, s = c.measured[h - 1, j], c.model[h - 1, j], c.sigma[h - 1, j]
    for recorder, where in ((amp, "amp"), (ph, "phase")):
        for x, y, fmt, yerr, style in recorder.lines:
            marker = symbol or ("star-open" if style.get("marker") == VALIDATION_STYLE["marker"] else "x-thin-open")
            kind_here = kind or ("measured" if marker == "star-open" else "predicted")
            value = z if kind_here == "measured" else m
            fig.add_trace(go.Scatter(
                x=x, y=y, mode="markers", name=group, legendgroup=group, showlegend=shown(group),
                marker={"symbol": marker, "color": line, "size": 11 if symbol is None else 7,
                        "line": {"color": line, "width": 1.5}}, error_y=_error(yerr),
                hovertemplate=hover(f"{group}, {kind_here}", f"{c.rpm:.1f} RPM",
                                    f"|{channel}, {h}X| {number(abs(value) * MICRO)} um, phase "
                                    f"{np.degrees(np.angle(value)):.1f} deg (model frame)"
                                    if where == "amp" else f"phase of {channel}, {h}X %{{y:.4~r}} deg",
                                    f"noise {2 * s * MICRO:.3g} um (2 sigma)")), *cell[where])


def polar_figure(dense: pd.DataFrame, comparisons: Sequence[RunComparison], variant: str,
                 orders: Sequence[int] = ORDERS) -> go.Figure:
    """``response_plots.plot_polar`` interactive: each channel's harmonics ``orders`` in the complex plane (model
    frame, radius in um, angle in deg): the model's run-up (solid) and run-down (dashed) per mass, every run's
    measured point (a legend entry each), the validation runs measured (stars) and predicted (crosses), the
    noise circle (2 sigma)."""
    H = min([int(dense["harmonic"].max())] + [c.H for c in comparisons])
    orders = [h for h in orders if h <= H]
    colours = {trial: colour(c) for trial, c in rp.trial_colours(dense).items()}
    channels = rp.channels_of(dense)
    comparisons = rp.by_channel(comparisons, channels)
    fig = make_subplots(rows=len(channels), cols=len(orders), specs=[[{"type": "polar"}] * len(orders)]
                        * len(channels), subplot_titles=[f"{h}X, {channel} [um]" for channel in channels
                                                         for h in orders], vertical_spacing=0.08)
    shown = LegendGroups()

    def point(z: complex, row: int, col: int, group: str, text: str, marker: Mapping, channel: str, h: int,
              line: str | None = None) -> None:
        fig.add_trace(go.Scatterpolar(
            r=[abs(z) * MICRO], theta=[np.degrees(np.angle(z))], mode="markers", name=group, legendgroup=group,
            showlegend=shown(group), marker=marker,
            hovertemplate=hover(text, f"|{channel}, {h}X| %{{r:.4~r}} um", "phase %{theta:.1f} deg")), row, col)

    for col, h in enumerate(orders, start=1):
        for j, channel in enumerate(channels):
            row = j + 1
            for (mass, angle, sweep), part in dense[dense["harmonic"] == h].groupby(rp.TRIAL + ["sweep"]):
                z = rp.channel_values(part, j)
                group = f"{rp.trial_label(mass, angle)} model, {sweep}"
                fig.add_trace(go.Scatterpolar(
                    r=np.abs(z) * MICRO, theta=np.degrees(np.angle(z)), mode="lines", name=group,
                    legendgroup=group, showlegend=shown(group), customdata=part["rpm"].to_numpy(),
                    line={"color": colours[(mass, angle)], "dash": "solid" if sweep == rp.SWEEPS["up"] else "dash",
                          "width": 1.2},
                    hovertemplate=hover(group, "%{customdata:.1f} RPM", f"|{channel}, {h}X| %{{r:.4~r}} um",
                                        "phase %{theta:.1f} deg")), row, col)
            for c in comparisons:
                group = _run_label(c)
                if c.role == "fit":
                    point(c.measured[h - 1, j], row, col, group, f"{group}, measured", channel=channel, h=h,
                          marker={"color": colours.get(rp.trial_key(c), "#000000"), "size": 7})
                else:
                    for z, kind, symbol in ((c.measured[h - 1, j], "measured", "star-open"),
                                            (c.model[h - 1, j], "predicted", "x-thin-open")):
                        point(z, row, col, group, f"{group}, {kind}", channel=channel, h=h,
                              marker={"symbol": symbol, "size": 11, "color": VALIDATION,
                                      "line": {"color": VALIDATION, "width": 1.5}})
            if comparisons:
                noise = 2 * np.median([c.sigma[h - 1, j] for c in comparisons]) * MICRO
                fig.add_trace(go.Scatterpolar(
                    r=np.full(91, noise), theta=np.linspace(0, 360, 91), mode="lines", name="noise (2 sigma)",
                    legendgroup="noise", showlegend=shown("noise"), line={"color": colour("0.4"), "dash": "dot",
                                                                          "width": 1},
                    hovertemplate=hover(f"noise (2 sigma) {noise:.3g} um")), row, col)
    return finish_figure(fig, f"variant {variant}: polar plots, model by continuation (solid run-up, dashed run-down) "
                         "vs measured, model's frame; magenta: validation runs", 460 * len(channels) + 120,
                   max(420 * len(orders), 900))


# --- the summary and the diagnosis -------------------------------------------------------------------------


def summary_figure(ledger: pd.DataFrame, errors: Mapping[str, pd.DataFrame]) -> go.Figure:
    """``summary.plot_summary`` interactive. Top: chi^2/dof of the fit runs and of the validation runs variant by
    variant, against the noise floor. Bottom: per run (rows, ``summary.run_order``) and variant (columns) the
    run's chi^2/dof (colour on a log scale, the number written, bold beyond the noise); the hover says the run,
    the variant, the value and whether it is beyond the noise (p < ALPHA)."""
    variants = [str(v) for v in ledger["variant"]]
    runs = sm.run_order(errors)
    table = pd.concat({v: errors[v].set_index("run")[["chi2_dof", "beyond_noise"]] for v in variants},
                      names=["variant", "run"]).reset_index()
    grid = table.pivot(index="run", columns="variant", values="chi2_dof").reindex(index=runs["run"],
                                                                                  columns=variants)
    beyond = table.pivot(index="run", columns="variant", values="beyond_noise").reindex(
        index=runs["run"], columns=variants).eq(True)  # a run a variant lacks: not beyond
    values = grid.to_numpy(float)
    fig = make_subplots(rows=2, cols=1, row_heights=[2.4, 2.6 + 0.24 * len(runs)], vertical_spacing=0.1,
                        subplot_titles=["the error, variant by variant (1 = noise floor)",
                                        f"where each variant fails: chi^2/dof per run, bold beyond the noise "
                                        f"(p < {ALPHA:g}); * validation run"])
    position = np.arange(len(variants))
    fig.add_trace(go.Scatter(x=position, y=ledger["chi2_dof"], mode="lines+markers", name="fit runs",
                             line={"color": "#000000", "width": 2}, marker={"symbol": "square", "size": 9},
                             customdata=variants, hovertemplate=hover("%{customdata}: fit runs",
                                                                      "chi^2/dof %{y:.4~r}")), row=1, col=1)
    validation = ledger["validation_chi2_dof"].astype(float)
    if np.isfinite(validation).any():
        fig.add_trace(go.Scatter(x=position, y=validation, mode="lines+markers", name="validation runs (never "
                                 "fitted)", line={"color": VALIDATION, "dash": "dash"},
                                 marker={"symbol": "star", "size": 12}, customdata=variants,
                                 hovertemplate=hover("%{customdata}: validation runs", "chi^2/dof %{y:.4~r}")),
                      row=1, col=1)
    fig.add_hrect(y0=NOISE_FLOOR, y1=sm.NEAR_NOISE * NOISE_FLOOR, fillcolor="green", opacity=0.25, line_width=0,
                  row=1, col=1)
    fig.add_hline(y=NOISE_FLOOR, line={"color": "green", "width": 1.5}, row=1, col=1)
    finite = values[np.isfinite(values)]
    top = max(float(finite.max()) if finite.size else 10.0, 10.0)
    labels = [f"{'* ' if r.role != 'fit' else ''}{r.run} ({r.rpm:.0f} RPM, {r.eccentric_mass_g:g} g)"
              for r in runs.itertuples()]
    text = [[("" if not np.isfinite(v) else f"<b>{sm.short_number(v)}</b>" if b else sm.short_number(v))
             for v, b in zip(row, brow)] for row, brow in zip(values, beyond.to_numpy())]
    said = [[(f"run {labels[i]}<br>variant {variants[j]}<br>chi^2/dof {number(v)}"
              + (f", beyond the noise (p < {ALPHA:g})" if beyond.iat[i, j] else ", within the noise"))
             if np.isfinite(v) else "" for j, v in enumerate(row)] for i, row in enumerate(values)]
    ticks = [t for t in (0.3, 1, 3, 10, 30, 100, 300, 1000, 3000, 1e4, 3e4, 1e5) if t <= top]
    fig.add_trace(go.Heatmap(
        x=position, y=np.arange(len(runs)), z=np.log10(np.clip(values, 0.1, None)), zmin=np.log10(0.3),
        zmax=np.log10(top), colorscale="RdYlGn_r", text=text, texttemplate="%{text}", customdata=said,
        hovertemplate=hover("%{customdata}"), showscale=True, name="chi^2/dof per run",
        colorbar={"title": {"text": "chi^2/dof"}, "tickvals": np.log10(ticks), "ticktext": [f"{t:g}" for t in ticks],
                  "len": 0.55, "y": 0.3}), row=2, col=1)
    for row in (1, 2):
        fig.update_xaxes(tickvals=position, ticktext=variants, range=[-0.5, len(variants) - 0.5], zeroline=False,
                         row=row, col=1)
    fig.update_yaxes(type="log", title_text="chi^2 / dof", row=1, col=1)
    fig.update_yaxes(tickvals=np.arange(len(runs)), ticktext=labels, autorange="reversed", row=2, col=1)
    return finish_figure(fig, "The answer first: the error per variant and where each variant fails",
                   420 + 22 * len(runs), max(640, 160 * len(variants) + 360))


def diagnosis_figure(result) -> go.Figure:
    """``diagnosis_report.plot`` interactive, for a ``conclusion.Diagnosis``: left, each candidate's score statistic
    (the chi^2 drop it predicts; colour: its verdict) with the significance threshold; right, chi^2/dof with each
    candidate added, predicted (open) and refitted (filled), against the variant's and the noise floor."""
    t = result.table.iloc[::-1]
    s = result.summary
    fig = make_subplots(rows=1, cols=2, shared_yaxes=True, horizontal_spacing=0.04,
                        subplot_titles=[f"{s['variant']}: candidate effects (green: add)", "chi^2 / dof"])
    effects = list(t["effect"])
    threshold = stats.chi2.isf(s["alpha_per_candidate"], t["dof"])
    said = [f"score statistic {number(r.statistic)} (threshold {number(limit, 3)}), p {r.p_value:.3g}<br>"
            f"{getattr(r, 'verdict', '')}" for r, limit in zip(t.itertuples(), threshold)]
    fig.add_trace(go.Bar(
        x=np.maximum(t["statistic"], 1e-3), y=effects, orientation="h", name="score statistic",
        marker_color=[colour(verdict_colour(code)) for code in t["verdict_code"]], customdata=said,
        hovertemplate=hover("%{y}", "%{customdata}")), row=1, col=1)
    fig.add_trace(go.Scatter(x=threshold, y=effects, mode="markers", name="significance threshold",
                             marker={"symbol": "line-ns-open", "size": 18, "color": "#000000", "line": {"width": 2}},
                             hovertemplate=hover("%{y}: threshold %{x:.3~r}")), row=1, col=1)
    for column, label, fill in (("predicted_chi2_dof", "predicted, added", "open"),
                                ("confirmed_chi2_dof", "refitted, added", "")):
        fig.add_trace(go.Scatter(x=t[column], y=effects, mode="markers", name=label,
                                 marker={"symbol": f"circle{'-' + fill if fill else ''}", "size": 10,
                                         "color": colour("tab:blue")},
                                 hovertemplate=hover("%{y}" + f", {label}", "chi^2/dof %{x:.4~r}")), row=1, col=2)
    for x, label, line in ((s["base_chi2_dof"], f"{s['variant']}: {s['base_chi2_dof']:.3g}", colour("tab:red")),
                           (1.0, "noise floor", "#000000")) if effects else ():
        fig.add_trace(go.Scatter(x=[x, x], y=[effects[0], effects[-1]], mode="lines", name=label,
                                 line={"color": line, "dash": "dash" if x == 1.0 else "solid"},
                                 hovertemplate=hover(f"{label.split(':')[0]}: chi^2/dof {number(x)}")), row=1, col=2)
    fig.update_xaxes(type="log", title_text="score statistic (predicted chi^2 drop)", row=1, col=1)
    fig.update_xaxes(type="log", title_text="chi^2 / dof", row=1, col=2)
    return finish_figure(fig, f"Diagnosis of {s['variant']}: which effect is missing", 26 * len(t) + 260)
