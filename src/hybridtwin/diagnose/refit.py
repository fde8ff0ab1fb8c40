"""Refits: a candidate effect added to the fitted model and fitted again with the full solver (diagnosis,
step 2).

From several starts (the base optimum, the score test's linear estimate, points across the candidate's range),
the range widened while the estimate sits at an edge (up to the effect's physical limits), and, when the refit
still misfits, a profile across the range widened both ways (the candidate held on a grid, the rest fitted at
each point): likelihood ratio LR = chi^2_base - chi^2_new ~ chi^2(k), Delta BIC = -LR + k ln n, and the new
parameters' 95 % intervals.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import stats

from ..identify import forward as fwd
from ..model.candidates import Candidate
from ..identify.arrow_problem import ArrowProblem, Layout
from ..identify.identification import Identification, conclude, units
from ..identify.lm import MAX_ITERATIONS, STALLED, LMOptions, LMResult, levenberg_marquardt
from ..identify.polish import check_fit_resolution
from ..identify.protocol import ProtocolResult
from .score_test import BaseFit, Score, Scores, extended_problem, scale_p_value

Array = np.ndarray

#: a refit stops when chi^2 fell by less than this over 3 iterations (well below the verdicts' thresholds)
STALL_CHI2 = 0.5
#: a thorough refit whose best start stopped (max_iterations, or the stall rule in a long valley) goes on from
#: there, with the damping reset, this many times more while it gains: a refit stopped early leaves chi^2 that
#: the next forward-selection step wrongly credits to any effect with extra freedom (measured: cross-coupled
#: stiffness alone stopped at chi^2 644, and any second effect then "explained" the rest down to 318)
CONTINUATIONS = 3
#: starts of the shared fit with the candidates' parameters across their ranges, and the times it may widen a
#: range whose estimate sits at an edge (``shared``)
SHARED_SPREAD, SHARED_WIDEN = 3, 4


@dataclass
class Confirmation:
    """A refit with one candidate added: chi^2, likelihood ratio, Delta BIC, the new parameters' intervals.

    ranges: the candidate's parameter ranges the refit ended with; widened: (parameter, old range, new range)
    of each widening (``refit``); start_chi2: the full solver's chi^2 at each start of the first refit.
    """

    candidate: Candidate
    fit: Identification
    chi2: float
    dof: int
    lr: float
    lr_p_value: float
    delta_bic: float
    estimates: pd.DataFrame  # the candidate's rows of the refit's table
    excludes_zero: bool
    seconds: float
    ranges: dict = field(default_factory=dict)
    widened: list = field(default_factory=list)
    start_chi2: list = field(default_factory=list)
    unstable_runs: list | None = None  # runs whose steady state at the optimum is unstable (None: not checked)

    @property
    def at_limit(self) -> list[str]:
        """Parameters whose estimate still sits at a range edge away from zero (the physical limit reached)."""
        edge = self.estimates["at_bound"].astype(bool) & (self.estimates["value"].abs() > 0)
        return self.estimates.loc[edge, "parameter"].tolist()

    def at_scale(self, dispersion: float, dof: int) -> "Confirmation":
        """The refit judged at the data's scale (a quasi-likelihood, ``score_test.scale_p_value``): the likelihood
        ratio divided by the dispersion phi of the fit it extends (its chi^2 / dof, ``dof`` degrees of freedom),
        its p-value from F(k, dof), Delta BIC = -LR / phi + k ln n. phi = 1: the refit as it is."""
        if dispersion == 1.0:
            return self
        k = len(self.candidate.parameters)
        penalty = self.delta_bic + self.lr  # k ln n
        p, _ = scale_p_value(self.lr, k, dispersion, dof)
        return replace(self, lr_p_value=p, delta_bic=float(-self.lr / dispersion + penalty))

    @property
    def widenable(self) -> bool:
        """Whether an estimate sits at a range edge away from zero that widening (``_widened``) would move: the
        truth may lie beyond the range (a quick refit, which does not widen, stops there)."""
        return bool(_widened(self.ranges, self.estimates, self.candidate))


def _refit_starts(theta0: Array, cols: list[int], step: Array, n_points: int, seed: int, quick: bool = False
                  ) -> Array:
    """Starts of a refit: beta = 0; the score's linear estimate, damped into the range, and a third of it (the
    linear estimate overshoots when the response bends, e.g. a cubic term); and ``n_points`` points across the
    candidate's range (a seeded Latin hypercube in [-0.7, 0.7], normalised): fits with several new parameters
    have local minima (one term at its edge compensating another), and where the base is far from the
    truth the linear estimate can point the wrong way. ``quick``: beta = 0 and the linear estimate only."""
    starts = [theta0]
    if step is not None and np.any(step):
        step = step * min(1.0, 1.0 / max(np.abs(step).max(), 1e-12))
        for scale in (1.0,) if quick else (1.0, 1.0 / 3.0):
            start = theta0.copy()
            start[cols] = np.clip(theta0[cols] + scale * step, -1.0, 1.0)
            starts.append(start)
    if n_points:
        rng = np.random.default_rng(seed)
        k = len(cols)
        grid = (np.argsort(rng.random((k, n_points)), axis=1).T + rng.random((n_points, k))) / n_points
        for point in 1.4 * grid - 0.7:
            start = theta0.copy()
            start[cols] = point
            starts.append(start)
    return np.array(starts)


def _widened(ranges: Mapping[str, tuple[float, float]], estimates: pd.DataFrame, candidate: Candidate,
             factor: float = 3.0) -> dict[str, tuple[float, float]]:
    """The ranges of the candidate's parameters whose estimate sits at a range edge away from zero, widened
    ``factor`` times towards that edge, up to the parameter's physical limits (``Parameter.limits``; without
    them 100 times the default range, never across zero for a range with 0 as an edge). Unchanged ranges
    (estimate inside, at zero, or at the limit already) are left out: an empty result means nothing to widen."""
    by_name = {p.name: p for p in candidate.parameters}
    out = {}
    for r in estimates.itertuples():
        if not (bool(r.at_bound) and abs(r.value) > 0):
            continue
        par = by_name[r.parameter]
        lo, hi = ranges[r.parameter]
        width = hi - lo
        d_lo, d_hi = par.bounds
        limit = par.limits or (d_lo - 100 * (d_hi - d_lo) if d_lo < 0 else d_lo,
                               d_hi + 100 * (d_hi - d_lo) if d_hi > 0 else d_hi)
        upper_edge = abs(r.value - hi) <= abs(r.value - lo)
        new = (lo, min(hi + (factor - 1) * width, limit[1])) if upper_edge else (max(lo - (factor - 1) * width,
                                                                                        limit[0]), hi)
        if new != (lo, hi):
            out[r.parameter] = new
    return out


#: chi^2 a refit across the far ranges (``_far_ranges``) must gain to replace the refit in the default range
FAR_GAIN = 10.0
#: chi^2/dof of a refit above which its far side is looked at even without a widening
FAR_MISFIT = 1.5


def _best(result: LMResult) -> int:
    """The trial with the lowest loss (a start with no solution has a NaN one)."""
    return int(np.nanargmin(np.where(np.isfinite(result.loss), result.loss, np.inf)))


def _concluded(problem: ArrowProblem, result: LMResult, best: int, base: BaseFit, confidence: float,
               ranges: Mapping[str, tuple[float, float]]) -> tuple[Identification, pd.DataFrame]:
    """A refit's result object at its best trial, and the estimates of the parameters in ``ranges``."""
    protocol = ProtocolResult.without_monte_carlo(result, best)
    fit = conclude(problem, protocol, base.data, base.X, confidence, units(problem.models[0].variant))
    table = fit.table()
    return fit, table[table["parameter"].isin(list(ranges)) & (table["run"] == "all")]


def _far_ranges(ranges: Mapping[str, tuple[float, float]], candidate: Candidate, factor: float = 3.0
                ) -> dict[str, tuple[float, float]]:
    """Each of the candidate's ranges widened ``factor`` times on both sides, within its physical limits
    (without limits: unchanged): where the base fit is far from the truth (a resonance moved), the estimate
    in the default range can sit at the edge opposite to the truth, and widening towards it never finds it."""
    out = dict(ranges)
    for par in candidate.parameters:
        if par.limits is None:
            continue
        lo, hi = ranges[par.name]
        width = hi - lo
        out[par.name] = (max(lo - (factor - 1) * width, par.limits[0]), min(hi + (factor - 1) * width, par.limits[1]))
    return out


def _theta_in(layout: Layout, fit: Identification, pool=np.mean) -> Array:
    """A fit's estimate (SI) as theta of another layout (other ranges; a parameter per run in the fit and shared
    in ``layout`` takes the ``pool`` of its per-run values; one shared in the fit and per run in ``layout``, the
    shared value at every run)."""
    values = dict(zip(fit.layout.entries(), fit.x))

    def value(name: str, run: str) -> float:
        if (name, run) in values:
            return values[(name, run)]
        if run == "all":
            return float(pool([values[(name, r)] for r in fit.layout.runs]))
        return values[(name, "all")]
    return np.array([layout.theta_of(e, value(*e)) for e in layout.entries()])


def _widened_starts(layout: Layout, fit: Identification, cols: list[int], names: Sequence[str],
                    wider: Mapping[str, tuple[float, float]], old: Mapping[str, tuple[float, float]]) -> Array:
    """The starts after a widening (``_widened``): the previous optimum ``fit`` in the new ``layout``, and the same
    with each widened parameter (``names`` at columns ``cols``) halfway from there to its new edge."""
    previous = _theta_in(layout, fit)
    further = previous.copy()
    for j, name in zip(cols, names):
        if name in wider:
            further[j] = 0.5 * (previous[j] + (1.0 if wider[name][1] > old[name][1] else -1.0))
    return np.vstack([previous, further])


def _continued(problem: ArrowProblem, result: LMResult, X: Array, options: LMOptions) -> LMResult:
    """The best trial continued (damping reset, at most CONTINUATIONS times) while it stopped descending at its
    iteration budget or on a stall; the continuations are appended as trials."""
    best = _best(result)
    for _ in range(CONTINUATIONS):
        if result.status[best] not in (MAX_ITERATIONS, STALLED):
            break
        before = result.loss[best]
        result = LMResult.concatenate([result, levenberg_marquardt(problem, result.x[[best]], X[:1], options)])
        best = _best(result)
        if (before - result.loss[best]) * problem.n_data < STALL_CHI2:
            break
    return result


#: points of a profile across the candidate's (far) ranges, and the profile fits' iteration budget
PROFILE_POINTS = 8
PROFILE_ITERATIONS = 20
#: profile points freed afterwards (the lowest chi^2 ones)
PROFILE_FREED = 2


def _profile(problem: ArrowProblem, theta0: Array, here: Array, cols: list[int],
             across: Mapping[str, tuple[float, float]], X0: Array, options: LMOptions, seed: int) -> LMResult:
    """A profile search: the candidate's parameters held at PROFILE_POINTS values across ``across`` (a grid
    for one parameter, a seeded Latin hypercube for more), the base's parameters, bows and phases fitted from the
    base optimum ``theta0`` at each (``levenberg_marquardt(..., fixed=)``); then the PROFILE_FREED best points
    and the refit's own optimum ``here`` fitted with everything free, and continued.

    Where a missing effect moves a resonance, the base fit compensates with its own parameters (a stiffness at a
    range edge); a refit from there, or from a start that moves the candidate alone, stays in that basin (the
    lower bearing 60 % softer: chi^2/dof 2e4 from every such start, 1 from the profile's best point)."""
    k, P = len(cols), PROFILE_POINTS
    if k == 1:
        points = np.linspace(-1.0, 1.0, P + 2)[1:-1, None]
    else:
        rng = np.random.default_rng(seed)
        points = 1.8 * (np.argsort(rng.random((k, P)), axis=1).T + rng.random((P, k))) / P - 0.9
    theta = np.repeat(theta0[None], P, axis=0)
    layout = problem.layout
    for j, (col, name) in enumerate(zip(cols, across)):  # the points in ``across``, normalised in the layout
        lo, hi = across[name]
        theta[:, col] = layout.normalise(layout.entries()[col][0], lo + 0.5 * (points[:, j] + 1.0) * (hi - lo))
    fixed = np.zeros(theta.shape, bool)
    fixed[:, cols] = True
    X = np.repeat(X0[None], P, axis=0)
    profile_options = replace(options, max_iterations=PROFILE_ITERATIONS)
    profile = levenberg_marquardt(problem, theta, X, profile_options, fixed=fixed)
    order = np.argsort(np.where(np.isfinite(profile.loss), profile.loss, np.inf))[:PROFILE_FREED]
    starts = np.vstack([here[None], profile.x[order]])
    X = np.repeat(X0[None], len(starts), axis=0)
    return _continued(problem, levenberg_marquardt(problem, starts, X, options), X, options)


def _fit_widening(base: BaseFit, kept: Sequence[Candidate], ranges: Mapping[str, tuple[float, float]],
                  per_run: Sequence[str] | None, first_starts, options: LMOptions, widen: int, confidence: float,
                  go_on: bool = True) -> tuple[Identification, pd.DataFrame, dict, list, list[float]]:
    """The base with the ``kept`` candidates fitted (full solver) in ``ranges`` (their parameters'), from
    ``first_starts(layout, theta0, cols)`` (cols: the candidates' parameters in the layout), the best start
    continued while it gains (``go_on``); then while an estimate sits at an edge away from zero its range is widened
    (``_widened``, at most ``widen`` times) and the fit goes on from its previous optimum (``_widened_starts``), so
    each widening can only lower chi^2. Returns the fit, its estimates of the candidates' parameters, the final
    ranges, the widenings (name, old range, new range) and the full solver's chi^2 at each first start."""
    ranges = dict(ranges)
    fit, start_chi2, widened, wider, old = None, [], [], {}, {}
    for attempt in range(widen + 1):
        problem, theta0 = extended_problem(base, kept, ranges, per_run)
        layout = problem.layout
        cols = [layout.entries().index((p.name, "all")) for c in kept for p in c.parameters]
        theta = first_starts(layout, theta0, cols) if fit is None else \
            _widened_starts(layout, fit, cols, list(ranges), wider, old)
        X = np.repeat(base.X[None], len(theta), axis=0)
        result = levenberg_marquardt(problem, theta, X, options)
        if fit is None:  # the objective at each start (LM's first evaluation): chi^2 plus any phase prior
            start_chi2 = (result.history[:, 0] * problem.n_data).tolist()
        if go_on:  # the best start stopped while descending: let it go on
            result = _continued(problem, result, X, options)
        fit, estimates = _concluded(problem, result, _best(result), base, confidence, ranges)
        wider = {}
        for c in kept:
            wider |= _widened(ranges, estimates[estimates["parameter"].isin([p.name for p in c.parameters])], c)
        if not wider or attempt == widen:
            break
        widened += [(name, ranges[name], new) for name, new in wider.items()]
        old = dict(ranges)
        ranges |= wider
    return fit, estimates, ranges, widened, start_chi2


def confirm(base: BaseFit, score: Score, scores: Scores, max_iterations: int = 40,
            confidence: float = 0.95, starts: int = 4, widen: int = 4, quick: bool = False, far: bool = True,
            far_misfit: bool = True) -> Confirmation:
    """Refit with ``score.candidate`` added (full solver), from several starts (``_refit_starts``), its range
    widened while its estimate sits at an edge (``_widened``, at most ``widen`` times); then, with ``far`` and
    when the refit needed a wider range or (with ``far_misfit``) still misfits (chi^2/dof > FAR_MISFIT), a profile
    across the default ranges widened both ways (``_profile``), kept when it gains more than FAR_GAIN.

    The result is the best start's (lowest chi^2); the full solver's chi^2 at every start is kept
    (``start_chi2``). After a widening the refit starts again from the previous optimum, so each widening can
    only lower chi^2."""
    start_time = time.perf_counter()
    c = score.candidate
    options = _options(max_iterations)

    def first_starts(layout: Layout, theta0: Array, cols: list[int]) -> Array:
        return _refit_starts(theta0, cols, score.step, starts, zlib.crc32(c.name.encode()), quick)

    fit, estimates, ranges, widened, start_chi2 = _fit_widening(
        base, [c], {p.name: tuple(p.bounds) for p in c.parameters}, None, first_starts, options, widen, confidence,
        go_on=not quick)  # a quick refit does not continue its best start
    # the far side: a truth beyond the range on the side the base fit did not lean to, or a base fit whose own
    # parameters sit in another basin; looked for when the refit needed a wider range or does not fit to the noise
    # (a refit that explains everything needs no other basin)
    if far and not quick and widen > 0 and (widened or (far_misfit and fit.chi2_dof > FAR_MISFIT)):
        # profiled across the default ranges widened both ways (within the limits): the refit's own widenings
        # follow where it leaned, which can be the wrong side; the bounds cover both
        around = _far_ranges({p.name: tuple(p.bounds) for p in c.parameters}, c)
        far = {name: (min(lo, ranges[name][0]), max(hi, ranges[name][1])) for name, (lo, hi) in around.items()}
        problem_f, theta0_f = extended_problem(base, [c], far)
        cols = [problem_f.layout.entries().index((p.name, "all")) for p in c.parameters]
        result = _profile(problem_f, theta0_f, _theta_in(problem_f.layout, fit), cols, around, base.X, options,
                          zlib.crc32(c.name.encode()) + 1)
        best = _best(result)
        if (fit.uncertainty.chi2 - result.loss[best] * problem_f.n_data) > FAR_GAIN:
            widened += [(name, ranges[name], far[name]) for name in far if far[name] != ranges[name]]
            ranges = far
            fit, estimates = _concluded(problem_f, result, best, base, confidence, ranges)
    # the records are steady states the machine stayed in: an optimum whose state is unstable at some run (a
    # Floquet multiplier outside the unit circle) cannot be the machine, whatever its chi^2 (forward.check_stability)
    check = None if quick else fwd.check_stability(fit)
    if not quick:  # a non-smooth candidate's optimum (a rub): its balance resolved, or the fit's notes say not
        check_fit_resolution(fit)
    return _confirmation(c, fit, estimates, ranges, scores.base_chi2, scores.n_data, start_time, widened,
                         start_chi2, check)


def _confirmation(candidate: Candidate, fit: Identification, estimates: pd.DataFrame,
                  ranges: Mapping[str, tuple[float, float]], before_chi2: float, n_data: int, start_time: float,
                  widened: list, start_chi2: Sequence[float], check) -> Confirmation:
    """A refit's Confirmation: likelihood ratio against ``before_chi2`` (the fit without the candidate) on the
    candidate's k = len(ranges) parameters, Delta BIC = -LR + k ln n, and whether zero is excluded."""
    chi2 = float(fit.uncertainty.chi2)
    k = len(ranges)
    lr = before_chi2 - chi2
    # zero is excluded by the interval, or by an estimate pinned at the range edge away from zero (the data want
    # more of the effect than the physical limit allows: its interval is not valid there, the likelihood ratio is)
    far_edge = estimates["at_bound"].astype(bool) & (estimates["value"].abs() > 0)
    excludes = bool(((estimates["ci_low"] > 0) | (estimates["ci_high"] < 0) | far_edge).any())
    return Confirmation(candidate, fit, chi2, int(fit.uncertainty.dof), float(lr),
                        float(stats.chi2.sf(max(lr, 0.0), k)), float(-lr + k * np.log(n_data)), estimates, excludes,
                        time.perf_counter() - start_time, {k_: tuple(map(float, v)) for k_, v in ranges.items()},
                        widened, [float(v) for v in start_chi2], None if check is None else check.unstable_runs)


def _options(max_iterations: int) -> LMOptions:
    """A refit's LM options: the verdicts compare chi^2 drops against thresholds of 6-10, so chi^2 to within ~0.5
    is all they need, and stopping there saves the long crawl along flat valleys."""
    return LMOptions(max_iterations=max_iterations, ftol=1e-6, xtol=1e-6, gtol=1e-8, stall_chi2=STALL_CHI2,
                     geodesic=True)


def _from_fit(base: BaseFit, kept: Sequence[Candidate], ranges: Mapping[str, tuple[float, float]],
              start: Identification, before_chi2: float, n_data: int, max_iterations: int, confidence: float,
              per_run: Sequence[str] | None = None, pools=(np.mean,), spread: int = 0, widen: int = 0
              ) -> Confirmation:
    """The base with the ``kept`` candidates (and ``per_run`` parameters, default the base's) fitted from a fuller
    fit's optimum ``start`` (a per-run value shared here: each of ``pools`` of the per-run values, one start
    each), continued while it gains; with ``spread``, as many more starts from the first pooled one with the
    kept candidates' parameters across their ranges (``_refit_starts``' Latin hypercube): the fuller fit's values
    of them can be far off where its per-run parameters traded off against them; with ``widen``, a kept
    candidate's range is widened (``_widened``, at most ``widen`` times) while its estimate sits at an edge, the
    fit going on from its previous optimum (and halfway to the new edge), as in ``confirm``. The Confirmation of
    the last kept candidate, its likelihood ratio against ``before_chi2``, the optimum's stability checked as in
    ``confirm``."""
    start_time = time.perf_counter()

    def first_starts(layout: Layout, theta0: Array, cols: list[int]) -> Array:
        theta = np.stack([_theta_in(layout, start, pool) for pool in pools])
        if spread:
            across = _refit_starts(theta[0], cols, None, spread, zlib.crc32("+".join(c.name for c in kept).encode()))
            theta = np.vstack([theta, across[1:]])
        return theta

    fit, estimates, kept_ranges, widened, start_chi2 = _fit_widening(
        base, kept, {p.name: tuple(ranges[p.name]) for c in kept for p in c.parameters}, per_run, first_starts,
        _options(max_iterations), widen, confidence)
    last = kept[-1]
    own = {p.name: kept_ranges[p.name] for p in last.parameters}
    estimates = estimates[estimates["parameter"].isin(list(own))]
    return _confirmation(last, fit, estimates, own, before_chi2, n_data, start_time,
                         [w for w in widened if w[0] in own], start_chi2, fwd.check_stability(fit))


def without(base: BaseFit, kept: Sequence[Candidate], ranges: Mapping[str, tuple[float, float]],
            start: Identification, before_chi2: float, n_data: int, max_iterations: int = 40,
            confidence: float = 0.95) -> Confirmation:
    """The base with only the ``kept`` candidates (a forward-selection path with one effect dropped: the
    diagnosis's backward elimination), fitted from a fuller fit's optimum ``start`` (its values of the kept
    entries; the dropped effect's parameters simply absent, i.e. zero), continued while it gains.

    Returned as the Confirmation of the last kept candidate, its likelihood ratio against ``before_chi2`` (the
    fit without it); the stability of the optimum is checked as in ``confirm``."""
    return _from_fit(base, kept, ranges, start, before_chi2, n_data, max_iterations, confidence)


def shared(base: BaseFit, kept: Sequence[Candidate], ranges: Mapping[str, tuple[float, float]],
           start: Identification, before_chi2: float, n_data: int, max_iterations: int = 40,
           confidence: float = 0.95) -> Confirmation:
    """The base with the ``kept`` candidates and no parameter per run: each of the base's per-run parameters
    (``base.layout.local``, e.g. the bow q_x, q_y) one value shared by all runs, fitted from a fuller fit's
    optimum ``start`` with its per-run values pooled (two starts: their mean and their median) and from SHARED_SPREAD
    more with the candidates' parameters across their ranges, continued while it gains, the candidates' ranges
    widened while an estimate sits at an edge: the per-run fit's values of them can be far off (with speed
    damping zeta_v = 0.2 hidden: 0.13 [-0.33, 0.60] in a range widened to [0, 0.15], where the shared fit
    stopped at chi^2 1845 against 341 per run). The diagnosis's sharing check (``elimination.sharing_check``)
    compares its chi^2 with ``start``'s. Returned as ``without``'s."""
    return _from_fit(base, kept, ranges, start, before_chi2, n_data, max_iterations, confidence, per_run=(),
                     pools=(np.mean, np.median), spread=SHARED_SPREAD, widen=SHARED_WIDEN)

