"""The diagnosis as people read it: Markdown (conclusion, what to do, forward-selection path, the residual's
fingerprint, candidates) and a figure; the paper's sparse route side by side."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from scipy import stats

from .. import tables
from .conclusion import Diagnosis
from .diagnosis_status import Status, plain, verdict_colour
from ..model.variants import Variant


def sparse_route(table: pd.DataFrame, variant: Variant) -> pd.DataFrame:
    """The paper's route (sec. 4.2): which terms an L1-sparse fit (eq. 11) of ``variant`` kept, from its joint
    parameter table. A term is active when its 95 % interval excludes zero, or when it sits at a range edge
    away from zero (the fit wanted more of it); the others are switched off or undetermined."""
    meanings = {p.name: (e.name, e.meaning) for e in variant.model.effects for p in e.parameters}
    rows = []
    for r in table[(table["run"] == "all") & (table["kind"] != "nuisance")].itertuples():
        lo, hi = variant.unknown.get(r.parameter, (np.nan, np.nan))
        if not lo <= 0.0 <= hi:  # a term that cannot be switched off (e.g. the bow) is not part of the route
            continue
        at_edge = bool(r.at_bound) and abs(r.value) > 0.01 * max(abs(lo), abs(hi))
        active = at_edge or bool(r.ci_low > 0 or r.ci_high < 0)
        effect, meaning = meanings.get(r.parameter, ("", ""))
        rows.append({"parameter": r.parameter, "effect": effect, "meaning": meaning, "value": r.value,
                     "ci_low": r.ci_low, "ci_high": r.ci_high, "unit": r.unit, "at_bound": bool(r.at_bound),
                     "active": active})
    return pd.DataFrame(rows, columns=["parameter", "effect", "meaning", "value", "ci_low", "ci_high", "unit",
                                       "at_bound", "active"])


def _sparse_markdown(sparse: pd.DataFrame, name: str) -> str:
    if sparse.empty:
        return ""
    def text(r) -> str:
        interval = "at its range edge" if r.at_bound else f"[{r.ci_low:.4g}, {r.ci_high:.4g}]"
        return f"{r.parameter} ({r.meaning}) = {r.value:.4g} {r.unit} {interval}"
    active = [text(r) for r in sparse[sparse["active"]].itertuples()]
    off = ", ".join(sparse.loc[~sparse["active"], "parameter"])
    lines = [f"\n## The paper's route, side by side\n\nThe L1-sparse fit of variant `{name}` (eq. 11) keeps:\n"]
    lines += [f"- {a}" for a in active] or ["- no term"]
    lines.append(f"\nand switches off (interval contains zero): {off or 'none'}.\n")
    return "\n".join(lines)


def _cell(value) -> str:
    """A table cell: numbers to 4 digits, blank where there is none (a candidate not refitted has no confirmed
    chi^2/dof or Delta BIC: the markdown printed "nan")."""
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else ""
    return str(value)


def markdown(result: Diagnosis, sparse: pd.DataFrame | None = None, sparse_name: str = "") -> str:
    """The conclusion, the recommendation (config lines), the ranked table and, when given, the paper's route
    (``sparse_route`` of variant ``sparse_name``), as Markdown."""
    s = result.summary
    columns = ["rank", "effect", "statistic", "p_value", "predicted_error_drop_pct", "confirmed_chi2_dof",
               "delta_bic", "estimate", "verdict"]
    rows = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for r in result.table[columns].itertuples(index=False):
        rows.append("| " + " | ".join(_cell(v) for v in r) + " |")
    recommendation = f"\n## What to do\n\n{result.recommendation}" if result.recommendation else ""
    if recommendation:
        recommendation = recommendation.replace("\n\n  ", "\n\n```yaml\n  ", 1) + "```\n"
    path = ""
    if result.path:
        steps = ["| step | effect added | chi^2/dof before | after | Delta BIC | explained | estimate |",
                 "|---|---|---|---|---|---|---|"]
        steps += [f"| {r.step} | {r.effect} | {r.chi2_dof_before:.4g} | {r.chi2_dof_after:.4g} | {r.delta_bic:.1f} | "
                  f"{r.explained_pct:.0f} % | {r.estimate} |" for r in result.path_table().itertuples()]
        path = ("\n## Forward selection\n\nEach step adds the best confirmed effect, then scores and refits the "
                "others at the extended fit; it stops when nothing significant is left.\n\n" + "\n".join(steps)
                + "\n" + _sharing_markdown(s.get("sharing")) + _intervals_markdown(s.get("intervals")))
    return (f"# Diagnosis of variant {s['variant']}\n\n"
            f"{len(s['runs'])} fit run{'' if len(s['runs']) == 1 else 's'}, {s['n_data']} data; chi^2/dof "
            f"{s['base_chi2_dof']:.3g} "
            f"(goodness-of-fit p = {s['base_gof_p_value']:.3g}); {len(s['candidates'])} candidates tested, "
            f"{len(s['refitted'])} refitted.\n\n**{result.conclusion}**\n{recommendation}{path}\n"
            + (f"## What the residual looks like\n\n{result.fingerprint.summary()}\n\n"
               if result.fingerprint and result.status not in (Status.UNEXPLAINED, Status.ADD_NEARLY) else "")
            + _form_markdown(s.get("intervals_over_candidates"), s.get("units", {}))
            + "## Candidates\n\n" + "\n".join(rows) + "\n"
            + ("" if sparse is None else _sparse_markdown(sparse, sparse_name)))


def _form_markdown(rows: list | None, units: dict) -> str:
    """The final model's shared parameters' intervals over the candidates not in it (``form_intervals``), a table;
    empty when there are none."""
    if not rows:
        return ""
    widened = [r for r in rows if r["widened_by"]]
    lines = ["| parameter | estimate | 95 % interval, this form | over the candidates | widened most by |",
             "|---|---|---|---|---|"]
    for r in rows:
        unit = f" {units[r['parameter']]}" if units.get(r["parameter"]) else ""
        by = r["widened_by"].split(", ")
        lines.append(f"| {r['parameter']} | {r['estimate']:.5g}{unit} | [{r['own_low']:.5g}, {r['own_high']:.5g}] | "
                     f"[{r['low']:.5g}, {r['high']:.5g}] | {', '.join(by[:2]) + (' ...' if len(by) > 2 else '')} |")
    what = ("These data leave room for some of them: where an interval widens, the estimate holds only if that effect "
            "is absent (or small)" if widened else "None of them widens an interval: the estimates hold whichever "
            "of the candidates is present, as far as these data can tell")
    return ("## Intervals over the effects these data cannot exclude\n\n"
            "Each interval of the final model holds for its own form. With each candidate effect not in it added "
            "(held to its range, linearised at the fit: `diagnosis_intervals.tsv`), the interval that holds over all "
            f"of them is the column \"over the candidates\". {what}.\n\n" + "\n".join(lines) + "\n\n")


def _intervals_markdown(intervals: dict | None) -> str:
    """A warning when a misfit remains at the path's end (``diagnosis_status.interval_note``): the intervals are
    scaled by sqrt(chi^2/dof) but a misfit of form also biases the estimates: they may be optimistic."""
    if not intervals or not intervals["optimistic"]:
        return ""
    return (f"\n**The intervals may be optimistic**: the final fit leaves chi^2/dof {intervals['chi2_dof']:.3g}, a "
            f"misfit beyond the noise. The 95 % intervals are widened by sqrt(chi^2/dof) = "
            f"{intervals['scaled_by']:.3g}, which covers residuals larger than the stated noise but not always the "
            "bias of a model whose form differs slightly from the data's: the truth can lie outside them "
            "(benchmarks/README.md).\n")


def _sharing_markdown(sharing: dict | None) -> str:
    """The sharing check's outcome (``elimination.sharing_check``), one paragraph; empty when it did not run."""
    if not sharing:
        return ""
    names = ", ".join(sharing["parameters"])
    figures = (f"chi^2 {sharing['chi2_shared']:.4g} with one value for all runs against {sharing['chi2_per_run']:.4g} "
               f"per run: likelihood ratio {sharing['lr']:.3g} on {sharing['lr_dof']} dof (p = "
               f"{sharing['lr_p_value']:.3g}), Delta BIC of the per-run values {sharing['delta_bic_per_run']:+.3g}")
    verdict = ("not needed: they are shared, the estimates above come from that fit, and the recommended variant "
               "says `per_run: []`" if sharing["shared"] else "needed: they stay per run")
    return f"\n**Sharing check** of the parameters fitted per run ({names}): {figures}; {verdict}.\n"


def plot(result: Diagnosis):
    """Score statistics with the significance threshold; chi^2/dof before and after each refitted effect."""
    import matplotlib.pyplot as plt

    t = result.table.iloc[::-1]
    s = result.summary
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 0.45 * len(t) + 2.0), sharey=True)
    colours = [verdict_colour(code) for code in t["verdict_code"]]
    left.barh(t["effect"], np.maximum(t["statistic"], 1e-3), color=colours)
    left.set_xscale("log")
    threshold = stats.chi2.isf(s["alpha_per_candidate"], t["dof"])
    left.plot(threshold, t["effect"], "k|", markersize=14, label="significance threshold")
    left.set_xlabel("score statistic (predicted chi^2 drop)")
    left.legend(loc="lower right", fontsize=8)
    left.set_title(f"{s['variant']}: candidate effects (green: add)")
    right.axvline(s["base_chi2_dof"], color="tab:red", label=f"{s['variant']}: {s['base_chi2_dof']:.3g}")
    right.axvline(1.0, color="k", linestyle="--", label="noise floor")
    right.plot(t["predicted_chi2_dof"], t["effect"], "o", mfc="none", color="tab:blue", label="predicted, added")
    right.plot(t["confirmed_chi2_dof"], t["effect"], "o", color="tab:blue", label="refitted, added")
    right.set_xscale("log")
    right.set_xlabel("chi^2 / dof")
    right.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return fig


def write(result: Diagnosis, table_path, markdown_path, summary_path, sparse: pd.DataFrame | None = None,
          sparse_name: str = "") -> None:
    """The diagnosis's outputs: the ranked table (``diagnosis.tsv``), the Markdown (``markdown``) and the summary
    (``diagnosis.yaml``). The summary is built from plain types (``diagnosis.plain``); it is converted once more
    here, so a value that slipped through is written as a number rather than stop the workflow, and one that is no
    number at all is refused with the file and the key it sits at."""
    try:
        summary = plain(result.summary)
    except TypeError as error:
        raise ValueError(f"{summary_path}: cannot write the diagnosis summary: {error}") from None
    tables.DIAGNOSIS.write(result.table, table_path)
    Path(markdown_path).write_text(markdown(result, sparse, sparse_name))
    write_diagnosis_summary(summary, summary_path)


def write_diagnosis_summary(summary: dict, path) -> None:
    """The diagnosis summary (``diagnosis.yaml``: plain types, ``diagnosis_status.plain``);
    ``read_diagnosis_summary`` is its inverse."""
    with open(path, "w") as stream:
        yaml.safe_dump(summary, stream, sort_keys=False)


def read_diagnosis_summary(path) -> dict:
    """A summary written by ``write_diagnosis_summary`` (``write``): the same mapping (conclusion, status, the
    recommended variant, ...)."""
    with open(path) as stream:
        return dict(yaml.safe_load(stream))
