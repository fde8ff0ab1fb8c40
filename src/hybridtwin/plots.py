"""Figures people would rather look at than read (matplotlib, no screen needed)."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib.pyplot as plt  # no backend forced: Agg by itself without a display, or the caller's choice
import numpy as np
import pandas as pd
from PIL import Image  # matplotlib's own dependency: loaded with it


def plot_sweep(table: pd.DataFrame, title: str) -> plt.Figure:
    """1X and 3X sensor amplitudes (0-peak, mm) vs speed, one line per eccentric mass (1X alone when the table
    has no 3X: H < 3)."""
    orders = [h for h in (1, 3) if f"U{h}_re_m" in table]
    fig, axes = plt.subplots(1, len(orders), figsize=(5 * len(orders) + 1, 4), sharex=True, squeeze=False)
    axes = axes[0]
    for h, ax in zip(orders, axes):
        for colour, (mass, group) in enumerate(table.groupby("eccentric_mass_g")):
            group = group.sort_values("rpm")
            ok = group["success"].to_numpy(bool)
            for axis, style in (("U", "-o"), ("V", "--s")):
                amplitude = np.hypot(group[f"{axis}{h}_re_m"], group[f"{axis}{h}_im_m"]) * 1e3
                ax.plot(group["rpm"][ok], amplitude[ok], style, ms=4, color=f"C{colour}", mfc="none",
                        label=f"{'x' if axis == 'U' else 'y'}, {mass:g} g")
            if (~ok).any():
                ax.plot(group["rpm"][~ok], np.full((~ok).sum(), np.nan), "x", color=f"C{colour}")
                for rpm in group["rpm"][~ok]:
                    ax.axvline(rpm, color=f"C{colour}", ls=":", lw=1)
        ax.set_title(f"{h}X at the sensor")
        ax.set_xlabel("speed [RPM]")
        ax.set_ylabel("amplitude, 0-peak [mm]")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"variant {title}: white-box response over the run plan")
    fig.tight_layout()
    return fig


def plot_parity(parity: pd.DataFrame, title: str) -> plt.Figure:
    """Library vs full solver, 1X sensor amplitude (mm), x and y, one colour per eccentric mass."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, axis in zip(axes, ("x", "y")):
        for colour, (mass, group) in enumerate(parity.groupby("eccentric_mass_g")):
            ax.plot(group[f"solver_{axis}_m"] * 1e3, group[f"library_{axis}_m"] * 1e3, ".", ms=3,
                    color=f"C{colour}", label=f"{mass:g} g")
        top = 1e3 * parity[[f"solver_{axis}_m", f"library_{axis}_m"]].to_numpy().max()
        ax.plot([0, top], [0, top], "k-", lw=0.8)
        ax.set_xlabel(f"full solver: 1X amplitude in {axis} [mm]")
        ax.set_ylabel(f"library: 1X amplitude in {axis} [mm]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(title="eccentric mass", fontsize=8)
    fig.suptitle(f"variant {title}: library vs full solver on held-out scenarios")
    fig.tight_layout()
    return fig


#: colours of a saved figure (``save_png``): a line plot's own few colours and their antialiased edges
PNG_COLOURS = 256


def png_palette_bytes(fig: plt.Figure, dpi: int = 100) -> bytes:
    """``fig`` as a PNG of at most ``PNG_COLOURS`` colours (Pillow's octree quantisation of matplotlib's RGB render,
    no dithering, the same bytes for the same figure): a report embeds every PNG, and a figure's few colours and
    their antialiased edges need no 24 bits a pixel (the quick example's 35 PNGs: 5.1 MB -> 1.4 MB; a pixel's
    colour off by 1.3 of 255 levels on average, at an edge by up to 40)."""
    stream = io.BytesIO()
    fig.savefig(stream, format="png", dpi=dpi)
    stream.seek(0)
    image = Image.open(stream).convert("RGB").quantize(colors=PNG_COLOURS, method=Image.Quantize.FASTOCTREE,
                                                       dither=Image.Dither.NONE)
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=True)
    return out.getvalue()


def save_png(fig: plt.Figure, path, dpi: int = 100) -> None:
    """``fig`` written to ``path`` as ``png_palette_bytes`` makes it (the workflow's figures)."""
    Path(path).write_bytes(png_palette_bytes(fig, dpi))
