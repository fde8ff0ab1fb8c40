"""The one-page figure of an assessment: the record against the twin, the residual against the noise, and what the
record says of each parameter (``plot_assessment``). It reads only the assessment's tables, so the figure of an
assessment read back from its files (``Assessment.read``) is the same."""

from __future__ import annotations

import textwrap

import numpy as np
from scipy import stats

from .assess import Assessment, Verdict

#: |E / sigma| of one complex entry is beyond the noise above this (chi^2 with 2 dof at 99 %)
NOISE_99 = float(np.sqrt(stats.chi2.ppf(0.99, 2)))


def plot_assessment(assessment: Assessment):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = assessment.harmonics
    channels = list(dict.fromkeys(table["channel"]))
    steady = table["run"].nunique() == 1
    fig = plt.figure(figsize=(8.3, 11.0))
    grid = fig.add_gridspec(3, len(channels), height_ratios=[1.2, 1.0, 1.0])
    changed = assessment.verdict is not Verdict.CONSISTENT
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
            top.errorbar(h, 1e6 * np.abs(measured), yerr=2e6 * sigma, fmt="o", color="k", ms=4, label="record (2 sigma)")
            top.plot(h, 1e6 * np.abs(twin), "s", mfc="none", color="tab:blue", label="twin")
            if changed:
                top.plot(h, 1e6 * np.abs(best), "x", color="tab:red", label=f"with {assessment.summary['best']}")
            top.set_yscale("log")
            top.set_xlabel("harmonic")
            mid.bar(h - 0.2, np.abs(measured - twin) / sigma, 0.4, color="tab:blue", label="twin")
            if changed:
                mid.bar(h + 0.2, np.abs(measured - best) / sigma, 0.4, color="tab:red", label="best change")
            mid.set_xlabel("harmonic")
        else:
            for h, style in zip(sorted(rows["harmonic"].unique())[:3], ("-", "--", ":")):
                one = rows["harmonic"] == h
                rpm = rows.loc[one, "rpm"]
                top.errorbar(rpm, 1e6 * np.abs(measured[one]), yerr=2e6 * sigma[one], fmt=".", color="k", ms=3)
                top.plot(rpm, 1e6 * np.abs(twin[one]), style, color="tab:blue", label=f"twin {h}X")
                if changed:
                    top.plot(rpm, 1e6 * np.abs(best[one]), style, color="tab:red", lw=0.8)
                mid.plot(rpm, np.abs(measured[one] - twin[one]) / sigma[one], style, color="tab:blue", label=f"{h}X")
            top.set_yscale("log")
            top.set_xlabel("speed [RPM]")
            mid.set_xlabel("speed [RPM]")
        top.set_title(f"probe {channel}: record vs twin", fontsize=9)
        top.set_ylabel("amplitude, 0-peak [um]")
        top.legend(fontsize=7)
        mid.axhline(NOISE_99, color="0.4", ls="--", lw=1, label="noise, 99 %")
        mid.set_yscale("log")
        mid.set_ylabel("|record - model| / sigma")
        mid.set_title("residual vs noise", fontsize=9)
        mid.legend(fontsize=7)
    ax = fig.add_subplot(grid[2, :])
    params = assessment.parameters
    params = params[(params["run"] == "all") | (params["run"].nunique() <= 2)]
    labels = [p if r == "all" else f"{p} [{r}]" for p, r in zip(params["parameter"], params["run"])]
    y = np.arange(len(params))[::-1]
    z = params["z"].to_numpy(float)
    half = params["stderr"] / np.hypot(params["stderr"], params["twin_stderr"].fillna(0))
    colours = ["tab:red" if m else "tab:blue" for m in params["moved"]]
    ax.errorbar(z, y, xerr=stats.norm.ppf(0.975) * half, fmt="none", ecolor="0.6")
    ax.scatter(z, y, c=colours, zorder=3)
    level = stats.norm.ppf(1 - assessment.summary["alpha"] / 2)
    for x in (-level, level):
        ax.axvline(x, color="0.5", ls="--", lw=1)
    ax.axvline(0, color="0.3", lw=0.8)
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xlabel("the record's estimate of each parameter (freed alone) against the twin's, in combined standard "
                  "errors", fontsize=8)
    ax.set_title("what the record says of each parameter (red: the change named; dashed: alarm level)", fontsize=9)
    fig.suptitle("\n".join(textwrap.wrap(assessment.line(), 110)), fontsize=8, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return fig
