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

The stop rule (issue 51). The first step is judged at the stated sigmas: the base's misfit is what is to be
explained. Every later step is judged at the scale the data show, a quasi-likelihood: with the dispersion
phi = chi^2 / dof of the fit it extends (the remaining misfit), each score statistic and likelihood ratio is divided
by phi, its p-value is from F(k, dof) ((S / k) / phi, the F test of a nested model with an estimated scale; chi^2(k)
of S / phi as dof grows), and Delta BIC = -LR / phi + k ln n. A misfit of form the candidates do not capture (the
quasi-steady model around a resonance, an effect of a slightly different law) inflates phi, and a candidate that
removes a small part of it no longer counts as an effect; a fit within the stated noise goes on to the score tests
too (no stop at chi^2/dof <= ``misfit_ratio``): where the stated sigmas are too large (records whose right model
gives chi^2/dof 0.85-0.9), phi < 1 and an effect hidden below the stated noise but above the data's own floor is
still found. The path's table gives each step's Delta BIC at its scale, the summary its ``judged_at`` phi.

Here: the refits of the significant candidates and the forward selection (``diagnose``: while the best confirmed
effect leaves a discrepancy, add it and test the others again), and the fingerprint of the residual left at its
end. After it, backward elimination and the sharing check: ``hybridtwin.diagnose.elimination``; the result, the
verdicts and the conclusion: ``hybridtwin.diagnose.conclusion``; the recommended variant written out:
``hybridtwin.diagnose.recommendation``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from ..model.candidates import Candidate
from ..progress import Progress
from .conclusion import (Diagnosis, Step, conclude_first_step, conclude_path, fits_the_noise, is_confirmed,
                         path_ranges, score_excess, set_verdict)
from .diagnosis_status import CandidateVerdict, Status, interval_note, negligible_step, plain
from .elimination import backward_elimination, sharing_check
from .fingerprint import Fingerprint, fingerprint
from .refit import Confirmation, confirm
from .form_intervals import FormIntervals, own_intervals
from .score_test import BaseFit, Scores, at_scale, by_score, extend, intervals_over_candidates, score_tests

Array = np.ndarray

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
    settled = bool(ranked) and fits_the_noise(quick[ranked[0].candidate.name], o)
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
    progress = Progress(log, len(deep), f"thorough refits of {base.variant.name}")
    for s in ranked:
        name = s.candidate.name
        cf = quick[name]
        if name in deep:  # once a refit fits to the noise, the others need no far side (they can only tie)
            cf = confirm(base, s, scores, int(o["max_iterations"]), starts=int(o["starts"]), widen=int(o["widen"]),
                         far=not fitted, far_misfit=s is ranked[0])
            cf.seconds += quick[name].seconds
            fitted = fitted or fits_the_noise(cf, o)
            progress.done(note=name)
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
#: chi^2/dof 2e4, the profile at 1). Nor does a step where one of the ``thorough`` best by score stopped its quick
#: refit at a range edge it could widen: its truth may lie beyond the range, where a quick refit cannot go (the
#: lower bearing 60 % softer on run-ups, second step after a speed-damping stand-in: its quick refit removed 2.4e4
#: of chi^2 9.9e5, the thorough one, widened to -9900 N/m, fitted to the noise).
REACH = 10.0


def _out_of_reach(scores: Scores, quick: Mapping[str, Confirmation], o: Mapping) -> str:
    """Why the forward selection stops at this step (empty: it goes on): the best quick refit's chi^2 drop,
    times REACH, is below the drop to chi^2/dof = ``misfit_ratio``, and none of the ``thorough`` best by score
    stopped at a range edge it could widen (``Confirmation.widenable``: those are refitted thoroughly)."""
    if not quick:
        return ""
    ranked = sorted((s for s in scores.scores if s.candidate.name in quick), key=by_score)
    if any(quick[s.candidate.name].widenable for s in ranked[: int(o["thorough"])]):
        return ""
    needed = scores.base_chi2 - o["misfit_ratio"] * scores.base_dof
    name, cf = min(quick.items(), key=lambda item: item[1].chi2)
    drop = scores.base_chi2 - cf.chi2
    if REACH * drop >= needed:
        return ""
    return (f"the best remaining candidate, {name}, removes {drop:.4g} of chi^2 {scores.base_chi2:.4g} in a quick "
            f"refit, far from the {needed:.4g} needed to fit the noise: no remaining candidate comes near "
            "explaining what is left")


def diagnose(base: BaseFit, candidates: Sequence[Candidate], options: Mapping, log=None) -> Diagnosis:
    """Score every candidate, refit every significant one, rank by the refits' Delta BIC and give verdicts
    (module docstring); then forward selection: add the best confirmed effect, score and refit the others at the
    extended fit judged at its remaining misfit (module docstring, "the stop rule"), and stop when nothing
    significant is left at that scale (``max_effects`` at most). The path (each step's effect, chi^2/dof, Delta
    BIC, the scale it was judged at) is in ``Diagnosis.path``."""
    o = dict(options)
    if not candidates:
        raise ValueError("no candidate effect to test (all are already in the variant, or none was listed)")
    scores = score_tests(base, candidates)
    if log:
        log.info("score tests of %d candidates in %.1f s: base chi^2/dof %.3g", len(candidates), scores.seconds,
                 scores.base_chi2 / scores.base_dof)
    alpha_each = o["alpha"] / len(candidates)
    confirmations = _refit_significant(base, scores, o, alpha_each, log)
    first = conclude_first_step(base, scores, confirmations, o, alpha_each)
    excess = score_excess(scores)
    path: list[Step] = []
    best = first.best
    current, remaining, before = base, list(candidates), scores.base_chi2 / scores.base_dof
    dispersion = 1.0  # the first step is judged at the stated sigmas: the base's misfit is what is to be explained
    while best is not None:
        path.append(Step(best.candidate.name, before, best.chi2 / best.dof, best.delta_bic,
                         (scores.base_chi2 - best.chi2) / excess, best, dispersion))
        remaining = [c for c in remaining if c.name != best.candidate.name]
        if len(path) >= int(o["max_effects"]) or not remaining:
            break
        current = BaseFit(extend(current.variant, [best.candidate], best.ranges), best.fit.layout, best.fit.theta,
                          current.data, current.harmonics)
        # the next step is judged at the scale the data show, not at the stated sigmas (module docstring, "the
        # stop rule"): the remaining misfit divides each statistic, and a fit within the stated noise goes on to
        # the score tests too (the stated sigmas can be too large: what they hide is looked for)
        raw_scores = score_tests(current, remaining)
        dispersion = raw_scores.base_chi2 / raw_scores.base_dof
        step_scores = at_scale(raw_scores, dispersion)
        step_alpha = o["alpha"] / len(remaining)
        if log:
            top = sorted(step_scores.scores, key=lambda s: -s.statistic)[:4]
            log.info("step %d scores at chi^2 %.4g (dof %d), judged at the remaining misfit %.4g: %s", len(path) + 1,
                     step_scores.base_chi2, step_scores.base_dof, dispersion,
                     ", ".join(f"{s.candidate.name} {s.statistic:.4g} (p {s.p_value:.3g})" for s in top))
        chosen, quick = _quick_refits(current, step_scores, o, step_alpha)
        stop = _out_of_reach(step_scores, quick, o)
        if stop:  # no remaining candidate comes near fitting the noise: the path ends, "unexplained" is what is left
            first.summary["path_stopped"] = stop
            if log:
                log.info("forward selection stops before step %d: %s", len(path) + 1, stop)
            break
        refits = _refit_significant(current, step_scores, o, step_alpha, log, (chosen, quick))
        refits = {name: cf.at_scale(dispersion, raw_scores.base_dof) for name, cf in refits.items()}
        confirmed = [cf for cf in refits.values() if is_confirmed(cf, o, step_alpha)]
        before = best.chi2 / best.dof
        previous, best = best, min(confirmed, key=lambda cf: cf.delta_bic) if confirmed else None
        negligible = best and negligible_step(best, previous.chi2, excess)
        if negligible:  # a step too small to matter is not taken to absorb a misfit the candidates do not capture
            first.summary["negligible_step"] = plain(negligible, "summary.negligible_step")
            rows = first.table.index[first.table["effect"] == best.candidate.name]
            set_verdict(first.table, rows, CandidateVerdict.NEGLIGIBLE, step=len(path) + 1,
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
    path = backward_elimination(base, path, scores, o, result, log)
    path = sharing_check(base, path, scores, o, result, log)
    result.path = path
    conclude_path(result, base, scores, o)
    if path:  # how far the estimates' intervals can be trusted with the misfit the path leaves
        final = path[-1].confirmation
        result.summary["intervals"] = interval_note(final.chi2, final.dof, o["alpha"])
    try:
        result.intervals = final_intervals(base, scores, path)
    except RuntimeError as error:  # the solver failed next to the final fit: the diagnosis stands without them
        result.intervals = FormIntervals.empty()
        result.summary["intervals_over_candidates_failed"] = str(error)
        if log:
            log.warning("no intervals over the candidates: %s", error)
    result.summary["intervals_over_candidates"] = intervals_summary(result.intervals)
    result.fingerprint = residual_fingerprint(base, path[-1].confirmation.fit.fun if path else scores.residual)
    result.summary["fingerprint"] = result.fingerprint.summary()
    if result.status in (Status.UNEXPLAINED, Status.ADD_NEARLY):
        result.conclusion += f". What the residual looks like: {result.fingerprint.summary()}"
        result.summary["conclusion"] = result.conclusion
    return result


def final_intervals(base: BaseFit, scores: Scores, path: Sequence[Step]) -> FormIntervals:
    """The final model's shared parameters' intervals over the candidates not in it (``form_intervals``): the
    base's, from its score tests, when the path is empty; else the path's last fit, with every remaining candidate
    scored at it (one batched solve)."""
    if not path:
        return intervals_over_candidates(scores, base.intervals)
    final = path[-1].confirmation
    added = {step.confirmation.candidate.name for step in path}
    model = BaseFit(extend(base.variant, [step.confirmation.candidate for step in path], path_ranges(path)),
                    final.fit.layout, final.fit.theta, base.data, base.harmonics)
    remaining = [s.candidate for s in scores.scores if s.candidate.name not in added]
    return intervals_over_candidates(score_tests(model, remaining), own_intervals(final.fit.table()))


def intervals_summary(intervals: FormIntervals) -> list[dict]:
    """The union rows (``FormIntervals.union``) as plain types, for diagnosis.yaml."""
    return plain(intervals.union().to_dict("records"), "summary.intervals_over_candidates")


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


def refits_table(result: Diagnosis) -> pd.DataFrame:
    """Every refit's parameter table (``Identification.table``) with its ``effect``: full-solver joint fits of
    the variant with one effect added, which the identification of such a variant starts its polish from."""
    tables = [cf.fit.table().assign(effect=name) for name, cf in result.confirmations.items()]
    if not tables:
        return pd.DataFrame(columns=["effect", "parameter", "run", "value", "normalised"])
    table = pd.concat(tables, ignore_index=True)
    return table[["effect"] + [c for c in table if c != "effect"]]
