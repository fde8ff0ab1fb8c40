"""Periodic steady state by harmonic balance with alternating frequency-time (HMH).

For a ``System`` M q'' + C q' + K q = Re(sum_h F_h e^{i h Omega t}) + F_nl(q)
the response is sought as q(t) = Re(sum_{h=0..H} Q_h e^{i h Omega t}).

1. Exact condensation. Per harmonic the dynamic stiffness
   D_h = K + i h Omega C - (h Omega)^2 M is solved once for the forcing and
   for unit loads on the c DOFs that the nonlinear forces touch:
   Q_h = D_h^-1 F_h + D_h^-1 B G_h = A_h + R_h G_h. On those DOFs this leaves
   x_h = a_h + H_h G_h(x), with H_h = B^T R_h the receptance (c x c). A block of ``banded.BANDED_MIN_DOF``
   DOFs or more (a finite-element rotor's) is solved in band storage (``banded``): O(n k^2), not O(n^3).
2. AFT. G_h(x) is the Fourier series of F_nl(x(t)) at N >= (d+1) H + 1 time
   samples (d the polynomial degree: 4H + 1 for cubic terms, alias-free),
   and its exact derivative dG/dx = E^+ diag(dF/dx) E.
3. Newton on r(x) = x - a - H G(x) = 0 with backtracking, batched over
   scenarios with a per-scenario convergence mask; or the paper's fixed-point
   iteration x <- (1 - beta) x + beta (a + H G(x)), falling back to Newton.
4. Stability of each converged solution: its Floquet multipliers (``floquet``).
   A solution with a multiplier |mu| >= 1 is flagged unstable (``SteadyState.stable``
   False, its message says so): the machine would not stay on it.

Amplitudes are 0-peak; t = 0 when the unbalance points to +x.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from . import banded, floquet
from .aft import aft_matrices, default_n_time
from ..model.effect_base import Array
from ..model.model import System

CONVERGED, MAX_ITER, SINGULAR, DIVERGED, LINEAR_SINGULAR, INVALID, STALLED = 0, 1, 2, 3, 4, 5, 6

# amplitude growth (vs the linear response) taken as "no bounded periodic solution found"
_DIVERGENCE_FACTOR = 1e3
_MAX_HALVINGS = 8  # backtracking steps of the damped Newton
#: the highest harmonic H of the harmonic balance when nothing else is said: the bundled config's ``harmonics`` (a
#: required key, no schema default: the workflow always passes the config's)
DEFAULT_HARMONICS = 5
BLOCK = 256  # most scenarios per batched solve (``floquet_radius``; a sweep's ``continuation._in_blocks``)


#: SteadyState's fields with one row per scenario
_PER_SCENARIO = ("harmonics", "Omega", "success", "status", "message", "iterations", "residual", "branch", "state",
                 "floquet_radius")


@dataclass
class SteadyState:
    """Periodic steady states of S scenarios (result object, like scipy's OptimizeResult).

    harmonics: (S, H+1, n) complex Q_h with q(t) = Re(sum_h Q_h exp(i h Omega t));
    NaN for scenarios that failed. ``message`` says why, ``branch`` how the
    solution was reached ("direct": from the linear response; "run-up" /
    "run-down": continued from the previous speed of a sweep). ``success``: the
    harmonic-balance equations are solved; ``floquet_radius``: the largest |Floquet
    multiplier| of a converged solution (NaN: failed, or its stability not assessed);
    ``stable``: converged and assessed stable (radius < 1). An unstable solution keeps
    success (it solves the equations, and continuation may go on from it) but its
    message starts with "unstable".
    """

    harmonics: Array
    Omega: Array
    success: Array
    status: Array
    message: Array
    iterations: Array
    residual: Array
    branch: Array
    state: Array  # (S, c, 2H+1) condensed real Fourier coefficients, for continuation
    n_time: int
    floquet_radius: Array | None = None  # (S,) largest |Floquet multiplier|; NaN where not assessed

    def __post_init__(self) -> None:
        if self.floquet_radius is None:
            self.floquet_radius = np.full(self.Omega.shape, np.nan)

    @property
    def stable(self) -> Array:
        """(S,) converged and asymptotically stable (every Floquet multiplier inside the unit circle)."""
        return self.success & (np.nan_to_num(self.floquet_radius, nan=np.inf) < 1.0)

    @property
    def n_scenarios(self) -> int:
        return self.Omega.shape[0]

    @property
    def H(self) -> int:
        return self.harmonics.shape[1] - 1

    def time_series(self, t: Array, dofs: Sequence[int] | None = None) -> Array:
        """q(t) at times ``t`` [s] (S, len(t), d) by evaluating the Fourier series."""
        X = self.harmonics if dofs is None else self.harmonics[:, :, list(dofs)]
        h = np.arange(self.H + 1)
        phase = np.exp(1j * h[None, None, :] * self.Omega[:, None, None] * np.asarray(t)[None, :, None])
        return np.einsum("sth,shd->std", phase, X, optimize=True).real

    def failures(self) -> dict[int, str]:
        """Failed scenarios and why."""
        return {int(i): str(self.message[i]) for i in np.flatnonzero(~self.success)}

    def take(self, rows: Array) -> "SteadyState":
        """The scenarios ``rows`` only."""
        return SteadyState(**{f: getattr(self, f)[rows] for f in _PER_SCENARIO}, n_time=self.n_time)

    def put(self, where: Array, source: "SteadyState") -> None:
        """Scenarios ``where`` of this result become ``source``'s (the same scenarios at the same speeds: every
        per-scenario field but ``Omega``), in place."""
        for f in _PER_SCENARIO:
            if f != "Omega":
                getattr(self, f)[where] = getattr(source, f)

    @staticmethod
    def concatenate(parts: Sequence["SteadyState"], order: Array | None = None) -> "SteadyState":
        """Stack results of disjoint scenario sets; ``order`` permutes the result."""
        stacked = {f: np.concatenate([getattr(p, f) for p in parts]) for f in _PER_SCENARIO}
        if order is not None:
            stacked = {f: v[order] for f, v in stacked.items()}
        return SteadyState(**stacked, n_time=parts[0].n_time)


class Condensed:
    """The harmonic-balance problem on the c nonlinear DOFs: x = a + H G(x) in real form."""

    def __init__(self, system: System, H: int, n_time: int | None, linear: bool = True):
        self.system, self.H = system, H
        self.dofs = np.unique(np.concatenate([f.dofs for f in system.forces])) if system.forces else np.array([], int)
        self.local = [np.searchsorted(self.dofs, f.dofs) for f in system.forces]
        self.N = n_time or default_n_time(H, system.forces)
        self.E, self.E_plus, self.W = aft_matrices(H, self.N)
        self.linear_ok = np.ones(system.n_scenarios, bool)
        if not linear:  # the AFT of the local forces only (``sensitivity``): no linear solves
            return
        self.X_lin, self.R = self._linear_solves()
        self.a = _to_real(self.X_lin[:, :, self.dofs])  # (S, c, 2H+1)
        Hc = self.R[:, :, self.dofs, :]  # the receptance on the nonlinear DOFs, (S, H+1, c, c)
        self.H0, self.Hh = Hc[:, 0].real.copy(), Hc[:, 1:].copy()  # h = 0 (real), h = 1..H (``_receptance_times``)

    def _linear_solves(self) -> tuple[Array, Array]:
        """Q_lin,h = D_h^-1 F_h and R_h = D_h^-1 B for h = 0..H, block by uncoupled block; blocks whose matrices
        are equal in every scenario (the two bending planes of an isotropic rotor) share one factorisation, their
        right-hand sides side by side (``_twin_blocks``)."""
        s = self.system
        S, n, c = s.n_scenarios, s.n_dof, len(self.dofs)
        unknown = sorted(h for h in s.forcing if h > self.H or h < 0)
        if unknown:
            raise ValueError(f"the forcing has harmonic(s) {unknown} outside 0..H = {self.H}: raise H")
        X_lin = np.zeros((S, self.H + 1, n), complex)
        R = np.zeros((S, self.H + 1, n, c), complex)
        pattern = banded.pattern_of(s.K, s.C, s.M)
        for group in _twin_blocks(_components(pattern), s.K, s.C, s.M):
            first = group[0]
            # one block of every DOF (a rotor whose planes the bearings or the speed couple): the matrices as they are
            Kb, Cb, Mb = (s.K, s.C, s.M) if first.size == n else (
                A[:, first[:, None], first[None, :]] for A in (s.K, s.C, s.M))
            plan = banded.band_plan(pattern[np.ix_(first, first)])  # None: a small block, solved dense
            pencil = None if plan is None else banded.BandedPencil(plan, Kb, Cb, Mb)
            cols = [np.flatnonzero(np.isin(self.dofs, block)) for block in group]  # nonlinear DOFs in each block
            B = [(block[:, None] == self.dofs[k][None, :]).astype(float) for block, k in zip(group, cols)]
            for h in range(self.H + 1):
                F = s.forcing.get(h)
                solved = [i for i, k in enumerate(cols) if F is not None or k.size]
                if not solved:
                    continue
                rhs = [np.concatenate([(np.zeros((S, first.size)) if F is None else F[:, group[i]])[:, :, None].astype(
                    complex), np.broadcast_to(B[i], (S,) + B[i].shape)], axis=2) for i in solved]
                sol = _dynamic_solve(Kb, Cb, Mb, pencil, h * s.Omega, rhs[0] if len(rhs) == 1 else
                                     np.concatenate(rhs, axis=2), self.linear_ok)
                start = 0
                for i, part in zip(solved, rhs):
                    block, k, width = group[i], cols[i], part.shape[2]
                    X_lin[:, h, block] = sol[:, :, start]
                    R[:, h, block[:, None], k[None, :]] = sol[:, :, start + 1:start + width]
                    start += width
        return X_lin, R

    def _force_series(self, x: Array, idx: Array, jacobian: bool) -> tuple[Array, Array | None]:
        """Nonlinear forces (S', c, N) and their derivatives (S', c, c, N) at x's time samples."""
        c, N = len(self.dofs), self.N
        xt = x @ self.E.T
        F = np.zeros((len(idx), c, N))
        J = np.zeros((len(idx), c, c, N)) if jacobian else None
        rows = self.system.rows[idx]
        for force, loc in zip(self.system.forces, self.local):
            f, j = force.evaluate(xt[:, loc], rows)
            F[:, loc] += f
            if jacobian:
                J[:, loc[:, None], loc[None, :]] += j
        return F, J

    def evaluate(self, x: Array, idx: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """Residual r = x - a - H G(x) (S', c, 2H+1) and, optionally, dr/dx = I - H dG/dx (S', m, m)."""
        return self._from_forces(x, idx, *self._force_series(x, idx, jacobian))

    def _from_forces(self, x: Array, idx: Array, F: Array, J: Array | None) -> tuple[Array, Array | None]:
        """``evaluate`` from the force series F at x and, unless None, its derivatives J (``_force_series``)."""
        jacobian = J is not None
        H0, Hh = self.H0[idx], self.Hh[idx]
        r = x - self.a[idx] - _receptance_times(H0, Hh, (F @ self.E_plus.T)[..., None])[..., 0]
        if not jacobian:
            return r, None
        S, c, K2 = x.shape
        m = c * K2
        # a product per scenario (a stack), not one over the batch: a scenario's round-off must not depend on its batch
        dG = (J.reshape(S, c * c, self.N) @ self.W).reshape(S, c, c, K2, K2).transpose(0, 1, 3, 2, 4).reshape(
            S, c, K2, m)
        Jr = _receptance_times(H0, Hh, dG).reshape(S, m, m)
        np.negative(Jr, out=Jr)
        Jr[:, np.arange(m), np.arange(m)] += 1.0
        return r, Jr

    def full_harmonics(self, x: Array, idx: Array) -> Array:
        """Q_h on all DOFs (S', H+1, n): Q_h = Q_lin,h + R_h G_h(x)."""
        if len(self.dofs) == 0:
            return self.X_lin[idx]
        F, _ = self._force_series(x, idx, jacobian=False)
        G = _to_complex(F @ self.E_plus.T)  # (S', c, H+1)
        return self.X_lin[idx] + np.einsum("shnc,sch->shn", self.R[idx], G, optimize=True)


def uncoupled_blocks(*matrices: Array) -> list[Array]:
    """DOF groups that no matrix couples in any scenario (connected components of the sparsity)."""
    return _components(banded.pattern_of(*matrices))


def _components(pattern: Array) -> list[Array]:
    """The connected components of a sparsity pattern (n, n), each its DOFs in ascending order."""
    from scipy.sparse.csgraph import connected_components

    n_blocks, labels = connected_components(pattern | pattern.T, directed=False)
    return [np.flatnonzero(labels == b) for b in range(n_blocks)]


def _twin_blocks(blocks: list[Array], *matrices: Array) -> list[list[Array]]:
    """``blocks`` grouped where every matrix is equal on them in every scenario (same size, same entries in the
    same order): the linear solves of a group need one factorisation (an isotropic rotor's two planes: half the
    work of the linear solves that every continuation step pays)."""
    groups: list[list[Array]] = []
    for block in blocks:
        for group in groups:
            first = group[0]
            if first.size == block.size and all(
                    np.array_equal(A[:, first[:, None], first[None, :]], A[:, block[:, None], block[None, :]])
                    for A in matrices):
                group.append(block)
                break
        else:
            groups.append([block])
    return groups


def _to_real(X: Array) -> Array:
    """(S, H+1, c) complex -> (S, c, 2H+1) real [Re Q_0, Re Q_1, Im Q_1, ...]."""
    S, H1, c = X.shape
    out = np.empty((S, c, 2 * H1 - 1))
    out[:, :, 0] = X[:, 0].real
    out[:, :, 1::2] = np.moveaxis(X[:, 1:].real, 1, 2)
    out[:, :, 2::2] = np.moveaxis(X[:, 1:].imag, 1, 2)
    return out


def _to_complex(x: Array) -> Array:
    """(S, c, 2H+1) real -> (S, c, H+1) complex."""
    out = np.empty(x.shape[:2] + ((x.shape[2] + 1) // 2,), complex)
    out[:, :, 0] = x[:, :, 0]
    out[:, :, 1:] = x[:, :, 1::2] + 1j * x[:, :, 2::2]
    return out


def _receptance_times(H0: Array, Hh: Array, Y: Array) -> Array:
    """x_h = H_h G_h in real coefficients for q columns at once: Y (S, c, 2H+1, q) -> (S, c, 2H+1, q).

    Harmonic h's cosine and sine rows are one complex product, (A + iB)(Y_cos + i Y_sin): the real block
    form [[A, -B], [B, A]] of the receptance (S, c 2H+1, c 2H+1) is block diagonal in h, so its product is
    H+1 products of c x c blocks, not one of the whole matrix."""
    out = np.empty(Y.shape)
    out[:, :, 0] = H0 @ Y[:, :, 0]
    product = Hh @ (Y[:, :, 1::2] + 1j * Y[:, :, 2::2]).transpose(0, 2, 1, 3)  # (S, H, c, q)
    out[:, :, 1::2] = product.real.transpose(0, 2, 1, 3)
    out[:, :, 2::2] = product.imag.transpose(0, 2, 1, 3)
    return out


def _dynamic_solve(K: Array, C: Array, M: Array, pencil: "banded.BandedPencil | None", w: Array, rhs: Array,
                   ok: Array) -> Array:
    """D^-1 rhs per scenario, D = K + i w C - w^2 M (w (S,) [rad/s], rhs (S, n, q)): in band storage when
    ``pencil`` (its bands of the same K, C, M) is given, else dense and batched; singular members get NaN and
    ok[i] = False."""
    if pencil is not None:
        return pencil.solve(w, rhs, ok)
    w = w[:, None, None]
    return _batched_solve(K + 1j * w * C - w * w * M, rhs, ok)


def _batched_solve(A: Array, b: Array, ok: Array) -> Array:
    """np.linalg.solve over a batch; singular members get NaN and ok[i] = False."""
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        out = np.full(b.shape, np.nan, dtype=np.result_type(A, b))
        for i in range(A.shape[0]):
            try:
                out[i] = np.linalg.solve(A[i], b[i])
            except np.linalg.LinAlgError:
                ok[i] = False
        return out


def _norm(x: Array) -> Array:
    flat = x.reshape(x.shape[0], -1)
    return np.sqrt(np.einsum("si,si->s", flat, flat))


def solve(
    system: System,
    harmonics: int = DEFAULT_HARMONICS,
    *,
    method: str = "newton",
    initial: Array | None = None,
    n_time: int | None = None,
    tol: float = 1e-10,
    max_iter: int = 30,
    relaxation: float = 0.5,
    fixed_point_iter: int = 300,
    branch: str = "direct",
    stall_window: int | None = None,
    stability: bool = True,
) -> SteadyState:
    """Periodic steady state of every scenario of ``system`` (harmonics 0..H).

    method: "newton" (default) or "fixed-point" (the paper's HMH iteration with
    relaxation ``relaxation``; scenarios it does not converge fall back to Newton).
    initial: condensed start (S, c, 2H+1), e.g. a previous speed's ``state``;
    default the linear response. tol: ||r|| <= tol ||x|| per scenario.
    stall_window: give a scenario up when its residual has not halved over this
    many Newton iterations (None: never; near folds Newton may need long damped
    progress before it converges, so continuation steps use a longer window
    than fresh starts). stability: assess each converged solution's stability
    (``assess_stability``; False leaves ``floquet_radius`` NaN, e.g. for the
    intermediate steps of a sweep).
    """
    if method not in ("newton", "fixed-point"):
        raise ValueError(f"method must be 'newton' or 'fixed-point', got {method!r}")
    if harmonics < 1:
        raise ValueError(f"harmonics must be >= 1, got {harmonics}")
    prob = Condensed(system, harmonics, n_time)
    S = system.n_scenarios
    x = prob.a.copy() if initial is None else np.array(initial, dtype=float)
    if x.shape != prob.a.shape:
        raise ValueError(f"initial state has shape {x.shape}, expected {prob.a.shape}")
    status = np.full(S, MAX_ITER)
    status[~prob.linear_ok] = LINEAR_SINGULAR
    iterations = np.zeros(S, int)
    residual = np.full(S, np.nan)
    notes = np.full(S, "", dtype=object)
    if len(prob.dofs) == 0:
        status[prob.linear_ok] = CONVERGED
        residual[prob.linear_ok] = 0.0
    else:
        open_ = np.flatnonzero(status == MAX_ITER)
        if method == "fixed-point":
            _fixed_point(prob, x, open_, status, iterations, residual, relaxation, fixed_point_iter, tol)
            fallback = np.flatnonzero(status == MAX_ITER)
            notes[fallback] = " after fixed-point fallback to Newton"
            x[fallback] = np.where(np.isfinite(x[fallback]), x[fallback], prob.a[fallback])
        _newton(prob, x, np.flatnonzero(status == MAX_ITER), status, iterations, residual, tol, max_iter,
                stall_window or max_iter + 1)
    invalid = system.problems != ""
    status[invalid] = INVALID
    success = status == CONVERGED
    Q = np.full((S, harmonics + 1, system.n_dof), np.nan + 0j)
    if success.any():
        Q[success] = prob.full_harmonics(x[success], np.flatnonzero(success))
    x[~success] = np.nan
    messages = np.array([_message(s, it, r) + n for s, it, r, n in zip(status, iterations, residual, notes)],
                        dtype=object)
    messages[invalid] = system.problems[invalid]
    result = SteadyState(
        harmonics=Q, Omega=system.Omega.copy(), success=success, status=status, message=messages,
        iterations=iterations, residual=residual, branch=np.full(S, branch, dtype=object), state=x, n_time=prob.N,
    )
    if stability:
        assess_stability(system, result)
    return result


def assess_stability(system: System, result: SteadyState, rows: Array | None = None) -> None:
    """The stability of the converged solutions among ``rows`` of ``result`` (default all), in place.

    system: the scenarios ``rows`` of ``result``, in that order (as ``solve`` was given them).
    Sets ``floquet_radius`` (``floquet_radius``) and, for an unstable solution (radius >= 1),
    a message that says so (``flag_unstable``).
    """
    rows = np.arange(result.n_scenarios) if rows is None else np.asarray(rows)
    if len(rows) != system.n_scenarios:
        raise ValueError(f"assess_stability: {len(rows)} rows for a system of {system.n_scenarios} scenarios")
    ok = np.flatnonzero(result.success[rows])
    if ok.size:
        flag_unstable(result, rows[ok], floquet_radius(system.subset(ok), result.harmonics[rows[ok]]))


def index_blocks(indices: Array) -> list[Array]:
    """``indices`` in consecutive blocks of at most ``BLOCK``, as even as possible (``np.array_split``)."""
    return np.array_split(indices, max(1, -(-len(indices) // BLOCK)))


def floquet_radius(system: System, harmonics: Array) -> Array:
    """The largest |Floquet multiplier| of each periodic solution ``harmonics`` (S, H+1, n) of ``system``
    (``floquet.spectral_radius``; a linear system's exactly from the eigenvalues of its first-order form,
    ``floquet.linear_spectral_radius``), in blocks of ``BLOCK`` scenarios (``index_blocks``; any mix of speeds)."""
    if system.n_scenarios == 0:
        return np.zeros(0)
    # blocks of similar speeds: a block's reduced model keeps the modes its fastest member needs
    order = np.argsort(system.Omega, kind="stable")
    blocks = index_blocks(order)
    radius = np.empty(system.n_scenarios)
    for b in blocks:
        # linear: the 2n multipliers exp(lambda T) exactly, from the eigenvalues of the first-order form
        radius[b] = floquet.spectral_radius(system.subset(b), harmonics[b]) if system.forces else \
            floquet.linear_spectral_radius(system.subset(b))
    return radius


def flag_unstable(result: SteadyState, rows: Array, radius: Array) -> None:
    """Store the radius of converged scenarios ``rows`` of ``result``; the unstable ones' message says so."""
    result.floquet_radius[rows] = radius
    for i, r in zip(rows[radius >= 1.0], radius[radius >= 1.0]):
        result.message[i] = (f"unstable periodic solution: largest Floquet multiplier |mu| = {r:.4g} >= 1 (a small "
                             f"deviation grows by that factor per period; harmonic-balance residual "
                             f"{result.residual[i]:.1e} after {result.iterations[i]} Newton iterations)")


def _message(status: int, iterations: int, residual: float) -> str:
    if status == CONVERGED:
        return f"converged in {iterations} iterations (residual {residual:.1e})"
    if status == MAX_ITER:
        return f"Newton did not converge in {iterations} iterations (residual {residual:.1e})"
    if status == SINGULAR:
        return f"singular Jacobian after {iterations} iterations (turning point or bifurcation)"
    if status == STALLED:
        return f"Newton stalled: the residual stopped falling after {iterations} iterations (residual {residual:.1e})"
    if status == DIVERGED:
        return (f"diverged after {iterations} iterations (amplitude > {_DIVERGENCE_FACTOR:g} x the linear "
                "response or not finite): no bounded periodic solution found")
    return "singular dynamic stiffness (undamped resonance of the linear part)"


def _fixed_point(prob, x, idx, status, iterations, residual, beta, max_iter, tol) -> None:
    """The paper's HMH fixed-point iteration x <- (1-beta) x + beta (a + H G(x))."""
    for _ in range(max_iter):
        if idx.size == 0:
            return
        r, _ = prob.evaluate(x[idx], idx, jacobian=False)
        nr, nx = _norm(r), _norm(x[idx])
        residual[idx] = nr / np.maximum(nx, 1e-300)
        done = nr <= tol * nx
        status[idx[done]] = CONVERGED
        bad = ~np.isfinite(nr) | (nx > _DIVERGENCE_FACTOR * np.maximum(_norm(prob.a[idx]), 1e-300))
        idx_left = idx[~done & ~bad]
        x[idx_left] -= beta * r[~done & ~bad]
        iterations[idx_left] += 1
        # diverging scenarios are handed to Newton from the linear start
        x[idx[bad & ~done]] = prob.a[idx[bad & ~done]]
        idx = idx_left


def _newton(prob, x, idx, status, iterations, residual, tol, max_iter, stall_window) -> None:
    """Damped Newton on r(x) = 0, batched; updates x, status, iterations, residual in place."""
    if idx.size == 0:
        return
    r, Jr = prob.evaluate(x[idx], idx)
    a_norm = np.maximum(_norm(prob.a), 1e-300)
    start = iterations.copy()
    history = np.full((len(status), max_iter + 1), np.inf)  # residual norm per Newton iteration
    for _ in range(max_iter + 1):
        nr, nx = _norm(r), _norm(x[idx])
        residual[idx] = nr / np.maximum(nx, 1e-300)
        step_no = iterations[idx] - start[idx]
        history[idx, step_no] = nr
        done = nr <= tol * nx
        done |= (nr == 0.0)
        bad = ~np.isfinite(nr) | (nx > _DIVERGENCE_FACTOR * a_norm[idx])
        stalled = (step_no >= stall_window) & (
            nr > 0.5 * history[idx, np.maximum(step_no - stall_window, 0)])
        status[idx[done]] = CONVERGED
        status[idx[bad & ~done]] = DIVERGED
        status[idx[stalled & ~done & ~bad]] = STALLED
        keep = ~done & ~bad & ~stalled & (iterations[idx] < max_iter)
        idx, r, Jr, nr = idx[keep], r[keep], Jr[keep], nr[keep]
        if idx.size == 0:
            return
        ok = np.ones(idx.size, bool)
        step = _batched_solve(Jr, -r.reshape(idx.size, -1, 1), ok).reshape(r.shape)
        status[idx[~ok]] = SINGULAR
        idx, r, nr, step = idx[ok], r[ok], nr[ok], step[ok]
        iterations[idx] += 1
        alpha = np.ones(idx.size)
        trial_r, trial_J = prob.evaluate(x[idx] + step, idx)
        worse = np.flatnonzero(~(_norm(trial_r) < nr))
        if worse.size:
            _backtrack(prob, x[idx[worse]], idx[worse], step[worse], nr[worse], alpha, worse, trial_r, trial_J)
        x[idx] += alpha[:, None, None] * step
        r, Jr = trial_r, trial_J


def _backtrack(prob, x, idx, step, nr, alpha, where, trial_r, trial_J) -> None:
    """Backtracking line search for the scenarios whose full Newton step did not lower the residual.

    Takes the largest of the step fractions 1/2, 1/4, ..., 2^-_MAX_HALVINGS that
    lowers the residual norm (the smallest if none does), as halving one at a time
    would; but in two batched calls, because the scenarios that need it are few
    and a call's fixed cost dominates (expansion chunk: 84 000 of 115 000
    residual evaluations were single halvings of ~2 scenarios): the half step of
    every row, then the other fractions at once for the rows the half step did
    not lower (all fractions for all rows, as before 2026-12-08, evaluated eight
    residuals a row where most need one: the same choices, bit for bit, an
    expansion chunk's solves 0.86 of the time, ``main_job_benchmark.py --solves``).
    The fractions' residuals come without Jacobians; the Jacobian is evaluated
    at the chosen fraction only. Writes alpha, trial_r, trial_J at ``where``.
    """
    fractions = 0.5 ** np.arange(1, _MAX_HALVINGS + 1)
    L, W = fractions.size, idx.size
    # the half step first, for all; the rows it does not lower try the other fractions, together (most backtracks
    # end at the half step: the same choice as all fractions at once, for an eighth of the evaluations)
    half = x + fractions[0] * step
    r, _ = prob.evaluate(half, idx, jacobian=False)
    first = np.zeros(W, int)
    rest = np.flatnonzero(~(_norm(r) < nr))
    if rest.size:
        candidates = x[rest][None] + fractions[1:, None, None, None] * step[rest][None]  # (L - 1, W', c, 2H+1)
        r, _ = prob.evaluate(candidates.reshape(((L - 1) * rest.size,) + x.shape[1:]), np.tile(idx[rest], L - 1),
                             jacobian=False)
        lower = (_norm(r).reshape(L - 1, rest.size) < nr[rest])
        first[rest] = np.where(lower.any(axis=0), lower.argmax(axis=0) + 1, L - 1)
    alpha[where] = fractions[first]
    trial_r[where], trial_J[where] = prob.evaluate(x + fractions[first][:, None, None] * step, idx)


# --- sensitivities of the steady state ---------------------------------------------------


def sensitivity(build: Callable[[Mapping[str, Array]], System], values: Mapping[str, Array], names: Sequence[str],
                state: SteadyState, steps: Sequence[float] | Array, condensed: bool = False
                ) -> Array | tuple[Array, Array]:
    """dQ_h/dp of converged steady states for each parameter p in ``names``, (S, P, H+1, n) complex.

    The harmonic-balance equations of eq. 29, per harmonic h,

        R_h(Q, p) = D_h(p) Q_h - F_h(p) - B G_h(B^T Q, p) = 0,   D_h = K + i h Omega C - (h Omega)^2 M,

    hold at every converged state, so by the implicit function theorem

        D_h dQ_h - B (dG/dx dx)_h = -(dD_h/dp Q_h - dF_h/dp - B dG_h/dp),   x = B^T Q.

    Condensed on the nonlinear DOFs as in ``solve`` (dQ_h = D_h^-1 rhs_h + R_h dG_h), this is
    J_r dx = B^T D^-1 rhs with J_r = I - H dG/dx, the Newton Jacobian at the solution: one linear
    solve per scenario for all parameters at once, no new steady state. The parameters' own
    derivatives dD_h/dp, dF_h/dp and dG_h/dp at fixed x are central differences of the *assembly*
    (``build``, no solve) with step ``steps[j]`` (SI): exact up to round-off for parameters that enter
    the matrices, forcing or force coefficients linearly (stiffness, damping, forcing, bearing
    coefficients), O(step^2) for the others (e.g. through omega_1 and Phi_1). Any effect is
    handled the same way: the solver never needs to know how a parameter enters.

    build(values) -> System of the scenarios whose parameter values are ``values`` (each (S',)), at
    the speeds of ``state``; values: complete, each (S,); state: ``solve``'s result for build(values)
    (its ``state`` and ``n_time`` are used). Failed scenarios get NaN. With ``condensed``, also the
    derivative of ``state.state`` (S, P, c, 2H+1), e.g. to predict a neighbour's state (continuation).
    """
    names = list(names)
    steps = np.asarray(steps, float)
    S, P, H = state.n_scenarios, len(names), state.H
    values = {k: np.broadcast_to(np.asarray(v, float), (S,)) for k, v in values.items()}
    if steps.shape != (P,) or not (np.isfinite(steps).all() and (steps > 0).all()):
        raise ValueError(f"sensitivity: need one positive step per parameter ({P}), got {steps}")
    out = np.full((S, P, H + 1, state.harmonics.shape[2]), np.nan + 0j)
    out_x = np.full((S, P) + state.state.shape[1:], np.nan)
    ok = np.flatnonzero(state.success)
    if ok.size == 0 or P == 0:
        return (out, out_x) if condensed else out
    values = {k: v[ok] for k, v in values.items()}
    s = ok.size
    system = build(values)
    # the perturbed assemblies, ordered (parameter, sign, scenario)
    stacked = {k: np.tile(v, 2 * P) for k, v in values.items()}
    for j, name in enumerate(names):
        for sign, offset in ((+1.0, 2 * j * s), (-1.0, (2 * j + 1) * s)):
            stacked[name][offset:offset + s] = values[name] + sign * steps[j]
    perturbed = build(stacked)

    def derivative(A: Array) -> Array:
        """(2 P s, ...) -> central difference (P, s, ...) per unit of each parameter."""
        A = A.reshape((P, 2, s) + A.shape[1:])
        return (A[:, 0] - A[:, 1]) / (2.0 * steps.reshape((P, 1) + (1,) * (A.ndim - 3)))

    dM, dC, dK = derivative(perturbed.M), derivative(perturbed.C), derivative(perturbed.K)
    Q = state.harmonics[ok]  # (s, H+1, n)
    x = state.state[ok]  # (s, c, 2H+1)
    Omega = system.Omega
    n = system.n_dof
    prob = Condensed(system, H, state.n_time)
    c = len(prob.dofs)
    # the local forces' own parameter derivative at fixed x: dG_h/dp (P, s, c, H+1)
    dG_p = np.zeros((P, s, c, H + 1), complex)
    if c:
        aft = Condensed(perturbed, H, state.n_time, linear=False)
        F, _ = aft._force_series(np.tile(x, (2 * P, 1, 1)), np.arange(2 * P * s), jacobian=False)
        dG_p = derivative(_to_complex(F @ aft.E_plus.T))
        B = np.zeros((n, c))
        B[prob.dofs, np.arange(c)] = 1.0
    # dD_h Q_h = dK Q_h + i h Omega dC Q_h - (h Omega)^2 dM Q_h: each derivative read once for all harmonics,
    # and not at all where it is zero (most parameters enter K alone, or only the forcing)
    products = {name: np.einsum("psij,shj->pshi", dA, Q, optimize=True) if np.any(dA) else None
                for name, dA in (("K", dK), ("C", dC), ("M", dM))}
    rhs_all = np.empty((s, P, H + 1, n), complex)
    for h in range(H + 1):
        w = (h * Omega)[:, None, None]
        dDQ = np.zeros((P, s, n), complex)
        for name, factor in (("K", 1.0), ("C", 1j * w[None, :, :, 0]), ("M", -(w * w)[None, :, :, 0])):
            if products[name] is not None:
                dDQ = dDQ + factor * products[name][:, :, h]
        dF = derivative(perturbed.forcing[h]) if h in perturbed.forcing else 0.0
        rhs = -(dDQ - dF)  # (P, s, n)
        if c:
            rhs = rhs + np.einsum("ik,psk->psi", B, dG_p[..., h])
        rhs_all[:, :, h] = np.moveaxis(rhs, 0, 1)
    out[ok], dx = linearised_response(prob, x, rhs_all)
    if c:
        out_x[ok] = dx
    return (out, out_x) if condensed else out


def linearised_response(prob: "Condensed", x: Array, rhs: Array) -> tuple[Array, Array | None]:
    """dQ (S, P, H+1, n) solving the harmonic-balance equations linearised about the converged states x (S, c, 2H+1)
    of ``prob`` (its system's scenarios), per harmonic h

        D_h dQ_h - B (dG/dx dx)_h = rhs_h,   D_h = K + i h Omega C - (h Omega)^2 M,   dx = B^T dQ,

    for P right-hand sides rhs (S, P, H+1, n) at once: D_h^-1 rhs_h, then on the nonlinear DOFs J_r dx = B^T D^-1 rhs
    with J_r = I - H dG/dx the Newton Jacobian at x (real form), and dQ_h = D_h^-1 rhs_h + R_h dG_h. The parameter
    sensitivities (``sensitivity``) and the sweep's first-order correction (``hybridtwin.solvers.sweep_forward``)
    are such solves. Returns dQ and dx (S, P, c, 2H+1) (None without nonlinear DOFs)."""
    system, H = prob.system, prob.H
    s, P, _, n = rhs.shape
    c = len(prob.dofs)
    Dinv_rhs = np.zeros((s, P, H + 1, n), complex)
    plan = banded.band_plan(banded.pattern_of(system.K, system.C, system.M))  # None: solved dense
    pencil = None if plan is None else banded.BandedPencil(plan, system.K, system.C, system.M)
    for h in range(H + 1):
        if not np.any(rhs[:, :, h]):  # D_h^-1 0 = 0 (a parameter that enters the forcing alone: one harmonic)
            continue
        ok_h = np.ones(s, bool)
        Dinv_rhs[:, :, h] = np.swapaxes(_dynamic_solve(system.K, system.C, system.M, pencil, h * system.Omega,
                                                       np.swapaxes(rhs[:, :, h], 1, 2), ok_h), 1, 2)
    if c == 0:
        return Dinv_rhs, None
    F_x, J = prob._force_series(x, np.arange(s), jacobian=True)  # the forces and dF/dq (s, c, c, N) at x
    _, Jr = prob._from_forces(x, np.arange(s), F_x, J)
    a = _to_real(Dinv_rhs[..., prob.dofs].reshape(s * P, H + 1, c)).reshape(s, P, -1)
    dx = np.linalg.solve(Jr, np.swapaxes(a, 1, 2))  # (s, m, P)
    dx = np.swapaxes(dx, 1, 2).reshape(s, P, c, 2 * H + 1)
    dF_t = np.einsum("sijn,spjn->spin", J, dx @ prob.E.T, optimize=True)  # (s, P, c, N)
    dG = _to_complex((dF_t @ prob.E_plus.T).reshape(s * P, c, -1)).reshape(s, P, c, H + 1)
    return Dinv_rhs + np.einsum("shnc,spch->sphn", prob.R, dG, optimize=True), dx


def solve_variant(variant, rpm: Array | float, overrides: Mapping[str, float | Array] | None = None,
                  harmonics: int = DEFAULT_HARMONICS, **options) -> SteadyState:
    """Steady state of a model variant (``hybridtwin.model.variants.Variant``) at ``rpm`` for the given parameter
    values (scalars or (S,) arrays; the variant's nominal values for the others): ``solve`` of its ``System``."""
    return solve(variant.system(rpm, overrides), harmonics, **options)
