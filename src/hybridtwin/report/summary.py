"""The answer first: the page ``snakemake --report report.html`` opens on (the "report" stage, after the ledger).

A user who opens the report wants three things before any figure of one run: how the error falls from
variant to variant (the ledger), what the diagnosis recommends, and where each variant still fails. This
module turns the ledger (``results/ledger.tsv``), each variant's per-run errors (``report/errors.tsv``,
``report/validation_errors.tsv``) and its diagnosis (``diagnosis.yaml``) into

- ``summary_table``: one row per variant (``results/summary.tsv``, columns ``tables.SUMMARY.columns``);
- ``plot_summary``: one figure (``results/summary.png``): chi^2/dof variant by variant, and per run and
  variant the normalised error, runs beyond the noise in bold;
- ``landing_rst``: the reStructuredText the report's first page includes (``results/summary.rst``, see
  ``workflow/report/workflow.rst``): the best variant, the ledger as a table, the recommendations, and per
  variant its runs beyond the noise, each linked to its figure in the report.

Numbers follow ``hybridtwin.report.report`` (chi^2/dof with 1 the noise floor, "beyond noise" at p < ALPHA, BIC).
Nothing is recomputed here: the page shows what the tables say.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping, Sequence
from urllib.parse import quote

import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm
from scipy import stats

from .. import tables
from ..data import measured
from ..plots import plt
from ..identify.uncertainty import ALPHA
from .report import NOISE_FLOOR
from .report_plots import VALIDATION_STYLE

#: the band above the noise floor drawn in the figure (as in the ledger's)
NEAR_NOISE = 1.1


def _finite(value) -> float:
    """A float, NaN for a missing value."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def matching_variant(spec: Mapping | None, variants: Mapping[str, Mapping]) -> str:
    """The config variant with exactly the effects of a recommended variant's ``spec`` ("" when none has)."""
    if not spec:
        return ""
    wanted = set(spec.get("effects", ()))
    return next((name for name, other in variants.items() if set(other.get("effects", ())) == wanted), "")


def summary_table(ledger: pd.DataFrame, errors: Mapping[str, pd.DataFrame], diagnoses: Mapping[str, Mapping],
                  variants: Mapping[str, Mapping]) -> pd.DataFrame:
    """One row per variant of the ledger (config order): its chi^2/dof, Delta BIC, how many fit and validation
    runs are beyond the noise and the worst, the diagnosis's conclusion and recommended variant, and which
    config variant already has that variant's effects.

    ledger: results/ledger.tsv; errors: per variant, its fit and validation runs (``report.error_table``);
    diagnoses: per variant, diagnosis.yaml; variants: the config's ``variants:``.
    """
    rows = []
    for r in ledger.itertuples():
        table = errors[r.variant]
        fit, val = table[table["role"] == "fit"], table[table["role"] == "validate"]
        worst = table.loc[table["chi2_dof"].idxmax()] if len(table) else None
        diagnosis = diagnoses.get(r.variant) or {}
        recommended = diagnosis.get("recommended_variant") or {}
        rows.append({"variant": r.variant, "chi2_dof": r.chi2_dof, "p_value": float(stats.chi2.sf(r.chi2, r.dof)),
                     "validation_chi2_dof": r.validation_chi2_dof,
                     "delta_bic": r.delta_bic, "fit_runs": len(fit),
                     "fit_runs_beyond_noise": int(fit["beyond_noise"].sum()), "validation_runs": len(val),
                     "validation_runs_beyond_noise": int(val["beyond_noise"].sum()),
                     "worst_run": "" if worst is None else str(worst["run"]),
                     "worst_run_chi2_dof": math.nan if worst is None else float(worst["chi2_dof"]),
                     "conclusion": str(diagnosis.get("conclusion", "")),
                     "status": str(diagnosis.get("status") or ""),  # the conclusion's code (diagnosis_status.Status)
                     "recommended_variant": str(recommended.get("name", "")),
                     "recommended_in_config": matching_variant(recommended.get("spec"), variants)})
    return pd.DataFrame(rows, columns=tables.SUMMARY.columns)


def best_variant(summary: pd.DataFrame) -> pd.Series:
    """The variant with the lowest BIC (Delta BIC 0), the first in config order on a tie."""
    return summary.loc[summary["delta_bic"].astype(float).idxmin()]


def run_order(errors: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """Every run of any variant once: run, rpm, eccentric_mass_g, role; fit runs by mass (heaviest first) and
    speed, then the validation runs by speed."""
    runs = pd.concat([table[["run", "rpm", "eccentric_mass_g", "role"]] for table in errors.values()])
    runs = runs.drop_duplicates("run")
    runs["order"] = (runs["role"] != "fit").astype(int)
    return runs.sort_values(["order", "eccentric_mass_g", "rpm"], ascending=[True, False, True]).drop(
        columns="order").reset_index(drop=True)


def short_number(value: float) -> str:
    """A chi^2/dof for a small cell: two significant digits, whole numbers from 100 on."""
    return f"{value:.0f}" if value >= 100 else f"{value:.2g}"


def wrapped(name: str, width: int) -> str:
    """A variant's name on lines of at most ``width`` characters, broken after '_', '+', '@' or '-' (a part longer
    than a line is cut), so that its label fits the figure and reads back whole with the line breaks removed."""
    parts = [piece[i:i + width] for piece in re.split(r"(?<=[_+@-])", name) if piece
             for i in range(0, len(piece), width)]
    lines = [""]
    for part in parts:
        if lines[-1] and len(lines[-1]) + len(part) > width:
            lines.append("")
        lines[-1] += part
    return "\n".join(lines)


def plot_summary(ledger: pd.DataFrame, errors: Mapping[str, pd.DataFrame]) -> plt.Figure:
    """Top: chi^2/dof of the fit runs (black) and of the validation runs (magenta) variant by variant, in config
    order, against the noise floor. Bottom: per run (rows) and variant (columns) the run's chi^2/dof, colour
    on a log scale, the value written, bold where the run is beyond the noise (p < ALPHA); validation runs
    marked with a star. Narrow (5.6 in) to sit in the report's first page."""
    variants = list(ledger["variant"])
    # each name on lines that fit its column (the figure is 5.6 in wide: ~70 characters of 8-point text in all)
    labels_of = [wrapped(str(v), max(8, 64 // max(len(variants), 1))) for v in variants]
    runs = run_order(errors)
    grid = np.full((len(runs), len(variants)), np.nan)
    beyond = np.zeros(grid.shape, bool)
    for j, variant in enumerate(variants):
        table = errors[variant].set_index("run")
        for i, run in enumerate(runs["run"]):
            if run in table.index:
                grid[i, j] = table.at[run, "chi2_dof"]
                beyond[i, j] = bool(table.at[run, "beyond_noise"])
    height = 2.6 + 0.24 * len(runs)
    fig, (ax, ax_runs) = plt.subplots(2, 1, figsize=(5.6, height + 2.4),
                                      gridspec_kw={"height_ratios": (2.4, height)})
    position = np.arange(len(variants))
    ax.plot(position, ledger["chi2_dof"], "ks-", ms=7, lw=2, label="fit runs")
    if np.isfinite(ledger["validation_chi2_dof"].astype(float)).any():
        ax.plot(position, ledger["validation_chi2_dof"], "--", color=VALIDATION_STYLE["color"], lw=1.5,
                marker=VALIDATION_STYLE["marker"], ms=9, label="validation runs (never fitted)")
    ax.axhspan(NOISE_FLOOR, NEAR_NOISE * NOISE_FLOOR, color="g", alpha=0.25)
    ax.axhline(NOISE_FLOOR, color="g", lw=1.5, label="noise floor")
    for i, value in enumerate(ledger["chi2_dof"]):
        ax.annotate(f"{value:.3g}", (i, value), xytext=(6, 4), textcoords="offset points", fontsize=8)
    ax.set_yscale("log")
    ax.set_xticks(position, labels_of, fontsize=8)
    ax.set_xlim(-0.5, len(variants) - 0.5)
    ax.set_ylabel("chi^2 / dof")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax.set_title("the error, variant by variant (1 = noise floor)", fontsize=9)

    finite = grid[np.isfinite(grid)]
    top = max(float(finite.max()) if finite.size else 10.0, 10.0)
    image = ax_runs.imshow(np.clip(grid, 0.1, None), cmap="RdYlGn_r", aspect="auto",
                           norm=LogNorm(vmin=0.3, vmax=top))
    norm = image.norm
    for (i, j), value in np.ndenumerate(grid):
        if np.isfinite(value):
            dark = not 0.2 < norm(max(value, 0.1)) < 0.8  # white text on the scale's dark ends
            ax_runs.text(j, i, short_number(value), ha="center", va="center", fontsize=7,
                         color="w" if dark else "k", fontweight="bold" if beyond[i, j] else "normal")
    labels = [f"{'* ' if r.role != 'fit' else ''}{r.run}  ({r.rpm:.0f} RPM, {r.eccentric_mass_g:g} g)"
              for r in runs.itertuples()]
    ax_runs.set_yticks(np.arange(len(runs)), labels, fontsize=7)
    ax_runs.set_xticks(position, labels_of, fontsize=8)
    ax_runs.xaxis.tick_top()
    fig.colorbar(image, ax=ax_runs, label="chi^2 / dof of the run", fraction=0.06, pad=0.02)
    ax_runs.set_xlabel(f"where each variant fails: chi^2/dof per run, bold beyond the noise (p < {ALPHA:g});\n"
                       "* validation run (predicted, never fitted)", fontsize=8)
    fig.tight_layout()
    return fig


def png_bytes(fig: plt.Figure, dpi: int = 100) -> bytes:
    """The figure as PNG bytes (results/summary.png)."""
    stream = io.BytesIO()
    fig.savefig(stream, format="png", dpi=dpi)
    return stream.getvalue()


# --- the first page (reStructuredText) --------------------------------------------------------------
#
# Snakemake's report centres its first page vertically in the window: a page taller than the window loses its
# top, where the answer is, out of reach of the scroll bar. So the page is short (no inline figure, bold leads
# instead of section titles, at most MAX_RUN_LINKS runs per variant) and points to summary.png for the rest.

#: the failing runs linked per variant on the first page (the worst; the error map shows them all)
MAX_RUN_LINKS = 3


def _text(value: str) -> str:
    """Plain text safe inside reStructuredText inline markup (backslash before the markup characters)."""
    return "".join("\\" + c if c in "\\`*_|<>[]" else c for c in str(value))


def _number(value: float) -> str:
    """Three significant digits, whole numbers from 1000 on, 'none' for a missing value."""
    value = _finite(value)
    return "none" if not np.isfinite(value) else f"{value:.0f}" if abs(value) >= 1000 else f"{value:.3g}"


def _p_value(p: float) -> str:
    return f"p = {p:.2g}" if p >= 1e-15 else "p < 1e-15"


def result_link(label: str, path: str) -> str:
    """An anonymous link that opens ``path`` (a file of the report) in Snakemake's report, as its own
    ``file.png``_ links do."""
    return f"`{_text(label)} <javascript:app.showResultInfo('{quote(path)}')>`__"


def run_figure(variant: str, run: str) -> str:
    """The per-run figure of ``run`` in variant ``variant`` (rule report_runs)."""
    return f"results/{variant}/report/runs/{run}.png"


def _list_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = [".. list-table::", "   :header-rows: 1", ""]
    for row in [header, *rows]:
        lines += [f"   * - {row[0]}"] + [f"     - {cell}" for cell in row[1:]]
    return "\n".join(lines)


def _runs(n: int, role: str) -> str:
    return f"{n} {role} run{'' if n == 1 else 's'}"


def _headline(summary: pd.DataFrame) -> str:
    best = best_variant(summary)
    p = float(best["p_value"])
    fits = (f"within the noise ({_p_value(p)})" if p >= ALPHA
            else f"beyond the noise ({_p_value(p)}): the model still misses something")
    which = f"Best of the {len(summary)} variants** (lowest BIC)" if len(summary) > 1 else "The only variant**"
    text = (f"**{which}: **{_text(best['variant'])}**, chi^2/dof "
            f"{_number(best['chi2_dof'])} on its {_runs(int(best['fit_runs']), 'fit')} (1 = the noise floor), {fits}")
    if best["validation_runs"]:
        n = int(best["validation_runs"])
        text += (f"; {_number(best['validation_chi2_dof'])} on its {_runs(n, 'validation')} "
                 f"(predicted, never fitted), {int(best['validation_runs_beyond_noise'])} beyond the noise")
    return text + "."


def _ledger_rows(summary: pd.DataFrame) -> list[list[str]]:
    rows = []
    for r in summary.itertuples():
        worst = (result_link(f"{r.worst_run} ({_number(r.worst_run_chi2_dof)})", run_figure(r.variant, r.worst_run))
                 if r.worst_run else "none")
        rows.append([_text(r.variant), _number(r.chi2_dof), _number(r.validation_chi2_dof),
                     f"{float(r.delta_bic):.0f}", worst])
    return rows


def verdict(conclusion: str) -> str:
    """A diagnosis's conclusion up to its first colon ("add expansion_k4", "no missing effect"): the evidence
    that follows is in diagnosis.md, and the first page has to stay short."""
    return conclusion.split(":", 1)[0].strip()


def _recommendation(r) -> str:
    line = f"**{_text(r.variant)}**: {_text(verdict(r.conclusion)) or 'no diagnosis'}"
    if r.recommended_variant and r.recommended_in_config:
        return line + f" (in the config as **{_text(r.recommended_in_config)}**)"
    if r.recommended_variant:
        return (line + f" (variant {_text(r.recommended_variant)}: "
                + result_link("diagnosis.md", f"results/{r.variant}/diagnosis.md") + ")")
    return line


#: what the first page says after a failing validation run, per explanation code (validation.tsv's ``explanation``,
#: hybridtwin.identify.validation_refit); {pinned}: the parameters the run pins
WHY = {"not_pinned": "the fit runs do not pin {pinned}; this run does", "bow_law": "its bow leaves the fit runs' law",
       "missing_physics": "missing physics: no parameter set the fit runs allow predicts it"}


def explanations(validation: pd.DataFrame) -> dict[str, str]:
    """Per validation run, what the first page says of its failure (``WHY``; none for the other codes), from
    validation.tsv (its explanation and pinned columns; a table without them: nothing)."""
    if "explanation" not in validation:
        return {}
    rows = validation.drop_duplicates("run")
    return {str(r.run): WHY[r.explanation].format(pinned=str(r.pinned).replace(",", ", "))
            for r in rows.itertuples() if r.explanation in WHY}


def _failures(variant: str, table: pd.DataFrame, why: Mapping[str, str] | None = None) -> str:
    beyond = table[table["beyond_noise"]].sort_values("chi2_dof", ascending=False)
    error_map = result_link("error map", f"results/{variant}/report/error_map.png")
    if beyond.empty:
        return f"**{_text(variant)}**: every run within the noise ({error_map})."
    why = why or {}
    runs = [result_link(f"{r.run}{' (validation)' if r.role != 'fit' else ''} {_number(r.chi2_dof)}",
                        run_figure(variant, r.run))
            + (f" ({_text(why[r.run])})" if r.role != "fit" and r.run in why else "")
            for r in beyond.head(MAX_RUN_LINKS).itertuples()]
    more = f" and {len(beyond) - MAX_RUN_LINKS} more" if len(beyond) > MAX_RUN_LINKS else ""
    return (f"**{_text(variant)}**: {len(beyond)} of {len(table)} runs: " + ", ".join(runs) + more
            + f" ({error_map}).")


def next_runs_line(variant: str, chosen: pd.DataFrame, intervals: pd.DataFrame) -> str:
    """The first page's line on the next runs to take for ``variant`` (its design/next_runs.tsv and intervals.tsv,
    hybridtwin.identify.design): the runs in order and the intervals of interest now and expected after them."""
    if chosen.empty:
        return ""
    runs = "; ".join(f"{r.rpm:g} RPM, {r.eccentric_mass_g:g} g" + (" with a keyphasor" if keyphasor else "")
                     for r, keyphasor in zip(chosen.itertuples(), measured.flags(chosen["keyphasor"])))
    wanted = intervals[measured.flags(intervals["interest"])]
    shrink = ", ".join(f"{_text(r.parameter)} +-{r.linear_half_width:.3g} -> +-{r.expected_half_width:.3g}"
                       for r in wanted.itertuples())
    return (f"**The next runs to take** for {_text(variant)} (D-optimal on its fitted twin, "
            + result_link("design.png", f"results/{variant}/design/design.png") + f"): {runs}; expected 95 % "
            f"half-widths {shrink}.")


#: the first page names a parameter whose interval over the candidates is wider than its own by this share of it
ASSUMED = 0.25


def assumptions_line(variant: str, diagnosis: Mapping) -> str:
    """The first page's line on what ``variant``'s estimates assume (its diagnosis.yaml's
    ``intervals_over_candidates``, ``hybridtwin.diagnose.form_intervals``): each shared parameter whose interval over
    the candidates the data cannot exclude is wider than its own by more than ASSUMED of it, with the candidate that
    widens it most and both intervals; empty when none is (or the diagnosis has no such intervals)."""
    rows = []
    for r in diagnosis.get("intervals_over_candidates") or []:
        own = float(r["own_high"]) - float(r["own_low"])
        wider = (float(r["high"]) - float(r["low"])) - own
        if r.get("widened_by") and own > 0 and wider > ASSUMED * own:
            digits = max(3, int(np.ceil(np.log10(max(abs(float(r["estimate"])), 1e-300) / own))) + 2)
            ends = [f"{float(r[k]):.{digits}g}" for k in ("own_low", "own_high", "low", "high")]
            first = str(r["widened_by"]).split(", ")[0]
            rows.append((wider / own, f"{_text(r['parameter'])} [{ends[0]}, {ends[1]}] holds if {_text(first)} is "
                                      f"absent ([{ends[2]}, {ends[3]}] over the candidates)"))
    if not rows:
        return ""
    rows = [text for _, text in sorted(rows, key=lambda row: -row[0])]
    more = f"; and {len(rows) - 3} more" if len(rows) > 3 else ""
    return (f"**What the estimates of {_text(variant)} assume** (intervals over the effects these data cannot exclude, "
            + result_link("diagnosis.md", f"results/{variant}/diagnosis.md") + "): " + "; ".join(rows[:3]) + more
            + ".")


def kept_out(harmonics: pd.DataFrame) -> pd.DataFrame:
    """The runs the data checks kept out (results/data/harmonics.tsv's usable false): run, role, note."""
    return measured.kept_out(harmonics)[["run", "role", "note"]]


def _kept_out_line(runs: pd.DataFrame) -> str:
    if runs.empty:
        return ""
    listed = "; ".join(f"{_text(r.run)} ({_text(r.role)}: {_text(str(r.note))})" for r in runs.itertuples())
    n = len(runs)
    return (f"**{n} run{'s' if n > 1 else ''} kept out by the data checks** (neither fitted nor scored; "
            f"results/data/check.tsv): {listed}.")


def landing_rst(summary: pd.DataFrame, errors: Mapping[str, pd.DataFrame],
                excluded: pd.DataFrame | None = None, why: Mapping[str, Mapping[str, str]] | None = None,
                next_runs: str = "", assumptions: str = "") -> str:
    """The report's first page: the best variant, the runs the data checks kept out (``excluded``: ``kept_out``),
    the ledger, what the diagnoses recommend and where each variant fails, with links that open the figures in
    the report, a failing validation run followed by why (``why``: per variant, ``explanations``), and the next
    runs to take for the best variant (``next_runs``: ``next_runs_line``) and what its estimates assume
    (``assumptions``: ``assumptions_line``).
    reStructuredText, included by workflow/report/workflow.rst; short, to fit a window (see above)."""
    why = why or {}
    excluded = excluded if excluded is not None else pd.DataFrame(columns=["run", "role", "note"])
    return "\n\n".join(part for part in [
        _headline(summary), _kept_out_line(excluded),
        "**The ledger** (Delta BIC: lower is better, above 10 is strong evidence; all columns: "
        + result_link("ledger.tsv", "results/ledger.tsv") + "):",
        _list_table(["variant", "chi^2/dof", "validation", "Delta BIC", "worst run"], _ledger_rows(summary)),
        "**What the diagnosis recommends** (the evidence and the lines to paste are in each variant's diagnosis.md):",
        "\n".join(f"- {_recommendation(r)}" for r in summary.itertuples()),
        (f"**Where each variant fails**: runs beyond the noise (p < {ALPHA:g}), worst first, with their "
         "chi^2/dof; a link opens the run's figure:"),
        "\n".join(f"- {_failures(r.variant, errors[r.variant], why.get(r.variant))}" for r in summary.itertuples()),
        assumptions, next_runs,
        "Every run of every variant in one figure: " + result_link("summary.png", "results/summary.png") + "."]
        if part) + "\n"
