"""The plots engineers read of a machine (matplotlib, no screen needed): the Campbell diagram.

``campbell_figure(model, values, rpm)``: the whirl frequencies of any model's linear part (``model.campbell``)
against speed, forward and backward branches apart, the 1X-3X excitation lines, the crossings of the 1X line
(the critical speeds) and the run speeds marked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt  # no backend forced: Agg by itself without a display, or the caller's choice
import numpy as np
import pandas as pd

from .model import Model, campbell

WHIRL_STYLE = {"forward": dict(color="C0", ls="-"), "backward": dict(color="C3", ls="--")}


def branches(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (``model.campbell``) with a column ``branch``: the rank of each mode among the modes of its
    whirl sense at its speed (0 = the lowest forward mode, ...). Following a branch along speed keeps a
    forward and a backward mode apart where they cross."""
    out = table.sort_values(["rpm", "whirl", "frequency_hz"]).copy()
    out["branch"] = out.groupby(["rpm", "whirl"]).cumcount()
    return out.sort_values(["rpm", "mode"])


def critical_speeds(table: pd.DataFrame, harmonic: int = 1) -> pd.DataFrame:
    """Where a branch crosses the ``harmonic`` X line (frequency = harmonic rpm / 60), by linear
    interpolation between the table's speeds: columns whirl, branch, rpm, frequency_hz."""
    rows = []
    for (whirl, branch), group in branches(table).groupby(["whirl", "branch"]):
        group = group.sort_values("rpm")
        rpm, f = group["rpm"].to_numpy(), group["frequency_hz"].to_numpy()
        gap = f - harmonic * rpm / 60.0
        for i in np.flatnonzero(np.sign(gap[:-1]) * np.sign(gap[1:]) < 0):
            t = gap[i] / (gap[i] - gap[i + 1])
            crossing = rpm[i] + t * (rpm[i + 1] - rpm[i])
            rows.append((whirl, int(branch), crossing, harmonic * crossing / 60.0))
    return pd.DataFrame(rows, columns=["whirl", "branch", "rpm", "frequency_hz"]).sort_values("rpm",
                                                                                               ignore_index=True)


def _lowest_branches(table: pd.DataFrame, n_modes: int) -> pd.DataFrame:
    """The branches of the ``n_modes`` lowest modes at the lowest speed, followed over all speeds."""
    first = table[table["rpm"] == table["rpm"].min()].nsmallest(n_modes, "frequency_hz")
    counts = first["whirl"].value_counts()
    keep = table["branch"] < table["whirl"].map(counts).fillna(0)
    return table[keep]


def campbell_figure(model: Model, values: Mapping[str, float], rpm: Sequence[float], run_rpm: Sequence[float] = (),
                    n_modes: int = 6, harmonics: Sequence[int] = (1, 2, 3), title: str = "",
                    table: pd.DataFrame | None = None) -> plt.Figure:
    """The Campbell diagram of ``model`` at parameter values ``values`` over the speeds ``rpm``.

    Whirl frequencies [Hz] of the branches of the ``n_modes`` lowest modes at the lowest speed, followed over
    the speeds (forward solid, backward dashed); the
    ``harmonics`` X lines; the critical speeds (1X crossings) as dots; the run speeds ``run_rpm`` as vertical
    lines. ``table``: a ``model.campbell`` table already computed (then ``values``, ``rpm`` and ``n_modes``
    are not used). The figure's data stay readable: ``fig.campbell`` is the table with its branches and
    ``fig.critical`` the crossings.
    """
    if table is None:  # twice the modes, so that a branch among the lowest is never cut off at high speed
        table = _lowest_branches(branches(campbell(model, values, rpm, 2 * n_modes)), n_modes)
    else:
        table = branches(table)
    if table.empty:
        raise ValueError("Campbell diagram: the model has no oscillating mode at these speeds")
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for (whirl, branch), group in table.groupby(["whirl", "branch"]):
        group = group.sort_values("rpm")
        ax.plot(group["rpm"], group["frequency_hz"], lw=1.5, **WHIRL_STYLE[whirl],
                label=f"{whirl} whirl" if branch == 0 else None, gid=f"{whirl}:{branch}")
    speed = np.array([table["rpm"].min(), table["rpm"].max()])
    top = table["frequency_hz"].max() * 1.05
    for h in harmonics:
        ax.plot(speed, h * speed / 60.0, color="0.4", lw=1, ls=":", gid=f"{h}X")
        end = min(speed[1], top * 60.0 / h)
        ax.annotate(f"{h}X", (end, h * end / 60.0), fontsize=8, color="0.3", ha="right", va="bottom")
    critical = critical_speeds(table, 1)
    if len(critical):
        ax.plot(critical["rpm"], critical["frequency_hz"], "o", color="k", ms=5, mfc="none",
                label="critical speeds (1X)", gid="critical")
        for _, row in critical.iterrows():
            ax.annotate(f"{row['rpm']:.0f}", (row["rpm"], row["frequency_hz"]), textcoords="offset points",
                        xytext=(4, -10) if row["whirl"] == "backward" else (-8, 5), fontsize=7,
                        ha="left" if row["whirl"] == "backward" else "right")
    for i, r in enumerate(sorted(set(float(v) for v in run_rpm))):
        ax.axvline(r, color="C2", lw=0.8, alpha=0.6, label="run speeds" if i == 0 else None, gid=f"run:{r:g}")
    ax.set_xlim(speed)
    ax.set_ylim(0, top)
    ax.set_xlabel("speed [RPM]")
    ax.set_ylabel("whirl frequency [Hz]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(title or f"Campbell diagram, {getattr(model.shaft, 'name', 'shaft')}")
    fig.tight_layout()
    fig.campbell, fig.critical = table, critical
    return fig
