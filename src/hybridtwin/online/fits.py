"""A record's fits with the twin as the prior, on the full solver, several hypotheses in one batch.

The record: R runs (one for a steady record, its speed bands for a run-up), each with measured harmonics X (H, C)
and their sigmas. The unknowns, in the variant's normalised units x = 2 (p - lo) / (hi - lo) - 1:

    v = [shared parameters (d_s), per-run parameters of each run (R x d_l), the phase of each run (R)].

The least squares of a hypothesis (a set of parameters ``free`` of their prior):

    chi^2(v) = sum_runs |(X - e^{i h phi} M(x_run)) / sigma|^2                 (the data, Re and Im)
             + |L^-1 (v_P - mu_P)|^2                                          (the twin's prior, P = not free)
             + sum_runs (phi / sigma_phi)^2                                   (keyphasor phases only)

with mu, L L^T the prior's mean and covariance (``twin.Prior``) marginalised onto P. The twin's hypothesis frees
nothing; a parameter freed keeps no prior and is estimated by the record alone, as is, in every hypothesis, a shared
parameter the twin left undetermined (it has no prior). Under "nothing changed" (and a model that is right to first
order) chi^2 at the optimum is chi^2 with dof = data rows + prior rows - fitted entries: for the twin's hypothesis
the data rows less the phases without a keyphasor and the undetermined parameters.

Every hypothesis advances in one Levenberg-Marquardt loop (Nielsen's damping update, Marquardt's scaling): the
responses of all hypotheses and runs come from one batched solve with warm starts and analytic sensitivities
(``forward.evaluate_runs``), so a hypothesis more costs a scenario more in that solve, not a solve more. The
problems are small (tens of entries): dense normal equations. A parameter whose range is non-negative (a
stiffness, a damping ratio, a bow) stays so; its ``Parameter.limits`` apply when declared.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc  # chi^2's survival function (scipy.stats costs ~1 s to import)

from ..data.measured import RunData, total_sigma
from ..identify.forward import SensorSurrogate, SolverModel, evaluate_runs
from ..model.variants import Variant
from .twin import Prior

Array = np.ndarray

#: a fit has converged when an accepted step lowers chi^2 by less than this fraction of it (chi^2 ~ dof ~ 10-1000:
#: 1e-5 of it and less, far below the differences of 1 and more a test reads) or moves no entry by more than
#: STEP_TOLERANCE (normalised units)
CHI2_TOLERANCE = 1e-7
STEP_TOLERANCE = 1e-9
MAX_ITERATIONS = 40
#: an entry this close to a limit (normalised units: the range is 2 wide) is on it
SNAP = 1e-9
#: damping beyond which no step lowers chi^2: the fit is at its optimum (or cannot move from it)
MAX_DAMPING = 1e10


@dataclass(frozen=True)
class Hypothesis:
    """Parameters free of the twin's prior (none: the twin itself), in groups (a group moves together, e.g. the
    bow's q_x and q_y)."""

    groups: tuple[tuple[str, ...], ...] = ()

    @property
    def free(self) -> tuple[str, ...]:
        return tuple(p for group in self.groups for p in group)

    @property
    def name(self) -> str:
        return "twin" if not self.groups else " + ".join(", ".join(g) for g in self.groups)


@dataclass
class RecordFit:
    """One hypothesis fitted (or, ``linear``, its one Gauss-Newton step from another fit): the entries v, the
    record's responses in its frame (R, H, C), chi^2 of the data and of the prior, dof, the covariance of v, and how
    the fit ended."""

    hypothesis: Hypothesis
    v: Array
    model: Array
    chi2_data: float
    chi2_prior: float
    dof: int
    covariance: Array
    iterations: int
    converged: bool
    linear: bool = False
    responses: list = field(default=None, repr=False)  # each run's (M, dM) at v (1, H, C[, d]): a linear step's base
    #: the twin's own prediction of the record (R, H, C), where the fit started: the prior's mean (the bow from its
    #: law), the undetermined parameters at the twin's values, the phases aligned on the 1X (or the keyphasor's 0)
    prediction: Array | None = field(default=None, repr=False)

    @property
    def chi2(self) -> float:
        return self.chi2_data + self.chi2_prior

    @property
    def p_value(self) -> float:
        return float(chdtrc(self.dof, self.chi2)) if self.dof > 0 else math.nan


class RecordProblem:
    """The record's least squares for any hypothesis (module docstring).

    ``libraries`` (one sPGD ``Library`` per run of ``data``, over the variant's unknowns and ranges): the responses
    from them instead of the full solver (``library_route``), each shifted by its run's ``offsets`` (H', C) complex
    [m] when given (the anchor), the sigmas then the measured ones and each run's relative ``model_error`` in
    quadrature (``measured.total_sigma``, as the identification on the libraries); ``measured_sigma`` keeps the
    measured ones alone."""

    def __init__(self, variant: Variant, data: Sequence[RunData], prior: Prior, harmonics: int,
                 libraries: Sequence | None = None, model_error: Sequence[float] | None = None,
                 offsets: Sequence[Array | None] | None = None):
        self.variant, self.data, self.prior = variant, list(data), prior
        self.names = list(variant.unknown)
        lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
        self.lower, self.upper = lower, upper
        H = min(harmonics, min(d.H for d in data))
        if libraries is not None:
            H = min([H] + [library.n_harmonics - 1 for library in libraries]
                    + [len(o) for o in offsets or () if o is not None])
        self.H, self.R = H, len(data)
        self.libraries = None if libraries is None else list(libraries)
        self.models = ([SolverModel.for_data(variant, d, self.names, lower, upper, H) for d in data]
                       if libraries is None else [Shifted(SensorSurrogate(library, H), o) for library, o in
                                                  zip(libraries, offsets or [None] * len(libraries))])
        self.X = np.stack([d.X[:H] for d in data])  # (R, H, C)
        self.measured_sigma = np.stack([d.sigma[:H] for d in data])
        self.sigma = self.measured_sigma if model_error is None else np.stack(
            [total_sigma(d, e)[:H] for d, e in zip(data, model_error)])
        self.C = self.X.shape[2]
        self.local = [p for p in self.names if (p, 0) in prior.names]
        self.shared = [p for p in self.names if p not in self.local]
        self.entries = ([(p, None) for p in self.shared] + [(p, k) for k in range(self.R) for p in self.local]
                        + [("phase", k) for k in range(self.R)])
        self.n = len(self.entries)
        self.column = {e: i for i, e in enumerate(self.entries)}
        half = dict(zip(self.names, 0.5 * (upper - lower)))
        self.scale = np.array([1.0 if p == "phase" else half[p] for p, _ in self.entries])  # dp/dv
        self.offset = np.array([0.0 if p == "phase" else 0.5 * (lower + upper)[self.names.index(p)]
                                for p, _ in self.entries])
        self.prior_columns = np.array([self.column[name] for name in prior.names], int)
        self.prior_mean = (prior.mean - self.offset[self.prior_columns]) / self.scale[self.prior_columns]
        s = self.scale[self.prior_columns]
        self.prior_covariance = prior.covariance / np.outer(s, s)
        self.undetermined = {self.column[(p, None)]: (value - self.offset[self.column[(p, None)]])
                             / self.scale[self.column[(p, None)]] for p, (value, _) in prior.undetermined.items()}
        self.phase_prior = np.array([1.0 / d.phase_sigma if math.isfinite(d.phase_sigma) else 0.0 for d in data])
        self.lo_v, self.hi_v = self._limits()
        self.h = np.arange(1, H + 1)
        self._whitening: dict[Hypothesis, tuple[Array, Array]] = {}

    # --- values ----------------------------------------------------------------------------

    def to_si(self, v: Array) -> Array:
        return self.offset + self.scale * np.asarray(v, float)

    def start(self) -> Array:
        """The twin: the prior's mean, undetermined entries at the twin's values, phases 0 (aligned by ``fit``)."""
        v = np.zeros(self.n)
        v[self.prior_columns] = self.prior_mean
        for column, value in self.undetermined.items():
            v[column] = value
        return v

    def _limits(self) -> tuple[Array, Array]:
        lo, hi = np.full(self.n, -np.inf), np.full(self.n, np.inf)
        parameters = self.variant.model.parameters
        for i, (p, _) in enumerate(self.entries):
            if p == "phase":
                continue
            j = self.names.index(p)
            limits = parameters[p].limits or ((0.0, np.inf) if self.lower[j] >= 0 else (-np.inf, np.inf))
            lo[i], hi[i] = ((np.array(limits, float) - self.offset[i]) / self.scale[i])
        return lo, hi

    # --- residuals and Jacobian -------------------------------------------------------------

    def run_x(self, V: Array) -> list[Array]:
        """Every run's normalised parameters x (N, d) at the rows of V (N, n), in the variant's order."""
        xs = []
        for k in range(self.R):
            x = np.empty((V.shape[0], len(self.names)))
            for j, p in enumerate(self.names):
                x[:, j] = V[:, self.column[(p, None) if p in self.shared else (p, k)]]
            xs.append(x)
        return xs

    def responses(self, V: Array) -> list[tuple[Array, Array]]:
        """Every run's model M (N, H, C) and dM/dx (N, H, C, d) at the rows of V (N, n), one batched solve."""
        return [(M[:, : self.H], dM[:, : self.H]) for M, dM in evaluate_runs(self.models, self.run_x(V), True)]

    def residuals(self, V: Array, responses, hypotheses: Sequence[Hypothesis]) -> list[tuple[Array, Array, int]]:
        """Per row of V: the residual vector, its Jacobian (rows, n) and the number of data rows."""
        out = []
        for i, hypothesis in enumerate(hypotheses):
            r_parts, J_parts = [], []
            for k, (M, dM) in enumerate(responses):
                phi = V[i, self.column[("phase", k)]]
                rot = np.exp(1j * self.h * phi)[:, None]  # (H, 1)
                model = rot * M[i]
                z = (self.X[k] - model) / self.sigma[k]
                J = np.zeros((2 * self.H * self.C, self.n))
                dz = -(rot[..., None] * dM[i]) / self.sigma[k][..., None]  # (H, C, d)
                for j, p in enumerate(self.names):
                    J[:, self.column[(p, None) if p in self.shared else (p, k)]] = _real(dz[..., j])
                J[:, self.column[("phase", k)]] = _real(-1j * self.h[:, None] * model / self.sigma[k])
                r_parts.append(_real(z))
                J_parts.append(J)
            n_data = sum(len(r) for r in r_parts)
            keep, root = self._whiten(hypothesis)
            prior_J = np.zeros((len(keep), self.n))
            prior_J[:, self.prior_columns[keep]] = root
            r_parts.append(root @ (V[i, self.prior_columns[keep]] - self.prior_mean[keep]))
            J_parts.append(prior_J)
            phases = np.flatnonzero(self.phase_prior)
            phase_J = np.zeros((phases.size, self.n))
            columns = [self.column[("phase", k)] for k in phases]
            phase_J[np.arange(phases.size), columns] = self.phase_prior[phases]
            r_parts.append(self.phase_prior[phases] * V[i, columns])
            J_parts.append(phase_J)
            out.append((np.concatenate(r_parts), np.vstack(J_parts), n_data))
        return out

    def _whiten(self, hypothesis: Hypothesis) -> tuple[Array, Array]:
        """The prior's entries kept by ``hypothesis`` and the inverse Cholesky factor of their marginal covariance."""
        if hypothesis not in self._whitening:
            keep = np.array([i for i, (p, _) in enumerate(self.prior.names) if p not in hypothesis.free], int)
            cov = self.prior_covariance[np.ix_(keep, keep)]
            # a singular prior (e.g. a bow law of the runs' values that the shared parameters fix exactly): a
            # floor of 1e-12 of the largest variance keeps it positive definite without changing any test
            floor = 1e-12 * max(float(np.max(np.diag(cov), initial=0.0)), 1e-300)
            factor = np.linalg.cholesky(cov + floor * np.eye(len(keep))) if len(keep) else np.zeros((0, 0))
            self._whitening[hypothesis] = (keep, np.linalg.inv(factor) if len(keep) else factor)
        return self._whitening[hypothesis]

    def align_phases(self, V: Array, responses) -> Array:
        """V with each phase without a keyphasor aligned on the 1X: phi = arg(sum_c X_1c conj(M_1c) / sigma^2)."""
        V = V.copy()
        for k, (M, _) in enumerate(responses):
            if self.phase_prior[k] == 0:
                weight = 1.0 / self.sigma[k, 0] ** 2
                V[:, self.column[("phase", k)]] = np.angle((self.X[k, 0] * np.conj(M[:, 0]) * weight).sum(-1))
        return V

    def frame(self, V: Array, responses, row: int) -> Array:
        """The model of row ``row`` in the record's frame (R, H, C)."""
        return np.stack([np.exp(1j * self.h * V[row, self.column[("phase", k)]])[:, None] * M[row]
                         for k, (M, _) in enumerate(responses)])


@dataclass
class Anchor:
    """A library's correction to the full solver at the twin (``library_route.anchors``): the shift ``offset``
    (H', C) complex [m] and, to first order, ``gradient`` (H', C, d) [m per normalised unit] the solver's Jacobian less
    the library's at the normalised point ``centre`` (d,): the corrected response M(x) + offset + gradient (x - centre)
    equals the solver's and its Jacobian at the centre."""

    offset: Array
    gradient: Array | None = None
    centre: Array | None = None

    def __len__(self) -> int:  # the harmonics it holds
        return len(self.offset)


class Shifted:
    """A forward model (``forward.HarmonicModel``) plus its ``Anchor`` (or a constant offset (H', C) complex [m];
    None: none): a library anchored on the full solver (``library_route``)."""

    def __init__(self, model, offset: Anchor | Array | None):
        self.model = model
        self.anchor = offset if offset is None or isinstance(offset, Anchor) else Anchor(np.asarray(offset))
        self.parameters, self.lower, self.upper, self.H = model.parameters, model.lower, model.upper, model.H

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        M, dM = self.model.evaluate(x, jacobian)
        if self.anchor is None:
            return M, dM
        H = M.shape[1]
        M = M + self.anchor.offset[None, :H]
        if self.anchor.gradient is not None:
            G = self.anchor.gradient[:H]  # (H, C, d); the library clips x to its box, so does the correction
            M = M + np.einsum("hcd,nd->nhc", G, np.clip(np.atleast_2d(x), -1.0, 1.0) - self.anchor.centre)
            if dM is not None:
                dM = dM + G[None]
        return M, dM


def fit(problem: RecordProblem, hypotheses: Sequence[Hypothesis], start: RecordFit | None = None
        ) -> list[RecordFit]:
    """Each hypothesis fitted by Levenberg-Marquardt, all in one batch (module docstring), from ``start`` (a fit
    whose entries and responses they all start from; default: the twin, ``RecordProblem.start``, the phases
    aligned on the 1X)."""
    N = len(hypotheses)
    if start is None:
        V = problem.start()[None]
        first = problem.responses(V)  # one solve for all: they start at the same point
        V = problem.align_phases(V, first)
        prediction = problem.frame(V, first, 0)
    else:
        V, first, prediction = start.v[None], start.responses, start.prediction
    V = np.repeat(V, N, axis=0)
    responses = [(np.repeat(M, N, axis=0), np.repeat(dM, N, axis=0)) for M, dM in first]
    current = problem.residuals(V, responses, hypotheses)
    cost = np.array([r @ r for r, _, _ in current])
    mu, nu = np.full(N, 1e-3), np.full(N, 2.0)
    active, converged, iterations = np.isfinite(cost), np.zeros(N, bool), np.zeros(N, int)
    for _ in range(MAX_ITERATIONS):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        trial, predicted = V[rows].copy(), np.zeros(rows.size)
        for t, i in enumerate(rows):
            step = _step(problem, V[i], current[i], mu[i])
            trial[t] += step
            r, J, _ = current[i]
            Js = J @ step
            predicted[t] = -(2 * r @ Js + Js @ Js)  # the decrease of chi^2 the linear model promises
        iterations[rows] += 1
        trial_responses = problem.responses(trial)
        evaluated = problem.residuals(trial, trial_responses, [hypotheses[i] for i in rows])
        for t, i in enumerate(rows):
            r_new = evaluated[t][0]
            new_cost = float(r_new @ r_new) if np.isfinite(r_new).all() else np.inf
            if not np.any(trial[t] != V[i]):  # every fitted entry held on a limit: the optimum on the box
                active[i], converged[i] = False, True
            elif new_cost < cost[i]:
                gain = min((cost[i] - new_cost) / predicted[t], 1.0) if predicted[t] > 0 else 1.0
                mu[i] *= max(1 / 3, 1 - (2 * gain - 1) ** 3)
                nu[i] = 2.0
                done = cost[i] - new_cost <= CHI2_TOLERANCE * cost[i] or np.abs(trial[t] - V[i]).max() <= STEP_TOLERANCE
                V[i], cost[i], current[i] = trial[t], new_cost, evaluated[t]
                responses = _replace(responses, trial_responses, i, t)
                if done:
                    active[i], converged[i] = False, True
            else:
                mu[i] *= nu[i]
                nu[i] *= 2
                if mu[i] > MAX_DAMPING:
                    active[i], converged[i] = False, True  # no step lowers chi^2: the optimum
    out = []
    for i in range(N):
        result = _result(problem, hypotheses[i], V[i], current[i], problem.frame(V, responses, i),
                         int(iterations[i]), bool(converged[i]))
        result.responses = [(M[i: i + 1], dM[i: i + 1]) for M, dM in responses]
        result.prediction = prediction
        out.append(result)
    return out


def _step(problem: RecordProblem, v: Array, evaluated, mu: float) -> Array:
    """A damped Gauss-Newton step (Marquardt's scaling), with an active set: an entry on a
    limit whose descent points out is held; a step that would leave the limits is shortened along its direction to
    end on them (projecting entry by entry would turn it off the descent)."""
    r, J, _ = evaluated
    lo, hi = problem.lo_v, problem.hi_v
    g = J.T @ r
    on_lo, on_hi = v <= lo + SNAP, v >= hi - SNAP
    free = ~((on_lo & (g > 0)) | (on_hi & (g < 0)))
    step = np.zeros_like(v)
    while free.any():
        Jf = J[:, free]
        A = Jf.T @ Jf
        d = np.maximum(np.diag(A), 1e-12 * max(float(np.diag(A).max()), 1e-300))
        step[:] = 0.0
        step[free] = np.linalg.solve(A + mu * np.diag(d), -g[free])
        out = free & ((on_lo & (step < 0)) | (on_hi & (step > 0)))  # the coupled step still pushes it out: hold it
        if not out.any():
            break
        free &= ~out
    else:
        return step
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(step < 0, (lo - v) / step, np.where(step > 0, (hi - v) / step, np.inf))
    fraction = float(np.min(room[free], initial=np.inf))
    if fraction < 1.0:
        step *= max(fraction, 0.0)
    new = v + step
    new = np.where(new <= lo + SNAP, lo, np.where(new >= hi - SNAP, hi, new))  # on a limit, not creeping to it
    return new - v


def linearised(problem: RecordProblem, base: RecordFit, hypothesis: Hypothesis) -> RecordFit:
    """``hypothesis``'s optimum to first order from the fit ``base``: one Gauss-Newton step from it, no solve. What
    a record says of each parameter when it is near the twin (a consistent record), at the cost of a linear
    solve."""
    V, single = base.v[None], base.responses
    r, J, n_data = problem.residuals(V, single, [hypothesis])[0]
    step = np.linalg.lstsq(J, -r, rcond=None)[0]
    v = base.v + step
    model = problem.frame(V, single, 0) + _model_change(problem, single, V, step)
    fitted = _result(problem, hypothesis, v, (r + J @ step, J, n_data), model, 0, True)
    fitted.linear, fitted.responses = True, single
    return fitted


def _model_change(problem: RecordProblem, responses, V: Array, dv: Array) -> Array:
    """The first-order change of the model in the record's frame (R, H, C) for a change dv of the entries."""
    out = []
    for k, (M, dM) in enumerate(responses):
        rot = np.exp(1j * problem.h * V[0, problem.column[("phase", k)]])[:, None]
        dx = np.array([dv[problem.column[(p, None) if p in problem.shared else (p, k)]] for p in problem.names])
        dphi = dv[problem.column[("phase", k)]]
        out.append(rot * (dM[0] @ dx) + 1j * problem.h[:, None] * rot * M[0] * dphi)
    return np.stack(out)


def _result(problem: RecordProblem, hypothesis: Hypothesis, v: Array, evaluated, model: Array, iterations: int,
            converged: bool) -> RecordFit:
    r, J, n_data = evaluated
    return RecordFit(hypothesis, v, model, float(r[:n_data] @ r[:n_data]), float(r[n_data:] @ r[n_data:]),
                     int(len(r) - problem.n), np.linalg.pinv(J.T @ J), iterations, converged)


def _replace(responses, new, i: int, t: int):
    """The batch's responses with row i replaced by row t of ``new`` (an accepted step)."""
    out = []
    for (M, dM), (Mn, dMn) in zip(responses, new):
        M, dM = M.copy(), dM.copy()
        M[i], dM[i] = Mn[t], dMn[t]
        out.append((M, dM))
    return out


def _real(z: Array) -> Array:
    """Complex (H, C, ...) -> real (2HC, ...): Re flattened, then Im."""
    flat = z.reshape((z.shape[0] * z.shape[1],) + z.shape[2:])
    return np.concatenate([flat.real, flat.imag], axis=0)
