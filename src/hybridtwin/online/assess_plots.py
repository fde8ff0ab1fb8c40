"""The one-page figure of an assessment: the record against the twin, the residual against the noise, and what the
record says of each parameter (``plot_assessment``). It reads only the assessment's tables, so the figure of an
assessment read back from its files (``Assessment.read``) is the same."""

from __future__ import annotations

import textwrap

import numpy as np
from scipy.special import ndtri  # the normal quantile (scipy.stats costs ~1 s to import)

from .assess import Assessment, RecordVerdict

#: |E / sigma| of one complex entry is beyond the noise above this (chi^2 with 2 dof at 99 %)
NOISE_99 = float(np.sqrt(-2 * np.log(0.01)))  # chi^2(2)'s 99 % point, -2 ln 0.01
#: significances drawn up to this many standard deviations (a move at p ~ 0 is off any scale)
CAP = 10.0


def plot_assessment(assessment: Assessment):
    import matplotlib.pyplot as plt  # here, not at import (the command's verdict needs no matplotlib); no backend
    # forced: Agg by itself without a display, or the caller's choice

    table = assessment.harmonics
    channels = list(dict.fromkeys(table["channel"]))
    steady = table["run"].nunique() == 1
    fig = plt.figure(figsize=(8.3, 11.0))
    grid = fig.add_gridspec(3, len(channels), height_ratios=[1.2, 1.0, 1.0])
    changed = assessment.verdict is not RecordVerdict.CONSISTENT
    for c, channel in enumerate(channels):
        rows = table[table["channel"] == channel]
        top = fig.add_subplot(grid[0, c])
        mid = fig.add_subplot(grid[1, c])
        measured = rows["measured_re_m"] + 1j * rows["measured_im_m"]
        twin = rows["twin_re_m"] + 1j * rows["twin_im_m"]
        best = rows["best_re_m"] + 1j * rows["best_im_m"]
        sigma = rows["sigma_m"]
        if steady:
            h = rows["harmonic"].to_numpy()
            floor = 0.1 * float(sigma.min())  # a harmonic the model lacks (zero) is drawn at the floor
            top.bar(h, 2e6 * sigma, 0.6, color="0.85", label="noise, 2 sigma")
            top.plot(h, 1e6 * np.abs(measured), "o", color="k", ms=4, label="record")
            top.plot(h, 1e6 * np.maximum(np.abs(twin), floor), "s", mfc="none", color="tab:blue",
                     label="twin's prediction")
            if changed:
                top.plot(h, 1e6 * np.maximum(np.abs(best), floor), "x", color="tab:red",
                         label=f"with {assessment.summary['best']}")
            top.set_yscale("log")
            top.set_xlabel("harmonic")
            mid.bar(h - 0.2, np.abs(measured - twin) / sigma, 0.4, color="tab:blue", label="twin's prediction")
            if changed:
                mid.bar(h + 0.2, np.abs(measured - best) / sigma, 0.4, color="tab:red", label="best change")
            mid.set_xlabel("harmonic")
        else:
            for h, style in zip(sorted(rows["harmonic"].unique())[:3], ("-", "--", ":")):
                one = rows["harmonic"] == h
                rpm = rows.loc[one, "rpm"]
                floor = 0.1 * float(sigma[one].min())  # a harmonic the model lacks (zero) is drawn at the floor
                top.plot(rpm, 1e6 * np.abs(measured[one]), ".", color="k", ms=3)
                top.plot(rpm, 1e6 * np.maximum(np.abs(twin[one]), floor), style, color="tab:blue", label=f"twin {h}X")
                if changed:
                    top.plot(rpm, 1e6 * np.maximum(np.abs(best[one]), floor), style, color="tab:red", lw=0.8)
                mid.plot(rpm, np.abs(measured[one] - twin[one]) / sigma[one], style, color="tab:blue", label=f"{h}X")
            top.set_yscale("log")
            top.set_xlabel("speed [RPM]")
            mid.set_xlabel("speed [RPM]")
        top.set_title(f"probe {channel}: record vs twin", fontsize=9)
        top.set_ylabel("amplitude, 0-peak [um]")
        top.legend(fontsize=7)
        mid.axhline(NOISE_99, color="0.4", ls="--", lw=1, label="noise, 99 %")
        mid.set_yscale("log")  # the twin's prediction of a changed machine: hundreds of sigmas
        mid.set_ylabel("|record - model| / sigma")
        mid.set_title("residual vs noise", fontsize=9)
        mid.legend(fontsize=7)
    ax = fig.add_subplot(grid[2, :])
    params = assessment.parameters.drop_duplicates("parameter")  # a group's test is one per parameter
    z = np.sign(params["change"]) * np.minimum(-ndtri(params["p_value"].to_numpy(float) / 2), CAP)
    y = np.arange(len(params))[::-1]
    colours = np.where(params["moved"], "tab:red", "tab:blue")
    ax.scatter(z, y, c=colours, zorder=3)  # a parameter the twin left undetermined has no test: not drawn
    tested = assessment.parameters[assessment.parameters["p_value"].notna()]
    groups = (tested["run"] == "all").sum() + (tested["run"] != "all").any()  # the per-run parameters: one group
    level = -ndtri(assessment.summary["alpha"] / (4 * max(groups, 1)))  # a move's alarm level (assess: Bonferroni)
    for x in (-level, level):
        ax.axvline(x, color="0.5", ls="--", lw=1)
    ax.axvline(0, color="0.3", lw=0.8)
    ax.set_xlim(-CAP - 0.5, CAP + 0.5)
    # no prior (twin_stderr NaN): a parameter the twin left undetermined, never tested
    labels = [f"{p} *" if np.isnan(sd) else p for p, sd in zip(params["parameter"], params["twin_stderr"])]
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xlabel("significance of the parameter's move (freed alone against the twin's prior), signed, in normal "
                  f"standard deviations (capped at {CAP:g})\n* left undetermined by the twin: not tested", fontsize=8)
    ax.set_title("what the record says of each parameter (red: the change named; dashed: a move's alarm level)",
                 fontsize=9)
    fig.suptitle("\n".join(textwrap.wrap(assessment.line(), 110)), fontsize=8, x=0.02, ha="left")
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.06, top=0.9, hspace=0.35, wspace=0.3)
    return fig
