"""Forward models: a run's sensor harmonics h = 1..H as a function of the unknown parameters.

Two kinds share one interface (``HarmonicModel``: ``parameters``, ``lower``,
``upper``, ``H``, ``evaluate(x (N, d), jacobian)`` -> M (N, H, 2) complex [m]
and dM/dx (N, H, 2, d), x the parameters normalised to [-1, 1]):

- ``SensorSurrogate``: a run's sPGD library (microseconds per evaluation,
  exact Jacobian of the surrogate);
- ``SolverModel``: the full harmonic-balance solver (no surrogate error).

Used by the identification, its full-solver polish, the validation
predictions and the diagnosis.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from .library import Library
from .pod import feature_index
from .scenarios import intermediate_speeds

Array = np.ndarray

class HarmonicModel(Protocol):
    """A run's sensor harmonics h = 1..H as a function of its parameters normalised to [-1, 1]."""

    parameters: list[str]
    lower: Array
    upper: Array
    H: int

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """x (N, d) -> M (N, H, 2) complex [m] and dM/dx (N, H, 2, d)."""


class SensorSurrogate:
    """A library's sensor harmonics h = 1..H and exact derivatives, evaluated for many trials at once.

    Same numbers as ``Library.sensor`` (the sPGD of eq. 6-7 on the POD basis,
    projected on the sensor DOFs once): y = (prod_j F_j(x_j)) A_s with
    A_s = amplitudes Phi_sensor^T, evaluated by ``SparsePGD.evaluate``, here in
    normalised coordinates and without the mean (h = 0).
    """

    def __init__(self, library: Library, harmonics: int | None = None):
        H_lib = library.n_harmonics - 1
        self.H = H_lib if harmonics is None else min(int(harmonics), H_lib)
        if self.H < 1:
            raise ValueError(f"library {library.run} has no harmonic h >= 1")
        h = np.arange(1, self.H + 1)
        rows = [feature_index(h, dof, library.n_harmonics, library.n_dof, imaginary)
                for imaginary in (False, True) for dof in library.sensor_dofs]
        sensor_modes = library.modes[np.concatenate(rows)]  # (4H, m): Re x, Re y, Im x, Im y
        self.model = library.model.projected(sensor_modes.T)  # outputs Re x, Re y, Im x, Im y (4H)
        self.parameters = list(library.parameters)
        self.lower, self.upper = np.asarray(library.lower, float), np.asarray(library.upper, float)
        self.run = library.run

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """M (N, H, 2) complex and dM/dx (N, H, 2, d) at normalised x (N, d) in [-1, 1]."""
        x = np.clip(np.atleast_2d(x), -1.0, 1.0)
        y, J = self.model.evaluate(x, jacobian=jacobian)
        if not jacobian:
            return self._complex(y), None
        N, d = x.shape
        out = self._complex(J.reshape(d * N, -1)).reshape(d, N, self.H, 2)
        return self._complex(y), np.moveaxis(out, 0, -1)

    def _complex(self, features: Array) -> Array:
        """(N, 4H) [Re x, Re y, Im x, Im y] -> (N, H, 2) complex."""
        parts = features.reshape(features.shape[0], 2, 2, self.H)  # (N, Re/Im, channel, h)
        return np.swapaxes(parts[:, 0] + 1j * parts[:, 1], 1, 2)



def run_up(variant, rpm: Sequence[float], values: Mapping[str, Array | float], harmonics: int,
           start_rpm: float = 300.0, step_rpm: float = 50.0) -> list:
    """Steady states of S parameter sets at each of ``rpm``, reached by one run-up from ``start_rpm``.

    values: parameter values [SI], scalars or (S,) arrays, m_e included (unlike
    ``scenarios.solve_runs``, which sets m_e from the run plan, an unknown m_e
    keeps each set's own value). Steps between speeds are at most ``step_rpm``
    (the offline stage's run-up). Returns the ``SteadyState`` at each of ``rpm``.
    """
    from .solver import solve_sweep

    base = variant.values(values)
    S = max(np.size(v) for v in base.values())
    arrays = {k: np.broadcast_to(np.asarray(v, float), (S,)) for k, v in base.items()}
    targets = np.asarray(rpm, float)
    points = np.unique(np.append(targets, min(start_rpm, targets.min())))
    grid = intermediate_speeds(points, step_rpm)
    rest = variant.model.at_rest(arrays)  # the speed-independent stages, once for the whole run-up
    sweep = solve_sweep(lambda speed, rows: variant.model.system_at(rest.rows(rows), speed),
                        grid, S, harmonics=harmonics, direction="up")
    by_rpm = dict(zip(sweep.rpm, sweep.results))
    return [by_rpm[r] for r in targets]


class SolverModel:
    """A run's sensor harmonics from the full harmonic-balance solver (run-up to the run's speed).

    Same interface as ``SensorSurrogate``: evaluate(x (N, d)) -> M, dM/dx, the
    derivative by forward differences (step ``step`` in normalised units), all
    N (1 + d) parameter sets solved in one batched run-up (``run_up``). m_e is
    the run's eccentric mass unless it is one of the parameters.
    """

    def __init__(self, variant, run: str, rpm: float, eccentric_mass_g: float, parameters: Sequence[str],
                 lower: Array, upper: Array, harmonics: int, step: float = 1e-5):
        self.variant, self.run = variant, run
        self.rpm, self.eccentric_mass_g = float(rpm), float(eccentric_mass_g)
        self.parameters = list(parameters)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.harmonics = int(harmonics)
        self.H = self.harmonics
        self.step = float(step)
        self.n_solves = 0

    def _solve(self, x: Array) -> Array:
        """Sensor harmonics (N, H, 2) at normalised x (N, d); NaN where there is no solution (or x is NaN)."""
        finite = np.isfinite(x).all(axis=1)
        if not finite.all():
            M = np.full((x.shape[0], self.harmonics, 2), np.nan + 0j)
            if finite.any():
                M[finite] = self._solve(x[finite])
            return M
        from .sensor import sensor_harmonics

        values = {"m_e": self.eccentric_mass_g * 1e-3}
        values |= {p: self.lower[j] + 0.5 * (x[:, j] + 1) * (self.upper[j] - self.lower[j])
                   for j, p in enumerate(self.parameters)}
        result = run_up(self.variant, [self.rpm], values, self.harmonics)[0]
        self.n_solves += x.shape[0]
        U, V = sensor_harmonics(result.harmonics, self.variant.model.shaft)  # (N, H+1) each
        M = np.stack([U[:, 1:], V[:, 1:]], axis=-1)
        M[~result.success] = np.nan
        return M

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        x = np.atleast_2d(x)
        N, d = x.shape
        if not jacobian:
            return self._solve(x), None
        steps = np.where(x + self.step <= 1.0, self.step, -self.step)  # (N, d), backwards at the upper bound
        shifted = np.repeat(x[:, None, :], d, axis=1)
        shifted[:, np.arange(d), np.arange(d)] += steps
        M_all = self._solve(np.concatenate([x, shifted.reshape(N * d, d)]))
        M = M_all[:N]
        M_shifted = M_all[N:].reshape(N, d, *M.shape[1:])
        # a shifted solve that fails (next to a fold, say) while the point itself solves: step the other way
        failed = ~np.isfinite(M_shifted).all(axis=(2, 3)) & np.isfinite(M).all(axis=(1, 2))[:, None]
        if failed.any():
            n, j = np.nonzero(failed)
            steps[n, j] = -steps[n, j]
            retry = x[n].copy()
            retry[np.arange(n.size), j] += steps[n, j]
            M_shifted[n, j] = self._solve(retry)
        dM = (M_shifted - M[:, None]) / steps[:, :, None, None]
        return M, np.moveaxis(dM, 1, -1)
