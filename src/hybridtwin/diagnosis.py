"""Diagnosis: which physical effect is the model missing? (issue 6)

Input: a variant fitted jointly to the fit runs (the identification stage's
``results/{variant}/parameters.tsv``: shared parameters, per-run ones, phases)
and candidate effects (``hybridtwin.candidates``), each switched on by
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

import time
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import optimize, stats

from .candidates import Candidate
from .fingerprint import Fingerprint, fingerprint
from .forward import SolverModel
from .identification import (ArrowProblem, Identification, Layout, RunData, conclude, theta_from_table,
                             units)
from .lm import MAX_ITERATIONS, STALLED, LMOptions, LMResult, levenberg_marquardt
from .model import Model
from .polish import hypercube_starts
from .protocol import ProtocolResult
from .uncertainty import BOUND_TOLERANCE
from .variants import Variant

Array = np.ndarray

#: the ``diagnosis:`` section's defaults (config/config.yaml; schema in workflow/schemas)
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


#: a refit stops when chi^2 fell by less than this over 3 iterations (well below the verdicts' thresholds)
STALL_CHI2 = 0.5
#: a thorough refit whose best start stopped (max_iterations, or the stall rule in a long valley) goes on from
#: there, with the damping reset, this many times more while it gains: a refit stopped early leaves chi^2 that
#: the next forward-selection step wrongly credits to any effect with extra freedom (measured: cross-coupled
#: stiffness alone stopped at chi^2 644, and any second effect then "explained" the rest down to 318)
CONTINUATIONS = 3


@dataclass
class BaseFit:
    """A variant's joint fit: layout, normalised optimum theta and the data it was fitted to."""

    variant: Variant
    layout: Layout
    theta: Array
    data: list[RunData]
    harmonics: int

    @property
    def X(self) -> Array:
        return np.stack([d.X[: self.harmonics] for d in self.data])

    @property
    def sigma(self) -> Array:
        return np.stack([d.sigma[: self.harmonics] for d in self.data])

    @classmethod
    def from_table(cls, variant: Variant, table: pd.DataFrame, data: Sequence[RunData], harmonics: int
                   ) -> "BaseFit":
        """From a joint parameter table (``Identification.table``: parameter, run, normalised, value)."""
        fitted = table[table["kind"] != "nuisance"]
        per_run = sorted(set(fitted.loc[fitted["run"] != "all", "parameter"]), key=list(variant.unknown).index)
        lower, upper = zip(*variant.unknown.values())
        layout = Layout.for_data(list(variant.unknown), lower, upper, data, per_run)
        theta = theta_from_table(table, layout)
        if theta is None:
            raise ValueError("the parameter table lacks an entry or has a non-finite estimate: the fit failed, "
                             "nothing to diagnose")
        return cls(variant, layout, theta, list(data), harmonics)


def extend(variant: Variant, candidates: Sequence[Candidate], ranges: Mapping[str, tuple[float, float]] | None = None
           ) -> Variant:
    """The variant with the candidates' effects added and their tested parameters unknown (absent at 0), in their
    ranges (``ranges`` overrides a parameter's default range, e.g. one widened by a refit)."""
    ranges = dict(ranges or {})
    for c in candidates:
        for p in c.parameters:
            lo, hi = ranges.get(p.name, p.bounds)
            if not lo <= 0.0 <= hi:
                raise ValueError(f"candidate {c.name}: the range [{lo:g}, {hi:g}] of {p.name} excludes 0 (absent)")
            if p.name in variant.unknown or p.name in variant.fixed:
                raise ValueError(f"candidate {c.name}: parameter {p.name} is already one of variant "
                                 f"{variant.name!r}'s")
    effects = variant.model.effects + [c.effect for c in candidates]
    unknown = dict(variant.unknown) | {p.name: tuple(ranges.get(p.name, p.bounds)) for c in candidates
                                       for p in c.parameters}
    name = "+".join([variant.name] + [c.name for c in candidates])
    return Variant(name, Model(effects, variant.model.shaft), unknown, dict(variant.fixed), variant.description)


def extended_problem(base: BaseFit, candidates: Sequence[Candidate],
                     ranges: Mapping[str, tuple[float, float]] | None = None) -> tuple[ArrowProblem, Array]:
    """The joint problem of the base extended by ``candidates`` (full solver), and theta at beta = 0."""
    ext = extend(base.variant, candidates, ranges)
    lower, upper = zip(*ext.unknown.values())
    layout = Layout.build(list(ext.unknown), lower, upper, base.layout.runs, base.layout.local,
                          base.layout.phase_sigma)
    models = [SolverModel(ext, d.run, d.rpm, d.eccentric_mass_g, layout.parameters, np.array(lower),
                          np.array(upper), base.harmonics) for d in base.data]
    known = dict(zip(base.layout.entries(), base.theta))
    theta = np.array([known[e] if e in known else float(layout.normalise(e[0], 0.0)) for e in layout.entries()])
    return ArrowProblem(models, layout, base.sigma), theta


def _basis(J: Array) -> Array:
    """Orthonormal basis of the column space of J (rank-revealing SVD)."""
    if J.shape[1] == 0:
        return np.zeros((J.shape[0], 0))
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    return U[:, s > 1e-10 * s[0]] if s.size and s[0] > 0 else np.zeros((J.shape[0], 0))


@dataclass
class Score:
    """One candidate's score test: statistic S, its p-value, the linear estimate b (normalised step) and the
    projected sensitivities G_p (for nesting and confounding)."""

    candidate: Candidate
    statistic: float
    p_value: float
    log_p: float
    step: Array
    projected: Array
    beyond_range: bool


@dataclass
class Scores:
    base_chi2: float
    base_dof: int
    n_data: int
    residual: Array  # r, weighted
    projected_residual: Array  # r_p
    scores: list[Score]
    seconds: float


def score_tests(base: BaseFit, candidates: Sequence[Candidate]) -> Scores:
    """Score (LM) test of every candidate at the base optimum (module docstring, step 1), one batched solve."""
    start = time.perf_counter()
    problem, theta = extended_problem(base, candidates)
    layout = problem.layout
    ev = problem.evaluate(theta[None], base.X[None], jacobian=True)
    prior_J, prior_r = problem.prior_rows(theta)  # keyphasor phases: their prior counts as data, as in the fit
    r = np.concatenate([ev.r[0].reshape(-1), prior_r])
    J = np.vstack([problem.dense_jacobian(ev), prior_J])
    if not (np.isfinite(r).all() and np.isfinite(J).all()):
        raise RuntimeError("the full solver failed at the base optimum (or next to it): no periodic solution "
                           "to diagnose from")
    entries = layout.entries()
    tested = {p.name for c in candidates for p in c.parameters}
    is_base = np.array([p not in tested for p, _ in entries])
    free = is_base & (layout.is_phase | (np.abs(theta) < 1.0 - BOUND_TOLERANCE))
    Q = _basis(J[:, free])
    r_p = r - Q @ (Q.T @ r)
    scores = []
    for c in candidates:
        cols = [entries.index((p.name, "all")) for p in c.parameters]
        G = J[:, cols] - Q @ (Q.T @ J[:, cols])
        at_zero_edge = theta[cols] <= -1.0 + BOUND_TOLERANCE  # 0 is the lower edge: only b >= 0 is physical
        at_top_edge = theta[cols] >= 1.0 - BOUND_TOLERANCE
        lower = np.where(at_zero_edge, 0.0, -np.inf)
        upper = np.where(at_top_edge, 0.0, np.inf)
        if np.linalg.norm(G) == 0:
            step = np.zeros(len(cols))
        else:
            step = optimize.lsq_linear(G, -r_p, bounds=(lower, upper), method="bvls").x
        statistic = float(r_p @ r_p - np.sum((r_p + G @ step) ** 2))
        statistic = max(statistic, 0.0)
        k = len(cols)
        beyond = bool(np.any(np.abs(theta[cols] + step) > 1.0))
        scores.append(Score(c, statistic, float(stats.chi2.sf(statistic, k)), float(stats.chi2.logsf(statistic, k)),
                            step, G, beyond))
    dof = r.size - int(free.sum())
    return Scores(float(r @ r), dof, r.size, r, r_p, scores, time.perf_counter() - start)


def _by_score(score: Score) -> tuple[float, float]:
    """Ranking key: most significant first (log p-value, exact where p underflows), then the larger drop."""
    return score.log_p, -score.statistic


def nested(a: Array, b: Array, tolerance: float = 1e-3) -> bool:
    """Whether span(a) lies within span(b): all principal angles between them are ~0."""
    Qa, Qb = _basis(a), _basis(b)
    if Qa.shape[1] == 0 or Qa.shape[1] > Qb.shape[1]:
        return False
    cosines = np.linalg.svd(Qa.T @ Qb, compute_uv=False)
    return bool(cosines.min() > 1.0 - tolerance)


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

    @property
    def at_limit(self) -> list[str]:
        """Parameters whose estimate still sits at a range edge away from zero (the physical limit reached)."""
        edge = self.estimates["at_bound"].astype(bool) & (self.estimates["value"].abs() > 0)
        return self.estimates.loc[edge, "parameter"].tolist()


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
    protocol = ProtocolResult(result, best, np.zeros((0, problem.layout.n)), np.zeros(0), result.seconds,
                              len(result.x))
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


def _theta_in(layout: Layout, fit: Identification) -> Array:
    """A fit's estimate (SI) as theta of another layout with the same entries (other ranges)."""
    values = dict(zip(fit.layout.entries(), fit.x))
    return np.array([values[e] if e[0] == "phase" else float(layout.normalise(e[0], values[e]))
                     for e in layout.entries()])


def confirm(base: BaseFit, score: Score, scores: Scores, max_iterations: int = 40,
            confidence: float = 0.95, starts: int = 4, widen: int = 4, quick: bool = False) -> Confirmation:
    """Refit with ``score.candidate`` added (full solver), from several starts (``_refit_starts``), its range
    widened while its estimate sits at an edge (``_widened``, at most ``widen`` times).

    The result is the best start's (lowest chi^2); the full solver's chi^2 at every start is kept
    (``start_chi2``). After a widening the refit starts again from the previous optimum, so each widening can
    only lower chi^2."""
    start_time = time.perf_counter()
    c = score.candidate
    ranges = {p.name: tuple(p.bounds) for p in c.parameters}
    widened: list = []
    # the verdicts compare chi^2 drops against thresholds of 6-10: chi^2 to within ~0.5 is all they need, and
    # stopping there saves the long crawl along flat valleys
    options = LMOptions(max_iterations=max_iterations, ftol=1e-6, xtol=1e-6, gtol=1e-8, stall_chi2=STALL_CHI2,
                        geodesic=True)
    fit, start_chi2, wider, old = None, [], {}, {}
    for attempt in range(widen + 1):
        problem, theta0 = extended_problem(base, [c], ranges)
        layout = problem.layout
        cols = [layout.entries().index((p.name, "all")) for p in c.parameters]
        if fit is None:
            theta = _refit_starts(theta0, cols, score.step, starts, zlib.crc32(c.name.encode()), quick)
        else:  # widened: from the previous optimum, and halfway from it to the new edge
            previous = _theta_in(layout, fit)
            further = previous.copy()
            for j, p in zip(cols, c.parameters):
                if p.name in wider:
                    edge = 1.0 if wider[p.name][1] > old[p.name][1] else -1.0
                    further[j] = 0.5 * (previous[j] + edge)
            theta = np.vstack([previous, further])
        X = np.repeat(base.X[None], len(theta), axis=0)
        first_refit = fit is None
        result = levenberg_marquardt(problem, theta, X, options)
        if first_refit:  # the objective at each start (LM's first evaluation): chi^2 plus any phase prior
            start_chi2 = (result.history[:, 0] * problem.n_data).tolist()
        best = _best(result)
        for _ in range(0 if quick else CONTINUATIONS):  # the best start stopped while descending: let it go on
            if result.status[best] not in (MAX_ITERATIONS, STALLED):
                break
            before = result.loss[best]
            result = LMResult.concatenate([result, levenberg_marquardt(problem, result.x[[best]], X[:1], options)])
            best = _best(result)
            if (before - result.loss[best]) * problem.n_data < STALL_CHI2:
                break
        fit, estimates = _concluded(problem, result, best, base, confidence, ranges)
        wider = _widened(ranges, estimates, c)
        if not wider or attempt == widen:
            break
        widened += [(name, ranges[name], new) for name, new in wider.items()]
        old = dict(ranges)
        ranges |= wider
    # the far side: a truth beyond the range on the side the base fit did not lean to; looked for when the refit
    # needed a wider range, or does not fit to the noise (a refit that explains everything needs no other basin)
    if not quick and widen > 0 and (widened or fit.chi2_dof > FAR_MISFIT):
        far = _far_ranges(ranges, c)
        if far != ranges:
            problem_f, theta0_f = extended_problem(base, [c], far)
            layout_f = problem_f.layout
            cols = [layout_f.entries().index((p.name, "all")) for p in c.parameters]
            here = _theta_in(layout_f, fit)
            # across the far ranges for the candidate alone, and across the whole box (a base fit far from the
            # truth leaves the base's own parameters in another basin: the polish's Latin hypercube)
            theta = np.vstack([here, _refit_starts(theta0_f, cols, None, max(starts, 2),
                                                   zlib.crc32(c.name.encode()) + 1)[1:],
                               problem_f.initial_phases(hypercube_starts(layout_f, here, max(starts, 2),
                                                                         zlib.crc32(c.name.encode()) + 2),
                                                        np.repeat(base.X[None], max(starts, 2), axis=0))])
            X = np.repeat(base.X[None], len(theta), axis=0)
            result = levenberg_marquardt(problem_f, theta, X, options)
            best = _best(result)
            if (fit.uncertainty.chi2 - result.loss[best] * problem_f.n_data) > FAR_GAIN:
                widened += [(name, ranges[name], far[name]) for name in far if far[name] != ranges[name]]
                ranges = far
                fit, estimates = _concluded(problem_f, result, best, base, confidence, ranges)
    chi2 = float(fit.uncertainty.chi2)
    k, n = len(ranges), scores.n_data
    lr = scores.base_chi2 - chi2
    # zero is excluded by the interval, or by an estimate pinned at the range edge away from zero (the data want
    # more of the effect than the physical limit allows: its interval is not valid there, the likelihood ratio is)
    far_edge = estimates["at_bound"].astype(bool) & (estimates["value"].abs() > 0)
    excludes = bool(((estimates["ci_low"] > 0) | (estimates["ci_high"] < 0) | far_edge).any())
    return Confirmation(c, fit, chi2, int(fit.uncertainty.dof), float(lr),
                        float(stats.chi2.sf(max(lr, 0.0), k)), float(-lr + k * np.log(n)), estimates, excludes,
                        time.perf_counter() - start_time, {k_: tuple(map(float, v)) for k_, v in ranges.items()},
                        widened, [float(v) for v in start_chi2])


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
        return {"step": None, "effect": self.effect, "chi2_dof_before": self.chi2_dof_before,
                "chi2_dof_after": self.chi2_dof_after, "delta_bic": self.delta_bic,
                "explained_pct": 100 * self.share, "estimate": _estimate_text(self.confirmation)}


def _refit_significant(base: BaseFit, scores: Scores, o: Mapping, alpha_each: float, log=None
                       ) -> dict[str, Confirmation]:
    """Refit every candidate the score test finds significant (``confirm: all``), or the ``confirm`` best plus
    any whose predicted drop is within ``confounded_bic`` of the best's (maybe confounded).

    Two passes: a quick refit of each (from beta = 0 and the linear estimate, ``quick_iterations``, ranges as
    given) ranks them by Delta BIC; the ``thorough`` best, and any within ``confounded_bic`` of the best, are
    refitted again from every start (``starts`` across the range) with range widening (``widen``), and that
    refit replaces the quick one. The ranking is by refit, never by the score statistic alone."""
    order = sorted(scores.scores, key=_by_score)
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
    ranked = sorted(chosen, key=lambda s: quick[s.candidate.name].delta_bic)
    best_bic = quick[ranked[0].candidate.name].delta_bic if ranked else 0.0
    deep = {s.candidate.name for i, s in enumerate(ranked) if i < int(o["thorough"])
            or quick[s.candidate.name].delta_bic - best_bic < o["confounded_bic"]}
    confirmations = {}
    for s in ranked:
        name = s.candidate.name
        cf = quick[name]
        if name in deep:
            cf = confirm(base, s, scores, int(o["max_iterations"]), starts=int(o["starts"]), widen=int(o["widen"]))
            cf.seconds += quick[name].seconds
        confirmations[name] = cf
        if log:
            widened = "; ".join(f"{p} range widened to [{new[0]:.4g}, {new[1]:.4g}]" for p, _, new in cf.widened)
            log.info("%s refit of %s with %s from %d starts: chi^2 %.4g -> %.4g, Delta BIC %.3g (%.1f s)%s",
                     "thorough" if name in deep else "quick", base.variant.name, name, len(cf.start_chi2),
                     scores.base_chi2, cf.chi2, cf.delta_bic, cf.seconds, f"; {widened}" if widened else "")
    return confirmations


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
        refits = _refit_significant(current, step_scores, o, step_alpha, log)
        confirmed = [cf for cf in refits.values() if _is_confirmed(cf, o, step_alpha)]
        before = best.chi2 / best.dof
        best = min(confirmed, key=lambda cf: cf.delta_bic) if confirmed else None
        if log:
            log.info("forward selection, step %d at %s: %s", len(path) + 1, current.variant.name,
                     "nothing significant left" if best is None else f"best {best.candidate.name}")
    first.path = path
    _conclude_path(first, base, scores, o)
    first.fingerprint = residual_fingerprint(base, path[-1].confirmation.fit.fun if path else scores.residual)
    first.summary["fingerprint"] = first.fingerprint.summary()
    if first.conclusion.startswith("unexplained"):
        first.conclusion += f". What the residual looks like: {first.fingerprint.summary()}"
        first.summary["conclusion"] = first.conclusion
    return first


def residual_fingerprint(base: BaseFit, r: Array) -> Fingerprint:
    """The fingerprint (``hybridtwin.fingerprint``) of a fit's weighted residuals r (eq. 10, the data part first:
    per run [Re, Im] of (X - M) / s over (H, 2), as ``ArrowProblem.evaluate``): E = X - M rebuilt from r."""
    R, H = len(base.data), base.harmonics
    parts = np.asarray(r, float)[: R * 4 * H].reshape(R, 2, H, 2)
    E = (parts[:, 0] + 1j * parts[:, 1]) * base.sigma  # (R, H, 2)
    measured = np.concatenate([np.zeros((R, 1, 2), complex), base.X], axis=1)  # h = 0 (DC) unused
    model = measured - np.concatenate([np.zeros((R, 1, 2), complex), E], axis=1)
    sigma = np.concatenate([np.full((R, 1, 2), np.inf), base.sigma], axis=1)
    return fingerprint(measured, model, sigma, [d.rpm for d in base.data], [d.eccentric_mass_g for d in base.data],
                       [d.run for d in base.data])


def _excess(scores: Scores) -> float:
    """chi^2 - dof, floored at one standard deviation of chi^2(dof), sqrt(2 dof): shares of an excess within
    the noise are not meaningful (a base at the noise floor would otherwise divide by ~0)."""
    return max(scores.base_chi2 - scores.base_dof, np.sqrt(2.0 * scores.base_dof))


def _is_confirmed(cf: Confirmation, o: Mapping, alpha_each: float) -> bool:
    return cf.lr_p_value < alpha_each and cf.delta_bic < o["bic_threshold"] and cf.excludes_zero


def _conclude(base: BaseFit, scores: Scores, confirmations: Mapping[str, Confirmation], o: Mapping,
              alpha_each: float) -> Diagnosis:
    excess = _excess(scores)
    base_ratio = scores.base_chi2 / scores.base_dof
    misfit = (stats.chi2.sf(scores.base_chi2, scores.base_dof) < o["alpha"]) and base_ratio > o["misfit_ratio"]
    by_name = {s.candidate.name: s for s in scores.scores}
    confirmed = sorted((cf for cf in confirmations.values() if _is_confirmed(cf, o, alpha_each)),
                       key=lambda cf: cf.delta_bic)
    best = confirmed[0] if confirmed else None
    verdicts: dict[str, str] = {}
    confounded: list[str] = []
    for cf in confirmed:
        name = cf.candidate.name
        if cf is best:
            continue
        projected, best_projected = by_name[name].projected, by_name[best.candidate.name].projected
        within_best, contains_best = nested(projected, best_projected), nested(best_projected, projected)
        inside = [b.candidate.name for b in confirmed if b is not cf and b.delta_bic <= cf.delta_bic
                  and nested(projected, by_name[b.candidate.name].projected)]
        if within_best and contains_best or (not inside and not contains_best
                                             and cf.delta_bic - best.delta_bic < o["confounded_bic"]):
            confounded.append(name)
            verdicts[name] = (f"confounded with {best.candidate.name}: these data cannot tell them apart "
                              f"(Delta BIC {cf.delta_bic:.1f} vs {best.delta_bic:.1f})")
        elif inside:
            verdicts[name] = f"part of {inside[0]} (its sensitivities lie within that effect's)"
        elif contains_best:
            verdicts[name] = (f"contains {best.candidate.name}; its extra terms are not supported by the data "
                              f"(Delta BIC {cf.delta_bic:.1f} vs {best.delta_bic:.1f})")
        else:
            verdicts[name] = f"confirmed, but weaker than {best.candidate.name}"
    share = 0.0 if best is None else (scores.base_chi2 - best.chi2) / excess
    gof_after = 0.0 if best is None else stats.chi2.sf(best.chi2, best.dof)
    if best is not None:
        name = best.candidate.name
        if share >= o["explained"] or gof_after >= o["alpha"]:
            verdicts[name] = "add: explains the discrepancy"
        elif share >= 0.5:
            verdicts[name] = f"add: explains {100 * share:.0f} % of the excess chi^2; a discrepancy remains"
        else:
            verdicts[name] = f"explains only {100 * share:.0f} % of the excess chi^2"
        if confounded:
            verdicts[name] += f" (confounded with {', '.join(confounded)})"
    for name, cf in confirmations.items():
        verdicts.setdefault(name, "not confirmed by the refit")
    for s in scores.scores:
        verdicts.setdefault(s.candidate.name, "significant, not refitted (ranked below the refitted ones)"
                            if s.p_value < alpha_each else "not significant")
    table = _table(scores, confirmations, verdicts, confirmed)
    conclusion, recommendation = _recommend(base, scores, best, confounded, share, misfit, base_ratio, o)
    summary = {"variant": base.variant.name, "runs": list(base.layout.runs), "n_data": scores.n_data,
               "base_chi2": scores.base_chi2, "base_dof": scores.base_dof, "base_chi2_dof": base_ratio,
               "base_gof_p_value": float(stats.chi2.sf(scores.base_chi2, scores.base_dof)),
               "misfit": bool(misfit), "alpha_per_candidate": alpha_each,
               "candidates": [s.candidate.name for s in scores.scores], "refitted": list(confirmations),
               "conclusion": conclusion, "score_seconds": scores.seconds,
               "recommended_variant": None if best is None else {
                   "name": f"{base.variant.name}_{best.candidate.name}",
                   "spec": variant_spec(base.variant, best.candidate, best.ranges)},
               "refit_seconds": float(sum(cf.seconds for cf in confirmations.values()))}
    return Diagnosis(table, conclusion, recommendation, summary, dict(confirmations), best)


def _conclude_path(result: Diagnosis, base: BaseFit, scores: Scores, o: Mapping) -> None:
    """The conclusion, verdict of the first effect and recommendation from the forward-selection path: "add"
    only for effects that together explain the discrepancy; otherwise "unexplained", the path as evidence."""
    path = result.path
    result.summary["path"] = [dict(step.row(), step=i + 1, ranges={k: list(v) for k, v in
                                                                   step.confirmation.ranges.items()})
                              for i, step in enumerate(path)]
    if not path:
        return
    final, share = path[-1].confirmation, path[-1].share
    # "add" only for effects that bring the fit to the noise: a large share of a huge excess can leave a misfit
    # many times the noise (an effect outside the candidates, half-mimicked by several of them)
    explains = _fits_the_noise(final, o)
    names = [step.effect for step in path]
    first = result.table.index[result.table["effect"] == names[0]][0]
    base_ratio = scores.base_chi2 / scores.base_dof
    estimates = "; ".join(f"{step.effect}: {_estimate_text(step.confirmation)}" for step in path)
    if explains and len(path) == 1:
        return  # _conclude's verdict and recommendation stand
    if explains:
        together = " and ".join(names)
        result.table.loc[first, "verdict"] = (f"add, with {', '.join(names[1:])}: together they explain the "
                                              f"discrepancy ({100 * share:.0f} % of the excess chi^2)")
        result.conclusion = (f"add {together}: together they explain the discrepancy ({100 * share:.0f} % of the "
                             f"excess chi^2); chi^2/dof {base_ratio:.3g} -> {final.chi2 / final.dof:.3g} "
                             f"(forward selection, {len(path)} steps); {estimates}")
        candidates = [step.confirmation.candidate for step in path]
        ranges = {k: v for step in path for k, v in step.confirmation.ranges.items()}
        name = "_".join([base.variant.name] + names)
        spec = variant_spec(base.variant, candidates, ranges)
        result.recommendation = (f"Add this variant under `variants:` in config/config.yaml, then run `snakemake "
                                 f"--cores 2` (only the new variant is built) and compare in results/ledger.tsv:"
                                 f"\n\n{variant_lines(name, spec)}\n")
        result.summary["recommended_variant"] = {"name": name, "spec": spec}
    else:
        result.table.loc[first, "verdict"] = (f"explains only {100 * path[0].share:.0f} % of the excess chi^2: "
                                              "part of an unexplained discrepancy")
        result.conclusion = (f"unexplained discrepancy: the candidates that help most, {', then '.join(names)}, "
                             f"remove only {100 * share:.0f} % of the excess chi^2 (chi^2/dof {base_ratio:.3g} -> "
                             f"{final.chi2 / final.dof:.3g}), and nothing significant is left among the others: "
                             f"the missing physics is not among the candidates (evidence: {estimates})")
        result.recommendation = ""
        result.summary["recommended_variant"] = None
    result.summary["conclusion"] = result.conclusion


def _estimate_text(cf: Confirmation) -> str:
    widened = {name for name, _, _ in cf.widened}

    def one(r) -> str:
        lo, hi = cf.ranges.get(r.parameter, (r.lower, r.upper))
        note = f" (range widened to [{lo:.4g}, {hi:.4g}])" if r.parameter in widened else ""
        if r.at_bound:
            return (f"{r.parameter} = {r.value:.4g} {r.unit} (at the edge of its range [{lo:.4g}, {hi:.4g}], the "
                    "physical limit: the data want more of this effect than it can physically give)")
        return f"{r.parameter} = {r.value:.4g} [{r.ci_low:.4g}, {r.ci_high:.4g}] {r.unit}".rstrip() + note
    return "; ".join(one(r) for r in cf.estimates.itertuples())


def _table(scores: Scores, confirmations: Mapping[str, Confirmation], verdicts: Mapping[str, str],
           confirmed: Sequence[Confirmation]) -> pd.DataFrame:
    """One row per candidate: confirmed ones first (by Delta BIC), then by score p-value."""
    excess = _excess(scores)
    first = [cf.candidate.name for cf in confirmed]
    rest = [s.candidate.name for s in sorted(scores.scores, key=_by_score)
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
            "verdict": verdicts[name],
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
                 ranges: Mapping[str, tuple[float, float]] | None = None) -> dict:
    """The config entry (``variants:`` form) of ``base`` + the candidate(s), their parameters unknown in their
    ranges (``ranges``: those a refit widened)."""
    added = [candidate] if isinstance(candidate, Candidate) else list(candidate)
    ranges = dict(ranges or {})
    unknown = dict(base.unknown) | {p.name: tuple(ranges.get(p.name, p.bounds)) for c in added for p in c.parameters}
    spec = {"description": f"{base.name} + " + " + ".join(f"{c.name}: {c.meaning}" for c in added),
            "effects": [e.name for e in base.model.effects] + [c.name for c in added],
            "unknown": {k: [float(lo), float(hi)] for k, (lo, hi) in unknown.items()}}
    if base.fixed:
        spec["fixed"] = {k: float(v) for k, v in base.fixed.items()}
    return spec


def variant_lines(name: str, spec: Mapping) -> str:
    """``spec`` as YAML lines to paste under ``variants:`` in config/config.yaml."""
    def flow(value) -> str:
        if isinstance(value, Mapping):
            return "{" + ", ".join(f"{k}: {flow(v)}" for k, v in value.items()) + "}"
        if isinstance(value, list):
            return "[" + ", ".join(flow(v) for v in value) + "]"
        return f"{value:g}" if isinstance(value, float) else str(value)
    lines = [f"  {name}:", f"    description: \"{spec['description']}\""]
    lines += [f"    {key}: {flow(spec[key])}" for key in ("effects", "unknown", "fixed") if key in spec]
    return "\n".join(lines)


def _recommend(base: BaseFit, scores: Scores, best: Confirmation | None, confounded: Sequence[str],
               share: float, misfit: bool, base_ratio: float, o: Mapping) -> tuple[str, str]:
    variant = base.variant
    if best is None:
        if not misfit:
            return ("no missing effect: the model fits the data to within the noise "
                    f"(chi^2/dof {base_ratio:.3g}) and no candidate is significant"), ""
        top = max(scores.scores, key=lambda s: s.statistic)
        return (f"unexplained discrepancy: chi^2/dof {base_ratio:.3g} is well above the noise floor (1), and no "
                f"candidate is confirmed (the best, {top.candidate.name}, would remove "
                f"{100 * top.statistic / _excess(scores):.0f} % of the excess chi^2 to first order); the missing "
                "physics is not among the candidates: look at the residual spectrum and the error map, and add "
                "your own candidate effects"), ""
    name = best.candidate.name
    if confounded:
        head = (f"add {name} or {', '.join(confounded)}: these data cannot tell them apart (measure where their "
                "responses differ, e.g. more speeds or unbalance masses, to decide)")
    elif share >= o["explained"]:
        head = f"add {name}: it explains the discrepancy ({100 * share:.0f} % of the excess chi^2)"
    elif share >= 0.5:
        head = f"add {name}: it explains {100 * share:.0f} % of the excess chi^2; a discrepancy remains"
    else:
        head = (f"unexplained discrepancy: the best confirmed candidate, {name}, explains only "
                f"{100 * share:.0f} % of the excess chi^2")
    conclusion = (f"{head}; chi^2/dof {base_ratio:.3g} -> {best.chi2 / best.dof:.3g} with it, "
                  f"Delta BIC {best.delta_bic:.1f}; {_estimate_text(best)}")
    new_name = f"{variant.name}_{name}"
    recommendation = (f"Add this variant under `variants:` in config/config.yaml, then run `snakemake --cores 2` "
                      f"(only the new variant is built) and compare in results/ledger.tsv:\n\n"
                      f"{variant_lines(new_name, variant_spec(variant, best.candidate, best.ranges))}\n")
    return conclusion, recommendation


def settings(config: Mapping) -> dict:
    """The diagnosis options: defaults, then the config's ``diagnosis:`` section."""
    return DEFAULTS | dict(config.get("diagnosis") or {})
