"""Levenberg-Marquardt for block-arrow least squares, batched over trials.

The problem: minimise ||r(theta)||^2 + ||rho(theta)||^2 for many trials at
once (random starts, Monte Carlo repeats), where theta = [shared (d_s),
block 1 (k), ..., block R (k)] and each block of residuals r_b depends on the
shared entries and on its own block only. J^T J then has the arrow form
[[A, B_1..B_R], [B_r^T, C_r]], solved by the Schur complement: R small solves,
not one dense n x n one (``arrow_solve``). rho has a diagonal Jacobian (a
penalty or prior per entry). This module knows nothing of runs, harmonics or
models: a problem is any object with

- ``layout``: ``n_shared`` (d_s), ``n_block`` (k), ``bounds()`` -> (lower, upper) of theta (n,);
- ``n_data``: the number of data residuals (for the reported loss = objective / n_data);
- ``evaluate(theta (N, n), X (N, ...), jacobian=True)`` -> ``Evaluation`` (residuals and Jacobian blocks).

Every trial advances in the same numpy operations, with its own damping
factor mu (Nielsen's update), Marquardt's scaling diag(J^T J), and trials that
have converged are masked out. Bounds are handled by projection with an active
set (no transform, so the Jacobian at the optimum is the model's): an entry on
a bound whose gradient points outwards is held fixed; if the coupled damped
Gauss-Newton step still pushes a bound entry out, it is held too and the step
solved again; a step that would leave the box is shortened along its
direction to end on the box (projecting it entry by entry would turn it, and
in a correlated valley it would then no longer descend), and an entry ending
within ``SNAP`` of a bound lands on it (no creeping in ever shorter steps).
Stopping: scipy's ftol/xtol/gtol, plus a stall rule (chi^2 fell by less than
``stall_chi2`` over ``stall_window`` iterations: points along a flat valley are
statistically equivalent). Optional geodesic acceleration (Transtrum & Sethna
2012) helps along curved valleys.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Array = np.ndarray

#: status codes of a trial (scipy.optimize.least_squares' meanings)
RUNNING, NONFINITE, MAX_ITERATIONS, GTOL, FTOL, XTOL, STALLED = -1, -2, 0, 1, 2, 3, 4
STATUS_MESSAGES = {
    NONFINITE: "no response at the start (the model failed there)",
    MAX_ITERATIONS: "the maximum number of iterations was reached",
    GTOL: "gtol termination: the projected gradient of the loss is below gtol",
    FTOL: "ftol termination: the relative reduction of the loss is below ftol",
    XTOL: "xtol termination: the step is below xtol",
    STALLED: "stall termination: chi^2 fell by less than stall_chi2 over the last stall_window iterations "
             "(a flat valley: the points along it are statistically equivalent)",
}
#: an LM step ending this close to a bound (normalised units; the range is 2 wide) lands on it
SNAP = 1e-3


@dataclass
class Evaluation:
    """Residuals and block-arrow Jacobian of N trials.

    r: (N, R, m) data residuals (Re then Im of (X - e^{ih phi} M) / s), rho: (N, n)
    sparsity residuals (eq. 11, one per entry of theta, 0 for phases) plus, for
    the phases of keyphasor runs, their prior phi / phase_sigma;
    Js: (N, R, m, d_s) d r / d shared, Jl: (N, R, m, k) d r / d run block,
    jd: (N, n) d rho / d theta (diagonal).
    """

    r: Array
    rho: Array
    Js: Array | None = None
    Jl: Array | None = None
    jd: Array | None = None

    @property
    def chi2(self) -> Array:
        return np.einsum("nrm,nrm->n", self.r, self.r)

    @property
    def objective(self) -> Array:
        """||r||^2 + ||rho||^2 (twice scipy's cost)."""
        return self.chi2 + np.einsum("ni,ni->n", self.rho, self.rho)



# --- the block-arrow normal equations ---------------------------------------------------


@dataclass
class Normal:
    """J^T J as [[A, B_1..B_R], [B_r^T, C_r]] and g = J^T r, for N trials."""

    A: Array  # (N, d_s, d_s)
    B: Array  # (N, R, d_s, k)
    C: Array  # (N, R, k, k)
    gs: Array  # (N, d_s)
    gl: Array  # (N, R, k)

    @classmethod
    def assemble(cls, ev: Evaluation, layout) -> "Normal":
        N, R = ev.r.shape[:2]
        ds, k = layout.n_shared, layout.n_block
        jd = ev.jd.reshape(N, -1)
        # batched matrix products: einsum's path search cost more than these small contractions
        Js_t, Jl_t = np.swapaxes(ev.Js, -1, -2), np.swapaxes(ev.Jl, -1, -2)  # (N, R, ., m)
        A = (Js_t @ ev.Js).sum(axis=1)
        B = Js_t @ ev.Jl
        C = Jl_t @ ev.Jl
        gs = (Js_t @ ev.r[..., None])[..., 0].sum(axis=1) + jd[:, :ds] * ev.rho[:, :ds]
        gl = (Jl_t @ ev.r[..., None])[..., 0] + (jd[:, ds:] * ev.rho[:, ds:]).reshape(N, R, k)
        A[:, np.arange(ds), np.arange(ds)] += jd[:, :ds] ** 2
        C[:, :, np.arange(k), np.arange(k)] += (jd[:, ds:] ** 2).reshape(N, R, k)
        return cls(A, B, C, gs, gl)

    def gradient(self) -> Array:
        """g = J^T r flattened as theta (N, n)."""
        return np.concatenate([self.gs, self.gl.reshape(self.gl.shape[0], -1)], axis=1)

    def diagonal(self) -> Array:
        """diag(J^T J) (N, n)."""
        ds = self.A.shape[1]
        a = self.A[:, np.arange(ds), np.arange(ds)]
        k = self.C.shape[-1]
        c = self.C[:, :, np.arange(k), np.arange(k)].reshape(self.C.shape[0], -1)
        return np.concatenate([a, c], axis=1)


def arrow_solve(normal: Normal, damping: Array, free: Array, gs: Array | None = None, gl: Array | None = None
                ) -> Array:
    """Solve (J^T J + diag(damping)) delta = -g over the free entries (delta = 0 elsewhere), Schur complement.

    g = (gs, gl), by default the normal equations' gradient J^T r.

    damping, free: (N, n). C_r^-1 per run, S = A - sum_r B_r C_r^-1 B_r^T,
    delta_s = S^-1 (-g_s + sum_r B_r C_r^-1 g_r), delta_r = C_r^-1 (-g_r - B_r^T delta_s).
    """
    N, ds = normal.gs.shape
    R, k = normal.gl.shape[1:]
    fs, fl = free[:, :ds].astype(float), free[:, ds:].reshape(N, R, k).astype(float)
    ds_idx, k_idx = np.arange(ds), np.arange(k)
    A = normal.A * fs[:, :, None] * fs[:, None, :]
    A[:, ds_idx, ds_idx] += damping[:, :ds] * fs + (1.0 - fs)
    C = normal.C * fl[..., :, None] * fl[..., None, :]
    C[:, :, k_idx, k_idx] += damping[:, ds:].reshape(N, R, k) * fl + (1.0 - fl)
    B = normal.B * fs[:, None, :, None] * fl[:, :, None, :]
    gs = -(normal.gs if gs is None else gs) * fs
    gl = -(normal.gl if gl is None else gl) * fl
    C_inv = np.linalg.inv(C)
    if ds == 0:
        return np.einsum("nrij,nrj->nri", C_inv, gl).reshape(N, -1)
    W = np.einsum("nrij,nrjk->nrik", B, C_inv)  # B_r C_r^-1 (N, R, ds, k)
    S = A - np.einsum("nrik,nrjk->nij", W, B)
    delta_s = np.linalg.solve(S, (gs - np.einsum("nrik,nrk->ni", W, gl))[..., None])[..., 0]
    delta_l = np.einsum("nrij,nrj->nri", C_inv, gl - np.einsum("nrji,nj->nri", B, delta_s))
    return np.concatenate([delta_s, delta_l.reshape(N, -1)], axis=1)


def _jvp(ev: Evaluation, delta: Array, layout) -> tuple[Array, Array]:
    """J delta: the data part (N, R, m) and the sparsity part (N, n)."""
    ds = layout.n_shared
    N, R = ev.r.shape[:2]
    dl = delta[:, ds:].reshape(N, R, layout.n_block)
    return (np.einsum("nrmi,ni->nrm", ev.Js, delta[:, :ds]) + np.einsum("nrmi,nri->nrm", ev.Jl, dl),
            ev.jd * delta)


def _jtv(ev: Evaluation, v: Array, v_rho: Array, layout) -> tuple[Array, Array]:
    """J^T v as (shared (N, d_s), blocks (N, R, k))."""
    N, R = ev.r.shape[:2]
    ds = layout.n_shared
    gs = np.einsum("nrmi,nrm->ni", ev.Js, v) + ev.jd[:, :ds] * v_rho[:, :ds]
    gl = np.einsum("nrmi,nrm->nri", ev.Jl, v) + (ev.jd[:, ds:] * v_rho[:, ds:]).reshape(N, R, layout.n_block)
    return gs, gl


def _linearised(ev: Evaluation, delta: Array, layout) -> Array:
    """||r + J delta||^2 + ||rho + jd delta||^2 (the Gauss-Newton model of the objective) (N,)."""
    jr, jrho = _jvp(ev, delta, layout)
    r, rho = ev.r + jr, ev.rho + jrho
    return np.einsum("nrm,nrm->n", r, r) + np.einsum("ni,ni->n", rho, rho)


def _geodesic(problem, ev: Evaluation, normal: Normal, theta: Array, delta: Array, X: Array,
              damping: Array, free: Array, h: float = 0.1) -> Array:
    """Geodesic acceleration (Transtrum & Sethna 2012): a = -(J^T J + D)^-1 J^T r_vv, r_vv the second
    directional derivative of the residuals along delta by finite differences (one extra evaluation)."""
    lower, upper = problem.layout.bounds()
    probe = problem.evaluate(np.clip(theta + h * delta, lower, upper), X, jacobian=False)
    jr, jrho = _jvp(ev, delta, problem.layout)
    rvv = (2.0 / h) * ((probe.r - ev.r) / h - jr)
    rvv_rho = (2.0 / h) * ((probe.rho - ev.rho) / h - jrho)
    gs, gl = _jtv(ev, rvv, rvv_rho, problem.layout)
    return arrow_solve(normal, damping, free, gs, gl)


# --- Levenberg-Marquardt, batched over trials -------------------------------------------


@dataclass(frozen=True)
class LMOptions:
    """Stopping rules (scipy.optimize.least_squares' meanings) and the damping start."""

    max_iterations: int = 100
    ftol: float = 1e-8
    xtol: float = 1e-8
    gtol: float = 1e-8
    initial_damping: float = 1e-3
    stall_chi2: float = 1e-2  # stop when chi^2 fell by less than this over stall_window iterations (0: never)
    stall_window: int = 5
    geodesic: bool = False  # geodesic acceleration (faster along curved valleys)
    geodesic_ratio: float = 0.75  # acceleration used when 2 |a| / |delta| <= this
    snap: float = SNAP  # a step ending this close to a bound lands on it (normalised units)
    batch: int = 10000  # trials advanced together (memory bound)


@dataclass
class LMResult:
    """Per trial: x (T, n) theta at the end, cost (T,) = 0.5 (||r||^2 + ||rho||^2) as in scipy,
    loss (T,) = the paper's loss (eq. 9), status (T,) (0 max iterations, 1 gtol, 2 ftol, 3 xtol),
    nfev, nit (T,), active_mask (T, n) (-1 lower, 1 upper bound, 0 free), history (T, max_iter + 1)
    loss after each iteration (NaN once stopped), seconds spent."""

    x: Array
    cost: Array
    loss: Array
    status: Array
    nfev: Array
    nit: Array
    active_mask: Array
    history: Array
    seconds: float = 0.0

    @property
    def message(self) -> list[str]:
        return [STATUS_MESSAGES.get(int(s), "running") for s in self.status]

    @property
    def success(self) -> Array:
        return self.status > 0

    def take(self, index: Array) -> "LMResult":
        return LMResult(self.x[index], self.cost[index], self.loss[index], self.status[index], self.nfev[index],
                        self.nit[index], self.active_mask[index], self.history[index], self.seconds)

    @staticmethod
    def concatenate(parts: Sequence["LMResult"]) -> "LMResult":
        return LMResult(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                          ("x", "cost", "loss", "status", "nfev", "nit", "active_mask", "history")),
                        sum(p.seconds for p in parts))


def levenberg_marquardt(problem, theta0: Array, X: Array, options: LMOptions = LMOptions(),
                        fixed: Array | None = None) -> LMResult:
    """Minimise ||r||^2 + ||rho||^2 (eq. 9-11) from every start theta0 (T, n), trial t on data X[t] (T, R, H, C).

    Batched projected Levenberg-Marquardt (module docstring), in batches of ``options.batch`` trials.
    ``fixed`` (T, n) or (n,) bool: entries held at their start (a profile: the others are fitted with these
    given, e.g. a new parameter on a grid across its range).
    """
    fixed = np.zeros(theta0.shape, bool) if fixed is None else np.broadcast_to(np.asarray(fixed, bool), theta0.shape)
    parts = [_lm_batch(problem, theta0[s], X[s], options, fixed[s])
             for s in batch_slices(theta0.shape[0], options.batch)]
    return LMResult.concatenate(parts)


def batch_slices(n: int, size: int) -> list[slice]:
    return [slice(i, min(i + size, n)) for i in range(0, n, max(int(size), 1))]


def _lm_batch(problem, theta0: Array, X: Array, options: LMOptions, fixed: Array) -> LMResult:
    start = time.perf_counter()
    layout = problem.layout
    lower, upper = layout.bounds()
    T, n = theta0.shape
    theta = np.clip(np.array(theta0, float), lower, upper)
    ev = problem.evaluate(theta, X)
    F = ev.objective
    mu = np.full(T, options.initial_damping)
    nu = np.full(T, 2.0)
    status = np.where(np.isfinite(F), RUNNING, NONFINITE)
    nfev, nit = np.ones(T, int), np.zeros(T, int)
    history = np.full((T, options.max_iterations + 1), np.nan)
    history[:, 0] = F / problem.n_data
    grad_scale = 2.0 / problem.n_data
    for iteration in range(options.max_iterations):
        act = np.flatnonzero(status == RUNNING)
        if act.size == 0:
            break
        sub = _take(ev, act)
        normal = Normal.assemble(sub, layout)
        g = normal.gradient()
        th = theta[act]
        free = ~(((th <= lower) & (g > 0)) | ((th >= upper) & (g < 0)) | fixed[act])
        done = grad_scale * np.abs(g * free).max(1) <= options.gtol
        diag = normal.diagonal()
        floor = 1e-12 * np.maximum(diag.max(1, keepdims=True), 1e-300)
        damping = mu[act, None] * np.maximum(diag, floor)
        delta = arrow_solve(normal, damping, free)
        leaving = ((th <= lower) & (delta < 0)) | ((th >= upper) & (delta > 0))
        if leaving.any():  # the coupled step pushes an entry out of the box: hold it and solve again
            again = np.flatnonzero(leaving.any(1))
            free[again] &= ~leaving[again]
            delta[again] = arrow_solve(_rows(normal, again), damping[again], free[again])
        if options.geodesic:
            acceleration = _geodesic(problem, sub, normal, th, delta, X[act], damping, free)
            nfev[act] += 1
            usable = (2 * np.linalg.norm(acceleration, axis=1)
                      <= options.geodesic_ratio * np.linalg.norm(delta, axis=1))
            delta = delta + 0.5 * acceleration * usable[:, None]
        new = _snap(th + _truncate(th, delta, lower, upper), delta, lower, upper, options.snap)
        delta = new - th
        predicted = F[act] - _linearised(sub, delta, layout)
        trial = problem.evaluate(new, X[act])
        nfev[act] += 1
        nit[act] += 1
        F_new = trial.objective
        actual = F[act] - F_new
        accept = np.isfinite(F_new) & (actual > 0) & ~done
        ratio = np.where(predicted > 0, actual / np.where(predicted > 0, predicted, 1.0), 0.0)
        # Nielsen's damping update
        mu[act] = np.where(accept, mu[act] * np.maximum(1 / 3, 1 - (2 * ratio - 1) ** 3), mu[act] * nu[act])
        nu[act] = np.where(accept, 2.0, nu[act] * 2.0)
        small_step = np.linalg.norm(delta, axis=1) <= options.xtol * (options.xtol + np.linalg.norm(th, axis=1))
        small_gain = accept & (actual <= options.ftol * F[act])
        keep = act[accept]
        theta[keep] = new[accept]
        F[keep] = F_new[accept]
        _put(ev, keep, _take(trial, np.flatnonzero(accept)))
        new_status = np.full(act.size, RUNNING)
        new_status[small_step | (mu[act] > 1e20)] = XTOL
        new_status[small_gain] = FTOL
        new_status[done] = GTOL
        history[act, iteration + 1] = F[act] / problem.n_data
        if options.stall_chi2 > 0 and iteration + 1 >= options.stall_window:
            gain = (history[act, iteration + 1 - options.stall_window] - history[act, iteration + 1]) * problem.n_data
            # only on an accepted step: rejected ones (the damping growing) are not a flat valley
            new_status[(new_status == RUNNING) & accept & (gain < options.stall_chi2)] = STALLED
        status[act] = new_status
    status[status == RUNNING] = MAX_ITERATIONS
    active = np.where(theta <= lower, -1, np.where(theta >= upper, 1, 0))
    return LMResult(theta, 0.5 * F, F / problem.n_data, status, nfev, nit, active, history,
                    time.perf_counter() - start)


def _rows(normal: Normal, index: Array) -> Normal:
    return Normal(*(getattr(normal, f)[index] for f in ("A", "B", "C", "gs", "gl")))


def _truncate(theta: Array, delta: Array, lower: Array, upper: Array) -> Array:
    """The step shortened along its own direction to end inside the box (N, n).

    Projecting entry by entry instead would change the step's direction: with correlated parameters
    (a flat valley) the projected step no longer lowers the Gauss-Newton model, is rejected, and
    the trial creeps. Along the direction ||r + J t delta||^2 falls for all t in [0, 1].
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(delta < 0, (lower - theta) / delta, np.where(delta > 0, (upper - theta) / delta, np.inf))
    return delta * np.clip(room.min(axis=1, initial=np.inf), 0.0, 1.0)[:, None]


def _snap(theta: Array, delta: Array, lower: Array, upper: Array, margin: float) -> Array:
    """Project into the box; an entry moving towards a bound and ending within ``margin`` of it lands on it
    (then the active set holds it there), so trials do not creep towards a bound in ever shorter steps."""
    theta = np.where((delta > 0) & (theta > upper - margin), upper, theta)
    theta = np.where((delta < 0) & (theta < lower + margin), lower, theta)
    return np.clip(theta, lower, upper)


def _take(ev: Evaluation, index: Array) -> Evaluation:
    return Evaluation(*(None if a is None else a[index] for a in (ev.r, ev.rho, ev.Js, ev.Jl, ev.jd)))


def _put(ev: Evaluation, index: Array, values: Evaluation) -> None:
    for name in ("r", "rho", "Js", "Jl", "jd"):
        getattr(ev, name)[index] = getattr(values, name)
