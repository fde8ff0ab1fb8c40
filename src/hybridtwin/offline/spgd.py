"""Sparse Proper Generalized Decomposition (sPGD) regression (paper eq. 6-7).

A vector output y(p) in R^m of d parameters p in [-1, 1]^d is written in
separated form

    y(p) = sum_{k=1..K} a_k prod_{j=1..d} F_j^k(p_j),      F_j^k(x) = N(x) . c_j^k,   (eq. 6-7)

with N(x) the Chebyshev polynomials T_0..T_n (1D interpolants at n + 1 degrees
of freedom per parameter). Fitting (Ibanez et al.'s sPGD, with the refinements
measured to matter):

- greedy enrichment: each new term is a rank-one fit of the current residual
  by alternating least squares (ALS) with ridge regularisation;
- backfitting: after each enrichment every earlier term is refitted with the
  others fixed (a few ALS iterations), then all amplitudes a_k are solved
  jointly by least squares;
- adaptive order: each new term is fitted with the same degree 1..n in every
  parameter and the degree that best lowers the validation error is kept, so
  early terms stay simple (a product of d high-degree factors overfits small
  samples). With ``degree_search="parameter"`` the term is then refitted
  parameter by parameter with that parameter's degree changed to each of
  0..n, so it takes a high degree only in the parameters that need it. That
  costs d (n + 1) more ALS fits per term (the trials of one choice are
  fitted together, in one batched ALS): benchmarks/library_benchmark.py
  (geometric, 5 runs), n = 10 per parameter against n = 6 per term: pooled
  test error median 0.030 -> 0.018 %, p95 2.47 -> 1.61 %, but the fit
  15 -> 94 s and the evaluation with Jacobian 1.8 -> 2.3 us per set. Per
  parameter at n = 6 gains little (median 0.029 %). The default is "term";
- the number of terms K is chosen on held-out (validation) data, never on the
  training residual: enrichment stops when the validation error has not
  improved for ``patience`` terms, or once it is at most ``tolerance`` (the
  accuracy the application needs), and the best K is kept.
- the highest degree n itself may be a list of candidates (``fit_spgd``): one
  sPGD per candidate, the lowest validation error kept. The greedy path
  depends on n: a high n pays where the data are dense and the response
  sharp (a resonance with thousands of enrichment scenarios), a low n where
  they are few. The candidates' paths are computed once up to the first
  term where they differ.

Optional sample weights turn the least squares into relative errors
(weight 1 / ||y_s||^2). ``predict`` returns y and ``jacobian`` its exact
derivative dy/dp, both batched.

A response with kinks at known values of one parameter takes one sPGD per interval of it:
``hybridtwin.offline.piecewise_spgd``.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from numpy.polynomial import chebyshev

from ..model.effect_base import Array

#: parameter sets per block in evaluate (K = 60, 1000 sets: 1.26 us per set in blocks of 256, 1.10 in 512, 1.05 in 1000)
_CHUNK = 512


class _Workspace(threading.local):
    """Scratch arrays of ``SparsePGD.evaluate``, kept per thread from call to call.

    Fresh arrays of a few hundred kB are mapped anew and page-faulted on every call once the allocator has
    returned the freed ones to the system. On this project's 2-core VM that made a standalone evaluation of
    1000 sets with the Jacobian 2-2.5x slower (2.7-3.5 against 1.26-1.35 us per set, geometric libraries;
    benchmarks/library_benchmark.py, whose process keeps more memory: 1.27-1.48 against 1.17-1.35 us).
    The arrays grow to the largest request (bounded by the block size) and are then reused.
    """

    def __init__(self) -> None:
        self.buffers: dict[str, Array] = {}

    def array(self, name: str, shape: tuple[int, ...]) -> Array:
        """An uninitialised array of ``shape`` (a view of the buffer ``name``)."""
        size = int(np.prod(shape))
        if self.buffers.get(name, np.empty(0)).size < size:
            self.buffers[name] = np.empty(size)
        return self.buffers[name][:size].reshape(shape)


_WORKSPACE = _Workspace()


def chebyshev_basis(x: Array, degree: int) -> Array:
    """T_0..T_degree at x (N,) -> (N, degree+1)."""
    return chebyshev.chebvander(x, degree)


def chebyshev_derivative_basis(x: Array, degree: int) -> Array:
    """dT_i/dx at x (N,) -> (N, degree+1)."""
    derivative = np.stack([chebyshev.chebder(np.eye(degree + 1)[i]) for i in range(degree + 1)], axis=1)
    if degree == 0:
        return np.zeros((x.size, 1))
    return chebyshev.chebvander(x, degree - 1) @ derivative


@dataclass
class FitHistory:
    """Per number of terms K = 1, 2, ...: training and validation relative errors."""

    train_error: list[float] = field(default_factory=list)
    validation_error: list[float] = field(default_factory=list)


@dataclass
class _Path:
    """One greedy enrichment path of ``SparsePGD._fit_paths`` with the degree cap ``cap``. ``lower``: lower caps
    whose choices have agreed with this path's at every term so far (their path is this one); ``best``:
    (validation error, K, A, C, degrees) at the best number of terms K so far."""

    cap: int
    lower: list[int]
    A: Array  # amplitudes a_k, (K, m)
    C: Array  # coefficients c_j^k, (K, d, nb)
    degrees: Array  # (K, d)
    residual: Array  # training residual, (n, m)
    residual_val: Array  # validation residual, (n_val, m)
    history: FitHistory
    best: tuple
    done: bool = False

    @classmethod
    def start(cls, cap: int, lower: list[int], Y: Array, Y_val: Array, d: int, degree: int) -> "_Path":
        A, C, degrees = np.zeros((0, Y.shape[1])), np.zeros((0, d, degree + 1)), np.zeros((0, d), int)
        return cls(cap, lower, A, C, degrees, Y.copy(), Y_val.copy(), FitHistory(), (np.inf, 0, A, C, degrees))

    def fork(self, cap: int) -> "_Path":
        """A copy of this path for ``cap`` and the lower caps below it, which leave this one."""
        history = FitHistory(list(self.history.train_error), list(self.history.validation_error))
        path = _Path(cap, [c for c in self.lower if c < cap], self.A, self.C, self.degrees, self.residual,
                     self.residual_val, history, self.best)
        self.lower = [c for c in self.lower if c > cap]
        return path


class SparsePGD:
    """Separated-representation regression y(p) = sum_k a_k prod_j F_j^k(p_j), p in [-1, 1]^d."""

    def __init__(self, degree: int = 8, max_terms: int = 60, ridge: float = 1e-8, als_iterations: int = 30,
                 als_tol: float = 1e-8, backfit_iterations: int = 3, patience: int = 8,
                 degree_search: str = "term", degree_tolerance: float = 0.0, tolerance: float = 0.0):
        if degree_search not in ("term", "parameter"):
            raise ValueError(f"degree_search must be 'term' or 'parameter', not {degree_search!r}")
        self.degree, self.max_terms, self.ridge, self.tolerance = degree, max_terms, ridge, tolerance
        self.als_iterations, self.als_tol = als_iterations, als_tol
        self.backfit_iterations, self.patience = backfit_iterations, patience
        self.degree_search, self.degree_tolerance = degree_search, degree_tolerance
        self.amplitudes = np.zeros((0, 0))  # a_k, (K, m)
        self.coefficients = np.zeros((0, 0, degree + 1))  # c_j^k, (K, d, n_used+1), zero above each degree
        self.degrees = np.zeros((0, 0), int)  # polynomial degree of each term in each parameter, (K, d)
        self.history = FitHistory()

    @property
    def n_terms(self) -> int:
        return self.amplitudes.shape[0]

    def fit(self, X: Array, Y: Array, X_val: Array, Y_val: Array, weights: Array | None = None,
            weights_val: Array | None = None) -> "SparsePGD":
        """Greedy enrichment + backfitting on (X, Y); K and each term's degree chosen on (X_val, Y_val)."""
        self._adopt(self._fit_paths(X, Y, X_val, Y_val, weights, weights_val, [self.degree])[self.degree])
        return self

    def _fit_paths(self, X: Array, Y: Array, X_val: Array, Y_val: Array, weights: Array | None,
                   weights_val: Array | None, caps: Sequence[int]) -> dict[int, "_Path"]:
        """The greedy path of every degree cap in ``caps`` (all <= ``self.degree``), sharing their common start.

        Up to the first term where two caps choose differently their paths are the same computation: every
        term's trials of degrees 1..n include those of any lower cap, so one path runs with the highest cap
        and a lower cap forks off, with the state at that term, when its own best trial differs. A path ends
        when the validation error has not improved for ``patience`` terms, at ``max_terms``, or once it is
        at most ``tolerance``.
        """
        X, X_val = checked_inputs(X), checked_inputs(X_val)
        Y, Y_val = np.asarray(Y, dtype=float), np.asarray(Y_val, dtype=float)
        d = X.shape[1]
        w = np.ones(X.shape[0]) if weights is None else np.asarray(weights, float)
        B = np.stack([chebyshev_basis(X[:, j], self.degree) for j in range(d)])  # (d, n, nb)
        B_val = np.stack([chebyshev_basis(X_val[:, j], self.degree) for j in range(d)])
        caps = sorted(set(int(c) for c in caps))
        open_paths = [_Path.start(caps[-1], caps[:-1], Y, Y_val, d, self.degree)]
        done = []
        while open_paths:
            path = open_paths.pop()
            while not path.done:
                trials = self._term_trials(B, B_val, path.residual, path.residual_val, w, weights_val, path.cap)
                open_paths += self._advance(path, trials, B, Y, w, B_val, Y_val, weights_val)
            done.append(path)
        return {cap: path for path in done for cap in [path.cap, *path.lower]}

    def _adopt(self, path: "_Path") -> None:
        """Take the best number of terms of ``path`` as this model."""
        _, _, self.amplitudes, C, self.degrees = path.best
        self.coefficients = C[:, :, : self.degrees.max(initial=0) + 1]  # evaluation cost grows with the width
        self.history = path.history

    def _advance(self, path: "_Path", trials: list[tuple], B: Array, Y: Array, w: Array, B_val: Array,
                 Y_val: Array, w_val: Array | None) -> list["_Path"]:
        """Add to ``path`` the term its cap chooses among ``trials``; the highest lower cap that chooses
        another term forks off with it (and may fork again). The forked paths."""
        choice = self._choose(trials, path.cap)
        forks = []
        for cap in sorted(path.lower, reverse=True):
            if self._choose(trials, cap) is not choice:
                fork = path.fork(cap)
                forks = [fork, *self._advance(fork, trials, B, Y, w, B_val, Y_val, w_val)]
                break
        _, a, c, p = choice
        path.degrees = np.vstack([path.degrees, p])
        path.A, path.C = self._backfit(B, Y, w, np.vstack([path.A, a[None]]), np.concatenate([path.C, c[None]]),
                                       path.degrees)
        path.residual = Y - _evaluate(B, path.A, path.C)
        path.history.train_error.append(relative_error(path.residual, Y, w))
        path.residual_val = Y_val - _evaluate(B_val, path.A, path.C)
        val_error = relative_error(path.residual_val, Y_val, w_val)
        path.history.validation_error.append(val_error)
        K = path.A.shape[0]
        if val_error < path.best[0]:
            path.best = (val_error, K, path.A.copy(), path.C.copy(), path.degrees.copy())
        path.done = (K >= self.max_terms or K - path.best[1] >= self.patience or path.best[0] <= self.tolerance)
        return forks

    def _term_trials(self, B: Array, B_val: Array, residual: Array, residual_val: Array, w: Array,
                     w_val: Array | None, cap: int) -> list[tuple]:
        """Rank-one fits of the residual with one degree 1..cap for all parameters; with
        ``degree_search="parameter"`` the best of them is then refitted one parameter at a time with each
        degree 0..cap, the others fixed (a single trial is left). Every trial is a full ALS fit; the trials
        of one choice are fitted together (``_rank_one``). Each choice is the lowest degree whose
        validation error is within ``degree_tolerance`` of the best trial's: higher degrees that
        gain less only fit noise in the validation data (and cost evaluation time)."""
        d = B.shape[0]
        fit = partial(self._trials, B, B_val, residual, residual_val, w, w_val)
        trials = fit(np.repeat(np.arange(min(1, cap), cap + 1)[:, None], d, 1))
        if self.degree_search == "term":
            return trials
        best = self._lowest_good(trials)
        for j in range(d):
            others = [p for p in range(cap + 1) if p != best[3][j]]
            degrees = np.repeat(best[3][None], len(others), 0)
            degrees[:, j] = others
            best = self._lowest_good(sorted(fit(degrees) + [best], key=lambda t: t[3][j]))
        return [best]

    def _choose(self, trials: list[tuple], cap: int) -> tuple:
        """The trial that a path with degree cap ``cap`` takes: the lowest good one of degree <= cap."""
        return self._lowest_good([t for t in trials if t[3].max() <= cap])

    def _lowest_good(self, trials: list[tuple]) -> tuple:
        """The first trial (lowest degree) within ``degree_tolerance`` of the lowest validation error."""
        threshold = min(t[0] for t in trials) * (1 + self.degree_tolerance)
        return next(t for t in trials if t[0] <= threshold)

    def _trials(self, B: Array, B_val: Array, residual: Array, residual_val: Array, w: Array,
                w_val: Array | None, degrees: Array) -> list[tuple[float, Array, Array, Array]]:
        """Rank-one fits with the given degrees (T, d): per trial (validation error, a, c (d, n+1), degrees)."""
        a, c = self._rank_one(B, degrees, residual, w)
        return [(relative_error(residual_val - _evaluate(B_val, a[t][None], c[t][None]), residual_val, w_val),
                 a[t], c[t], degrees[t]) for t in range(len(degrees))]

    def _rank_one(self, B: Array, degrees: Array, R: Array, w: Array) -> tuple[Array, Array]:
        """Best a prod_j (N_j c_j) for the residual R (n, m) by ALS with ridge (the enrichment step),
        for T trials at once that differ in their degrees (T, d): a (T, m), c (T, d, n+1).

        Trial t's factor j lives on N_j's first degrees[t, j] + 1 functions: its normal matrix is
        masked to them (identity elsewhere, zero right-hand side), so each trial solves exactly its
        own truncated least squares, in one batched solve per parameter. A trial stops updating once
        its term changes by less than ``als_tol``. The normal matrices use T_b T_c = (T_{b+c} + T_{|b-c|}) / 2:
        sum_n v_n T_b T_c comes from the 2n + 1 moments sum_n v_n T_e, not from (n + 1)^2 products per point.
        """
        d, n, nb = B.shape
        T = degrees.shape[0]
        mask = np.arange(nb)[None, None, :] <= degrees[:, :, None]  # (T, d, nb)
        mask2 = mask[:, :, :, None] & mask[:, :, None, :]  # (T, d, nb, nb): a trial's active block
        active = mask.sum(2)  # (T, d)
        moments_basis = np.stack([chebyshev_basis(B[j, :, min(1, nb - 1)], 2 * (nb - 1)) for j in range(d)])
        pairs = _moment_pairs(nb)  # moments (2 nb - 1) -> normal matrix (nb, nb) in one product
        _, s, vt = np.linalg.svd(R * np.sqrt(w)[:, None], full_matrices=False)
        a = np.repeat((s[0] * vt[0] / np.sqrt(w.sum()))[None], T, 0)
        c = np.zeros((T, d, nb))
        c[:, :, 0] = 1.0  # T_0 = 1: every factor starts constant
        F = np.ones((T, d, n))
        previous_prod, previous_a = np.zeros((T, n)), np.zeros_like(a)
        running = np.ones(T, bool)
        diagonal = np.arange(nb)
        g, gw, scratch = np.empty((T, n)), np.empty((T, n)), np.empty((T, n))  # reused (T, n) intermediates
        for _ in range(self.als_iterations):
            t_proj = a @ R.T  # the residual projected on each trial's output direction, (T, n)
            aa = np.einsum("tm,tm->t", a, a)
            suffix = _suffix_products(F)  # suffix[j] = F_{j+1} ... F_{d-1}; the prefix follows the updates
            prod = np.ones((T, n))
            for j in range(d):
                np.multiply(prod, suffix[j], out=g)  # the product of the other factors
                np.multiply(g, w, out=gw)
                g *= gw
                moments = g @ moments_basis[j]  # sum_n w g^2 T_e, (T, 2 nb - 1)
                moments *= aa[:, None]
                G = (moments @ pairs).reshape(T, nb, nb)  # sum_n v_tn T_b T_c
                rhs = (np.multiply(gw, t_proj, out=scratch) @ B[j]) * mask[:, j]
                G *= mask2[:, j]
                ridge = self.ridge * (np.trace(G, axis1=1, axis2=2) / active[:, j] + 1e-300)
                G[:, diagonal, diagonal] += np.where(mask[:, j], ridge[:, None], 1.0)
                cj = np.linalg.solve(G, rhs[..., None])[..., 0]
                Fj = cj @ B[j].T
                scale = np.maximum(Fj.max(axis=1), -Fj.min(axis=1))  # max |F_j|
                scale[scale == 0] = 1.0
                cj /= scale[:, None]
                Fj /= scale[:, None]
                if running.all():
                    c[:, j], F[:, j] = cj, Fj
                    prod *= Fj
                else:
                    c[running, j], F[running, j] = cj[running], Fj[running]
                    prod *= F[:, j]
            np.multiply(prod, w, out=scratch)
            a_new = (scratch @ R) / (np.einsum("tn,tn->t", scratch, prod) + 1e-300)[:, None]
            a[running] = a_new[running]
            running &= _term_change(prod, a, previous_prod, previous_a) > self.als_tol
            if not running.any():
                break
            previous_prod, previous_a = prod, a.copy()
        return a, c

    def _backfit(self, B: Array, Y: Array, w: Array, A: Array, C: Array, degrees: Array) -> tuple[Array, Array]:
        """Refit all terms together: per parameter j the factors F_j^k of every term, then all a_k.

        With every factor but the j-th fixed the model is linear in {c_j^k}_k:
        y_n = sum_{k,b} Z[n, (k, b)] a_k c_j^k[b], Z[n, (k, b)] = g_k(n) N_b(p_nj),
        g_k the product of term k's other factors: a ridge least-squares problem.
        Term k keeps its degrees: coefficients of parameter j above degrees[k, j] stay zero, and only
        the columns (k, b <= degrees[k, j]) enter the normal matrix (``_normal_matrix``). The
        factors of every term are kept and only the refitted parameter's row is updated.
        """
        K, d, nb = C.shape
        index = np.arange(nb)
        F = np.einsum("jnb,kjb->kjn", B, C)  # every factor at every point, (K, d, n)
        for _ in range(self.backfit_iterations):
            for j in range(d):
                term, b = np.nonzero(index[None, :] <= degrees[:, j, None])  # the active (k, b)
                g = _product_except(F, j)  # (K, n)
                G = self._normal_matrix(B[j], g, w, term, b, 2 * int(degrees[:, j].max()))
                G *= (A @ A.T)[np.ix_(term, term)]
                rhs = ((g * w * (Y @ A.T).T) @ B[j])[term, b]
                G[np.diag_indices_from(G)] += self.ridge * (np.trace(G) / G.shape[0] + 1e-300)
                C[:, j] = 0.0
                C[term, j, b] = np.linalg.solve(G, rhs)
                Fj = C[:, j] @ B[j].T  # (K, n)
                scale = np.abs(Fj).max(axis=1)
                scale[scale == 0] = 1.0
                C[:, j] /= scale[:, None]
                F[:, j] = Fj / scale[:, None]
                A = A * scale[:, None]
            A = self._amplitudes(B, Y, w, C)
        return A, C

    @staticmethod
    def _normal_matrix(Bj: Array, g: Array, w: Array, term: Array, b: Array, top: int) -> Array:
        """sum_n w_n g_k(n) g_l(n) T_b(p_nj) T_c(p_nj) over the active columns (k, b), (l, c).

        By T_b T_c = (T_{b+c} + T_{|b-c|}) / 2 it follows from the K^2 (top + 1) moments
        sum_n w g_k g_l T_e, e <= top (twice the highest degree): used where they take fewer products
        per point than the Gram matrix of the columns (active^2), i.e. at many terms of high degree
        (a 5522-point resonance run's fits, degrees 8 and 12: 44 -> 30 s), else the columns' Gram matrix.
        """
        K, active = g.shape[0], term.size
        if (top + 1) * K * K > active * active:
            Z = g[term].T * Bj[:, b]
            return Z.T @ (Z * w[:, None])
        moments_basis = chebyshev_basis(Bj[:, min(1, Bj.shape[1] - 1)], top)
        gw = g * w
        moments = np.stack([(gw * e) @ g.T for e in moments_basis.T], axis=-1)  # (K, K, top + 1)
        plus, minus = _product_index(Bj.shape[1])
        k, l, bb, cc = term[:, None], term[None, :], b[:, None], b[None, :]
        return 0.5 * (moments[k, l, plus[bb, cc]] + moments[k, l, minus[bb, cc]])

    def _amplitudes(self, B: Array, Y: Array, w: Array, C: Array) -> Array:
        """All a_k at once by ridge least squares given the factors."""
        W = _products(B, C).T  # (n, K)
        G = W.T @ (W * w[:, None])
        return np.linalg.solve(G + self._ridge(G), W.T @ (Y * w[:, None]))

    def _ridge(self, G: Array) -> Array:
        """Ridge term scaled to the normal matrix: ridge * mean(diag G) * I."""
        return self.ridge * (np.trace(G) / G.shape[0] + 1e-300) * np.eye(G.shape[0])

    def evaluate(self, X: Array, jacobian: bool = False) -> tuple[Array, Array | None]:
        """y = sum_k a_k prod_j F_j^k (N, m) at X (N, d) and, with ``jacobian``, dy/dp stacked as (d, N, m).

        For a few outputs of many (the sensor rows of a POD basis), evaluate ``projected`` instead.
        All factors come from one Chebyshev recurrence over every parameter at once and one batched
        product per parameter; the Jacobian uses prefix and suffix products of the factors
        (no division) and one matrix product for y and all d derivatives together.
        """
        X = checked_inputs(X)
        A = self.amplitudes
        N, d = X.shape
        out = np.zeros((d + 1 if jacobian else 1, N, A.shape[1]))  # y, then dy/dp_1..d
        if self.coefficients.shape[0] > 0:
            C = np.ascontiguousarray(self.coefficients.transpose(1, 2, 0))  # (d, n+1, K)
            for start in range(0, N, _CHUNK):  # blocks of _CHUNK sets: the workspace stays bounded
                rows = slice(start, min(start + _CHUNK, N))
                self._evaluate_block(X[rows], A, C, out[:, rows])
        return out[0], (out[1:] if jacobian else None)

    @staticmethod
    def _evaluate_block(X: Array, A: Array, C: Array, out: Array) -> None:
        """y into out[0] (N, m) and, if out has d + 1 rows, dy/dp_j into out[1 + j]; every intermediate
        lives in this thread's ``_WORKSPACE``."""
        N, d = X.shape
        K = C.shape[-1]
        jacobian = out.shape[0] > 1
        rows = N * (1 + jacobian)  # T_b, then dT_b/dx below
        basis = _chebyshev_stack(X, C.shape[1] - 1, jacobian, _WORKSPACE.array("basis", (d, rows, C.shape[1])))
        F = np.matmul(basis, C, out=_WORKSPACE.array("factors", (d, rows, K)))  # (d, N or 2N, K)
        product = _WORKSPACE.array("product", (N, K))
        if not jacobian:
            np.copyto(product, F[0])
            for j in range(1, d):
                product *= F[j]
            np.matmul(product, A, out=out[0])
            return
        F, dF = F[:, :N], F[:, N:]
        stacked = _WORKSPACE.array("stacked", (d + 1, N, K))
        stacked[d] = dF[d - 1]
        np.copyto(product, F[d - 1])  # the suffix product F_{j+1} ... F_{d-1}
        for j in range(d - 2, -1, -1):
            np.multiply(product, dF[j], out=stacked[1 + j])
            product *= F[j]
        stacked[0] = product
        np.copyto(product, F[0])  # the prefix product F_0 ... F_{j-1}
        for j in range(1, d):
            stacked[1 + j] *= product
            if j < d - 1:
                product *= F[j]
        np.matmul(stacked, A, out=out)

    def predict(self, X: Array) -> Array:
        """y(p) at X (N, d) -> (N, m)."""
        return self.evaluate(X)[0]

    def predict_with_jacobian(self, X: Array) -> tuple[Array, Array]:
        """y(p) (N, m) and dy/dp (N, m, d) at X (N, d), exact."""
        y, J = self.evaluate(X, jacobian=True)
        return y, np.moveaxis(J, 0, -1)

    def to_arrays(self) -> dict[str, Array]:
        return {"amplitudes": self.amplitudes, "coefficients": self.coefficients}

    @classmethod
    def from_arrays(cls, amplitudes: Array, coefficients: Array) -> "SparsePGD":
        model = cls(degree=coefficients.shape[-1] - 1)
        model.amplitudes, model.coefficients = np.asarray(amplitudes), np.asarray(coefficients)
        nonzero = model.coefficients != 0
        model.degrees = np.where(nonzero.any(-1), nonzero.shape[-1] - 1 - np.argmax(nonzero[..., ::-1], -1), 0)
        return model

    def projected(self, P: Array) -> "SparsePGD":
        """The same model with outputs y P (m, m'), e.g. the sensor rows of a POD basis: exact, the output
        is linear in the amplitudes a_k, and evaluating m' outputs is cheaper."""
        return SparsePGD.from_arrays(np.ascontiguousarray(self.amplitudes @ P), self.coefficients)

    def with_trailing_fixed(self, x: Array) -> "SparsePGD":
        """The model of the first d - len(x) parameters with the last ones fixed at x (normalised): each
        term's last factors are numbers, a_k prod_j F_j^k = (a_k prod_{j > d'} F_j^k(x_j)) prod_{j <= d'} F_j^k."""
        x = np.atleast_1d(np.asarray(x, float))
        d = self.coefficients.shape[1] - x.size
        C = self.coefficients
        factors = np.einsum("jb,kjb->kj", chebyshev_basis(x, C.shape[-1] - 1), C[:, d:])
        return SparsePGD.from_arrays(self.amplitudes * factors.prod(axis=1)[:, None], C[:, :d])


def fit_spgd(X: Array, Y: Array, X_val: Array, Y_val: Array, weights: Array | None = None,
             weights_val: Array | None = None, degree: int | Sequence[int] = 8, **options) -> SparsePGD:
    """An sPGD per candidate highest degree (``degree``: one or several), the one with the lowest validation
    error kept (the lowest degree on ties; errors at or below ``tolerance`` tie); ``options`` as ``SparsePGD``'s.

    With ``degree_search="term"`` the candidates share their greedy paths up to the first term where they
    choose differently (``SparsePGD._fit_paths``): the same fits as one sPGD per candidate, computed once
    where they agree (bundled data, candidates [8, 12], 5 runs sampled per variant: one path to the end at 3
    runs of Final and of Geometric+slope, at 1 of Expansion; the Geometric paths shared 0-60 of their 60 terms).
    """
    candidates = [degree] if isinstance(degree, (int, np.integer)) else sorted(set(int(d) for d in degree))
    if not candidates:
        raise ValueError("sPGD: no candidate degree")
    if options.get("degree_search", "term") == "term":
        paths = SparsePGD(degree=candidates[-1], **options)._fit_paths(X, Y, X_val, Y_val, weights, weights_val,
                                                                         candidates)
        fits = [SparsePGD(degree=n, **options) for n in candidates]
        for model in fits:
            model._adopt(paths[model.degree])
    else:
        fits = [SparsePGD(degree=n, **options).fit(X, Y, X_val, Y_val, weights, weights_val) for n in candidates]
    tolerance = options.get("tolerance", 0.0)
    return min(fits, key=lambda model: max(min(model.history.validation_error, default=np.inf), tolerance))


def _chebyshev_stack(X: Array, degree: int, derivative: bool = False, out: Array | None = None) -> Array:
    """T_0..T_degree of every column of X (N, d) -> (d, N, degree+1); with ``derivative`` the
    derivatives dT_b/dx stacked below -> (d, 2N, degree+1). Three-term recurrences
    T_b = 2x T_{b-1} - T_{b-2} and T_b' = 2 T_{b-1} + 2x T_{b-1}' - T_{b-2}'."""
    N, d = X.shape
    x = X.T  # (d, N)
    out = np.empty((d, 2 * N if derivative else N, degree + 1)) if out is None else out
    T = out[:, :N]
    T[:, :, 0] = 1.0
    if degree >= 1:
        T[:, :, 1] = x
    two_x = 2.0 * x
    for b in range(2, degree + 1):
        T[:, :, b] = two_x * T[:, :, b - 1] - T[:, :, b - 2]
    if derivative:
        D = out[:, N:]
        D[:, :, 0] = 0.0
        if degree >= 1:
            D[:, :, 1] = 1.0
        for b in range(2, degree + 1):
            D[:, :, b] = 2.0 * T[:, :, b - 1] + two_x * D[:, :, b - 1] - D[:, :, b - 2]
    return out


def _product_index(nb: int) -> tuple[Array, Array]:
    """b + c and |b - c| for b, c < nb: T_b T_c = (T_{b+c} + T_{|b-c|}) / 2."""
    index = np.arange(nb)
    return index[:, None] + index[None, :], np.abs(index[:, None] - index[None, :])


def _moment_pairs(nb: int) -> Array:
    """P (2 nb - 1, nb^2) with (m P)[b nb + c] = (m[b + c] + m[|b - c|]) / 2 (T_b T_c = (T_{b+c} + T_{|b-c|}) / 2),
    exact: each column adds two halves of moments (or one whole one, b = c = 0)."""
    plus, minus = _product_index(nb)
    pairs = np.zeros((2 * nb - 1, nb * nb))
    columns = np.arange(nb * nb)
    np.add.at(pairs, (plus.ravel(), columns), 0.5)
    np.add.at(pairs, (minus.ravel(), columns), 0.5)
    return pairs


def _term_change(prod: Array, a: Array, previous_prod: Array, previous_a: Array) -> Array:
    """Relative change ||p a^T - p' a'^T||_F / ||p a^T||_F of T rank-one terms, (T,), from inner products
    without forming the (T, n, m) terms. The difference is dp a^T + p' da^T (dp = p - p', da = a - a'),
    so its squared norm is ||dp||^2 ||a||^2 + ||p'||^2 ||da||^2 + 2 (dp . p')(a . da): no cancellation
    between two nearly equal norms when the change is small (the expanded form loses it below
    ~sqrt(eps), at the tolerance's scale)."""
    dp, da = prod - previous_prod, a - previous_a

    def dot(x: Array, y: Array) -> Array:
        return np.einsum("ti,ti->t", x, y)

    change2 = dot(dp, dp) * dot(a, a) + dot(previous_prod, previous_prod) * dot(da, da) \
        + 2.0 * dot(dp, previous_prod) * dot(a, da)
    return np.sqrt(np.maximum(change2, 0.0) / (dot(prod, prod) * dot(a, a) + 1e-300))


def _suffix_products(F: Array) -> Array:
    """suffix[j] = prod_{i > j} F_i over axis -2 of F (..., d, n): (d, ..., n), suffix[d - 1] = 1."""
    d = F.shape[-2]
    suffix = np.empty((d,) + F.shape[:-2] + F.shape[-1:])
    suffix[d - 1] = 1.0
    for j in range(d - 2, -1, -1):
        np.multiply(suffix[j + 1], F[..., j + 1, :], out=suffix[j])
    return suffix


def _product_except(F: Array, j: int) -> Array:
    """prod over axis -2 of F (..., d, n) leaving out row j (no division: a factor may vanish)."""
    rows = [i for i in range(F.shape[-2]) if i != j]
    return np.prod(F[..., rows, :], axis=-2) if rows else np.ones(F.shape[:-2] + F.shape[-1:])


def _products(B: Array, C: Array) -> Array:
    """prod_j F_j^k at the points of the bases B (d, n, nb): (K, n)."""
    return np.prod(np.einsum("jnb,kjb->kjn", B[:, :, : C.shape[-1]], C, optimize=True), axis=1)


def _evaluate(B: Array, A: Array, C: Array) -> Array:
    """sum_k a_k prod_j F_j^k at the points of B: (n, m)."""
    return _products(B, C).T @ A


def relative_error(residual: Array, Y: Array, w: Array | None = None) -> float:
    """sqrt(sum_n w_n |r_n|^2 / sum_n w_n |y_n|^2), the error the fits and their validation use."""
    w = np.ones(Y.shape[0]) if w is None else w
    return float(np.sqrt((w * (residual * residual).sum(1)).sum() / (w * (Y * Y).sum(1)).sum()))


def checked_inputs(X: Array) -> Array:
    X = np.atleast_2d(np.asarray(X, dtype=float))
    if X.size and (np.nanmax(np.abs(X)) > 1 + 1e-9 or not np.isfinite(X).all()):
        raise ValueError("sPGD inputs must be finite and normalised to [-1, 1]")
    return X
