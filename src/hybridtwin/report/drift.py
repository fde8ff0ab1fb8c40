"""The per-run estimates and their drift with speed: one implementation, for the identification's per-run table
and figure (rule identify_joint: ``drift_table``, ``plot_per_run``) and the report's drift test (rule report_drift:
``drift_statistics``, ``plot_drift``).

A physical constant that drifts with speed means the model misses something (the per-run fits' diagnostic).

- The per-run fits side by side (``drift_table``, identification/per_run.tsv): each fit run's estimates of the
  physical parameters with the run's speed and unbalance, their weighted mean by their standard errors and each
  one's distance from it in standard errors; ``plot_per_run`` (the paper's Fig. 9) draws them with their 95 %
  intervals.
- Drift of a constant (``drift_test``, ``drift_statistics``: report/drift.tsv): the per-run estimates v_r with
  uncertainties s_r (the Monte Carlo spread of each per-run fit, which the linearised standard error misrepresents
  in the per-run problems' flat valleys; the standard error when there is no Monte Carlo: ``drift_sigma``) are
  tested for one common value, chi^2 = sum (v_r - mean_w)^2 / s_r^2 on n - 1 dof, and for a trend, the weighted
  least-squares slope against speed and its t = slope / stderr; it drifts when either p-value is below ALPHA / 2
  (Bonferroni: at most ALPHA false alarms per parameter). ``plot_drift`` draws the estimates the test used (1 sigma
  bars), the weighted mean and slope, and the statistics.

Both weighted means are ``weighted_mean``'s: the table's over every estimate with a standard error, the test's over
the usable estimates (``drift_usable``) by ``drift_sigma``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables
from ..identify.validation import spans
from ..plots import plt
from ..identify.uncertainty import ALPHA
from .report_plots import mass_colours

Array = np.ndarray


def weighted_mean(value: Array | pd.Series, sigma: Array | pd.Series) -> tuple[float, float]:
    """(sum w v / sum w, sum w) with w = 1 / sigma^2 over the estimates with a positive sigma (the others, and NaN
    values, left out); (the mean of the values, 0) when no sigma is positive."""
    v, s = np.asarray(value, float), np.asarray(sigma, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(s > 0, 1.0 / s**2, np.nan)
        if np.isnan(w).all():
            return float(np.nansum(v) / np.count_nonzero(~np.isnan(v))), 0.0
        return float(np.nansum(w * v) / np.nansum(w)), float(np.nansum(w))


def drift_table(per_run: Sequence[pd.DataFrame], runs: pd.DataFrame) -> pd.DataFrame:
    """The per-run fits side by side (one row per run and parameter) with speed and unbalance
    (identification/per_run.tsv, a parameter table: ``identification.write_parameters``).

    A physical constant that drifts with speed means the model misses something
    (the per-run fits' diagnostic); ``weighted_mean``: ``weighted_mean`` of the values by their standard errors;
    ``spread_in_stderr``: |value - weighted mean| / stderr.
    """
    rows = []
    for table in per_run:
        rows.append(table[table["kind"] != "nuisance"])
    if not rows:
        return pd.DataFrame()
    out = pd.concat(rows, ignore_index=True)
    out = out.merge(runs[["run", "rpm", "eccentric_mass_g"]], on="run", how="left", suffixes=("", "_sheet"))
    for p, group in out.groupby("parameter"):
        mean, _ = weighted_mean(group["value"], group["stderr"])
        out.loc[group.index, "weighted_mean"] = mean
        out.loc[group.index, "spread_in_stderr"] = (group["value"] - mean).abs() / group["stderr"]
    return out


def plot_per_run(drift: pd.DataFrame, joint: pd.DataFrame | None, title: str) -> plt.Figure:
    """Per-run estimates vs speed (the paper's Fig. 9, identification/per_run.png) with their 95 % intervals, and
    the joint values: the fits as they came out; ``plot_drift`` draws the same estimates with what the drift test
    used (1 sigma bars, the usable ones) and its statistics.

    The axes span each parameter's range (an interval wider than the range is cut at it); open markers
    are estimates the uncertainty analysis calls not identifiable, crosses estimates at a range edge.
    """
    names = list(dict.fromkeys(drift["parameter"])) if len(drift) else []
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(3.2 * max(len(names), 1), 3.4), squeeze=False)
    for ax, p in zip(axes[0], names):
        group = drift[drift["parameter"] == p]
        lo, hi = float(group["lower"].iloc[0]), float(group["upper"].iloc[0])
        for colour, (mass, sub) in enumerate(group.groupby("eccentric_mass_g")):
            low, high = sub["ci_low"].clip(lo, hi), sub["ci_high"].clip(lo, hi)
            err = np.nan_to_num(np.vstack([sub["value"] - low, high - sub["value"]]).clip(min=0))
            ok = sub["identifiable"].astype(bool).to_numpy()
            edge = sub["at_bound"].astype(bool).to_numpy()
            ax.errorbar(sub["rpm"], sub["value"], yerr=err, fmt="none", color=f"C{colour}", capsize=2, lw=0.8)
            ax.plot(sub["rpm"][ok], sub["value"][ok], "o", ms=4, color=f"C{colour}", label=f"{mass:g} g")
            ax.plot(sub["rpm"][~ok & ~edge], sub["value"][~ok & ~edge], "o", ms=4, mfc="none", color=f"C{colour}")
            ax.plot(sub["rpm"][edge], sub["value"][edge], "x", ms=5, color=f"C{colour}")
        if joint is not None:
            shared = joint[(joint["parameter"] == p) & (joint["run"] == "all")]
            for row in shared.itertuples():
                ax.axhline(row.value, color="k", lw=1, label="joint")
                ax.axhspan(max(row.ci_low, lo), min(row.ci_high, hi), color="k", alpha=0.1)
            local = joint[(joint["parameter"] == p) & (joint["run"] != "all")].merge(
                drift[["run", "rpm"]].drop_duplicates(), on="run")
            if len(local):
                ax.plot(local["rpm"], local["value"], "k+", label="joint")
        pad = 0.05 * (hi - lo)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(p)
        ax.set_xlabel("speed [RPM]")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"variant {title}: per-run estimates (95 % intervals; open: not identifiable, x: at a range "
                 "edge) and the joint fit", fontsize=9)
    fig.tight_layout()
    return fig


#: the per-run estimates' slope along speed is tested only when their runs' speeds span this fraction of the fastest
SLOPE_SPEED_SPREAD = 0.05


def drift_test(value: Array, sigma: Array, rpm: Array, alpha: float = ALPHA) -> dict[str, float | bool]:
    """Do the estimates v (n,) with uncertainties s (n,) at speeds rpm (n,) share one value? (module docstring)

    Returns weighted_mean, weighted_mean_stderr, chi2, dof, chi2_dof, p_value,
    slope_per_rpm (the weighted line passes through the weighted means of value
    and speed, slope_centre_rpm), slope_stderr_per_rpm, slope_t, slope_p_value
    and drifts.
    """
    v, s, x = (np.asarray(a, float) for a in (value, sigma, rpm))
    w = 1.0 / s**2
    mean, total = weighted_mean(v, s)
    chi2 = float((w * (v - mean) ** 2).sum())
    dof = v.size - 1
    p = float(stats.chi2.sf(chi2, dof)) if dof > 0 else math.nan
    centre = (w * x).sum() / w.sum()
    # a slope along speed needs speeds to slope along: runs within SLOPE_SPEED_SPREAD of one speed have none (a
    # "slope" over their 0.3 % of refined speed is noise read as a trend)
    sxx = float((w * (x - centre) ** 2).sum()) if spans(x, SLOPE_SPEED_SPREAD) else 0.0
    slope = float((w * (x - centre) * (v - mean)).sum() / sxx) if sxx > 0 else math.nan
    slope_stderr = 1.0 / math.sqrt(sxx) if sxx > 0 else math.nan
    t = slope / slope_stderr
    p_slope = float(2.0 * stats.norm.sf(abs(t))) if v.size > 2 and math.isfinite(t) else math.nan
    drifts = bool(np.nanmin([p, p_slope, 1.0]) < 0.5 * alpha)
    return {"weighted_mean": mean, "weighted_mean_stderr": float(1.0 / math.sqrt(total)), "chi2": chi2,
            "dof": dof, "chi2_dof": chi2 / dof if dof > 0 else math.nan, "p_value": p, "slope_per_rpm": slope,
            "slope_centre_rpm": float(centre),
            "slope_stderr_per_rpm": slope_stderr, "slope_t": t, "slope_p_value": p_slope, "drifts": drifts}


def drift_sigma(per_run: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """Uncertainty of each per-run estimate: the Monte Carlo spread (mc_std) where there is one, else the
    linearised standard error; and its source ("monte_carlo" or "linearised")."""
    mc = per_run["mc_std"] if "mc_std" in per_run else pd.Series(np.nan, index=per_run.index)
    has_mc = np.isfinite(mc) & (mc > 0)
    return mc.where(has_mc, per_run["stderr"]), pd.Series(np.where(has_mc, "monte_carlo", "linearised"),
                                                           index=per_run.index)


def drift_usable(per_run: pd.DataFrame) -> pd.Series:
    """Estimates a drift test can use: finite, not at a range edge (a pile-up at a bound is not Gaussian),
    with a positive finite uncertainty."""
    sigma, _ = drift_sigma(per_run)
    return np.isfinite(per_run["value"]) & ~per_run["at_bound"].astype(bool) & np.isfinite(sigma) & (sigma > 0)




def drift_statistics(per_run: pd.DataFrame, joint: pd.DataFrame, alpha: float = ALPHA) -> pd.DataFrame:
    """One row per physical parameter of the per-run fits (identification/per_run.tsv): ``drift_test`` on
    its usable estimates, with the joint fit's kind (shared constant or per run) and value.

    ``flagged``: a constant of the joint model (kind shared) that drifts, i.e. the model misses something;
    a per-run parameter (the bow) is allowed to vary and never flagged.
    """
    sigma, source = drift_sigma(per_run)
    usable = drift_usable(per_run)
    kinds = joint[joint["kind"] != "nuisance"].groupby("parameter")["kind"].first()
    shared = joint[joint["run"] == "all"].set_index("parameter")["value"]
    rows = []
    for p, group in per_run.groupby("parameter", sort=False):
        ok = usable[group.index]
        kind = str(kinds.get(p, "fixed"))
        row = {"parameter": p, "unit": group["unit"].iloc[0], "kind": kind, "n_runs": len(group),
               "n_used": int(ok.sum()), "n_at_bound": int(group["at_bound"].astype(bool).sum()),
               "sigma_source": ",".join(sorted(set(source[group.index][ok]))),
               "joint_value": float(shared.get(p, math.nan))}
        if ok.sum() >= 3:
            row |= drift_test(group["value"][ok], sigma[group.index][ok], group["rpm"][ok], alpha)
        else:
            row["drifts"] = False
        row["flagged"] = bool(row["drifts"] and kind == "shared")
        row["verdict"] = _drift_verdict(row, kind)
        rows.append(row)
    return pd.DataFrame(rows, columns=tables.DRIFT.columns)


def _drift_verdict(row: Mapping, kind: str) -> str:
    if row["n_used"] < 3:
        return "too few usable per-run estimates to test"
    if kind != "shared":
        return "estimated per run in the joint fit (allowed to vary)"
    if row["flagged"]:
        return "drifts: a constant of the model changes from run to run, the model misses something"
    return "constant within the per-run uncertainties"


def plot_drift(per_run: pd.DataFrame, statistics: pd.DataFrame, joint: pd.DataFrame, variant: str) -> plt.Figure:
    """Per-run estimates vs speed (1 sigma bars: ``drift_sigma``; open: at a range edge, not tested), the
    weighted mean and slope, the joint value (line for a shared parameter, crosses for a per-run one);
    titles give the drift statistic, flagged constants in red."""
    names = list(statistics["parameter"])
    n = max(len(names), 1)
    rows = math.ceil(n / 4)
    columns = math.ceil(n / rows)
    fig, axes = plt.subplots(rows, columns, figsize=(4.3 * columns, 3.6 * rows), squeeze=False)
    sigma, _ = drift_sigma(per_run)
    usable = drift_usable(per_run)
    colours = mass_colours(per_run["eccentric_mass_g"])
    for ax, stat in zip(axes.flat, statistics.itertuples()):
        group = per_run[per_run["parameter"] == stat.parameter]
        for mass, colour in colours.items():
            sub = group[group["eccentric_mass_g"] == mass]
            ok = usable[sub.index]
            ax.errorbar(sub["rpm"][ok], sub["value"][ok], yerr=sigma[sub.index][ok], fmt="o", ms=4, color=colour,
                        capsize=2, label=f"{mass:g} g")
            ax.plot(sub["rpm"][~ok], sub["value"][~ok], "o", ms=4, mfc="none", color=colour)
        _drift_lines(ax, group, stat)
        local = joint[(joint["parameter"] == stat.parameter) & (joint["run"] != "all")].merge(
            group[["run", "rpm"]], on="run")
        ax.plot(local["rpm"], local["value"], "k+", ms=7, label="joint fit" if len(local) else None)
        lo, hi = float(group["lower"].iloc[0]), float(group["upper"].iloc[0])
        ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        ax.set_title(_drift_title(stat), fontsize=8, color="r" if stat.flagged else "k")
        ax.set_xlabel("speed [RPM]")
        ax.set_ylabel(f"{stat.parameter} [{stat.unit}]")
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"variant {variant}: per-run estimates vs speed and their drift (1 sigma bars, open: at a range "
                 f"edge, not tested); red: a constant of the model that drifts (either p < {ALPHA / 2:g})", fontsize=9)
    fig.tight_layout()
    return fig


def _drift_lines(ax: plt.Axes, group: pd.DataFrame, stat: Any) -> None:
    """The joint value, weighted mean and weighted slope of one parameter (``stat``: a drift_statistics row)."""
    if np.isfinite(stat.joint_value):
        ax.axhline(stat.joint_value, color="k", lw=1.2, label="joint fit")
    mean = stat.weighted_mean
    if np.isfinite(mean):
        rpm = np.array([group["rpm"].min(), group["rpm"].max()])
        ax.axhline(mean, color="0.5", lw=1, ls=":", label="weighted mean")
        if np.isfinite(stat.slope_per_rpm):
            ax.plot(rpm, mean + stat.slope_per_rpm * (rpm - stat.slope_centre_rpm), "--", color="0.4",
                    label="weighted slope")


def _drift_title(stat: Any) -> str:
    """The drift statistic of one parameter in a line (``stat``: a drift_statistics row)."""
    if not np.isfinite(stat.chi2_dof):
        return f"{stat.parameter}: {stat.verdict}"
    flag = "  DRIFTS" if stat.flagged else ("  (per run)" if stat.kind != "shared" else "")
    slope = (f"slope t {stat.slope_t:.2g} (p {stat.slope_p_value:.2g})" if np.isfinite(stat.slope_p_value)
             else "no slope (one speed)")
    return f"{stat.parameter}: chi^2/dof {stat.chi2_dof:.2g} (p {stat.p_value:.2g}), {slope}{flag}"
