"""Stability of periodic steady states: Floquet multipliers of the linearised equations of motion.

About a periodic solution q*(t) of eq. 29 (``solver.solve``), a small deviation y(t) obeys

    M y'' + C y' + K y = B J(t) B^T y,      J(t) = dF_nl/dq (q*(t)) at the c nonlinear DOFs,

a linear system with T-periodic coefficients (T = 2 pi / Omega). Its monodromy matrix Phi (the state
[y, y'] after one period as a function of the state at its start) has the Floquet multipliers mu as
eigenvalues: the periodic solution is asymptotically stable when every |mu| < 1, unstable when one
|mu| > 1 (deviations then grow by that factor per period: the machine leaves that state).

Method (monodromy matrix, chosen over Hill's method on the harmonic-balance Jacobian: Hill's matrix gives
2 n (2H + 1) = 968 eigenvalues of which 2n are meaningful, picked by a sorting heuristic that truncation
upsets, from an eigenproblem ~ 1000 times costlier than the ones below; batched over scenarios, the
monodromy matrix costs about as much as one harmonic-balance solve):

1. Reduction. The deviation is sought in a Ritz basis: the undamped modes of (sym K, M) up to
   ``cutoff_factor`` x the larger of J(t)'s highest harmonic (d - 1) H Omega and the first mode's
   frequency, plus the static deflections K^-1 B under unit loads at the nonlinear DOFs (modal truncation
   augmentation: the reduced model's static receptance at those DOFs is exact, so the truncated stiff
   modes still act as the quasi-static flexibility they are). M, C and K (speed terms, skew parts
   included) are projected on it: 2 m = 20-24 states instead of 2 n = 88. A truncated mode r, which the
   nonlinear force moves only quasi-statically, keeps its own multiplier, |mu_r| = exp(-phi_r^T C phi_r
   T / 2) (M-normalised phi_r: its modal decay over one period). That bound needs every mode: one generalised
   eigenproblem per distinct (sym K, M) (``model.distinct_scenarios``: runs at one speed that differ in their
   forcing share it), for a block of ``banded.BANDED_MIN_DOF`` DOFs or more by LAPACK's sygvd per scenario, with
   K^-1 B and C phi_r in band storage (``banded``).
2. Exponential integrator. Over each of ``n_steps`` steps of a period, with u = J(t) x linear in time
   (exponential trapezoidal rule, second order), the reduced state w' = A w + P u is propagated exactly:
   w+ = e^{Ah} w + h (phi1 - phi2)(Ah) P u + h phi2(Ah) P u+, phi1(z) = (e^z - 1)/z, phi2(z) = (e^z - 1 -
   z)/z^2, all from one matrix exponential per scenario (real, exact whether or not A can be diagonalised);
   u+ = J+ x+ makes each step a c x c solve. The stiff modes need no small steps, and the scheme is
   stable for any step.
3. mu = eigenvalues of the reduced monodromy matrix.

Accuracy (measured on ~370 orbits of the three built-in variants over their boxes at 300-1200 RPM, direct
solves, some unstable): against the same steps on all 88 states, the reduction changes the radius by < 1e-9
on stable orbits and < 5e-5 on strongly unstable ones; against the full model with 512 steps, the default
(reduced, 64 steps) is within 2e-4 near |mu| = 1 and 5e-3 for |mu| up to 1.5 (the error falls as
n_steps^-2); no stability decision differs. The closed form of a
linear system and time integrations of nonlinear orbits (``transient``) agree (``tests/test_stability.py``).

This module knows only the ``System`` and the solution's harmonics: no solver internals.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.linalg import expm

from . import banded
from ..model.model import System, distinct_scenarios

Array = np.ndarray

#: fewest steps per period of the exponential integrator (the error in the multipliers falls as its square);
#: at least 6 per period of J(t)'s highest harmonic
DEFAULT_STEPS = 64
#: modes up to this multiple of the highest frequency in the linearised system's coefficients are kept (0.7
#: changed the radius by < 1e-6 against no reduction: the static modes carry the rest)
DEFAULT_CUTOFF_FACTOR = 1.0


def multipliers(system: System, harmonics: Array, n_steps: int | None = None,
                cutoff_factor: float | None = DEFAULT_CUTOFF_FACTOR) -> tuple[Array, Array]:
    """Floquet multipliers of the S periodic solutions ``harmonics`` (S, H+1, n) of ``system``.

    Returns mu (S, 2m) of the reduced model (``cutoff_factor=None``: the full 2n states, no
    reduction) and the modal damping phi_r^T C phi_r of the truncated modes (S, n - k) [1/s].
    n_steps: steps per period (default max(``DEFAULT_STEPS``, 6 (d - 1) H), d the forces' degree).
    """
    if system.n_scenarios == 0:
        return np.zeros((0, 0), complex), np.zeros((0, 0))
    Q = np.asarray(harmonics)
    H = Q.shape[1] - 1
    dofs = np.unique(np.concatenate([f.dofs for f in system.forces])) if system.forces else np.array([], int)
    degree = max([f.degree or 3 for f in system.forces], default=1)  # not polynomial: taken as cubic
    n_steps = n_steps or max(DEFAULT_STEPS, 6 * (degree - 1) * H)
    J = _force_jacobian(system, Q, dofs, n_steps)  # (S, n_steps + 1, c, c)
    full = (np.broadcast_to(np.eye(system.n_dof), system.M.shape), np.zeros((system.n_scenarios, 0)))
    if cutoff_factor is None:
        basis, truncated = full
    else:
        try:
            basis, truncated = _ritz_basis(system, dofs, cutoff_factor, (degree - 1) * H * system.Omega)
        except np.linalg.LinAlgError:  # a singular K or static modes inside the kept modes' span: no reduction
            basis, truncated = full
    return _monodromy_eigenvalues(system, basis, dofs, J, n_steps), truncated


def linear_spectral_radius(system: System) -> Array:
    """The largest |mu| per scenario (S,) of a system with no nonlinear force: its Floquet multipliers are
    exp(lambda T) for the eigenvalues lambda of the first-order form [[0, I], [-M^-1 K, -M^-1 C]] (time-invariant
    linear flow), so the radius is exp(T max Re lambda), with no matrix exponential and no modal basis."""
    first, inverse = distinct_scenarios(system.M, system.C, system.K)  # scenarios that share M, C and K: once
    A = _first_order(system.M[first], system.C[first], system.K[first])
    T = 2.0 * np.pi / system.Omega
    return np.exp(T * np.linalg.eigvals(A).real.max(axis=1)[inverse])


def _first_order(M: Array, C: Array, K: Array) -> Array:
    """The first-order form A = [[0, I], [-M^-1 K, -M^-1 C]] (S, 2m, 2m) of M q'' + C q' + K q = 0."""
    S, m = M.shape[0], M.shape[1]
    A = np.zeros((S, 2 * m, 2 * m))
    A[:, :m, m:] = np.eye(m)
    A[:, m:, :m] = -np.linalg.solve(M, K)
    A[:, m:, m:] = -np.linalg.solve(M, C)
    return A


def spectral_radius(system: System, harmonics: Array, **options) -> Array:
    """The largest |mu| per solution (S,): of the reduced model and of the truncated modes
    (|mu_r| = exp(-phi_r^T C phi_r T / 2), their own decay over a period)."""
    mu, truncated = multipliers(system, harmonics, **options)
    radius = np.abs(mu).max(axis=1, initial=0.0)
    if truncated.size:
        T = 2.0 * np.pi / system.Omega
        radius = np.maximum(radius, np.exp(-0.5 * truncated.min(axis=1) * T))
    return radius


def _force_jacobian(system: System, Q: Array, dofs: Array, n_steps: int) -> Array:
    """dF_nl/dq at the nonlinear DOFs at t_k = k T / n_steps, k = 0..n_steps: (S, n_steps + 1, c, c)."""
    S, c = Q.shape[0], dofs.size
    tau = 2.0 * np.pi * np.arange(n_steps) / n_steps
    h = np.arange(Q.shape[1])
    x = np.einsum("th,shc->sct", np.exp(1j * np.outer(tau, h)), Q[:, :, dofs]).real  # (S, c, N)
    J = np.zeros((S, c, c, n_steps))
    for force in system.forces:
        loc = np.searchsorted(dofs, force.dofs)
        _, j = force.evaluate(x[:, loc], system.rows)
        J[:, loc[:, None], loc[None, :]] += j
    J = np.moveaxis(J, 3, 1)
    return np.concatenate([J, J[:, :1]], axis=1)  # periodic: t_N = T is t_0


def _ritz_basis(system: System, dofs: Array, factor: float, highest: Array) -> tuple[Array, Array]:
    """M-orthonormal basis (S, n, m): the undamped modes of (sym K, M) up to ``factor`` x the larger of
    ``highest`` (S,) [rad/s] and the first mode's frequency, and the static deflections K^-1 B; and the
    modal damping of the truncated modes (S, n - k)."""
    S, n = system.n_scenarios, system.n_dof
    K_sym = 0.5 * (system.K + np.swapaxes(system.K, 1, 2))
    omega2, modes = _undamped_modes(K_sym, system.M)
    cutoff = factor * np.maximum(highest, np.sqrt(np.abs(omega2[:, 0])))
    k = int(np.max(np.sum(omega2 <= (cutoff * cutoff)[:, None], axis=1)))
    k = min(k, n - dofs.size)
    kept, rest = modes[:, :, :k], modes[:, :, k:]
    C_plan = banded.band_plan(banded.pattern_of(system.C))  # a large rotor's C in its band: O(n k) a mode
    C_rest = system.C @ rest if C_plan is None else banded.band_product(C_plan, system.C, rest)
    truncated = np.sum(rest * C_rest, axis=1)  # phi_r^T C phi_r
    if dofs.size == 0:
        return kept, truncated
    unit_loads = np.broadcast_to(np.eye(n)[:, dofs], (S, n, dofs.size))
    plan = banded.band_plan(banded.pattern_of(system.K))  # a large finite-element rotor: K^-1 B in band storage
    if plan is None:
        static = np.linalg.solve(system.K, unit_loads)
    else:
        ok = np.ones(S, bool)
        static = banded.solve_band(plan, banded.to_band(plan, system.K), unit_loads, ok)
        if not ok.all():
            raise np.linalg.LinAlgError("singular stiffness matrix")
    static = static - kept @ (np.swapaxes(kept, 1, 2) @ (system.M @ static))  # M-orthogonal to the modes
    G = np.swapaxes(static, 1, 2) @ system.M @ static
    static = static @ np.swapaxes(np.linalg.inv(np.linalg.cholesky(G)), 1, 2)
    return np.concatenate([kept, static], axis=2), truncated


def _undamped_modes(K: Array, M: Array) -> tuple[Array, Array]:
    """omega^2 (S, n) ascending and M-orthonormal modes (S, n, n) of symmetric pencils (K, M), block by block
    of the DOFs that neither matrix couples (the two bending planes: a quarter of the work of one eigh)."""
    from scipy.sparse.csgraph import connected_components

    S, n = K.shape[:2]
    first, inverse = distinct_scenarios(K, M)
    if first.size < S:  # scenarios that share their pencil (a run's speeds with K and M independent of speed): once
        omega2, modes = _undamped_modes(K[first], M[first])
        return omega2[inverse], modes[inverse]
    pattern = np.any(K != 0, axis=0) | np.any(M != 0, axis=0)
    n_blocks, labels = connected_components(pattern | pattern.T, directed=False)
    omega2, modes = np.empty((S, n)), np.zeros((S, n, n))
    column = 0
    for block in range(n_blocks):
        idx = np.flatnonzero(labels == block)
        columns = slice(column, column + idx.size)
        column += idx.size
        if idx.size >= banded.BANDED_MIN_DOF:
            # a large block: LAPACK's generalised solver (sygvd: Cholesky, reduction, eigh, back-substitution) per
            # scenario, 0.6 of the batched route below at 224 DOFs, where the explicit inverse and products cost
            # more than the eigh itself
            for s in range(S):
                omega2[s, columns], modes[s, idx, columns] = scipy.linalg.eigh(
                    K[s][np.ix_(idx, idx)], M[s][np.ix_(idx, idx)], driver="gvd", check_finite=False)
            continue
        Linv = np.linalg.inv(np.linalg.cholesky(M[:, idx[:, None], idx[None, :]]))
        Linv_T = np.swapaxes(Linv, 1, 2)
        w2, vectors = np.linalg.eigh(Linv @ K[:, idx[:, None], idx[None, :]] @ Linv_T)
        omega2[:, columns] = w2
        modes[:, idx, columns] = Linv_T @ vectors
    if n_blocks == 1:  # one block: LAPACK's ascending order already (a large array's reordering costs ~ the eigh)
        return omega2, modes
    order = np.argsort(omega2, axis=1, kind="stable")
    return np.take_along_axis(omega2, order, axis=1), np.take_along_axis(modes, order[:, None, :], axis=2)


def _project(Bt: Array, X: Array, basis: Array) -> Array:
    """basis^T X basis (S, m, m); X's product with the basis in its band for a large rotor (O(n k m), not
    O(n^2 m))."""
    plan = banded.band_plan(banded.pattern_of(X))
    return Bt @ X @ basis if plan is None else Bt @ banded.band_product(plan, X, basis)


def _monodromy_eigenvalues(system: System, basis: Array, dofs: Array, J: Array, n_steps: int) -> Array:
    """Eigenvalues of the monodromy matrix of the system projected on ``basis`` (S, n, m)."""
    S, m, c = system.n_scenarios, basis.shape[2], dofs.size
    Bt = np.swapaxes(basis, 1, 2)
    M, C, K = (_project(Bt, X, basis) for X in (system.M, system.C, system.K))
    A = _first_order(M, C, K)
    T = 2.0 * np.pi / system.Omega
    if c == 0:
        return np.linalg.eigvals(expm(A * T[:, None, None]))
    at_dofs = basis[:, dofs, :]  # x = at_dofs q_r, (S, c, m)
    P = np.zeros((S, 2 * m, c))
    P[:, m:] = np.linalg.solve(M, np.swapaxes(at_dofs, 1, 2))
    h = (T / n_steps)[:, None, None]
    # exp([[A h, P h, 0], [0, 0, I], [0, 0, 0]]) = [[e^{Ah}, h phi1(Ah) P, h phi2(Ah) P], [0, I, I], [0, 0, I]]
    # (the phi-functions from one exponential of an augmented matrix, Saad 1992): a step's propagators, real,
    # and exact whether or not A can be diagonalised
    Z = np.zeros((S, 2 * m + 2 * c, 2 * m + 2 * c))
    Z[:, :2 * m, :2 * m] = A * h
    Z[:, :2 * m, 2 * m:2 * m + c] = P * h
    Z[:, 2 * m:2 * m + c, 2 * m + c:] = np.eye(c)
    F = expm(Z)
    E, P1, P2 = F[:, :2 * m, :2 * m], F[:, :2 * m, 2 * m:2 * m + c], F[:, :2 * m, 2 * m + c:]
    P_now, P_next = P1 - P2, P2  # weights of u at the step's start and end (u linear in time)
    b = np.concatenate([at_dofs, np.zeros_like(at_dofs)], axis=2)  # x = b [q_r, q_r'], (S, c, 2m)
    implicit = b @ P_next  # x+ = b (E w + P_now u) + implicit u+,  u+ = J+ x+
    Jt = np.moveaxis(J, 1, 0)  # (N + 1, S, c, c)
    gain = np.linalg.solve(np.swapaxes(np.eye(c) - implicit[None] @ Jt, -1, -2), np.swapaxes(Jt, -1, -2))
    gain_b = np.swapaxes(gain, -1, -2) @ b[None]  # u+ = J+ (I - implicit J+)^-1 b (E w + P_now u)
    # w_k = h_k + P_next u_k with h_{k+1} = E w_k + P_now u_k = E h_k + (E P_next + P_now) u_k: one product a step
    step = np.concatenate([E, E @ P_next + P_now], axis=2)  # (S, 2m, 2m + c)
    U = J[:, 0] @ b  # u_0 for w_0 = I
    HU = np.concatenate([np.eye(2 * m) - P_next @ U, U], axis=1)  # [h_0; u_0]
    for k in range(n_steps):
        HU[:, :2 * m] = step @ HU
        HU[:, 2 * m:] = gain_b[k + 1] @ HU[:, :2 * m]
    W = HU[:, :2 * m] + P_next @ HU[:, 2 * m:]
    return np.linalg.eigvals(W)
