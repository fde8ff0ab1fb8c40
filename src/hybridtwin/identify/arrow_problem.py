"""The identification's least-squares problem in block-arrow form (paper eq. 9-11; the loss and how it is made
precise: ``hybridtwin.identify.identification``).

``Layout``: where each unknown sits in theta = [shared, run 1 block, ..., run R block] (a run's block: its local
parameters, then its phase), the normalisation of the physical parameters to [-1, 1] and the phases' keyphasor
prior. ``ArrowProblem``: the weighted residuals of eq. 10, the smoothed L1 term of eq. 11 as residuals, and the
Jacobian in the layout's block-arrow form (shared columns, one block per run) that the batched Levenberg-Marquardt
(``hybridtwin.identify.lm``) solves by the Schur complement. ``wrap``: angles to (-pi, pi].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .forward import HarmonicModel, evaluate_runs
from ..data.measured import RunData
from .lm import Evaluation

Array = np.ndarray


# --- the problem: parameters, residuals, block-arrow Jacobian ---------------------------


@dataclass(frozen=True)
class Layout:
    """Where each unknown sits in theta = [shared (d_s), run 1 block, ..., run R block].

    A run's block is its local parameters (d_l) then its phase [rad]. Physical
    parameters are normalised to [-1, 1] with ``lower``/``upper`` (SI, in the
    order of ``parameters``, the libraries' order); phases are free, with a
    Gaussian prior N(0, phase_sigma^2) for runs with a keyphasor (finite phase_sigma).
    """

    parameters: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    shared: tuple[str, ...]
    local: tuple[str, ...]
    runs: tuple[str, ...]
    phase_sigma: tuple[float, ...] = ()  # [rad] per run, inf: arbitrary origin (the default for all)

    def __post_init__(self) -> None:
        if not self.phase_sigma:
            object.__setattr__(self, "phase_sigma", (math.inf,) * len(self.runs))
        if len(self.phase_sigma) != len(self.runs):
            raise ValueError(f"phase_sigma has {len(self.phase_sigma)} entries for {len(self.runs)} runs")
        both = set(self.shared) & set(self.local)
        if both or set(self.shared) | set(self.local) != set(self.parameters):
            raise ValueError(f"shared {list(self.shared)} and per-run {list(self.local)} parameters must split "
                             f"the libraries' parameters {list(self.parameters)} exactly")

    @classmethod
    def build(cls, parameters: Sequence[str], lower: Sequence[float], upper: Sequence[float],
              runs: Sequence[str], per_run: Sequence[str] = (), phase_sigma: Sequence[float] = ()) -> "Layout":
        local = tuple(p for p in parameters if p in set(per_run))
        shared = tuple(p for p in parameters if p not in set(local))
        return cls(tuple(parameters), tuple(map(float, lower)), tuple(map(float, upper)), shared, local,
                   tuple(runs), tuple(map(float, phase_sigma)))

    @classmethod
    def for_data(cls, parameters: Sequence[str], lower: Sequence[float], upper: Sequence[float],
                 data: Sequence[RunData], per_run: Sequence[str] = ()) -> "Layout":
        """The layout of a fit of ``data``: a phase prior for the runs with absolute (keyphasor) phases."""
        return cls.build(parameters, lower, upper, [d.run for d in data], per_run,
                         [d.phase_sigma for d in data])

    @property
    def n_shared(self) -> int:
        return len(self.shared)

    @property
    def n_block(self) -> int:
        return len(self.local) + 1

    @property
    def n_runs(self) -> int:
        return len(self.runs)

    @property
    def n(self) -> int:
        return self.n_shared + self.n_runs * self.n_block

    def index(self, name: str) -> int:
        return self.parameters.index(name)

    @property
    def shared_index(self) -> Array:
        """Positions of the shared parameters in the libraries' parameter order."""
        return np.array([self.index(p) for p in self.shared], int)

    @property
    def local_index(self) -> Array:
        return np.array([self.index(p) for p in self.local], int)

    def block(self, r: int) -> slice:
        start = self.n_shared + r * self.n_block
        return slice(start, start + self.n_block)

    def entries(self) -> list[tuple[str, str]]:
        """(parameter, run) of every entry of theta; run "all" for shared ones, parameter "phase" for phases."""
        out = [(p, "all") for p in self.shared]
        for run in self.runs:
            out += [(p, run) for p in self.local] + [("phase", run)]
        return out

    @property
    def is_phase(self) -> Array:
        return np.array([p == "phase" for p, _ in self.entries()])

    @property
    def phase_prior(self) -> Array:
        """1 / phase_sigma of each entry [1/rad]: nonzero for the phases of runs with a keyphasor, else 0."""
        sigma = dict(zip(self.runs, self.phase_sigma))
        return np.array([1.0 / sigma[run] if p == "phase" else 0.0 for p, run in self.entries()])

    @property
    def absolute_runs(self) -> list[str]:
        """The runs whose phases are absolute (a keyphasor): their phase has a prior."""
        return [run for run, sigma in zip(self.runs, self.phase_sigma) if math.isfinite(sigma)]

    def bounds(self) -> tuple[Array, Array]:
        """Bounds of theta: [-1, 1] for physical parameters, +-inf for phases."""
        lo = np.where(self.is_phase, -np.inf, -1.0)
        return lo, -lo

    def scale(self) -> Array:
        """dp/dtheta: (hi - lo) / 2 for physical entries [SI], 1 for phases [rad]."""
        half = {p: 0.5 * (hi - lo) for p, lo, hi in zip(self.parameters, self.lower, self.upper)}
        return np.array([1.0 if p == "phase" else half[p] for p, _ in self.entries()])

    def to_si(self, theta: Array) -> Array:
        """theta (..., n) -> physical values [SI] (phases unchanged, wrapped to (-pi, pi])."""
        lo = {p: v for p, v in zip(self.parameters, self.lower)}
        hi = {p: v for p, v in zip(self.parameters, self.upper)}
        out = np.array(theta, dtype=float, copy=True)
        for i, (p, _) in enumerate(self.entries()):
            out[..., i] = wrap(out[..., i]) if p == "phase" else lo[p] + 0.5 * (out[..., i] + 1.0) * (hi[p] - lo[p])
        return out

    def normalise(self, name: str, value: Array | float) -> Array:
        i = self.index(name)
        return 2.0 * (np.asarray(value, float) - self.lower[i]) / (self.upper[i] - self.lower[i]) - 1.0

    def run_parameters(self, theta: Array, r: int) -> tuple[Array, Array]:
        """Run r's normalised library parameters x (N, d) and phase (N,) from theta (N, n)."""
        N = theta.shape[0]
        x = np.empty((N, len(self.parameters)))
        x[:, self.shared_index] = theta[:, : self.n_shared]
        block = theta[:, self.block(r)]
        x[:, self.local_index] = block[:, :-1]
        return x, block[:, -1]

    def l1_scale(self) -> tuple[Array, Array]:
        """s = a theta + b, the paper's normalisation p / max|range| (eq. 11) of each entry.

        a = b = 0 (no L1 term) for phases and for parameters whose range excludes 0
        (e.g. the bow q in [1, 10] mm: sparsity means switching a term off).
        """
        a, b = np.zeros(self.n), np.zeros(self.n)
        for i, (p, _) in enumerate(self.entries()):
            if p == "phase":
                continue
            k = self.index(p)
            lo, hi = self.lower[k], self.upper[k]
            if not lo <= 0.0 <= hi:  # a term that cannot be switched off is not penalised
                continue
            top = max(abs(lo), abs(hi))
            a[i], b[i] = 0.5 * (hi - lo) / top, (lo + 0.5 * (hi - lo)) / top
        return a, b


def wrap(phase: Array | float) -> Array:
    """Angle wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(phase, float), 2.0 * np.pi)


class ArrowProblem:
    """The weighted least-squares problem of eq. 9-11 for R runs in the layout's block-arrow form."""

    def __init__(self, models: Sequence[HarmonicModel], layout: Layout, sigma: Array, sparsity: float = 0.0,
                 l1_epsilon: float = 1e-3):
        if len(models) != layout.n_runs:
            raise ValueError(f"{len(models)} models for {layout.n_runs} runs")
        for model in models:
            if list(model.parameters) != list(layout.parameters):
                raise ValueError(f"model parameters {model.parameters} differ from {list(layout.parameters)}")
            if not (np.allclose(model.lower, layout.lower) and np.allclose(model.upper, layout.upper)):
                raise ValueError("the libraries of a joint fit must share the parameter ranges")
        self.models = list(models)
        self.layout = layout
        self.H = int(sigma.shape[1])
        if any(m.H < self.H for m in models):
            raise ValueError(f"a model has fewer harmonics than the data's H = {self.H}")
        self.sigma = np.asarray(sigma, float)  # (R, H, C), C channels (the sensors; x, y on the VARM)
        self.C = int(self.sigma.shape[2])
        self.sparsity = float(sparsity)
        self.l1_epsilon = float(l1_epsilon)
        self.l1_a, self.l1_b = layout.l1_scale()
        self.h = np.arange(1, self.H + 1)

    @property
    def n_data(self) -> int:
        """Real data residuals per trial, n_r of eq. 10."""
        return self.layout.n_runs * 2 * self.C * self.H

    def model_response(self, theta: Array, r: int, jacobian: bool) -> tuple[Array, Array | None, Array]:
        """Run r's harmonics in the record's frame e^{ih phi} M (N, H, C), d/dx (N, H, C, d), rotation."""
        x, phi = self.layout.run_parameters(theta, r)
        M, dM = self.models[r].evaluate(x, jacobian)
        rotation = np.exp(1j * np.outer(phi, self.h))[:, :, None]  # (N, H, 1)
        M = rotation * M[:, : self.H]
        return M, (None if dM is None else rotation[..., None] * dM[:, : self.H]), rotation

    def responses(self, theta: Array, jacobian: bool) -> list[tuple[Array, Array | None]]:
        """Every run's ``model_response`` (M, dM) at theta (N, n), the models evaluated together where they can
        be batched across runs (``forward.evaluate_runs``)."""
        xs, phis = zip(*(self.layout.run_parameters(theta, k) for k in range(self.layout.n_runs)))
        out = []
        for k, (M, dM) in enumerate(evaluate_runs(self.models, xs, jacobian)):
            rotation = np.exp(1j * np.outer(phis[k], self.h))[:, :, None]  # (N, H, 1)
            out.append((rotation * M[:, : self.H], None if dM is None else rotation[..., None] * dM[:, : self.H]))
        return out

    def evaluate(self, theta: Array, X: Array, jacobian: bool = True) -> Evaluation:
        """Residuals (and Jacobian) at theta (N, n) for data X (N, R, H, C) complex."""
        N, R, L = theta.shape[0], self.layout.n_runs, self.layout
        m = 2 * self.C * self.H
        r = np.empty((N, R, m))
        Js = np.empty((N, R, m, L.n_shared)) if jacobian else None
        Jl = np.empty((N, R, m, L.n_block)) if jacobian else None
        responses = self.responses(theta, jacobian)
        for k in range(R):
            M, dM = responses[k]
            r[:, k] = _real((X[:, k] - M) / self.sigma[k])
            if jacobian:
                dM = -dM / self.sigma[k][None, :, :, None]
                Js[:, k] = _real(dM[..., L.shared_index])
                Jl[:, k, :, :-1] = _real(dM[..., L.local_index])
                Jl[:, k, :, -1] = _real(-1j * self.h[None, :, None] * M / self.sigma[k])
        rho, jd = self._sparsity(theta, jacobian)
        prior = self.layout.phase_prior  # the keyphasor phases' prior, phi / (Omega sigma_t), on other entries
        return Evaluation(r, rho + prior * theta, Js, Jl, None if jd is None else jd + prior)

    def prior_rows(self, theta: Array) -> tuple[Array, Array]:
        """The phase prior as pseudo-measurements at theta (n,): rows (p, n) of d rho / d theta, residuals (p,)."""
        prior = self.layout.phase_prior
        rows = np.diag(prior)[prior > 0]
        return rows, rows @ theta

    def _sparsity(self, theta: Array, jacobian: bool) -> tuple[Array, Array | None]:
        """rho = sqrt(lambda n_r) s / (s^2 + eps^2)^(1/4), s = a theta + b (module docstring, eq. 11)."""
        if self.sparsity <= 0:
            return np.zeros_like(theta), (np.zeros_like(theta) if jacobian else None)
        c = math.sqrt(self.sparsity * self.n_data)
        s = self.l1_a * theta + self.l1_b
        q = s * s + self.l1_epsilon**2
        rho = np.where(self.l1_a > 0, c * s * q**-0.25, 0.0)
        if not jacobian:
            return rho, None
        return rho, np.where(self.l1_a > 0, c * (0.5 * s * s + self.l1_epsilon**2) * q**-1.25 * self.l1_a, 0.0)

    def initial_phases(self, theta: Array, X: Array) -> Array:
        """theta with each run's phase set to align the 1X response: phi = arg(sum_c X_1c conj(M_1c) / s^2)."""
        theta = theta.copy()
        for k in range(self.layout.n_runs):
            if math.isfinite(self.layout.phase_sigma[k]):
                continue  # absolute phases: start at the keyphasor's 0
            x, _ = self.layout.run_parameters(theta, k)
            M, _ = self.models[k].evaluate(x, jacobian=False)
            weight = 1.0 / self.sigma[k, 0] ** 2
            theta[:, self.layout.block(k).stop - 1] = np.angle((X[:, k, 0] * np.conj(M[:, 0]) * weight).sum(-1))
        return theta

    def dense_jacobian(self, evaluation: Evaluation, trial: int = 0, data_only: bool = True) -> Array:
        """The trial's Jacobian as a dense (R m [+ n], n) matrix (uncertainty, scipy comparison)."""
        L = self.layout
        R, m = evaluation.r.shape[1:]
        J = np.zeros((R * m, L.n))
        for k in range(R):
            J[k * m:(k + 1) * m, : L.n_shared] = evaluation.Js[trial, k]
            J[k * m:(k + 1) * m, L.block(k)] = evaluation.Jl[trial, k]
        if data_only:
            return J
        return np.vstack([J, np.diag(evaluation.jd[trial])])

    def loss(self, evaluation: Evaluation) -> Array:
        """The paper's loss (eq. 9): chi^2 / n_r + lambda ||s||_1 (smoothed)."""
        return evaluation.objective / self.n_data


def _real(z: Array) -> Array:
    """Complex (N, H, C, ...) -> real (N, 2CH, ...) as [Re (H, C) flattened, Im (H, C) flattened]."""
    N = z.shape[0]
    flat = z.reshape((N, z.shape[1] * z.shape[2]) + z.shape[3:])
    return np.concatenate([flat.real, flat.imag], axis=1)
