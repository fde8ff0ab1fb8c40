"""After the forward selection (``hybridtwin.diagnose.diagnosis``): what its path no longer needs is eliminated.

Backward elimination (``backward_elimination``): an effect the path added early that a later one made redundant is
dropped.
The sharing check (``sharing_check``): the base's per-run parameters are shared by all runs when the path's effects no
longer need them per run. Each is a refit from the path's final optimum (``refit.without``, ``refit.shared``), kept
or dropped by the same likelihood ratio and Delta BIC as any effect.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy import stats

from .conclusion import Diagnosis, Step, score_excess, fits_the_noise, path_ranges, set_verdict
from .diagnosis_status import CandidateVerdict, plain
from .refit import shared, without
from .score_test import BaseFit, Scores


def backward_elimination(base: BaseFit, path: list[Step], scores: Scores, o: Mapping, result: Diagnosis, log=None
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
        ranges = path_ranges(path)
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
        set_verdict(result.table, rows, CandidateVerdict.DROPPED, others=", ".join(others),
                     verb="is" if len(others) == 1 else "are", lr=lr, bic=-lr + k * np.log(n))
        path = [step for j, step in enumerate(path) if j != i]
        before = path[-2].confirmation.chi2 if len(path) > 1 else scores.base_chi2
        dof = path[-2].confirmation.dof if len(path) > 1 else scores.base_dof
        k_last = len(cf.candidate.parameters)
        path[-1] = Step(path[-1].effect, before / dof, cf.chi2 / cf.dof, -(before - cf.chi2) + k_last * np.log(n),
                        (scores.base_chi2 - cf.chi2) / score_excess(scores), cf)
    return path


def sharing_check(base: BaseFit, path: list[Step], scores: Scores, o: Mapping, result: Diagnosis, log=None
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
    if not path or not local or len(base.layout.runs) < 2 or not fits_the_noise(path[-1].confirmation, o):
        return path  # (one run: per run and shared are the same fit)
    final, n = path[-1].confirmation, scores.n_data
    ranges = path_ranges(path)
    before = path[-2].confirmation.chi2 if len(path) > 1 else scores.base_chi2
    cf = shared(base, [step.confirmation.candidate for step in path], ranges, final.fit, before, n,
                int(o["max_iterations"]))
    k = len(local) * (len(base.layout.runs) - 1)  # the per-run values' extra parameters
    lr = cf.chi2 - final.chi2
    p_value, delta_bic = float(stats.chi2.sf(max(lr, 0.0), k)), float(-lr + k * np.log(n))
    keep = (p_value < o["alpha"] and delta_bic < o["bic_threshold"]) or bool(cf.unstable_runs) or \
        not fits_the_noise(cf, o)
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
    # the step keeps its share of the base's excess (the effect's, measured as the base was fitted: per run); the
    # shared fit's chi^2 has more dof, and against the per-run base's excess it read as a negative share ("it
    # explains the discrepancy (-64 % of the excess chi^2)" on the bundled expansion variant)
    return path[:-1] + [Step(last.effect, last.chi2_dof_before, cf.chi2 / cf.dof, last.delta_bic, last.share, cf,
                             last.dispersion)]
