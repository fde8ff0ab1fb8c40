"""The diagnosis's result and what it concludes (``hybridtwin.diagnose.diagnosis``, step 3 of its module docstring).

``Diagnosis``: the ranked table, the conclusion, the recommendation and the forward-selection path, a ``Step`` per
effect added. The tests a refit is judged by: confirmed (``is_confirmed``: likelihood ratio and Delta BIC), fits to
the noise (``fits_the_noise``), shares of the excess chi^2 (``score_excess``). Each candidate's verdict and the
ranked table (``conclude_first_step``, ``_table``), the first step's outcome and recommendation (``_recommend``,
``_thin_plan``: when the fit runs are too thin to rule an effect out), and the conclusion from the whole path (``conclude_path``), with
the estimates said with their intervals (``_estimate_text``). The recommended variant is written out by
``hybridtwin.diagnose.recommendation``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from ..model.fixed_values import is_fixed_value
from .diagnosis_status import (NEARLY_EXPLAINED, CandidateVerdict, Status, opening, plain, share_text,
                               verdict_text)
from .fingerprint import Fingerprint
from .recommendation import joined_variant_name, variant_spec, what_to_do
from .refit import Confirmation
from .score_test import BaseFit, Scores, by_score, nested
from ..identify.validation import spans


#: a base fit with fewer degrees of freedom cannot rule a missing effect out (a chi^2 of 10 dof spans 0.26-2.3
#: times its mean at 99 %: an effect's share of it is lost in that spread)
MIN_DOF = 10
#: ... nor fewer fit runs than this, nor fit runs whose speeds span no more than this fraction of the fastest
MIN_FIT_RUNS, SPEED_SPREAD = 3, 0.05


@dataclass
class Diagnosis:
    """The ranked table, the overall conclusion and the recommendation (config lines to add)."""

    table: pd.DataFrame
    conclusion: str
    recommendation: str
    summary: dict = field(default_factory=dict)
    confirmations: dict[str, Confirmation] = field(default_factory=dict)
    best: Confirmation | None = None  # the first step's best confirmed effect
    path: list = field(default_factory=list)  # forward selection, a Step per effect added
    fingerprint: Fingerprint | None = None  # of the residual left at the end of the path (or of the base)
    status: Status | None = None  # the overall outcome, a code (``summary["status"]``): act on it, not on the text
    #: the final model's shared parameters' intervals over the candidates not in it (``form_intervals``)
    intervals: object | None = None

    def estimates(self) -> pd.DataFrame:
        """The path's effects' parameters (``Identification.table`` rows, with ``effect``) at the path's final
        fit, every effect in: an earlier step's own estimate was made without the effects added after it."""
        if not self.path:
            return pd.DataFrame(columns=["effect", "parameter", "value", "ci_low", "ci_high"])
        table = self.path[-1].confirmation.fit.table()
        table = table[table["run"] == "all"]
        rows = [table[table["parameter"].isin([p.name for p in step.confirmation.candidate.parameters])]
                .assign(effect=step.effect) for step in self.path]
        out = pd.concat(rows, ignore_index=True)
        return out[["effect"] + [c for c in out if c != "effect"]]

    def path_table(self) -> pd.DataFrame:
        """One row per forward-selection step: effect, chi^2/dof before and after, Delta BIC, explained share."""
        rows = [dict(step.row(), step=i + 1) for i, step in enumerate(self.path)]
        return pd.DataFrame(rows, columns=["step", "effect", "chi2_dof_before", "chi2_dof_after", "delta_bic",
                                           "explained_pct", "estimate"])


@dataclass
class Step:
    """One step of the forward selection: the effect added at it and the fit with every effect so far."""

    effect: str
    chi2_dof_before: float
    chi2_dof_after: float
    delta_bic: float
    share: float  # of the base's excess chi^2 removed by the path up to this step
    confirmation: Confirmation
    #: the scale the step was judged at (its score tests, likelihood ratio and Delta BIC): 1 for the first (the
    #: stated sigmas), the remaining misfit chi^2 / dof of the fit it extends for the others (a quasi-likelihood)
    dispersion: float = 1.0

    def row(self) -> dict:
        return {"step": None, "effect": self.effect, "chi2_dof_before": float(self.chi2_dof_before),
                "chi2_dof_after": float(self.chi2_dof_after), "delta_bic": float(self.delta_bic),
                "explained_pct": float(100 * self.share), "estimate": _estimate_text(self.confirmation)}


def fits_the_noise(cf: Confirmation, o: Mapping) -> bool:
    return stats.chi2.sf(cf.chi2, cf.dof) >= o["alpha"] or cf.chi2 / cf.dof <= o["misfit_ratio"]


def path_ranges(path: Sequence[Step]) -> dict[str, tuple[float, float]]:
    """The ranges the path's refits ended with, every effect's parameters (widened ones as widened)."""
    return {k: v for step in path for k, v in step.confirmation.ranges.items()}


def _sharing_text(result: Diagnosis) -> str:
    """The conclusion's sentence on the sharing check (empty when the per-run values stay)."""
    s = result.summary.get("sharing")
    if not s or not s["shared"]:
        return ""
    names = ", ".join(s["parameters"])
    return (f"; {names} need not be estimated per run once the effect{'s are' if len(result.path) > 1 else ' is'} "
            f"in (shared: chi^2 {s['chi2_shared']:.4g} against {s['chi2_per_run']:.4g} per run, likelihood ratio "
            f"{s['lr']:.3g} on {s['lr_dof']} dof, Delta BIC of the per-run values {s['delta_bic_per_run']:+.3g}): "
            "the estimates are from the fit with them shared, and the recommended variant shares them")


def score_excess(scores: Scores) -> float:
    """chi^2 - dof, floored at one standard deviation of chi^2(dof), sqrt(2 dof): shares of an excess within
    the noise are not meaningful (a base at the noise floor would otherwise divide by ~0)."""
    return float(max(scores.base_chi2 - scores.base_dof, np.sqrt(2.0 * scores.base_dof)))


def is_confirmed(cf: Confirmation, o: Mapping, alpha_each: float) -> bool:
    """A significant likelihood ratio and Delta BIC below the threshold. The likelihood ratio is the test of
    "absent" (beta = 0): where the effect's parameter lies in a valley with the base's own (speed damping and
    the structural damping), the linearised (Wald) interval can span 0 while the refit's chi^2 drop is
    1e5; the interval is reported (``excludes_zero``) but does not overrule the likelihood ratio. An optimum whose
    steady state is unstable at some run (``Confirmation.unstable_runs``) is not the machine that was measured:
    never confirmed."""
    return cf.lr_p_value < alpha_each and cf.delta_bic < o["bic_threshold"] and not cf.unstable_runs


def conclude_first_step(base: BaseFit, scores: Scores, confirmations: Mapping[str, Confirmation], o: Mapping,
                        alpha_each: float) -> Diagnosis:
    excess = score_excess(scores)
    base_ratio = scores.base_chi2 / scores.base_dof
    misfit = (stats.chi2.sf(scores.base_chi2, scores.base_dof) < o["alpha"]) and base_ratio > o["misfit_ratio"]
    by_name = {s.candidate.name: s for s in scores.scores}
    confirmed = sorted((cf for cf in confirmations.values() if is_confirmed(cf, o, alpha_each)),
                       key=lambda cf: cf.delta_bic)
    best = confirmed[0] if confirmed else None
    verdicts: dict[str, tuple[CandidateVerdict, str]] = {}
    confounded: list[str] = []
    for cf in confirmed:
        name = cf.candidate.name
        if cf is best:
            continue
        projected, best_projected = by_name[name].projected, by_name[best.candidate.name].projected
        within_best, contains_best = nested(projected, best_projected), nested(best_projected, projected)
        inside = [b.candidate.name for b in confirmed if b is not cf and b.delta_bic <= cf.delta_bic
                  and nested(projected, by_name[b.candidate.name].projected)]
        # the refits decide: sensitivities that span the same space at the base fit (a local statement, and a
        # borderline one: 1e-3 on a principal angle's cosine) are confounded only if the refits tie as well
        tie = cf.delta_bic - best.delta_bic < o["confounded_bic"]
        figures = {"best": best.candidate.name, "bic": cf.delta_bic, "best_bic": best.delta_bic}
        if tie and (within_best and contains_best or (not inside and not contains_best)):
            confounded.append(name)
            verdicts[name] = _say(CandidateVerdict.CONFOUNDED, **figures)
        elif within_best and contains_best:
            verdicts[name] = _say(CandidateVerdict.WEAKER, **figures)
        elif inside:
            verdicts[name] = _say(CandidateVerdict.PART_OF, inside=inside[0])
        elif contains_best:
            verdicts[name] = _say(CandidateVerdict.CONTAINS, **figures)
        else:
            verdicts[name] = _say(CandidateVerdict.CONFIRMED_WEAKER, **figures)
    share = 0.0 if best is None else (scores.base_chi2 - best.chi2) / excess
    gof_after = 0.0 if best is None else stats.chi2.sf(best.chi2, best.dof)
    if best is not None:
        tied = f" (confounded with {', '.join(confounded)})" if confounded else ""
        code = (CandidateVerdict.ADD if share >= o["explained"] or gof_after >= o["alpha"]
                else CandidateVerdict.ADD_PART if share >= 0.5
                else CandidateVerdict.EXPLAINS_ONLY_TIED if confounded else CandidateVerdict.EXPLAINS_ONLY)
        verdicts[best.candidate.name] = _say(code, pct=100 * share, tied=tied)
    for name, cf in confirmations.items():
        verdicts.setdefault(name, _say(CandidateVerdict.NOT_CONFIRMED_UNSTABLE, runs=", ".join(cf.unstable_runs))
                            if cf.unstable_runs else _say(CandidateVerdict.NOT_CONFIRMED))
    for s in scores.scores:
        verdicts.setdefault(s.candidate.name, _say(CandidateVerdict.SIGNIFICANT if s.p_value < alpha_each
                                                   else CandidateVerdict.NOT_SIGNIFICANT))
    table = _table(scores, confirmations, verdicts, confirmed)
    status, conclusion, recommendation = _recommend(base, scores, best, confounded, share, misfit, base_ratio, o)
    summary = plain({"variant": base.variant.name, "runs": list(base.layout.runs), "n_data": scores.n_data,
               "base_chi2": scores.base_chi2, "base_dof": scores.base_dof, "base_chi2_dof": base_ratio,
               "base_gof_p_value": float(stats.chi2.sf(scores.base_chi2, scores.base_dof)),
               "misfit": bool(misfit), "alpha_per_candidate": alpha_each,
               "candidates": [s.candidate.name for s in scores.scores], "refitted": list(confirmations),
               "status": status.value, "conclusion": conclusion, "score_seconds": scores.seconds,
               "recommended_variant": None if best is None else {
                   "name": joined_variant_name([base.variant.name, best.candidate.name]),
                   "spec": variant_spec(base.variant, best.candidate, best.ranges)},
               "refit_seconds": float(sum(cf.seconds for cf in confirmations.values())),
               "confounded": list(confounded)})
    return Diagnosis(table, conclusion, recommendation, summary, dict(confirmations), best, status=status)


def conclude_path(result: Diagnosis, base: BaseFit, scores: Scores, o: Mapping) -> None:
    """The conclusion, verdict of the first effect and recommendation from the forward-selection path: "add"
    for effects that together explain the discrepancy, or that carry nearly all of it (NEARLY_EXPLAINED of the
    excess chi^2: the small misfit left is reported as a form the candidates do not quite capture, with its
    fingerprint); otherwise "unexplained", the path as evidence."""
    path = result.path
    result.summary["path"] = plain([dict(step.row(), step=i + 1, ranges=step.confirmation.ranges,
                                         judged_at=step.dispersion) for i, step in enumerate(path)], "summary.path")
    if not path:
        return
    final, share = path[-1].confirmation, path[-1].share
    # "add" only for effects that bring the fit to the noise: a large share of a huge excess can leave a misfit
    # many times the noise (an effect outside the candidates, half-mimicked by several of them)
    explains = fits_the_noise(final, o)
    nearly = not explains and share >= NEARLY_EXPLAINED
    names = [step.effect for step in path]
    first = result.table.index[result.table["effect"] == names[0]][0]
    base_ratio = scores.base_chi2 / scores.base_dof
    final_rows = result.estimates()
    estimates = "; ".join(f"{step.effect}: "
                          f"{_estimate_text(step.confirmation, final_rows[final_rows['effect'] == step.effect])}"
                          for step in path)
    eliminated = [e["effect"] for e in result.summary.get("eliminated", [])]
    sharing = _sharing_text(result)
    if explains and len(path) == 1 and not eliminated and not sharing:
        return  # conclude_first_step's verdict and recommendation stand
    dropped = (f"; {', '.join(eliminated)} dropped by backward elimination (not needed once "
               f"{' and '.join(names)} {'is' if len(names) == 1 else 'are'} in)") if eliminated else ""
    if explains or nearly:
        together, steps = " and ".join(names), len(path) + len(eliminated)
        confounded = result.summary.get("confounded") or []
        if nearly:
            result.status = Status.ADD_NEARLY
            head = opening(result.status, effects=together, they="it" if len(names) == 1 else "together they",
                           share=share_text(share), after=f"{final.chi2 / final.dof:.3g}")
            set_verdict(result.table, first, CandidateVerdict.ADD_NEARLY, share=share_text(share),
                         with_=", with " + ", ".join(names[1:]) if len(names) > 1 else "")
        elif len(path) == 1 and confounded and not eliminated:  # the first step's tie stands (the sharing check only)
            result.status = Status.ADD_CONFOUNDED
            head = (f"{opening(result.status, effects=together)} or {', '.join(confounded)}: these data cannot "
                    f"tell them apart; {together} "
                    "explains the discrepancy")
        elif len(path) == 1:
            result.status = Status.ADD
            set_verdict(result.table, first, CandidateVerdict.ADD)
            head = f"{opening(result.status, effects=together)}: it explains the discrepancy"
        else:
            result.status = Status.ADD
            set_verdict(result.table, first, CandidateVerdict.ADD_WITH, others=", ".join(names[1:]), pct=100 * share)
            head = f"{opening(result.status, effects=together)}: together they explain the discrepancy"
        if not nearly:
            head += f" ({100 * share:.0f} % of the excess chi^2)"
        result.conclusion = (f"{head}; chi^2/dof {base_ratio:.3g} -> "
                             f"{final.chi2 / final.dof:.3g} (forward selection, {steps} step{'s' if steps != 1 else ''}"
                             f"{dropped}{sharing}); {estimates}")
        candidates = [step.confirmation.candidate for step in path]
        ranges = path_ranges(path)
        name = joined_variant_name([base.variant.name] + names)
        spec = variant_spec(base.variant, candidates, ranges, per_run=[] if sharing else None)
        result.recommendation = what_to_do(name, spec, o, base.variant)
        result.summary["recommended_variant"] = {"name": name, "spec": spec}
    else:
        result.status = Status.UNEXPLAINED
        left = result.summary.get("path_stopped") or "nothing significant is left among the others"
        set_verdict(result.table, first, CandidateVerdict.PART_OF_UNEXPLAINED, pct=100 * path[0].share)
        helps = (f"the candidate that helps most, {names[0]}, removes" if len(names) == 1 else
                 f"the candidates that help most, {', then '.join(names)}, remove")
        leave = "leaves" if len(names) == 1 else "leave"
        result.conclusion = (f"{opening(result.status)}: {helps} {100 * share:.0f} % of the excess chi^2 but {leave} "
                             f"chi^2/dof {final.chi2 / final.dof:.3g} (from {base_ratio:.3g}; the noise gives about "
                             f"1), and {left}: the missing physics is not among the candidates (evidence: "
                             f"{estimates})")
        result.recommendation = ""
        result.summary["recommended_variant"] = None
    result.summary["status"] = result.status.value
    result.summary["conclusion"] = result.conclusion


def _estimate_text(cf: Confirmation, estimates: pd.DataFrame | None = None) -> str:
    """The candidate's estimates (``cf.estimates``, or ``estimates``: its rows of another fit) with intervals and
    the ranges the refit widened."""
    widened = {name for name, _, _ in cf.widened}
    limits = {p.name: p.limits for p in cf.candidate.parameters}

    def one(r) -> str:
        lo, hi = cf.ranges.get(r.parameter, (r.lower, r.upper))
        note = f" (range widened to [{lo:.4g}, {hi:.4g}])" if r.parameter in widened else ""
        if r.at_bound:
            edge = hi if abs(r.value - hi) <= abs(r.value - lo) else lo
            physical = limits.get(r.parameter) is not None and edge in tuple(limits[r.parameter])
            why = ("its physical limit: the data want more of this effect than it can physically give" if physical
                   else "the data want more of this effect than the range allows")
            return (f"{r.parameter} = {r.value:.4g} {r.unit} (at the edge of its range [{lo:.4g}, {hi:.4g}], "
                    f"{why})")
        d = _digits(r.value, r.ci_high - r.ci_low)
        if is_fixed_value(cf.candidate):  # "zeta_s fixed at 0.0271: the data say 0.024 [...]"
            freed = cf.candidate.effect
            d = _digits(freed.fixed_value + r.value, r.ci_high - r.ci_low)
            return freed.value_text(r.value, r.ci_low, r.ci_high, d) + note
        return f"{r.parameter} = {r.value:.{d}g} [{r.ci_low:.{d}g}, {r.ci_high:.{d}g}] {r.unit}".rstrip() + note
    return "; ".join(one(r) for r in (cf.estimates if estimates is None else estimates).itertuples())


def _digits(value: float, width: float) -> int:
    """Significant digits that show an interval of ``width`` around ``value`` (4 at least): the interval's ends
    differ in the printed text (1.2e+06 [1.2e+06, 1.2e+06] says nothing; 1.200005e+06 [1.199927e+06, ...] does)."""
    if not (np.isfinite(value) and np.isfinite(width)) or width <= 0 or value == 0:
        return 4
    return int(min(12, max(4, np.ceil(np.log10(abs(value) / width)) + 2)))


def _say(code: CandidateVerdict, **figures) -> tuple[CandidateVerdict, str]:
    """A verdict: its code and its sentence (``verdict_text``)."""
    return code, verdict_text(code, **figures)


def set_verdict(table: pd.DataFrame, rows, code: CandidateVerdict, **figures) -> None:
    """The table's ``rows`` get verdict ``code``: its code and its sentence, side by side."""
    table.loc[rows, "verdict"] = verdict_text(code, **figures)
    table.loc[rows, "verdict_code"] = code.value


def _table(scores: Scores, confirmations: Mapping[str, Confirmation],
           verdicts: Mapping[str, tuple[CandidateVerdict, str]], confirmed: Sequence[Confirmation]) -> pd.DataFrame:
    """One row per candidate: confirmed ones first (by Delta BIC), then by score p-value."""
    excess = score_excess(scores)
    first = [cf.candidate.name for cf in confirmed]
    rest = [s.candidate.name for s in sorted(scores.scores, key=by_score)
            if s.candidate.name not in first]
    by_name = {s.candidate.name: s for s in scores.scores}
    rows = []
    for rank, name in enumerate(first + rest, start=1):
        s, cf = by_name[name], confirmations.get(name)
        k = len(s.candidate.parameters)
        rows.append({
            "rank": rank, "effect": name, "meaning": s.candidate.meaning,
            "parameters": ",".join(p.name for p in s.candidate.parameters),
            "statistic": s.statistic, "dof": k, "p_value": s.p_value, "log10_p_value": s.log_p / np.log(10),
            "predicted_error_drop_pct": 100 * s.statistic / excess,
            "predicted_chi2_dof": (scores.base_chi2 - s.statistic) / max(scores.base_dof - k, 1),
            "confirmed_error_drop_pct": np.nan if cf is None else 100 * (scores.base_chi2 - cf.chi2) / excess,
            "confirmed_chi2_dof": np.nan if cf is None else cf.chi2 / cf.dof,
            "lr_statistic": np.nan if cf is None else cf.lr,
            "lr_p_value": np.nan if cf is None else cf.lr_p_value,
            "delta_bic": np.nan if cf is None else cf.delta_bic,
            "estimate": "" if cf is None else _estimate_text(cf),
            "beyond_range": s.beyond_range,
            "verdict": verdicts[name][1], "verdict_code": verdicts[name][0].value,
        })
    return pd.DataFrame(rows)


def _recommend(base: BaseFit, scores: Scores, best: Confirmation | None, confounded: Sequence[str],
               share: float, misfit: bool, base_ratio: float, o: Mapping) -> tuple[Status, str, str]:
    """The first step's outcome (a Status), its conclusion (opening from the status) and recommendation."""
    variant = base.variant
    if best is None:
        weak = _thin_plan(base, scores)
        if weak and base.undetermined:
            weak.append(f"the fit leaves {', '.join(base.undetermined)}")
        if not misfit and weak:
            return Status.CANNOT_RULE_OUT, (f"{opening(Status.CANNOT_RULE_OUT)}: "
                    f"{'; '.join(weak)}, where an effect can hide (chi^2/dof {base_ratio:.3g}, no candidate "
                    "significant); fit runs at more speeds and unbalance masses decide, and the validation runs "
                    "tell whether the model predicts (results/ledger.tsv)"), ""
        if not misfit:
            return Status.NO_MISSING_EFFECT, (f"{opening(Status.NO_MISSING_EFFECT)}: the model fits the data to "
                    "within the noise "
                    f"(chi^2/dof {base_ratio:.3g}) and no candidate is significant"), ""
        top = max(scores.scores, key=lambda s: s.statistic)
        return Status.UNEXPLAINED, (f"{opening(Status.UNEXPLAINED)}: chi^2/dof {base_ratio:.3g} is well above the "
                "noise floor (1), and no "
                f"candidate is confirmed (the best, {top.candidate.name}, would remove "
                f"{100 * top.statistic / score_excess(scores):.0f} % of the excess chi^2 to first order); the missing "
                "physics is not among the candidates: look at the residual spectrum and the error map, and add "
                "your own candidate effects"), ""
    name = best.candidate.name
    if confounded:
        status = Status.ADD_CONFOUNDED
        head = (f"{opening(status, effects=name)} or {', '.join(confounded)}: these data cannot tell them apart "
                "(measure where their "
                "responses differ, e.g. more speeds or unbalance masses, to decide)")
    elif share >= o["explained"]:
        status = Status.ADD
        head = f"{opening(status, effects=name)}: it explains the discrepancy ({100 * share:.0f} % of the excess chi^2)"
    elif share >= 0.5:
        status = Status.ADD_PART
        head = (f"{opening(status, effects=name)}: it explains {100 * share:.0f} % of the excess chi^2; a "
                "discrepancy remains")
    else:
        status = Status.UNEXPLAINED
        head = (f"{opening(status)}: the best confirmed candidate, {name}, explains only "
                f"{100 * share:.0f} % of the excess chi^2")
    conclusion = (f"{head}; chi^2/dof {base_ratio:.3g} -> {best.chi2 / best.dof:.3g} with it, "
                  f"Delta BIC {best.delta_bic:.1f}; {_estimate_text(best)}")
    new_name = joined_variant_name([variant.name, name])
    recommendation = what_to_do(new_name, variant_spec(variant, best.candidate, best.ranges), o, variant)
    return status, conclusion, recommendation


def _thin_plan(base: BaseFit, scores: Scores) -> list[str]:
    """Why the fit runs cannot rule a missing effect out, whatever their chi^2 (empty: they can): fewer than
    MIN_FIT_RUNS runs, one speed (within SPEED_SPREAD), or fewer than MIN_DOF degrees of freedom. An effect's
    signature is how the response changes with speed and unbalance; with too few, the base's parameters (a bow
    per run, k_b) absorb it."""
    rpm = np.array([d.rpm for d in base.data])
    why = []
    if len(rpm) < MIN_FIT_RUNS:
        why.append(f"only {len(rpm)} fit run{'s' if len(rpm) > 1 else ''}")
    elif not spans(rpm, SPEED_SPREAD):
        why.append(f"every fit run at one speed ({rpm.min():.0f}-{rpm.max():.0f} RPM)")
    if scores.base_dof < MIN_DOF:
        why.append(f"only {scores.base_dof} degrees of freedom")
    return why
