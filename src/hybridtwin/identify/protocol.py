"""The paper's protocol (sec. 2.3, 4.1): tau random trials, n_MC Monte Carlo repeats, one batched LM.

tau = 50 random starts of Levenberg-Marquardt on the measured data, the lowest-loss trial kept (the
estimate); n_MC = 1000 repeats on data re-sampled with the measured sigmas (X + sigma (N(0,1) + i N(0,1)))
give the paper's average and a distribution that checks the linearised uncertainty. Every LM problem of a
protocol advances in one batched LM (``hybridtwin.identify.lm``).

Where the repeats start (``ProtocolOptions.monte_carlo_starts``):

- 0, the paper's literal protocol: each repeat from tau fresh random starts (tau (1 + n_MC) LM problems,
  each from a random point of the box: 50 050 problems of ~20 iterations for a per-run fit);
- k > 0: each repeat from the k best distinct end points of the trials on the measured data
  (``distinct_optima``). A repeat's data differ from the measured data by the noise only, so its minimum
  lies next to one of the minima the tau trials found; started there, LM needs a few iterations instead of
  a descent from anywhere in the box, and each repeat keeps the lowest of k local minima, never a worse
  basin that none of its random starts left. The estimate itself (the trials on the measured data) is the
  same computation in both modes.

The problem is duck-typed (``hybridtwin.identify.arrow_problem.ArrowProblem``: ``layout`` with ``n``, ``is_phase``,
``bounds()``, ``phase_sigma``; ``initial_phases``; what ``levenberg_marquardt`` needs).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .lm import LMOptions, LMResult, batch_slices, levenberg_marquardt
from .uncertainty import nuisance

Array = np.ndarray

#: two end points are the same optimum when no physical entry differs by more than this (normalised units,
#: the range is 2 wide: 0.5 % of it) and no phase by more than this [rad]
SAME_OPTIMUM = 1e-2


@dataclass(frozen=True)
class ProtocolOptions:
    """The paper's protocol (sec. 2.3, 4.1): tau trials, n_MC repeats, lambda; LM stopping rules.
    monte_carlo_starts: where each repeat starts (module docstring): 0 tau fresh random starts, k > 0 the
    k best distinct optima of the trials on the measured data."""

    trials: int = 50  # tau
    monte_carlo: int = 1000  # n_MC
    sparsity: float = 0.0  # lambda (eq. 11): 0 Geometric, 0.1 Expansion
    l1_epsilon: float = 1e-3
    seed: int = 0
    confidence: float = 0.95
    lm: LMOptions = LMOptions()
    monte_carlo_starts: int = 0


@dataclass
class ProtocolResult:
    """Trials on the measured data (repeat 0) and the best trial of every Monte Carlo repeat.

    trials: LMResult of repeat 0's trials (with loss histories); best: index of the
    lowest-loss one; monte_carlo: (n_MC, n) best theta of each repeat;
    monte_carlo_loss: (n_MC,); seconds: wall time of the whole protocol.
    """

    trials: LMResult
    best: int
    monte_carlo: Array
    monte_carlo_loss: Array
    seconds: float
    n_lm: int  # LM problems solved in all

    @property
    def theta(self) -> Array:
        return self.trials.x[self.best]

    @classmethod
    def without_monte_carlo(cls, trials: LMResult, best: int, n_lm: int | None = None) -> "ProtocolResult":
        """LM runs from given starts and no Monte Carlo repeat (a full-solver polish, a diagnosis refit): the
        uncertainty then comes from the Jacobian at the best trial alone."""
        n = trials.x.shape[1]
        return cls(trials, int(best), np.zeros((0, n)), np.zeros(0), float(trials.seconds),
                   len(trials.x) if n_lm is None else int(n_lm))


def random_starts(layout, n: int, rng: np.random.Generator) -> Array:
    """n uniform random starts in [-1, 1] for the physical entries (phases set later, runout offsets 0),
    (n, layout.n)."""
    theta = rng.uniform(-1.0, 1.0, (n, layout.n))
    theta[:, nuisance(layout)] = 0.0
    return theta


def run_protocol(problem, X: Array, sigma_noise: Array, options: ProtocolOptions = ProtocolOptions(),
                 extra_starts: Array | None = None) -> ProtocolResult:
    """tau random trials (+ ``extra_starts``) on the data and on n_MC re-sampled copies, batched LM.

    X, sigma_noise: (R, H, C) measured harmonics (C channels) and the measured sigmas used for
    re-sampling (X + sigma (N(0,1) + i N(0,1)), independently per repeat; with runout offsets in the layout,
    ``resample``: their share s of sigma drawn once per record, common to its bands). The random numbers are
    drawn in the same order in both modes (the noise of every repeat, the offsets' if any, then the trials'
    starts): the trials on the measured data, hence the estimate, do not depend on ``monte_carlo_starts``.
    """
    start = time.perf_counter()
    rng = np.random.default_rng(options.seed)
    layout = problem.layout
    extra = np.zeros((0, layout.n)) if extra_starts is None else np.atleast_2d(extra_starts)
    per_repeat = options.trials + extra.shape[0]
    if per_repeat < 1:
        raise ValueError("the protocol needs at least one trial")
    noise = rng.standard_normal((options.monte_carlo, *X.shape)) + 1j * rng.standard_normal(
        (options.monte_carlo, *X.shape))
    data = np.concatenate([X[None], X[None] + resample(layout, sigma_noise, noise, rng)])  # (repeats, R, H, C)
    if options.monte_carlo_starts <= 0 or options.monte_carlo == 0:
        repeats = 1 + options.monte_carlo
        theta0 = np.concatenate([np.concatenate([random_starts(layout, options.trials, rng), extra])
                                 for _ in range(repeats)])
        data_t = np.repeat(data, per_repeat, axis=0)
        theta0 = _initial_phases(problem, theta0, data_t, extra.shape[0], per_repeat)
        result = levenberg_marquardt(problem, theta0, data_t, options.lm)
        loss = result.loss.reshape(repeats, per_repeat)
        best = loss.argmin(1)
        best_theta = result.x.reshape(repeats, per_repeat, -1)[np.arange(repeats), best]
        return ProtocolResult(result.take(np.arange(per_repeat)), int(best[0]), best_theta[1:],
                              loss[np.arange(repeats), best][1:], time.perf_counter() - start, theta0.shape[0])
    theta0 = np.concatenate([random_starts(layout, options.trials, rng), extra])
    data_t = np.repeat(data[:1], per_repeat, axis=0)
    trials = levenberg_marquardt(problem, _initial_phases(problem, theta0, data_t, extra.shape[0], per_repeat),
                                 data_t, options.lm)
    best = int(np.argmin(np.where(np.isfinite(trials.loss), trials.loss, np.inf)))
    starts = distinct_optima(trials, layout.is_phase, options.monte_carlo_starts)
    k = starts.shape[0]
    repeats = levenberg_marquardt(problem, np.tile(starts, (options.monte_carlo, 1)),
                                  np.repeat(data[1:], k, axis=0), options.lm)
    loss = repeats.loss.reshape(options.monte_carlo, k)
    loss = np.where(np.isfinite(loss), loss, np.inf)
    chosen = loss.argmin(1)
    rows = np.arange(options.monte_carlo)
    return ProtocolResult(trials, best, repeats.x.reshape(options.monte_carlo, k, -1)[rows, chosen],
                          loss[rows, chosen], time.perf_counter() - start, per_repeat + k * options.monte_carlo)


def resample(layout, sigma: Array, noise: Array, rng: np.random.Generator) -> Array:
    """The repeats' noise (n_MC, R, H, C): sigma times ``noise``; where the layout has runout offsets
    (``arrow_problem``'s "Runout offsets"), the offset's s of a band's sigma is drawn once per repeat and record,
    common to the record's bands (its own part sqrt(sigma^2 - s^2) per band), as the data hold it."""
    if not getattr(layout, "n_offsets", 0) or not len(noise):
        return sigma[None] * noise
    common = rng.standard_normal((len(noise), layout.n_offsets))
    out = np.zeros(noise.shape, complex)
    first = len(layout.shared)
    for k in range(layout.n_runs):
        for i, h, c, s in layout.run_offsets(k):
            if h <= sigma.shape[1]:
                out[:, k, h - 1, c] = s * (common[:, i - first] + 1j * common[:, i - first + 1])
    return out + layout.own_sigma(sigma)[None] * noise


def distinct_optima(trials: LMResult, is_phase: Array, most: int, tolerance: float = SAME_OPTIMUM) -> Array:
    """The end points of ``trials`` in order of loss, one per optimum (an end point within ``tolerance`` of a
    better one, ``SAME_OPTIMUM``, is that optimum), at most ``most``: (k, n), k >= 1 (the best trial alone when
    no trial has a finite loss)."""
    order = np.argsort(np.where(np.isfinite(trials.loss), trials.loss, np.inf), kind="stable")
    finite = [t for t in order if np.isfinite(trials.loss[t])] or [int(order[0])]
    kept: list[int] = []
    for t in finite:
        if len(kept) == most:
            break
        difference = trials.x[kept] - trials.x[t]
        difference[:, is_phase] = np.pi - np.mod(np.pi - difference[:, is_phase], 2.0 * np.pi)  # wrapped
        if not kept or (np.abs(difference).max(axis=1) > tolerance).all():
            kept.append(int(t))
    return trials.x[kept]


def _initial_phases(problem, theta0: Array, data: Array, n_extra: int, per_repeat: int) -> Array:
    """Random starts get 1X-aligned phases; extra starts keep theirs unless they are zero."""
    out = theta0.copy()
    aligned = np.concatenate([problem.initial_phases(theta0[s], data[s]) for s in batch_slices(len(theta0), 20000)])
    is_extra = (np.arange(len(theta0)) % per_repeat) >= per_repeat - n_extra
    phase = problem.layout.is_phase
    keep = is_extra[:, None] & phase[None, :] & (theta0 != 0)
    out[:, phase] = np.where(keep[:, phase], theta0[:, phase], aligned[:, phase])
    return out
