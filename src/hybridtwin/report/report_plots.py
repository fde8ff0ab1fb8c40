"""The report's figures: where a variant fails, drawn from the tables of ``hybridtwin.report.report`` (its module
docstring states the conventions: the model frame, the whirl, chi^2 / dof).

One run (``plot_run``: orbit, signals over two revolutions with the residual, the residual's whirl spectrum, a row per
plane with an x and a y probe), the error map over speed and unbalance mass (``plot_error_map``) and the ledger from
variant to variant (``plot_ledger``); and the style the report's other figures share (``ORDERS``, ``VALIDATION_STYLE``,
``mass_colours``, ``MICRO``, ``MILLI``). The per-run estimates and their drift: ``hybridtwin.report.drift``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm

from ..data.records import record_channels
from ..plots import plt
from ..identify.uncertainty import ALPHA
from .report import NOISE_FLOOR, RunComparison, pooled, waveform, waveform_noise, whirl, whirl_noise

Array = np.ndarray


#: harmonics shown in the Bode and polar plots
ORDERS = (1, 2, 3)
#: marker and colour of the validation runs in every figure
VALIDATION_STYLE = {"marker": "*", "color": "m", "ms": 11}
MICRO = 1e6  # m -> um
MILLI = 1e3  # m -> mm


def mass_colours(masses: Iterable) -> dict:
    """One colour per eccentric mass (or per trial, (mass, angle)), heaviest first (C0, C1, ...; magenta is kept
    for validation runs)."""
    masses = sorted(set(masses), reverse=True)
    palette = [f"C{i}" for i in range(10) if i != 6]  # C6 (pink) is too close to the validation magenta
    return {m: palette[i % len(palette)] for i, m in enumerate(masses)}


def _run_title(c: RunComparison) -> str:
    return (f"{c.run} ({'validation, predicted' if c.role == 'validate' else 'fit'}): {c.rpm:.1f} RPM, "
            f"{c.eccentric_mass_g:g} g; chi^2/dof = {c.chi2_dof:.3g}, error {100 * c.error_rel:.2g} %")


def plot_run(c: RunComparison, variant: str, pairs: Sequence[tuple[str, str]] | None = None) -> plt.Figure:
    """One run: orbit, x and y over two revolutions with the residual, and the residual whirl spectrum; a row per
    plane with an x and a y probe (``pairs``: the channels' names, ``sensor_pair_names``; None: consecutive
    channels, the VARM's x, y, one row). A probe without a partner has no orbit: it is in the run's rows of
    harmonics.tsv and in its chi^2, and the title says so."""
    pairs = probe_pairs(c, pairs)
    fig = plt.figure(figsize=(14, 6.2 * len(pairs)))
    grid = fig.add_gridspec(2 * len(pairs), 3, width_ratios=(1.0, 1.5, 1.3), height_ratios=(1.4, 1.0) * len(pairs))
    for k, pair in enumerate(pairs):
        _orbit(fig.add_subplot(grid[2 * k:2 * k + 2, 0]), pair)
        signals = fig.add_subplot(grid[2 * k, 1])
        _signals(signals, fig.add_subplot(grid[2 * k + 1, 1], sharex=signals), pair)
        _spectrum(fig.add_subplot(grid[2 * k:2 * k + 2, 2]), pair)
    left = [name for name in c.channels if not any(name in pair.channels for pair in pairs)]
    shown = "" if not left else (f"\nnot drawn: channel{'s' if len(left) > 1 else ''} {', '.join(left)} (no pair); "
                                 f"chi^2 and error over all {len(c.channels)}: {', '.join(c.channels)}")
    fig.suptitle(f"variant {variant}, {_run_title(c)}{shown}", fontsize=10)
    fig.tight_layout()
    return fig


def probe_pairs(c: RunComparison, pairs: Sequence[tuple[str, str]] | None = None) -> list[RunComparison]:
    """Each plane's (x, y) probes as a RunComparison of those two channels. pairs: the channels' names
    (``sensor_pair_names`` of the machine); None: consecutive channels (0, 1), (2, 3), ..., which are the planes
    only when every probe has a partner (the VARM's x, y). A name the run lacks is a ValueError."""
    if pairs is None:
        pairs = [tuple(c.channels[j:j + 2]) for j in range(0, len(c.channels) - 1, 2)]
    return [c.select(pair) for pair in pairs]


def sensor_pair_names(sensors=None) -> list[tuple[str, str]] | None:
    """The (x, y) channel names of each plane with one probe of each for ``sensors`` (a machine's sensors in any
    form ``records.record_channels`` takes: the config's {name: {node, direction}}, a Machine); None for the
    VARM (its x, y)."""
    names, pairs = record_channels(sensors)
    return None if pairs is None else [(names[i], names[j]) for i, j in pairs]


def _orbit(ax: plt.Axes, c: RunComparison) -> None:
    for Z, label, style in ((c.measured, "measured", {"color": "k", "lw": 2.2}),
                            (c.model, "model", {"color": "C3", "lw": 1.3, "ls": "--"})):
        _, xy = waveform(Z, 1.0)
        ax.plot(xy[:, 0] * MILLI, xy[:, 1] * MILLI, label=label, **style)
        ax.plot(xy[0, 0] * MILLI, xy[0, 1] * MILLI, "o", color=style["color"], ms=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{c.channels[0]} [mm]")
    ax.set_ylabel(f"{c.channels[1]} [mm]")
    ax.set_title("orbit (h = 1..H, DC removed); dot: t = 0", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def _signals(ax: plt.Axes, ax_residual: plt.Axes, c: RunComparison) -> None:
    angle, measured = waveform(c.measured)
    _, model = waveform(c.model)
    turns = angle / (2 * np.pi)
    noise = waveform_noise(c.sigma)
    for j, channel in enumerate(c.channels[:2]):
        colour = f"C{j}"
        ax.plot(turns, measured[:, j] * MILLI, color=colour, lw=2, label=f"{channel} measured")
        ax.plot(turns, model[:, j] * MILLI, color="k", lw=1, ls="--" if j == 0 else ":", label=f"{channel} model")
        ax_residual.plot(turns, (measured[:, j] - model[:, j]) * MICRO, color=colour, label=f"{channel}")
        ax_residual.axhspan(-2 * noise[j] * MICRO, 2 * noise[j] * MICRO, color=colour, alpha=0.12)
    ax.set_ylabel("displacement [mm]")
    ax.set_title("synchronous average over two revolutions (model frame)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    ax.tick_params(labelbottom=False)
    ax_residual.set_xlabel("revolutions (Omega t / 2 pi)")
    ax_residual.set_ylabel("residual [um]")
    ax_residual.set_title("measured - model; bands: +-2 sigma of the noise", fontsize=9)
    ax_residual.legend(fontsize=7)
    ax_residual.grid(alpha=0.3)


def _spectrum(ax: plt.Axes, c: RunComparison) -> None:
    """Bars of |measured|, |model|, |residual| per whirl component (-H..-1 backward, 1..H forward), noise RMS."""
    H = c.H
    order = np.concatenate([-np.arange(H, 0, -1), np.arange(1, H + 1)])
    noise = whirl_noise(c.sigma)
    noise = np.concatenate([noise[::-1], noise]) * MICRO

    def signed(Z: Array) -> Array:
        forward, backward = whirl(Z)
        return np.abs(np.concatenate([backward[::-1], forward])) * MICRO
    floor = 0.05 * noise.min()
    position = np.arange(2 * H)
    for offset, (values, label, colour) in zip((-0.27, 0.0, 0.27), (
            (signed(c.measured), "measured", "0.55"), (signed(c.model), "model", "C3"),
            (signed(c.residual), "residual", "C2"))):
        ax.bar(position + offset, np.maximum(values, floor), width=0.27, bottom=0, color=colour, label=label)
    ax.hlines(noise, position - 0.45, position + 0.45, color="k", lw=1.5, label="noise RMS")
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor)
    ax.set_xticks(position, [f"{h:+d}X" for h in order])
    ax.axvline(H - 0.5, color="k", lw=0.8)
    ax.set_ylabel("|component| of z = x + i y [um]")
    ax.set_title("whirl spectrum: backward (-h) | forward (+h)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(axis="y", which="both", alpha=0.3)


def plot_error_map(errors: pd.DataFrame, variant: str) -> plt.Figure:
    """Where the model fails: chi^2/dof per run on speed x unbalance mass (colour, log scale, value written),
    runs beyond noise (p < ALPHA) outlined, validation runs as stars; and chi^2/dof vs speed per mass."""
    fig, (ax, ax_speed) = plt.subplots(1, 2, figsize=(14, 5.2), gridspec_kw={"width_ratios": (1.25, 1)})
    values = errors["chi2_dof"].clip(lower=1e-2)
    norm = LogNorm(vmin=min(values.min(), 0.5), vmax=max(values.max(), 10.0))
    points = []
    for role, marker, size in (("fit", "s", 420), ("validate", VALIDATION_STYLE["marker"], 700)):
        sub = errors[errors["role"] == role]
        edge = np.where(sub["beyond_noise"], "k", "none")
        points += [ax.scatter(sub["rpm"], sub["eccentric_mass_g"], c=values[sub.index], norm=norm, cmap="RdYlGn_r",
                              marker=marker, s=size, edgecolors=edge, linewidths=1.5, label=role)]
        for r in sub.itertuples():
            ax.annotate(f"{r.chi2_dof:.3g}", (r.rpm, r.eccentric_mass_g), xytext=(0, -17), textcoords="offset points",
                        ha="center", fontsize=7)
    fig.colorbar(points[0], ax=ax, label="chi^2 / dof (1 = noise floor)")
    ax.set_xlabel("speed [RPM]")
    ax.set_ylabel("eccentric mass [g]")
    ax.margins(0.08, 0.15)
    ax.set_title(f"normalised error per run; black edge: beyond noise (p < {ALPHA:g})", fontsize=9)
    ax.grid(alpha=0.3)
    colours = mass_colours(errors.loc[errors["role"] == "fit", "eccentric_mass_g"])
    for mass, sub in errors[errors["role"] == "fit"].groupby("eccentric_mass_g"):
        sub = sub.sort_values("rpm")
        ax_speed.plot(sub["rpm"], sub["chi2_dof"], "o-", color=colours[mass], label=f"{mass:g} g")
    val = errors[errors["role"] == "validate"]
    if len(val):
        ax_speed.plot(val["rpm"], val["chi2_dof"], ls="none", mfc="none", label="validation",
                      **{k: VALIDATION_STYLE[k] for k in ("marker", "color", "ms")})
    ax_speed.axhline(NOISE_FLOOR, color="g", lw=1.5, label="noise floor")
    ax_speed.set_yscale("log")
    ax_speed.set_xlabel("speed [RPM]")
    ax_speed.set_ylabel("chi^2 / dof")
    ax_speed.set_title("normalised error vs speed", fontsize=9)
    ax_speed.grid(alpha=0.3, which="both")
    ax_speed.legend(fontsize=7)
    fit, val_pooled = pooled(errors[errors["role"] == "fit"]), pooled(val)
    validation = (f"validation runs {val_pooled['chi2_dof']:.3g} (error {val_pooled['error_pct']:.2g} %)"
                  if len(val) else "no validation run")
    fig.suptitle(f"variant {variant}: where the model fails. Fit runs chi^2/dof = {fit['chi2_dof']:.3g} "
                 f"(error {fit['error_pct']:.2g} %); {validation}", fontsize=10)
    fig.tight_layout()
    return fig


def plot_ledger(ledger: pd.DataFrame, errors: Mapping[str, pd.DataFrame]) -> plt.Figure:
    """The error from variant to variant (config order) toward the noise floor: chi^2/dof of the fit runs
    (overall, black; per run, grey), of the validation runs (magenta); and BIC - min BIC."""
    fig, (ax, ax_bic) = plt.subplots(2, 1, figsize=(max(6.0, 1.9 * len(ledger) + 3), 8), sharex=True,
                                     gridspec_kw={"height_ratios": (2.2, 1)})
    position = np.arange(len(ledger))
    for i, variant in enumerate(ledger["variant"]):
        table = errors[variant]
        fit, val = table[table["role"] == "fit"], table[table["role"] == "validate"]
        jitter = np.linspace(-0.15, 0.15, max(len(fit), 1))[: len(fit)]
        ax.plot(i + jitter, fit["chi2_dof"], "o", ms=3.5, color="0.6", label="fit run" if i == 0 else None)
        ax.plot(np.full(len(val), i + 0.25), val["chi2_dof"], ls="none", mfc="none",
                label="validation run" if i == 0 else None,
                **{k: VALIDATION_STYLE[k] for k in ("marker", "color")}, ms=8)
    ax.plot(position, ledger["chi2_dof"], "ks-", ms=8, lw=2, label="all fit runs")
    ax.plot(position + 0.25, ledger["validation_chi2_dof"], "--", color=VALIDATION_STYLE["color"], lw=1.5,
            label="all validation runs")
    ax.axhspan(NOISE_FLOOR, 1.1 * NOISE_FLOOR, color="g", alpha=0.25, label="within 10 % of the noise floor")
    ax.axhline(NOISE_FLOOR, color="g", lw=1.5)
    for i, r in enumerate(ledger.itertuples()):
        ax.annotate(f"{r.chi2_dof:.3g}", (i, r.chi2_dof), xytext=(8, 4), textcoords="offset points", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("chi^2 / dof (1 = noise floor)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax.set_title("normalised error per variant, in config order", fontsize=10)
    ax_bic.bar(position, ledger["delta_bic"], color="0.5")
    for i, value in enumerate(ledger["delta_bic"]):
        ax_bic.annotate(f"{value:.0f}", (i, value), ha="center", va="bottom", fontsize=8)
    ax_bic.set_ylabel("BIC - min BIC")
    ax_bic.set_xticks(position, ledger["variant"])
    ax_bic.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return fig
