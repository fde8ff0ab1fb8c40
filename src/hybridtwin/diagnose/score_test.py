"""The score test: which candidate effects could the fitted model be missing? (diagnosis, step 1)

A variant fitted jointly to the fit runs (``BaseFit``) and candidate effects (``hybridtwin.model.candidates``), each
switched on by parameters beta that are absent at zero. Every response comes from the full harmonic-balance
solver (``forward.SolverModel``), never from a library: the candidates are not in the libraries, and the test
must not mistake surrogate error for physics.

r: the weighted residuals of eq. 10 with the measured sigmas, so r ~ N(0, I) when the model is right;
J = d r / d theta of the base entries (shared, per-run, phases; entries held at a range edge excluded, as in the
fit); G = d r / d beta at beta = 0, all candidates in one batched solve (the base extended by every candidate at
zero *is* the base). With Q an orthonormal basis of J, r_p = r - Q Q^T r and G_p = G - Q Q^T G (the base's
sensitivities projected out, so an effect the base can absorb scores ~0):

    S = ||r_p||^2 - min_b ||r_p + G_p b||^2,          b >= 0 if 0 is a range edge,

the chi^2 drop the candidate predicts to first order, and S ~ chi^2(k) under "absent" (k = its parameters;
with a sign constraint the law is the chi-bar^2 mixture, so chi^2(k) is conservative). The screen is cheap;
the ranking is by refit (``hybridtwin.diagnose.refit``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import optimize, stats

from ..model.candidates import Candidate
from .form_intervals import form_intervals, own_intervals
from ..identify.forward import SolverModel
from ..identify.arrow_problem import ArrowProblem, Layout
from ..identify.identification import RunData, theta_from_table
from ..model.model import Model
from ..identify.uncertainty import BOUND_TOLERANCE
from ..model.variants import Variant

Array = np.ndarray


@dataclass
class BaseFit:
    """A variant's joint fit: layout, normalised optimum theta and the data it was fitted to."""

    variant: Variant
    layout: Layout
    theta: Array
    data: list[RunData]
    harmonics: int
    #: the fit's parameters the data left undetermined (not identifiable, or at a range edge), each with why:
    #: where a missing effect can hide (the diagnosis then cannot rule one out)
    undetermined: tuple[str, ...] = ()
    #: the fit's reported 95 % interval [SI] of each shared parameter (parameters.tsv), where known
    intervals: dict = field(default_factory=dict)

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
        return cls(variant, layout, theta, list(data), harmonics, undetermined_parameters(fitted),
                   own_intervals(table) if {"ci_low", "ci_high", "kind"} <= set(table) else {})


def undetermined_parameters(table: pd.DataFrame) -> tuple[str, ...]:
    """Each physical or per-run parameter of a parameter table (``Identification.table``, phases left out) that
    its fit left undetermined: "k_b (not identifiable)", "zeta_s (at a range edge)", once per parameter."""
    out: dict[str, str] = {}
    for row in table[table["kind"] != "nuisance"].itertuples():
        why = [text for flag, text in (("identifiable", "not identifiable"), ("at_bound", "at a range edge"))
               if flag in table and (str(getattr(row, flag)).lower() in ("true", "1")) != (flag == "identifiable")]
        if why and row.parameter not in out:
            out[row.parameter] = f"{row.parameter} ({', '.join(why)})"
    return tuple(out.values())


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
                     ranges: Mapping[str, tuple[float, float]] | None = None,
                     per_run: Sequence[str] | None = None, resolve: bool = True) -> tuple[ArrowProblem, Array]:
    """The joint problem of the base extended by ``candidates`` (full solver), and theta at beta = 0 (the base's
    entries; with ``per_run`` other than the base's, entries it lacks are at 0 normalised: set them yourself).
    per_run: the parameters estimated per run (default: the base's). resolve: the harmonic balance carries the
    harmonics a non-smooth candidate declares (``SolverModel``'s ``resolve``; False: the data's)."""
    ext = extend(base.variant, candidates, ranges)
    lower, upper = zip(*ext.unknown.values())
    layout = Layout.build(list(ext.unknown), lower, upper, base.layout.runs,
                          base.layout.local if per_run is None else per_run, base.layout.phase_sigma,
                          base.layout.offsets, base.layout.run_records)
    models = [SolverModel.for_data(ext, d, layout.parameters, np.array(lower), np.array(upper), base.harmonics,
                                   resolve=resolve) for d in base.data]
    known = dict(zip(base.layout.entries(), base.theta))
    theta = np.array([known[e] if e in known else layout.theta_of(e, 0.0) for e in layout.entries()])
    return ArrowProblem(models, layout, base.sigma), theta


def column_basis(J: Array) -> Array:
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
    # the linearisation the scores come from (``form_intervals`` reuses it): J (m, n) over the extended problem's
    # entries (the base's and every candidate's, at beta = 0), theta (n,), which base entries are free, and each
    # candidate's columns; the extended layout (its ranges)
    jacobian: Array | None = None
    theta: Array | None = None
    free: Array | None = None
    columns: dict | None = None
    layout: Layout | None = None


def score_tests(base: BaseFit, candidates: Sequence[Candidate]) -> Scores:
    """Score (LM) test of every candidate at the base optimum (module docstring, step 1), one batched solve."""
    start = time.perf_counter()
    # at beta = 0 every candidate is absent: a rub's force is nil and its derivative there (clearance 0: a ring
    # touching all round) linear, nothing non-smooth to resolve, so the data's harmonics (``extended_problem``)
    problem, theta = extended_problem(base, candidates, resolve=False)
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
    free = is_base & (layout.is_nuisance | (np.abs(theta) < 1.0 - BOUND_TOLERANCE))
    Q = column_basis(J[:, free])
    r_p = r - Q @ (Q.T @ r)
    scores, columns = [], {}
    for c in candidates:
        cols = [entries.index((p.name, "all")) for p in c.parameters]
        columns[c.name] = cols
        scores.append(candidate_score(c, J[:, cols], Q, r_p, theta[cols]))
    dof = r.size - int(free.sum())
    return Scores(float(r @ r), dof, r.size, r, r_p, scores, time.perf_counter() - start, J, theta, free, columns,
                  layout)


def intervals_over_candidates(scores: Scores, own: Mapping[str, tuple[float, float]] | None = None,
                              confidence: float = 0.95):
    """The shared parameters' intervals over each scored candidate (``form_intervals``), from the score tests'
    linearisation; ``own``: the fit's reported intervals [SI]."""
    L = scores.layout
    lower, upper = dict(zip(L.parameters, L.lower)), dict(zip(L.parameters, L.upper))
    return form_intervals(scores.jacobian, scores.residual, scores.theta, L.entries(), scores.free, scores.columns,
                          dict(own or {}), lower, upper, scores.base_dof, confidence)


def candidate_score(candidate: Candidate, G: Array, Q: Array, r_p: Array, theta: Array) -> Score:
    """One candidate's score test (module docstring): G = d r / d beta (its columns, normalised beta), Q an
    orthonormal basis of what the base can absorb, r_p the residual with it projected out, theta the candidate's
    entries (at beta = 0: a sign constraint where 0 is a range edge)."""
    G = G - Q @ (Q.T @ G)
    at_zero_edge = theta <= -1.0 + BOUND_TOLERANCE  # 0 is the lower edge: only b >= 0 is physical
    at_top_edge = theta >= 1.0 - BOUND_TOLERANCE
    lower = np.where(at_zero_edge, 0.0, -np.inf)
    upper = np.where(at_top_edge, 0.0, np.inf)
    if np.linalg.norm(G) == 0:
        step = np.zeros(G.shape[1])
    else:
        step = optimize.lsq_linear(G, -r_p, bounds=(lower, upper), method="bvls").x
    statistic = max(float(r_p @ r_p - np.sum((r_p + G @ step) ** 2)), 0.0)
    k = G.shape[1]
    beyond = bool(np.any(np.abs(theta + step) > 1.0))
    return Score(candidate, statistic, float(stats.chi2.sf(statistic, k)), float(stats.chi2.logsf(statistic, k)),
                 step, G, beyond)


def scale_p_value(statistic: float, k: int, dispersion: float, dof: int) -> tuple[float, float]:
    """(p, log p) of a chi^2 drop ``statistic`` on ``k`` parameters judged at the scale the data show: with the
    quasi-likelihood's dispersion phi (the remaining misfit chi^2 / dof, estimated on ``dof`` degrees of freedom),
    (statistic / k) / phi ~ F(k, dof) when the effect is absent (McCullagh and Nelder, Generalized Linear Models,
    sec. 9.2: the F test of a nested model with an estimated scale; chi^2(k) of statistic / phi as dof -> inf).
    phi = 1 and dof -> inf give the plain chi^2(k) test of the stated sigmas."""
    f = max(statistic, 0.0) / (k * dispersion)
    return float(stats.f.sf(f, k, max(dof, 1))), float(stats.f.logsf(f, k, max(dof, 1)))


def at_scale(scores: Scores, dispersion: float) -> Scores:
    """The score tests judged at the data's scale (a quasi-likelihood, ``scale_p_value``): each statistic divided
    by the dispersion phi (the chi^2 drop in units of the remaining misfit), its p-value from F(k, dof); the
    residuals, steps and sensitivities as they are. phi = 1: the tests as stated, p-values from chi^2(k)."""
    if dispersion == 1.0:
        return scores
    judged = []
    for s in scores.scores:
        k = s.projected.shape[1]
        p, log_p = scale_p_value(s.statistic, k, dispersion, scores.base_dof)
        judged.append(replace(s, statistic=s.statistic / dispersion, p_value=p, log_p=log_p))
    return replace(scores, scores=judged)


def by_score(score: Score) -> tuple[float, float]:
    """Ranking key: most significant first (log p-value, exact where p underflows), then the larger drop."""
    return score.log_p, -score.statistic


def nested(a: Array, b: Array, tolerance: float = 1e-3) -> bool:
    """Whether span(a) lies within span(b): all principal angles between them are ~0."""
    Qa, Qb = column_basis(a), column_basis(b)
    if Qa.shape[1] == 0 or Qa.shape[1] > Qb.shape[1]:
        return False
    cosines = np.linalg.svd(Qa.T @ Qb, compute_uv=False)
    return bool(cosines.min() > 1.0 - tolerance)
