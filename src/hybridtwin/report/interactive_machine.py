"""The machine's figures of the report, interactive (issue 39, item 2; ``interactive`` has the others and the
writer): the Campbell diagram and the mode shapes of ``machine_plots``, as plotly figures to zoom, hover (speed in
RPM, frequency in Hz, log decrement, position along the shaft in m) and toggle branches and modes.

Each takes what its PNG's function takes and draws that function's own numbers: the PNG's figure is made, its data
(``fig.campbell`` and ``fig.critical``; ``fig.modes`` and ``fig.shapes``) taken and the figure closed, so the two
files cannot disagree (no second eigen-solution, no second choice of the modes drawn).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from ..model.model import Model
from . import machine_plots as mp
from .interactive import finish_figure, LegendGroups, speeds_line, colour, hover


def _style(whirl: str) -> dict:
    """A whirl's line as the PNG draws it (``machine_plots.WHIRL_STYLE``)."""
    style = mp.WHIRL_STYLE[whirl]
    return {"color": colour(style["color"]), "dash": "dash" if style["ls"] == "--" else "solid", "width": 1.6}


def campbell_figure(model: Model, values: Mapping[str, float], rpm: Sequence[float], run_rpm: Sequence[float] = (),
                    n_modes: int = 6, harmonics: Sequence[int] = (1, 2, 3), title: str = "",
                    table: pd.DataFrame | None = None, operating: Sequence[float] | None = None) -> go.Figure:
    """``machine_plots.campbell_figure`` interactive (the same arguments): each branch's whirl frequency [Hz]
    against speed [RPM] (forward solid, backward dashed; a legend entry per branch) and below it its log
    decrement; the ``harmonics`` X lines, the critical speeds (1X crossings), the run speeds and the operating
    range. Pass ``table=`` the PNG's ``fig.campbell`` to skip the eigenvalues' second computation."""
    png = mp.campbell_figure(model, values, rpm, run_rpm, n_modes, harmonics, title, table, operating)
    table, critical = png.campbell, png.critical
    mp.plt.close(png)
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, row_heights=[2.2, 1.0], vertical_spacing=0.07,
                        subplot_titles=["", "damping: logarithmic decrement 2 pi zeta / sqrt(1 - zeta^2) of each "
                                            "branch (< 0: unstable)"])
    shown = LegendGroups()
    for (whirl, branch), group in table.groupby(["whirl", "branch"]):
        group = group.sort_values("rpm")
        name = f"{branch + 1}{whirl[0].upper()}: {whirl} whirl, branch {branch + 1}"
        both = np.column_stack([group["frequency_hz"], group["log_decrement"]])
        for row, y, value in ((1, group["frequency_hz"], "%{y:.4~r} Hz, log decrement %{customdata[1]:.3~r}"),
                              (2, group["log_decrement"], "log decrement %{y:.3~r} at %{customdata[0]:.4~r} Hz")):
            fig.add_trace(go.Scatter(x=group["rpm"], y=y, mode="lines", line=_style(whirl), name=name,
                                     legendgroup=name, showlegend=shown(name), customdata=both,
                                     hovertemplate=hover(name, "%{x:.0f} RPM", value)), row=row, col=1)
    speed = np.array([table["rpm"].min(), table["rpm"].max()])
    top = float(table["frequency_hz"].max()) * 1.05
    for h in harmonics:
        fig.add_trace(go.Scatter(x=speed, y=h * speed / 60.0, mode="lines", name=f"{h}X", legendgroup="excitation",
                                 showlegend=shown(f"{h}X"), line={"color": colour("0.4"), "dash": "dot", "width": 1},
                                 hovertemplate=hover(f"{h}X excitation", "%{x:.0f} RPM: %{y:.4~r} Hz")), row=1, col=1)
    if len(critical):
        fig.add_trace(go.Scatter(
            x=critical["rpm"], y=critical["frequency_hz"], mode="markers", name="critical speeds (1X)",
            marker={"symbol": "circle-open", "size": 9, "color": "#000000", "line": {"width": 1.5}},
            customdata=np.column_stack([critical["whirl"], critical["branch"] + 1, critical["log_decrement"]]),
            hovertemplate=hover("critical speed %{x:.0f} RPM (%{y:.4~r} Hz)",
                                "%{customdata[0]} whirl, branch %{customdata[1]}",
                                "log decrement %{customdata[2]:.3~r}")), row=1, col=1)
    if len(run_rpm):
        x, y = speeds_line(run_rpm, top)
        fig.add_trace(go.Scatter(x=x, y=y, mode="lines", name="run speeds", opacity=0.6,
                                 line={"color": colour("C2"), "width": 0.8},
                                 hovertemplate=hover("run speed %{x:.1f} RPM")), row=1, col=1)
    if operating is not None:
        fig.add_vrect(x0=min(operating), x1=max(operating), fillcolor=colour("C2"), opacity=0.12, line_width=0,
                      row="all", col=1)
    fig.add_hline(y=0.0, line={"color": "#000000", "width": 0.8}, row=2, col=1)  # below: a mode that grows
    finite = table["log_decrement"].to_numpy(float)
    finite = finite[np.isfinite(finite)]
    if finite.size:  # every branch's decrement in view, the zero line too (as the PNG)
        lo, hi = min(finite.min(), 0.0), max(finite.max(), 0.0)
        pad = 0.08 * (hi - lo) or 0.1
        fig.update_yaxes(range=[lo - pad, hi + pad], row=2, col=1)
    fig.update_xaxes(range=list(speed), row=1, col=1)
    fig.update_yaxes(range=[0, top], title_text="whirl frequency [Hz]", row=1, col=1)
    fig.update_yaxes(title_text="log decrement", row=2, col=1)
    fig.update_xaxes(title_text="speed [RPM]", row=2, col=1)
    return finish_figure(fig, title or f"Campbell diagram, {getattr(model.shaft, 'name', 'shaft')}", 780)


def mode_shapes_figure(model: Model, values: Mapping[str, float], rpm: float = 0.0, n_modes: int = 4,
                       title: str = "", modes: mp.Modes | None = None) -> go.Figure:
    """``machine_plots.mode_shape_figure`` interactive (the same arguments): a panel per mode drawn by the PNG (its
    frequency and whirl in the panel's title and legend entry), the deflection along the shaft (largest +1), the
    nodes as dots, the machine's bearings, disks, unbalance planes and probes marked (hover: name and z [m])."""
    png = mp.mode_shape_figure(model, values, rpm, n_modes, title, modes)
    picked, (z, shapes) = png.modes, png.shapes
    mp.plt.close(png)
    shaft = model.shaft
    at_node = np.isin(z, np.asarray(shaft.z, float))  # the Hermite points include each node's own z
    labels = [f"mode {k + 1}: {r.frequency_hz:.4g} Hz, "
              + ("x and y planes alike" if r.pair else f"{r.whirl} whirl") for k, r in enumerate(picked.itertuples())]
    fig = make_subplots(rows=len(labels), cols=1, shared_xaxes=True, subplot_titles=labels,
                        vertical_spacing=0.25 / max(len(labels), 1))
    shown = LegendGroups()
    for k, label in enumerate(labels):
        fig.add_trace(go.Scatter(x=z, y=shapes[:, k], mode="lines", name=label, legendgroup=label,
                                 line={"color": colour("C0"), "width": 1.6},
                                 hovertemplate=hover(label, "z %{x:.4~r} m", "deflection %{y:.3~r} (largest 1)")),
                      row=k + 1, col=1)
        fig.add_trace(go.Scatter(x=z[at_node], y=shapes[at_node, k], mode="markers", legendgroup=label,
                                 showlegend=False, marker={"color": colour("C0"), "size": 5}, name=label,
                                 hovertemplate=hover(label, "node at z %{x:.4~r} m", "deflection %{y:.3~r}")),
                      row=k + 1, col=1)
        fig.add_hline(y=0.0, line={"color": colour("0.6"), "width": 0.8}, row=k + 1, col=1)
        _machine(fig, shaft, k + 1, shown)
        fig.update_yaxes(range=[-1.3, 1.3], title_text="deflection", row=k + 1, col=1)
    fig.update_xaxes(title_text="z along the shaft [m]", row=len(labels), col=1)
    return finish_figure(fig, title or f"Undamped mode shapes at {rpm:g} RPM, {getattr(shaft, 'name', 'shaft')}",
                   200 * len(labels) + 140)


def _machine(fig: go.Figure, shaft, row: int, shown: LegendGroups) -> None:
    """The places ``machine_plots.mark_machine`` marks, on the shaft axis of panel ``row``: bearings (triangles),
    disks (bars), unbalance planes (stars), probes (diamonds); a legend entry per kind."""
    z = np.asarray(shaft.z, float)
    kinds = (("bearings", getattr(shaft, "bearings", ()), "triangle-up", "0.7", 12, lambda b: f"bearing {b.name}"),
             ("disks", getattr(shaft, "disks", ()), "line-ns-open", "C1", 30,
              lambda d: f"disk {getattr(d, 'name', '')}"),
             ("unbalance planes", getattr(shaft, "unbalance_planes", ()), "star", "C3", 13,
              lambda p: f"unbalance plane {p.name}"),
             ("probes", getattr(shaft, "sensors", ()), "diamond", "C2", 9, lambda s: f"probe {s.name}"))
    for kind, items, symbol, fill, size, name in kinds:
        if not items:
            continue
        nodes = [item.node for item in items]
        fig.add_trace(go.Scatter(
            x=z[nodes], y=np.zeros(len(nodes)), mode="markers", name=kind, legendgroup=kind, showlegend=shown(kind),
            marker={"symbol": symbol, "size": size, "color": colour(fill), "line": {"color": colour(fill), "width": 3}
                    if symbol.startswith("line") else {"color": "#000000", "width": 1}},
            customdata=[f"{name(item)} (node {item.node})" for item in items],
            hovertemplate=hover("%{customdata}", "z %{x:.4~r} m")), row=row, col=1)
