"""Dynamic-stiffness solves in band storage, for finite-element rotors of many DOFs.

A shaft of beam elements couples each node to its neighbours only, and bearings, seals and disks act at one node:
K, C and M of every scenario share one sparsity pattern which, its DOFs reordered by reverse Cuthill-McKee, lies
within a narrow band (ROSS's compressor: 224 DOFs, half-bandwidth 7). The harmonic balance solves the dynamic
stiffness D_h = K + i h Omega C - (h Omega)^2 M of each scenario and harmonic (``solver.Condensed``, the
sensitivities' ``solver.linearised_response``); dense, each solve costs O(n^3), in band storage O(n k^2)
(LAPACK's gbsv: LU with partial pivoting, the same elimination as the dense LU of the reordered matrix, whose
entries outside the band are zero). The result is the dense solve's up to round-off.

Small systems keep the dense batched solve (``BANDED_MIN_DOF``): the built-in variants (the VARM's 44 DOFs, the
stepped rotor's 72) stay bit for bit what they were.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

Array = np.ndarray

#: fewest DOFs (of one uncoupled block) solved in band storage. At 72 DOFs (the stepped rotor, half-bandwidth 7)
#: the banded solve would cost ~0.7 of the dense batched one: too little to give up its bit-for-bit results (the
#: VARM's blocks have 22 DOFs); at 224 (ROSS's compressor) the solve with every harmonic costs 0.1 of the dense one
#: (benchmarks/solver_cost_by_dof.py)
BANDED_MIN_DOF = 100
#: band storage (3 k + 1 rows for half-bandwidth k) worth it up to this fraction of the dense n rows
_MAX_BAND_FRACTION = 0.25


@dataclass(frozen=True)
class BandPlan:
    """A DOF order with a narrow band: ``order`` (n,) the reverse Cuthill-McKee permutation, ``k`` the
    half-bandwidth (no nonzero A[order[i], order[j]] with |i - j| > k), and the positions of the band entries in
    LAPACK's gbsv storage (row 2k + i - j of column j for entry (i, j))."""

    order: Array
    k: int
    rows: Array  # band-storage row of each band entry (the arrays are shared: read-only)
    cols: Array  # its column (in the new order)
    source_i: Array  # its row in the original order
    source_j: Array  # its column in the original order

    @property
    def n(self) -> int:
        return self.order.size


def band_plan(pattern: Array) -> BandPlan | None:
    """The band order of a sparsity pattern (n, n) bool, or None when the dense solve is the better one (fewer than
    ``BANDED_MIN_DOF`` DOFs, or a band wider than ``_MAX_BAND_FRACTION`` of n). A machine's systems share their
    pattern: the order is found once per pattern."""
    n = pattern.shape[0]
    if n < BANDED_MIN_DOF:
        return None
    return _band_plan(n, np.packbits(pattern).tobytes())


@functools.lru_cache(maxsize=16)
def _band_plan(n: int, packed: bytes) -> BandPlan | None:
    """``band_plan`` of the pattern ``packed`` (np.packbits of an (n, n) bool array)."""
    pattern = np.unpackbits(np.frombuffer(packed, np.uint8), count=n * n).reshape(n, n).astype(bool)
    symmetric = pattern | pattern.T
    order = reverse_cuthill_mckee(csr_matrix(symmetric), symmetric_mode=True).astype(int)
    i, j = np.nonzero(symmetric[np.ix_(order, order)])
    k = int(np.abs(i - j).max(initial=0))
    if 3 * k + 1 > _MAX_BAND_FRACTION * n:
        return None
    offset = np.arange(-k, k + 1)  # i - j
    jj = np.tile(np.arange(n), offset.size)
    ii = jj + np.repeat(offset, n)
    keep = (ii >= 0) & (ii < n)
    ii, jj = ii[keep], jj[keep]
    arrays = (order, 2 * k + ii - jj, jj, order[ii], order[jj])
    for a in arrays:
        a.flags.writeable = False
    return BandPlan(arrays[0], k, *arrays[1:])


def pattern_of(*matrices: Array) -> Array:
    """The nonzeros (n, n) of stacked matrices (S, n, n), in any scenario of any of them."""
    pattern = np.zeros(matrices[0].shape[-2:], bool)
    for A in matrices:
        pattern |= np.any(A != 0, axis=0)
    return pattern


def to_band(plan: BandPlan, A: Array) -> Array:
    """Stacked matrices A (S, n, n) in band storage, transposed: (S, n, 3k + 1), each [s].T the (3k + 1, n)
    Fortran-ordered array gbsv takes (its top k rows the room for the LU's fill)."""
    out = np.zeros((A.shape[0], plan.n, 3 * plan.k + 1), A.dtype)
    out[:, plan.cols, plan.rows] = A[:, plan.source_i, plan.source_j]
    return out


def solve_band(plan: BandPlan, bands: Array, rhs: Array, ok: Array) -> Array:
    """X with A_s X_s = rhs_s per scenario s: ``bands`` (S, n, 3k + 1) from ``to_band``, rhs (S, n, q) in the
    original order. A singular A_s gives NaN and ok[s] = False (as ``solver._batched_solve``)."""
    S, n, q = rhs.shape
    dtype = np.result_type(bands, rhs)
    gbsv = lapack.zgbsv if np.iscomplexobj(np.empty(0, dtype)) else lapack.dgbsv
    out = np.empty((S, n, q), dtype)
    permuted = np.ascontiguousarray(np.swapaxes(rhs[:, plan.order, :], 1, 2), dtype=dtype)  # (S, q, n): [s].T F-order
    ab = np.ascontiguousarray(bands, dtype=dtype)
    for s in range(S):
        _, _, x, info = gbsv(plan.k, plan.k, ab[s].T, permuted[s].T, overwrite_ab=1, overwrite_b=1)
        if info < 0:
            raise ValueError(f"gbsv: argument {-info} is invalid")
        if info > 0:
            ok[s] = False
            out[s] = np.nan
        else:
            out[s, plan.order] = x
    return out


def band_product(plan: BandPlan, A: Array, X: Array) -> Array:
    """A_s X_s per scenario, A (S, n, n) with its nonzeros in ``plan``'s band, X (S, n, q): O(n k q) each, as one
    sparse product of the block-diagonal matrix of all S (the dense one is O(n^2 q))."""
    S, n = A.shape[0], plan.n
    offset = (np.arange(S) * n)[:, None]
    rows, cols = (plan.source_i + offset).ravel(), (plan.source_j + offset).ravel()
    blocks = csr_matrix((A[:, plan.source_i, plan.source_j].ravel(), (rows, cols)), shape=(S * n, S * n))
    return np.asarray(blocks @ np.reshape(X, (S * n, -1))).reshape(X.shape)


class BandedPencil:
    """The dynamic stiffness D(w) = K + i w C - w^2 M of S scenarios in band storage (``plan``): the bands of K, C
    and M taken once, D formed from them by the same operations, entry by entry, as the dense D."""

    def __init__(self, plan: BandPlan, K: Array, C: Array, M: Array):
        self.plan = plan
        self.K, self.C, self.M = (to_band(plan, A) for A in (K, C, M))

    def solve(self, w: Array, rhs: Array, ok: Array) -> Array:
        """D(w_s)^-1 rhs_s per scenario: w (S,) [rad/s], rhs (S, n, q); a singular D_s gives NaN and ok[s] False."""
        w = np.asarray(w, float)[:, None, None]
        return solve_band(self.plan, self.K + 1j * w * self.C - w * w * self.M, rhs, ok)
