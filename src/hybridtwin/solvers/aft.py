"""The alternating frequency-time (AFT) scheme's matrices: the real discrete Fourier transform between a
trajectory's harmonics and its time samples, and the sample count that keeps a polynomial force free of aliasing
(the harmonic balance's nonlinear forces are evaluated in time, ``solver.Condensed``)."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

Array = np.ndarray


def fourier_matrices(H: int, N: int) -> tuple[Array, Array]:
    """Inverse E (N, 2H+1) and forward E+ (2H+1, N) real DFT, E+ E = I for N >= 2H+1.

    Coefficients [c_0, c_1, s_1, ..., c_H, s_H] stand for Q_h = c_h + i s_h, so
    x(tau_n) = c_0 + sum_h (c_h cos h tau_n - s_h sin h tau_n), tau_n = 2 pi n / N.
    """
    if N < 2 * H + 1:
        raise ValueError(f"n_time = {N} is too few samples for H = {H} (need >= {2 * H + 1})")
    tau = 2.0 * np.pi * np.arange(N) / N
    E = np.ones((N, 2 * H + 1))
    E_plus = np.full((2 * H + 1, N), 1.0 / N)
    for h in range(1, H + 1):
        E[:, 2 * h - 1], E[:, 2 * h] = np.cos(h * tau), -np.sin(h * tau)
        E_plus[2 * h - 1], E_plus[2 * h] = 2.0 / N * np.cos(h * tau), -2.0 / N * np.sin(h * tau)
    return E, E_plus


@functools.cache
def aft_matrices(H: int, N: int) -> tuple[Array, Array, Array]:
    """``fourier_matrices`` and W[n, (k, l)] = E+[k, n] E[n, l], with which the AFT derivative
    dG[s, i, k, j, l] = sum_n E+[k, n] J[s, i, j, n] E[n, l] is one product J @ W; once per (H, N), read-only."""
    E, E_plus = fourier_matrices(H, N)
    W = (E_plus.T[:, :, None] * E[:, None, :]).reshape(N, (2 * H + 1) ** 2)
    for A in (E, E_plus, W):
        A.flags.writeable = False
    return E, E_plus, W


def default_n_time(H: int, forces: Sequence) -> int:
    """Alias-free AFT sample count (d+1) H + 1 for degree-d polynomial forces; 64 if not polynomial."""
    degrees = [f.degree for f in forces]
    if any(d is None for d in degrees):
        return max(64, 4 * H + 1)
    return (max(degrees, default=1) + 1) * H + 1
