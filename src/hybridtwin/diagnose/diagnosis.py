"""Diagnosis: which physical effect is the model missing? (issue 6)

Input: a variant fitted jointly to the fit runs (the identification stage's
``results/{variant}/parameters.tsv``: shared parameters, per-run ones, phases)
and candidate effects (``hybridtwin.model.candidates``), each switched on by
parameters beta that are absent at zero. Every response below comes from the
full harmonic-balance solver (``identification.SolverModel``), never from a
library: the candidates are not in the libraries, and the test must not
mistake surrogate error for physics.

1. Score (Lagrange multiplier) test of every candidate at the fitted base.
   r: the weighted residuals of eq. 10 with the measured sigmas, so r ~ N(0, I)
   when the model is right; J = d r / d theta of the base entries (shared,
   per-run, phases; entries held at a range edge excluded, as in the fit);
   G = d r / d beta at beta = 0, all candidates in one batched solve (the base
   extended by every candidate at zero *is* the base). With Q an orthonormal
   basis of J, r_p = r - Q Q^T r and G_p = G - Q Q^T G (the base's
   sensitivities projected out, so an effect the base can absorb scores ~0):

       S = ||r_p||^2 - min_b ||r_p + G_p b||^2,          b >= 0 if 0 is a range edge,

   the chi^2 drop the candidate predicts to first order, and S ~ chi^2(k)
   under "absent" (k = its parameters; with a sign constraint the law is the
   chi-bar^2 mixture, so chi^2(k) is conservative). Bonferroni over the
   candidates keeps the family-wise false-alarm rate at ``alpha``.
2. Confirmation of the best ones: a joint refit with the candidate added
   (full solver, LM from the base optimum and from the linear estimate b):
   likelihood ratio LR = chi^2_base - chi^2_new ~ chi^2(k),
   Delta BIC = -LR + k ln n, and the new parameters' 95 % intervals.
3. Verdicts, said honestly: "add" (confirmed, explains the discrepancy down to
   the noise), "add, explains part" (a discrepancy remains), "confounded with
   X" (both confirmed, these data cannot tell them apart: their Delta BIC
   differ by less than ``confounded_bic``), "part of X" (its sensitivities
   lie within X's: nested), "not confirmed", "not significant"; and overall
   "no missing effect" (the base fits to the noise and nothing is
   significant), or "unexplained discrepancy" when the base misfit is real and
   no candidate explains most of it: the evidence (chi^2/dof, the best
   candidate's share) is given instead of a least-bad name.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from ..model.candidates import Candidate
from .diagnosis_status import (NEARLY_EXPLAINED, Status, Verdict, interval_note, negligible_step, opening, plain,
                               share_text, verdict_text)
from .fingerprint import Fingerprint, fingerprint
from .refit import Confirmation, confirm, shared, without
from .score_test import BaseFit, Scores, by_score, extend, nested, score_tests
from ..identify.validation import spans
from ..model.variants import Variant

Array = np.ndarray

#: the ``diagnosis:`` section's defaults (config/config.yaml; schema in workflow/schemas)
#: a base fit with fewer degrees of freedom cannot rule a missing effect out (a chi^2 of 10 dof spans 0.26-2.3
#: times its mean at 99 %: an effect's share of it is lost in that spread)
MIN_DOF = 10
#: ... nor fewer fit runs than this, nor fit runs whose speeds span no more than this fraction of the fastest
MIN_FIT_RUNS, SPEED_SPREAD = 3, 0.05

DEFAULTS: dict = {
    "candidates": None,  # names to test (built in or from effects_files); None: every built-in candidate
    "confirm": "all",  # candidates refitted: every significant one, or the n best by score (+ any within
    # confounded_bic of the best)
    "starts": 4,  # points across a candidate's range a refit starts from, besides zero and the linear estimate
    "widen": 4,  # times a refit may widen a candidate's range (x3 towards the edge its estimate sits at)
    "thorough": 3,  # candidates, the best by a quick refit's Delta BIC, refitted again from every start with
    # range widening (the quick refit: beta = 0 and the linear estimate, no widening, quick_iterations)
    "quick_iterations": 12,
    "max_effects": 3,  # effects the forward selection adds at most
    "alpha": 0.01,  # family-wise false-alarm rate (Bonferroni over the candidates)
    "explained": 0.9,  # share of the excess chi^2 an effect must remove to "explain the discrepancy"
    "misfit_ratio": 1.2,  # chi^2/dof above which a significant misfit is called a discrepancy (sigma tolerance)
    "confounded_bic": 6.0,  # candidates whose Delta BIC differ by less cannot be told apart ("strong" evidence)
    "bic_threshold": -10.0,  # Delta BIC a confirmed effect must reach ("very strong" evidence, Kass & Raftery)
    "max_iterations": 40,  # LM iterations of a confirmation refit
    "sparse_variant": "expansion",  # the paper's route, shown side by side: that variant's L1-sparse fit (or null)
}


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

    def row(self) -> dict:
        return {"step": None, "effect": self.effect, "chi2_dof_before": float(self.chi2_dof_before),
                "chi2_dof_after": float(self.chi2_dof_after), "delta_bic": float(self.delta_bic),
                "explained_pct": float(100 * self.share), "estimate": _estimate_text(self.confirmation)}


def _quick_refits(base: BaseFit, scores: Scores, o: Mapping, alpha_each: float) -> tuple[list, dict]:
    """The candidates to refit (every significant one with ``confirm: all``, or the ``confirm`` best plus any
    whose predicted drop is within ``confounded_bic`` of the best's) and their quick refits (from beta = 0 and the
    linear estimate, ``quick_iterations``, ranges as given)."""
    order = sorted(scores.scores, key=by_score)
    significant = [s for s in order if s.p_value < alpha_each]
    if o["confirm"] == "all":
        chosen = significant
    else:
        chosen = significant[: int(o["confirm"])]
        if significant:
            top = significant[0].statistic
            chosen += [s for s in significant[len(chosen):] if top - s.statistic < o["confounded_bic"]]
    quick = {s.candidate.name: confirm(base, s, scores, int(o["quick_iterations"]), starts=0, widen=0, quick=True)
             for s in chosen}
    return chosen, quick


def _refit_significant(base: BaseFit, scores: Scores, o: Mapping, alpha_each: float, log=None,
                       quick_refits: tuple[list, dict] | None = None) -> dict[str, Confirmation]:
    """Refit every candidate the score test finds significant (``confirm: all``), or the ``confirm`` best plus
    any whose predicted drop is within ``confounded_bic`` of the best's (maybe confounded).

    Two passes: a quick refit of each (from beta = 0 and the linear estimate, ``quick_iterations``, ranges as
    given) ranks them by Delta BIC; the ``thorough`` best, any within ``confounded_bic`` of the best, and any
    of the ``thorough`` best by score whose quick refit stopped at a range edge it could widen, are
    refitted again (only those within ``confounded_bic`` when the best quick refit fits to the noise already)
    from every start (``starts`` across the range) with range widening (``widen``) and, until one
    of them fits to the noise, the far side (``refit.confirm``'s profile: for a refit that needed a wider range,
    or for the best-ranked one when it still misfits), and that
    refit replaces the quick one. The ranking is by refit, never by the score statistic alone."""
    chosen, quick = quick_refits or _quick_refits(base, scores, o, alpha_each)
    ranked = sorted(chosen, key=lambda s: quick[s.candidate.name].delta_bic)
    best_bic = quick[ranked[0].candidate.name].delta_bic if ranked else 0.0
    # when the best quick refit fits to the noise already, no other refit can do much better: only those that
    # may tie with it (within confounded_bic) are refitted thoroughly, not the ``thorough`` best regardless
    settled = bool(ranked) and _fits_the_noise(quick[ranked[0].candidate.name], o)
    deep = {s.candidate.name for i, s in enumerate(ranked) if (i < int(o["thorough"]) and not settled)
            or quick[s.candidate.name].delta_bic - best_bic < o["confounded_bic"]}
    # a candidate the score test ranks among the ``thorough`` best whose quick refit stopped at a range edge (its
    # truth may lie beyond the range, which a quick refit does not widen) is refitted thoroughly too: ranked by
    # its quick refit alone it fell behind a stand-in (k_xy = 600 N/m against a range of +-200: quick chi^2 1.5e5,
    # upper_bearing_anisotropy's 3.4e4; its thorough refit, widened, fits to the noise)
    if not settled:
        deep |= {s.candidate.name for s in sorted(chosen, key=by_score)[: int(o["thorough"])]
                 if quick[s.candidate.name].widenable}
    confirmations, fitted = {}, False
    for s in ranked:
        name = s.candidate.name
        cf = quick[name]
        if name in deep:  # once a refit fits to the noise, the others need no far side (they can only tie)
            cf = confirm(base, s, scores, int(o["max_iterations"]), starts=int(o["starts"]), widen=int(o["widen"]),
                         far=not fitted, far_misfit=s is ranked[0])
            cf.seconds += quick[name].seconds
            fitted = fitted or _fits_the_noise(cf, o)
        confirmations[name] = cf
        if log:
            widened = "; ".join(f"{p} range widened to [{new[0]:.4g}, {new[1]:.4g}]" for p, _, new in cf.widened)
            log.info("%s refit of %s with %s from %d starts: chi^2 %.4g -> %.4g (quick refit: %.4g), Delta BIC %.3g "
                     "(%.1f s)%s", "thorough" if name in deep else "quick", base.variant.name, name,
                     len(cf.start_chi2), scores.base_chi2, cf.chi2, quick[name].chi2, cf.delta_bic, cf.seconds,
                     f"; {widened}" if widened else "")
    return confirmations


#: a forward-selection step's thorough refits are skipped when the best quick refit removes less than 1/REACH of
#: the chi^2 drop still needed to fit the noise. A quick refit (12 iterations, 2 starts) falls short of the
#: thorough one; measured at the second step of benchmarks/diagnosis_benchmark.py's two_effects case, its drop
#: was within 3 % of the thorough refit's (from chi^2 24170, expansion_k4 to 341.4 vs 340.8, expansion_k7 to
#: 7925 vs 7431): a factor
#: 10 leaves ample room. The first step never stops: its best candidate is the evidence of an unexplained
#: discrepancy, and its base can be far from any linearisation (the lower bearing 60 % softer: quick refits at
#: chi^2/dof 2e4, the profile at 1).
REACH = 10.0


def _out_of_reach(scores: Scores, quick: Mapping[str, Confirmation], o: Mapping) -> str:
    """Why the forward selection stops at this step (empty: it goes on): the best quick refit's chi^2 drop,
    times REACH, is below the drop to chi^2/dof = ``misfit_ratio``."""
    if not quick:
        return ""
    needed = scores.base_chi2 - o["misfit_ratio"] * scores.base_dof
    name, cf = min(quick.items(), key=lambda item: item[1].chi2)
    drop = scores.base_chi2 - cf.chi2
    if REACH * drop >= needed:
        return ""
    return (f"the best remaining candidate, {name}, removes {drop:.4g} of chi^2 {scores.base_chi2:.4g} in a quick "
            f"refit, far from the {needed:.4g} needed to fit the noise: no remaining candidate comes near "
            "explaining what is left")


def _fits_the_noise(cf: Confirmation, o: Mapping) -> bool:
    return stats.chi2.sf(cf.chi2, cf.dof) >= o["alpha"] or cf.chi2 / cf.dof <= o["misfit_ratio"]


def diagnose(base: BaseFit, candidates: Sequence[Candidate], options: Mapping | None = None,
             log=None) -> Diagnosis:
    """Score every candidate, refit every significant one, rank by the refits' Delta BIC and give verdicts
    (module docstring); then forward selection: while the best confirmed effect leaves a discrepancy, add it,
    score and refit the others at the extended fit, and stop when nothing significant is left (``max_effects``
    at most). The path (each step's effect, chi^2/dof, Delta BIC) is in ``Diagnosis.path``."""
    o = DEFAULTS | dict(options or {})
    if not candidates:
        raise ValueError("no candidate effect to test (all are already in the variant, or none was listed)")
    scores = score_tests(base, candidates)
    if log:
        log.info("score tests of %d candidates in %.1f s: base chi^2/dof %.3g", len(candidates), scores.seconds,
                 scores.base_chi2 / scores.base_dof)
    alpha_each = o["alpha"] / len(candidates)
    confirmations = _refit_significant(base, scores, o, alpha_each, log)
    first = _conclude(base, scores, confirmations, o, alpha_each)
    excess = _excess(scores)
    path: list[Step] = []
    best = first.best
    current, remaining, before = base, list(candidates), scores.base_chi2 / scores.base_dof
    while best is not None:
        path.append(Step(best.candidate.name, before, best.chi2 / best.dof, best.delta_bic,
                         (scores.base_chi2 - best.chi2) / excess, best))
        remaining = [c for c in remaining if c.name != best.candidate.name]
        if _fits_the_noise(best, o) or len(path) >= int(o["max_effects"]) or not remaining:
            break
        current = BaseFit(extend(current.variant, [best.candidate], best.ranges), best.fit.layout, best.fit.theta,
                          current.data, current.harmonics)
        step_scores = score_tests(current, remaining)
        step_alpha = o["alpha"] / len(remaining)
        if log:
            top = sorted(step_scores.scores, key=lambda s: -s.statistic)[:4]
            log.info("step %d scores at chi^2 %.4g (dof %d): %s", len(path) + 1, step_scores.base_chi2,
                     step_scores.base_dof, ", ".join(f"{s.candidate.name} {s.statistic:.4g}" for s in top))
        chosen, quick = _quick_refits(current, step_scores, o, step_alpha)
        stop = _out_of_reach(step_scores, quick, o)
        if stop:  # no remaining candidate comes near fitting the noise: the path ends, "unexplained" is what is left
            first.summary["path_stopped"] = stop
            if log:
                log.info("forward selection stops before step %d: %s", len(path) + 1, stop)
            break
        refits = _refit_significant(current, step_scores, o, step_alpha, log, (chosen, quick))
        confirmed = [cf for cf in refits.values() if _is_confirmed(cf, o, step_alpha)]
        before = best.chi2 / best.dof
        previous, best = best, min(confirmed, key=lambda cf: cf.delta_bic) if confirmed else None
        negligible = best and negligible_step(best, previous.chi2, excess)
        if negligible:  # a step too small to matter is not taken to absorb a misfit the candidates do not capture
            first.summary["negligible_step"] = plain(negligible, "summary.negligible_step")
            rows = first.table.index[first.table["effect"] == best.candidate.name]
            _set_verdict(first.table, rows, Verdict.NEGLIGIBLE, step=len(path) + 1,
                         fraction=100 * negligible["estimate_fraction_of_range"], drop=negligible["share_of_excess"])
            if log:
                log.info("forward selection stops before step %d: %s is negligible (%s)", len(path) + 1,
                         best.candidate.name, negligible)
            best = None
        if log:
            log.info("forward selection, step %d at %s: %s", len(path) + 1, current.variant.name,
                     "nothing significant left" if best is None else f"best {best.candidate.name}")
    return _finish(first, base, scores, path, o, log)


def _finish(result: Diagnosis, base: BaseFit, scores: Scores, path: list[Step], o: Mapping, log=None) -> Diagnosis:
    """After the forward selection's ``path``: backward elimination, the sharing check, the conclusion from the
    path and the residual's fingerprint."""
    path = _backward(base, path, scores, o, result, log)
    path = _sharing(base, path, scores, o, result, log)
    result.path = path
    _conclude_path(result, base, scores, o)
    if path:  # how far the estimates' intervals can be trusted with the misfit the path leaves
        final = path[-1].confirmation
        result.summary["intervals"] = interval_note(final.chi2, final.dof, o["alpha"])
    result.fingerprint = residual_fingerprint(base, path[-1].confirmation.fit.fun if path else scores.residual)
    result.summary["fingerprint"] = result.fingerprint.summary()
    if result.status in (Status.UNEXPLAINED, Status.ADD_NEARLY):
        result.conclusion += f". What the residual looks like: {result.fingerprint.summary()}"
        result.summary["conclusion"] = result.conclusion
    return result


def _backward(base: BaseFit, path: list[Step], scores: Scores, o: Mapping, result: Diagnosis, log=None
              ) -> list[Step]:
    """Backward elimination after the forward selection: an effect added early can be made redundant by a later
    one (a base far from the truth takes a stand-in first: speed damping before the softer lower bearing that
    explains everything). Each earlier effect of the path is dropped in turn and the rest refitted from the final
    optimum (``refit.without``); the one whose removal costs least is dropped when keeping it is not confirmed
    (likelihood ratio not significant or Delta BIC above ``bic_threshold``), and so on. The last step stays (it
    was confirmed with all the others in). The dropped effects, with their figures, are in
    ``summary["eliminated"]`` and the table's verdicts; the path's earlier rows stay as the forward selection
    took them, its last row is the refit without the dropped effects."""
    n = scores.n_data
    while len(path) >= 2:
        final = path[-1].confirmation
        ranges = _path_ranges(path)
        trials = []
        for i in range(len(path) - 1):
            kept = [step.confirmation.candidate for j, step in enumerate(path) if j != i]
            # the likelihood ratio of the refit's last effect is taken against the fit before the path's last step
            # (the base for a path of two; for longer paths that fit still holds the dropped effect: approximate)
            previous = scores.base_chi2 if len(path) == 2 else path[-2].confirmation.chi2
            cf = without(base, kept, ranges, final.fit, previous, n, int(o["max_iterations"]))
            trials.append((cf.chi2 - final.chi2, i, cf))
        lr, i, cf = min(trials, key=lambda t: t[0])
        k = len(path[i].confirmation.candidate.parameters)
        keep = stats.chi2.sf(max(lr, 0.0), k) < o["alpha"] / len(scores.scores) and -lr + k * np.log(n) < \
            o["bic_threshold"] and not final.unstable_runs
        if log:
            log.info("backward elimination: without %s chi^2 %.4g vs %.4g with it (Delta BIC of keeping it %.3g): %s",
                     path[i].effect, cf.chi2, final.chi2, -lr + k * np.log(n), "kept" if keep else "dropped")
        if keep:
            break
        dropped = path[i].effect
        others = [step.effect for j, step in enumerate(path) if j != i]
        result.summary.setdefault("eliminated", []).append(
            {"effect": dropped, "chi2_without": float(cf.chi2), "chi2_with": float(final.chi2),
             "delta_bic": float(-lr + k * np.log(n))})
        rows = result.table.index[result.table["effect"] == dropped]
        _set_verdict(result.table, rows, Verdict.DROPPED, others=", ".join(others),
                     verb="is" if len(others) == 1 else "are", lr=lr, bic=-lr + k * np.log(n))
        path = [step for j, step in enumerate(path) if j != i]
        before = path[-2].confirmation.chi2 if len(path) > 1 else scores.base_chi2
        dof = path[-2].confirmation.dof if len(path) > 1 else scores.base_dof
        k_last = len(cf.candidate.parameters)
        path[-1] = Step(path[-1].effect, before / dof, cf.chi2 / cf.dof, -(before - cf.chi2) + k_last * np.log(n),
                        (scores.base_chi2 - cf.chi2) / _excess(scores), cf)
    return path


def _path_ranges(path: Sequence[Step]) -> dict[str, tuple[float, float]]:
    """The ranges the path's refits ended with, every effect's parameters (widened ones as widened)."""
    return {k: v for step in path for k, v in step.confirmation.ranges.items()}


def _sharing(base: BaseFit, path: list[Step], scores: Scores, o: Mapping, result: Diagnosis, log=None
             ) -> list[Step]:
    """The sharing check, once the path's effects explain the discrepancy: are the base's per-run parameters
    (``identification.per_run``, e.g. the bow q_x, q_y) still needed with the effects in? The path's model is
    fitted with each of them one value shared by all runs (``refit.shared``); the per-run values are kept when
    their likelihood ratio is significant (``alpha``) with a Delta BIC below ``bic_threshold``, as any effect
    must be. Otherwise the path's last step becomes the shared fit (its estimates and intervals: per-run values
    the data do not need trade off against the new effect, e.g. each run's bow and unknown phase absorb most of
    its 1X response and bias a bearing stiffness resting on the higher harmonics), the recommended variant
    shares them (``per_run: []``), and ``summary["sharing"]`` has the figures."""
    local = list(base.layout.local)
    if not path or not local or len(base.layout.runs) < 2 or not _fits_the_noise(path[-1].confirmation, o):
        return path  # (one run: per run and shared are the same fit)
    final, n = path[-1].confirmation, scores.n_data
    ranges = _path_ranges(path)
    before = path[-2].confirmation.chi2 if len(path) > 1 else scores.base_chi2
    cf = shared(base, [step.confirmation.candidate for step in path], ranges, final.fit, before, n,
                int(o["max_iterations"]))
    k = len(local) * (len(base.layout.runs) - 1)  # the per-run values' extra parameters
    lr = cf.chi2 - final.chi2
    p_value, delta_bic = float(stats.chi2.sf(max(lr, 0.0), k)), float(-lr + k * np.log(n))
    keep = (p_value < o["alpha"] and delta_bic < o["bic_threshold"]) or bool(cf.unstable_runs) or \
        not _fits_the_noise(cf, o)
    result.summary["sharing"] = plain({"parameters": local, "chi2_per_run": final.chi2, "dof_per_run": final.dof,
                                       "chi2_shared": cf.chi2, "dof_shared": cf.dof, "lr": lr, "lr_dof": k,
                                       "lr_p_value": p_value, "delta_bic_per_run": delta_bic, "shared": not keep},
                                      "summary.sharing")
    if log:
        log.info("sharing check: %s shared chi^2 %.4g (dof %d) vs per run %.4g (dof %d): likelihood ratio %.3g on %d "
                 "dof, Delta BIC of per-run values %.3g: %s", ", ".join(local), cf.chi2, cf.dof, final.chi2,
                 final.dof, lr, k, delta_bic, "kept per run" if keep else "shared")
    if keep:
        return path
    last = path[-1]
    return path[:-1] + [Step(last.effect, last.chi2_dof_before, cf.chi2 / cf.dof, last.delta_bic,
                             (scores.base_chi2 - cf.chi2) / _excess(scores), cf)]


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


def residual_fingerprint(base: BaseFit, r: Array) -> Fingerprint:
    """The fingerprint (``hybridtwin.diagnose.fingerprint``) of a fit's weighted residuals r (eq. 10, the data part first:
    per run [Re, Im] of (X - M) / s over (H, C), as ``ArrowProblem.evaluate``): E = X - M rebuilt from r."""
    R, H = len(base.data), base.harmonics
    C = base.sigma.shape[2]  # channels: the sensors (x, y on the VARM)
    parts = np.asarray(r, float)[: R * 2 * C * H].reshape(R, 2, H, C)
    E = (parts[:, 0] + 1j * parts[:, 1]) * base.sigma  # (R, H, C)
    measured = np.concatenate([np.zeros((R, 1, C), complex), base.X], axis=1)  # h = 0 (DC) unused
    model = measured - np.concatenate([np.zeros((R, 1, C), complex), E], axis=1)
    sigma = np.concatenate([np.full((R, 1, C), np.inf), base.sigma], axis=1)
    return fingerprint(measured, model, sigma, [d.rpm for d in base.data], [d.eccentric_mass_g for d in base.data],
                       [d.run for d in base.data])


def _excess(scores: Scores) -> float:
    """chi^2 - dof, floored at one standard deviation of chi^2(dof), sqrt(2 dof): shares of an excess within
    the noise are not meaningful (a base at the noise floor would otherwise divide by ~0)."""
    return float(max(scores.base_chi2 - scores.base_dof, np.sqrt(2.0 * scores.base_dof)))


def _is_confirmed(cf: Confirmation, o: Mapping, alpha_each: float) -> bool:
    """A significant likelihood ratio and Delta BIC below the threshold. The likelihood ratio is the test of
    "absent" (beta = 0): where the effect's parameter lies in a valley with the base's own (speed damping and
    the structural damping), the linearised (Wald) interval can span 0 while the refit's chi^2 drop is
    1e5; the interval is reported (``excludes_zero``) but does not overrule the likelihood ratio. An optimum whose
    steady state is unstable at some run (``Confirmation.unstable_runs``) is not the machine that was measured:
    never confirmed."""
    return cf.lr_p_value < alpha_each and cf.delta_bic < o["bic_threshold"] and not cf.unstable_runs


def _conclude(base: BaseFit, scores: Scores, confirmations: Mapping[str, Confirmation], o: Mapping,
              alpha_each: float) -> Diagnosis:
    excess = _excess(scores)
    base_ratio = scores.base_chi2 / scores.base_dof
    misfit = (stats.chi2.sf(scores.base_chi2, scores.base_dof) < o["alpha"]) and base_ratio > o["misfit_ratio"]
    by_name = {s.candidate.name: s for s in scores.scores}
    confirmed = sorted((cf for cf in confirmations.values() if _is_confirmed(cf, o, alpha_each)),
                       key=lambda cf: cf.delta_bic)
    best = confirmed[0] if confirmed else None
    verdicts: dict[str, tuple[Verdict, str]] = {}
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
            verdicts[name] = _say(Verdict.CONFOUNDED, **figures)
        elif within_best and contains_best:
            verdicts[name] = _say(Verdict.WEAKER, **figures)
        elif inside:
            verdicts[name] = _say(Verdict.PART_OF, inside=inside[0])
        elif contains_best:
            verdicts[name] = _say(Verdict.CONTAINS, **figures)
        else:
            verdicts[name] = _say(Verdict.CONFIRMED_WEAKER, **figures)
    share = 0.0 if best is None else (scores.base_chi2 - best.chi2) / excess
    gof_after = 0.0 if best is None else stats.chi2.sf(best.chi2, best.dof)
    if best is not None:
        tied = f" (confounded with {', '.join(confounded)})" if confounded else ""
        code = (Verdict.ADD if share >= o["explained"] or gof_after >= o["alpha"] else Verdict.ADD_PART
                if share >= 0.5 else Verdict.EXPLAINS_ONLY_TIED if confounded else Verdict.EXPLAINS_ONLY)
        verdicts[best.candidate.name] = _say(code, pct=100 * share, tied=tied)
    for name, cf in confirmations.items():
        verdicts.setdefault(name, _say(Verdict.NOT_CONFIRMED_UNSTABLE, runs=", ".join(cf.unstable_runs))
                            if cf.unstable_runs else _say(Verdict.NOT_CONFIRMED))
    for s in scores.scores:
        verdicts.setdefault(s.candidate.name, _say(Verdict.SIGNIFICANT if s.p_value < alpha_each
                                                   else Verdict.NOT_SIGNIFICANT))
    table = _table(scores, confirmations, verdicts, confirmed)
    status, conclusion, recommendation = _recommend(base, scores, best, confounded, share, misfit, base_ratio, o)
    summary = plain({"variant": base.variant.name, "runs": list(base.layout.runs), "n_data": scores.n_data,
               "base_chi2": scores.base_chi2, "base_dof": scores.base_dof, "base_chi2_dof": base_ratio,
               "base_gof_p_value": float(stats.chi2.sf(scores.base_chi2, scores.base_dof)),
               "misfit": bool(misfit), "alpha_per_candidate": alpha_each,
               "candidates": [s.candidate.name for s in scores.scores], "refitted": list(confirmations),
               "status": status.value, "conclusion": conclusion, "score_seconds": scores.seconds,
               "recommended_variant": None if best is None else {
                   "name": _variant_name([base.variant.name, best.candidate.name]),
                   "spec": variant_spec(base.variant, best.candidate, best.ranges)},
               "refit_seconds": float(sum(cf.seconds for cf in confirmations.values())),
               "confounded": list(confounded)})
    return Diagnosis(table, conclusion, recommendation, summary, dict(confirmations), best, status=status)


def _conclude_path(result: Diagnosis, base: BaseFit, scores: Scores, o: Mapping) -> None:
    """The conclusion, verdict of the first effect and recommendation from the forward-selection path: "add"
    for effects that together explain the discrepancy, or that carry nearly all of it (NEARLY_EXPLAINED of the
    excess chi^2: the small misfit left is reported as a form the candidates do not quite capture, with its
    fingerprint); otherwise "unexplained", the path as evidence."""
    path = result.path
    result.summary["path"] = plain([dict(step.row(), step=i + 1, ranges=step.confirmation.ranges)
                                    for i, step in enumerate(path)], "summary.path")
    if not path:
        return
    final, share = path[-1].confirmation, path[-1].share
    # "add" only for effects that bring the fit to the noise: a large share of a huge excess can leave a misfit
    # many times the noise (an effect outside the candidates, half-mimicked by several of them)
    explains = _fits_the_noise(final, o)
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
        return  # _conclude's verdict and recommendation stand
    dropped = (f"; {', '.join(eliminated)} dropped by backward elimination (not needed once "
               f"{' and '.join(names)} {'is' if len(names) == 1 else 'are'} in)") if eliminated else ""
    if explains or nearly:
        together, steps = " and ".join(names), len(path) + len(eliminated)
        confounded = result.summary.get("confounded") or []
        if nearly:
            result.status = Status.ADD_NEARLY
            head = opening(result.status, effects=together, they="it" if len(names) == 1 else "together they",
                           share=share_text(share), after=f"{final.chi2 / final.dof:.3g}")
            _set_verdict(result.table, first, Verdict.ADD_NEARLY, share=share_text(share),
                         with_=", with " + ", ".join(names[1:]) if len(names) > 1 else "")
        elif len(path) == 1 and confounded and not eliminated:  # the first step's tie stands (the sharing check only)
            result.status = Status.ADD_CONFOUNDED
            head = (f"{opening(result.status, effects=together)} or {', '.join(confounded)}: these data cannot "
                    f"tell them apart; {together} "
                    "explains the discrepancy")
        elif len(path) == 1:
            result.status = Status.ADD
            _set_verdict(result.table, first, Verdict.ADD)
            head = f"{opening(result.status, effects=together)}: it explains the discrepancy"
        else:
            result.status = Status.ADD
            _set_verdict(result.table, first, Verdict.ADD_WITH, others=", ".join(names[1:]), pct=100 * share)
            head = f"{opening(result.status, effects=together)}: together they explain the discrepancy"
        if not nearly:
            head += f" ({100 * share:.0f} % of the excess chi^2)"
        result.conclusion = (f"{head}; chi^2/dof {base_ratio:.3g} -> "
                             f"{final.chi2 / final.dof:.3g} (forward selection, {steps} step{'s' if steps != 1 else ''}"
                             f"{dropped}{sharing}); {estimates}")
        candidates = [step.confirmation.candidate for step in path]
        ranges = _path_ranges(path)
        name = _variant_name([base.variant.name] + names)
        spec = variant_spec(base.variant, candidates, ranges, per_run=[] if sharing else None)
        result.recommendation = what_to_do(name, spec, o)
        result.summary["recommended_variant"] = {"name": name, "spec": spec}
    else:
        result.status = Status.UNEXPLAINED
        left = result.summary.get("path_stopped") or "nothing significant is left among the others"
        _set_verdict(result.table, first, Verdict.PART_OF_UNEXPLAINED, pct=100 * path[0].share)
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


def _variant_name(parts: Sequence[str]) -> str:
    """A recommended variant's name, valid in the config (a letter, then letters, digits, _): the base's and the
    effects' names joined by _, an effect placed at a bearing (``cross_coupled_stiffness@b``) spelled ``..._at_b``,
    any other character an effect's name may hold (``oil-film_b``) as _."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", "_".join(parts).replace("@", "_at_"))
    return name if name[:1].isalpha() else f"v_{name}"


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
        return f"{r.parameter} = {r.value:.{d}g} [{r.ci_low:.{d}g}, {r.ci_high:.{d}g}] {r.unit}".rstrip() + note
    return "; ".join(one(r) for r in (cf.estimates if estimates is None else estimates).itertuples())


def _digits(value: float, width: float) -> int:
    """Significant digits that show an interval of ``width`` around ``value`` (4 at least): the interval's ends
    differ in the printed text (1.2e+06 [1.2e+06, 1.2e+06] says nothing; 1.200005e+06 [1.199927e+06, ...] does)."""
    if not (np.isfinite(value) and np.isfinite(width)) or width <= 0 or value == 0:
        return 4
    return int(min(12, max(4, np.ceil(np.log10(abs(value) / width)) + 2)))


def _say(code: Verdict, **figures) -> tuple[Verdict, str]:
    """A verdict: its code and its sentence (``verdict_text``)."""
    return code, verdict_text(code, **figures)


def _set_verdict(table: pd.DataFrame, rows, code: Verdict, **figures) -> None:
    """The table's ``rows`` get verdict ``code``: its code and its sentence, side by side."""
    table.loc[rows, "verdict"] = verdict_text(code, **figures)
    table.loc[rows, "verdict_code"] = code.value


def _table(scores: Scores, confirmations: Mapping[str, Confirmation], verdicts: Mapping[str, tuple[Verdict, str]],
           confirmed: Sequence[Confirmation]) -> pd.DataFrame:
    """One row per candidate: confirmed ones first (by Delta BIC), then by score p-value."""
    excess = _excess(scores)
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


def refits_table(result: Diagnosis) -> pd.DataFrame:
    """Every refit's parameter table (``Identification.table``) with its ``effect``: full-solver joint fits of
    the variant with one effect added, which the identification of such a variant starts its polish from."""
    tables = [cf.fit.table().assign(effect=name) for name, cf in result.confirmations.items()]
    if not tables:
        return pd.DataFrame(columns=["effect", "parameter", "run", "value", "normalised"])
    table = pd.concat(tables, ignore_index=True)
    return table[["effect"] + [c for c in table if c != "effect"]]


def variant_spec(base: Variant, candidate: Candidate | Sequence[Candidate],
                 ranges: Mapping[str, tuple[float, float]] | None = None, per_run: Sequence[str] | None = None
                 ) -> dict:
    """The config entry (``variants:`` form) of ``base`` + the candidate(s), their parameters unknown in their
    ranges (``ranges``: those a refit widened); ``per_run``: the variant's own parameters per run (its
    ``per_run`` key, overriding ``identification.per_run``; None: not set)."""
    added = [candidate] if isinstance(candidate, Candidate) else list(candidate)
    ranges = dict(ranges or {})
    unknown = dict(base.unknown) | {p.name: tuple(ranges.get(p.name, p.bounds)) for c in added for p in c.parameters}
    spec = {"description": f"{base.name} + " + " + ".join(f"{c.name}: {c.meaning}" for c in added),
            "effects": [e.name for e in base.model.effects] + [c.name for c in added],
            "unknown": {k: [float(lo), float(hi)] for k, (lo, hi) in unknown.items()}}
    if base.fixed:
        spec["fixed"] = {k: float(v) for k, v in base.fixed.items()}
    if per_run is not None:
        spec["per_run"] = list(per_run)
    return spec


def yaml_number(value: float) -> str:
    """``value`` to 6 significant digits as YAML reads a number: 2000, 0.05, 3.0e+07, -2.0e+06 (``3e+07`` would
    be a string to YAML 1.1, the loader of PyYAML and Snakemake: a float's exponent form needs a point)."""
    text = f"{value:g}"
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def variant_lines(name: str, spec: Mapping) -> str:
    """``spec`` as YAML lines to paste under ``variants:`` in config/config.yaml."""
    def flow(value) -> str:
        if isinstance(value, Mapping):
            return "{" + ", ".join(f"{k}: {flow(v)}" for k, v in value.items()) + "}"
        if isinstance(value, list):
            return "[" + ", ".join(flow(v) for v in value) + "]"
        return yaml_number(value) if isinstance(value, float) else str(value)
    lines = [f"  {name}:", f"    description: \"{spec['description']}\""]
    lines += [f"    {key}: {flow(spec[key])}" for key in ("effects", "unknown", "fixed", "per_run") if key in spec]
    return "\n".join(lines)


#: where the user's project is, for the recommendation's what to do: a project at the repository root; the workflow
#: passes its own (``project`` of the options: a project run with --directory DIR names DIR's config and command)
PROJECT = {"config": "config/config.yaml", "command": "snakemake --cores 2", "ledger": "results/ledger.tsv"}


def what_to_do(name: str, spec: Mapping, o: Mapping) -> str:
    """The recommendation: the variant ``name`` (``spec``) to paste, where, and the command that builds it."""
    place = PROJECT | dict(o.get("project") or {})
    return (f"Add this variant under `variants:` in {place['config']}, then run `{place['command']}` (only the new "
            f"variant is built) and compare in {place['ledger']}:\n\n{variant_lines(name, spec)}\n")


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
                f"{100 * top.statistic / _excess(scores):.0f} % of the excess chi^2 to first order); the missing "
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
    new_name = _variant_name([variant.name, name])
    recommendation = what_to_do(new_name, variant_spec(variant, best.candidate, best.ranges), o)
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


def settings(config: Mapping) -> dict:
    """The diagnosis options: defaults, then the config's ``diagnosis:`` section."""
    return DEFAULTS | dict(config.get("diagnosis") or {})
