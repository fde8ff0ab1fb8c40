"""The full-solver polish: a library optimum refined with the harmonic-balance solver itself.

The sPGD library has an error of its own (``library_validation.tsv``); the
polish re-runs Levenberg-Marquardt on the same data with the full solver as
the forward model (``forward.SolverModel``: warm-started steady states and
analytic sensitivities), weighted by the measured sigmas only, and recomputes
the uncertainty from the solver's Jacobian.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.stats import qmc

from .arrow_problem import ArrowProblem
from ..solvers.resolution import RESOLUTION_TOLERANCE, Resolution, check_resolution
from .forward import HarmonicModel, SolverModel, check_stability
from .identification import Identification, conclude
from .lm import LMOptions, LMResult, levenberg_marquardt
from .protocol import ProtocolResult

Array = np.ndarray


#: a polished chi^2/dof above this (and above the library's own) calls for random starts across the box
MISFIT = 4.0
#: random starts added then (a seeded Latin hypercube of the shared parameters)
RANDOM_STARTS = 6


def polish(fit: Identification, solver_models: Sequence[HarmonicModel], max_iterations: int = 60,
           starts: Array | None = None, labels: Sequence[str] | None = None, random_starts: int = RANDOM_STARTS,
           misfit: float = MISFIT, seed: int = 0) -> Identification:
    """Refine a library optimum with the full solver (no surrogate error), the result and its uncertainty.

    LM from fit.theta and every extra start (``starts``, named by ``labels``), all advanced in the same
    batched solves, on the same data weighted by the measured sigmas only (the solver has no library
    error to allow for). Every start is scored with the solver (its chi^2 before and after, in
    ``result.starts``). When the best chi^2/dof still exceeds ``misfit`` (and the library's own), the
    library optimum may sit in a basin of the surrogate that the solver does not share: ``random_starts``
    more, a seeded Latin hypercube across the box for the shared parameters (the per-run ones and the
    phases from the best so far), are polished too. The result is the best end point of all: never worse
    than the best start, since each LM run only accepts steps that lower its chi^2. The uncertainty is
    recomputed from the solver's exact Jacobian, and the stability of every run's steady state at the result
    is checked (``forward.check_stability``: an unstable one is named in the message and notes).
    """
    sigma = np.stack([d.sigma[: fit.X.shape[1]] for d in fit.data])
    exact = ArrowProblem(solver_models, fit.layout, sigma, fit.problem.sparsity, fit.problem.l1_epsilon)
    theta0 = fit.theta[None] if starts is None else np.vstack([fit.theta[None], starts])
    names = ["library optimum"] + [f"start {i + 2}" for i in range(len(theta0) - 1)]
    if labels is not None:
        names = list(labels)[: len(theta0)] + names[len(labels):]
    options = LMOptions(max_iterations=max_iterations, ftol=1e-8, xtol=1e-8, gtol=1e-10, stall_chi2=1e-3,
                        geodesic=True)  # one extra solve per iteration, 2-3x fewer iterations in the valleys
    result = _run(exact, theta0, fit.X, options)
    dof = max(exact.n_data - fit.layout.n, 1)
    best_chi2 = np.nanmin(np.where(np.isfinite(result.loss), result.loss, np.nan)) * exact.n_data \
        if np.isfinite(result.loss).any() else np.inf
    if random_starts > 0 and best_chi2 / dof > max(misfit, fit.chi2_dof):
        best = result.x[int(np.nanargmin(np.where(np.isfinite(result.loss), result.loss, np.inf)))] \
            if np.isfinite(result.loss).any() else fit.theta
        extra = hypercube_starts(fit.layout, best, random_starts, seed)
        result = LMResult.concatenate([result, _run(exact, extra, fit.X, options)])
        names += [f"random start {i + 1}" for i in range(random_starts)]
    best = int(np.argmin(np.where(np.isfinite(result.loss), result.loss, np.inf)))  # a start may not solve
    protocol = ProtocolResult.without_monte_carlo(result, best, len(names))
    polished = conclude(exact, protocol, fit.data, fit.X, fit.confidence, fit.units)
    # every start's chi^2/dof on the result's dof (its data and phase priors less its free entries): the
    # selected start's is then the fit's chi2_dof (the ledger's), not another count of the same chi^2
    dof = max(polished.uncertainty.dof, 1)
    polished.starts = pd.DataFrame({
        "start": names, "chi2_start": result.history[:, 0] * exact.n_data, "chi2": result.loss * exact.n_data,
        "chi2_dof": result.loss * exact.n_data / dof, "iterations": result.nit, "status": result.status,
        "selected": np.arange(len(names)) == best})
    # the LM iterations solve without the stability check (30-40 % cheaper); the optimum reported is checked: an
    # unstable steady state at some run says so in the fit's message and notes, and warns (forward.check_stability)
    check_stability(polished)
    check_fit_resolution(polished)  # a variant with a non-smooth effect (a rub): its balance resolved, or said not
    return polished


def _run(problem: ArrowProblem, theta0: Array, X: Array, options: LMOptions) -> LMResult:
    return levenberg_marquardt(problem, theta0, np.repeat(X[None], len(theta0), axis=0), options)


def hypercube_starts(layout, centre: Array, n: int, seed: int) -> Array:
    """n starts: the shared physical entries on a seeded Latin hypercube of [-0.9, 0.9], the others
    (per-run parameters, phases) as in ``centre``."""
    out = np.repeat(centre[None], n, axis=0)
    shared = np.flatnonzero([run == "all" and p != "phase" for p, run in layout.entries()])
    if shared.size:
        out[:, shared] = 0.9 * (2.0 * qmc.LatinHypercube(d=shared.size, seed=seed).random(n) - 1.0)
    return out


def next_best_trials(fit: Identification, n: int = 4, distinct: float = 1e-3) -> Array:
    """Extra polish starts: the protocol's next-best trials on the measured data (distinct from the best by
    more than ``distinct`` in normalised units), so that the polish survives a best trial where the full
    solver has no solution."""
    trials = fit.protocol.trials
    order = np.argsort(np.where(np.isfinite(trials.loss), trials.loss, np.inf))
    chosen: list[Array] = []
    for i in order[1:]:
        if not np.isfinite(trials.loss[i]) or len(chosen) == n:
            break
        if all(np.abs(trials.x[i] - c).max() > distinct for c in chosen + [fit.theta]):
            chosen.append(trials.x[i])
    return np.array(chosen).reshape(-1, fit.layout.n)


def compare_polish(library_fit: Identification, polished: Identification) -> pd.DataFrame:
    """Library optimum vs full-solver optimum per entry: difference in SI, relative, and in standard errors."""
    a, b = library_fit.table(), polished.table()
    out = a[["parameter", "run", "unit"]].copy()
    out["library_value"], out["solver_value"] = a["value"], b["value"]
    out["difference"] = b["value"] - a["value"]
    out["difference_rel"] = out["difference"] / b["value"].abs().where(b["value"] != 0)
    out["difference_in_stderr"] = out["difference"] / b["stderr"]
    out["stderr"] = b["stderr"]
    return out


class ResolutionWarning(UserWarning):
    """A fit's optimum whose harmonic balance is not resolved at some run (``check_fit_resolution``)."""


def check_fit_resolution(fit, tolerance: float = RESOLUTION_TOLERANCE) -> Resolution | None:
    """Whether the steady states a full-solver fit reports are resolved (``resolution.check_resolution``: solved
    again with twice the harmonics and four times the time samples), for a variant with a non-smooth effect (one
    that declares ``needs_harmonics``, a rub); None otherwise (a smooth model's balance at the data's harmonics is
    exact to round-off), or for a fit without ``SolverModel``s. A run not resolved is never left silent: the
    sentence joins the fit's notes, and a ``ResolutionWarning`` is issued and logged."""
    models = [] if fit.problem is None else fit.problem.models
    if not models or not all(isinstance(m, SolverModel) for m in models) or not any(
            getattr(e, "needs_harmonics", None) for e in models[0].variant.model.effects):
        return None
    theta = np.asarray(fit.theta, float)[None]
    xs = [fit.layout.run_parameters(theta, k)[0] for k in range(fit.layout.n_runs)]
    batch = SolverModel.steady_states(models, xs)
    if batch is None:
        return None
    ok = np.flatnonzero(batch.result.success)
    result = check_resolution(batch.build({k: v[ok] for k, v in batch.values.items()}, batch.rpm[ok]),
                              batch.result.take(ok), tolerance)
    runs = [fit.layout.runs[i] for i in ok]  # one row per run (a fit's point is one set)
    bad = [f"{runs[i]}: {result.message[i]}" for i in np.flatnonzero(~np.asarray(result.resolved, bool))]
    if bad:
        note = "harmonic balance not resolved at the fitted parameters: " + "; ".join(bad)
        if note not in fit.uncertainty.notes:
            fit.uncertainty.notes.append(note)
        logging.getLogger(__name__).warning("%s", note)
        warnings.warn(note, ResolutionWarning, stacklevel=2)
    return result
