"""The full-solver polish: a library optimum refined with the harmonic-balance solver itself.

The sPGD library has an error of its own (``library_validation.tsv``); the
polish re-runs Levenberg-Marquardt on the same data with the full solver as
the forward model (``forward.SolverModel``: warm-started steady states and
analytic sensitivities), weighted by the measured sigmas only, and recomputes
the uncertainty from the solver's Jacobian.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from .forward import HarmonicModel
from .identification import ArrowProblem, Identification, ProtocolResult, conclude
from .lm import LMOptions, levenberg_marquardt

Array = np.ndarray


def polish(fit: Identification, solver_models: Sequence[HarmonicModel], max_iterations: int = 60,
           starts: Array | None = None) -> Identification:
    """Refine a library optimum with the full solver (no surrogate error), the result and its uncertainty.

    LM from fit.theta (and any extra ``starts``, all advanced in the same batched
    solves), on the same data weighted by the measured sigmas only (the solver
    has no library error to allow for). The uncertainty is recomputed from the
    solver's Jacobian (forward differences).
    """
    sigma = np.stack([d.sigma[: fit.X.shape[1]] for d in fit.data])
    exact = ArrowProblem(solver_models, fit.layout, sigma, fit.problem.sparsity, fit.problem.l1_epsilon)
    theta0 = fit.theta[None] if starts is None else np.vstack([fit.theta[None], starts])
    options = LMOptions(max_iterations=max_iterations, ftol=1e-8, xtol=1e-8, gtol=1e-10, stall_chi2=1e-3,
                        geodesic=True)  # one extra solve per iteration, 2-3x fewer iterations in the valleys
    result = levenberg_marquardt(exact, theta0, np.repeat(fit.X[None], len(theta0), axis=0), options)
    best = int(np.argmin(np.where(np.isfinite(result.loss), result.loss, np.inf)))  # a start may not solve
    protocol = ProtocolResult(result, best, np.zeros((0, fit.layout.n)), np.zeros(0), result.seconds, len(theta0))
    return conclude(exact, protocol, fit.data, fit.X, fit.confidence, fit.units)


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
