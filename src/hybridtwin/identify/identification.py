"""Grey-box identification on the sPGD libraries (paper sec. 2.3, eq. 9-11; sec. 4.1).

The unknown parameters p of a variant are found by minimising, over the
parameters normalised to x = 2 (p - lo) / (hi - lo) - 1 in [-1, 1],

    L(x, phi) = L2 + L1,                                                       (eq. 9)
    L2 = (1 / n_r) sum_{run, h = 1..H, c = x, y} |X_hc - exp(i h phi_run) M_hc(x)|^2 / s_hc^2,   (eq. 10)
    L1 = lambda sum_j |p_j| / max(|lo_j|, |hi_j|),                            (eq. 11)

with X_hc the measured sensor harmonics (results/data/harmonics.tsv), M_hc the
library's (``Library``: response and exact Jacobian), s_hc the standard
uncertainty of each real and imaginary part (the measured sigma, plus, by
default, the library's own error, see ``total_sigma``) and n_r = 2 C H per run
the number of real residuals. The channels c are the machine's sensors in
the machine's order, C of them (x, y on the VARM: n_r = 4 H); the run's phase phi_run
is shared by all its channels (one time origin per record). How the paper's
loss is made precise here:

- eq. 10 is a sum of squares weighted by the uncertainties (a chi^2 per
  residual), so L2 ~ 1 when the model explains the data to within its noise;
  the paper's unweighted norm becomes that when the noise is white.
- Nuisances. Without a keyphasor the time origin of each record is arbitrary:
  a per-run phase phi rotates harmonic h by exp(i h phi) and is estimated with
  the parameters (it is never a physical result). With a keyphasor the phases
  are absolute (the unbalance on +x at the mark, docs/measurement-format.md), known
  to within the mark's timing uncertainty sigma_t: one common rotation of the
  record, h Omega delta_t. The run's phase is then kept, with a Gaussian prior
  phi ~ N(0, (Omega sigma_t)^2) (a residual phi / (Omega sigma_t) in the least
  squares, ``RunData.phase_sigma``, ``Layout.phase_prior``), and the measured
  sigmas are those of the noise alone (the origin's share, which
  preprocessing folds into them, taken out: it is that same rotation). The
  phase of the response then tells the damping apart from a bow fitted per
  run. DC offsets only touch h = 0, which is left out.
- eq. 11 acts on p / max|range| (the paper's normalisation, its Table 4), where
  0 is physical zero, so the L1 term switches terms off (only parameters whose
  range contains 0 are penalised); on [-1, 1] min-max
  coordinates 0 would be the middle of the range. |s| is smoothed as
  s^2 / sqrt(s^2 + eps^2) (eps = ``l1_epsilon``) and enters the least squares
  as a residual rho = sqrt(lambda n_r) s / (s^2 + eps^2)^(1/4), so the same
  problem goes to scipy.optimize.least_squares unchanged.


Optimiser: Levenberg-Marquardt batched over trials, with bounds by an active
set (``hybridtwin.identify.lm``).

Runs are joined in one block-arrow problem: shared physical parameters
(k_b, zeta_s, ...), and per run a block of local parameters (q_x, q_y by
default) and its phase. The normal matrix [[A, B], [B^T, C]] has one small
C_r per run and is solved by the Schur complement, so a joint fit of R runs
costs R small solves, not one dense n x n one (``arrow_solve``). A per-run fit
is the same problem with one run and every parameter "shared".

The paper's protocol (``hybridtwin.identify.protocol``): tau = 50 random trials, the lowest-loss trial kept as the
estimate; n_MC Monte Carlo repeats on data re-sampled with the measured sigmas (each from the best distinct
optima of the fit's trials, ``monte_carlo_starts`` and ``joint.monte_carlo_starts``); lambda = 0 for the Geometric
model, 0.1 for the Expansion model. The per-run and joint stages: ``hybridtwin.identify.run_fits``. Uncertainty and
identifiability: ``hybridtwin.identify.uncertainty``. The response models (library or full solver):
``hybridtwin.identify.forward``. Validation runs and per-run drift: ``hybridtwin.identify.validation``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .forward import HarmonicModel, SolverModel, evaluate_runs
from ..data.measured import (  # noqa: F401 (the measured harmonics: hybridtwin.data.measured, also read from here)
    CHANNELS, RunData, model_errors, read_harmonics, run_data, table_harmonics, total_sigma,
)
from .lm import STATUS_MESSAGES, Evaluation, LMOptions
from .protocol import ProtocolOptions, ProtocolResult, run_protocol
from .uncertainty import Profiled, Uncertainty, analyse_uncertainty, interval_basis, loose_entries, student_t

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


# --- results ----------------------------------------------------------------------------


#: the columns of ``Identification.table`` (parameters.tsv), in order
TABLE_COLUMNS = ("parameter", "run", "kind", "unit", "value", "normalised", "stderr", "ci_low", "ci_high", "interval",
                 "loose", "at_bound", "identifiable", "lower", "upper", "mc_mean", "mc_std", "mc_ci_low", "mc_ci_high",
                 "vif", "source")
#: the per-entry statistics among them (``Identification.statistics``); at_bound and identifiable are flags,
#: interval (a code of ``uncertainty.INTERVAL_CODES``) and loose (parameter names, comma-separated) text
STATISTICS = ("stderr", "ci_low", "ci_high", "interval", "loose", "at_bound", "identifiable", "mc_mean", "mc_std",
              "mc_ci_low", "mc_ci_high", "vif")
_FLAGS = ("at_bound", "identifiable")
_TEXT = ("interval", "loose")


@dataclass
class Identification:
    """An identification (one run or several jointly), scipy-like: x [SI] per entry of the layout,
    cost, fun (weighted data residuals), jac (d fun / d p, SI), status, message; plus the protocol,
    the uncertainty and the tables.

    A result read back from its parameter table (``from_table``) holds what the table holds: the layout
    (runs, shared and per-run parameters, ranges), x, theta, units, source and the per-entry statistics;
    problem, protocol, fun, jac, uncertainty and X are None there."""

    layout: Layout
    problem: ArrowProblem | None
    protocol: ProtocolResult | None
    x: Array
    theta: Array
    cost: float
    loss: float
    fun: Array | None
    jac: Array | None
    status: int
    message: str
    uncertainty: Uncertainty | None
    confidence: float
    data: list[RunData]
    X: Array | None  # (R, H, C) measured harmonics used
    units: dict[str, str] = field(default_factory=dict)
    source: str = "library"  # the response model: "library" (sPGD) or "solver" (full harmonic balance)
    starts: pd.DataFrame | None = None  # a polish's starts: start, chi2_start, chi2, chi2_dof, iterations, status
    read_columns: dict[str, Array] | None = None  # ``statistics`` and ``ranges`` as ``from_table`` read them
    profile: Profiled | None = None  # the intervals over the loose parameters (``hybridtwin.identify.profile``)
    unstable_runs: tuple[str, ...] = ()  # runs whose steady state at theta is unstable (``forward.check_stability``)

    @property
    def success(self) -> bool:
        return self.status > 0

    @property
    def chi2_dof(self) -> float:
        return math.nan if self.uncertainty is None else self.uncertainty.chi2_dof

    def _require_fit(self, what: str) -> None:
        if self.problem is None:
            raise ValueError(f"{what} needs the fit itself: this result was read from a parameter table "
                             f"(Identification.from_table), which holds only the estimates and their statistics")

    def entry(self, parameter: str, run: str | None = None) -> int:
        """Where ``parameter`` sits in x and theta: the shared entry, or ``run``'s own (a per-run parameter, or
        "phase"; ``run`` None: the first run)."""
        run = self.layout.runs[0] if run is None else run
        entries = self.layout.entries()
        for key in ((parameter, run), (parameter, "all")):
            if key in entries:
                return entries.index(key)
        raise KeyError(f"no entry {parameter!r} for run {run!r} (runs {list(self.layout.runs)})")

    def values(self, run: str | None = None) -> dict[str, float]:
        """Physical values [SI] of the shared parameters and of ``run``'s local ones (first run by default)."""
        run = self.layout.runs[0] if run is None else run
        return {p: float(v) for (p, r), v in zip(self.layout.entries(), self.x) if p != "phase"
                and r in ("all", run)}

    def fitted(self, trial_theta: Array | None = None) -> Array:
        """The fitted harmonics in each record's frame (R, H, C) complex [m]."""
        self._require_fit("the fitted harmonics")
        theta = (self.theta if trial_theta is None else trial_theta)[None]
        return np.stack([self.problem.model_response(theta, k, False)[0][0] for k in range(self.layout.n_runs)])

    def statistics(self) -> dict[str, Array]:
        """Per entry of theta (``STATISTICS``): stderr, the interval x -+ t stderr at ``confidence`` (Student t),
        widened over the loose parameters where ``profile`` holds their profile, what each interval is (``interval``,
        ``loose``: ``uncertainty.interval_basis``), at_bound, identifiable, the Monte Carlo repeats' mean, std and
        percentile interval (phases unwrapped around the estimate; NaN without repeats) and the variance inflation
        factor vif."""
        if self.read_columns is not None:
            return {name: self.read_columns[name] for name in STATISTICS}
        u, L = self.uncertainty, self.layout
        t = student_t(self.confidence, u.dof)
        mc = L.to_si(self.protocol.monte_carlo) if len(self.protocol.monte_carlo) else None
        alpha = 100 * (0.5 - 0.5 * self.confidence)
        out = {name: np.full(L.n, np.nan) for name in STATISTICS if name not in _FLAGS + _TEXT}
        out["at_bound"] = np.asarray(u.at_bound, bool) & ~L.is_phase
        out["identifiable"] = np.asarray(u.identifiable, bool)
        for i, (p, _) in enumerate(L.entries()):
            out["stderr"][i], out["vif"][i] = u.stderr[i], u.vif[i]
            out["ci_low"][i], out["ci_high"][i] = self.x[i] - t * u.stderr[i], self.x[i] + t * u.stderr[i]
            if mc is None:
                continue
            values = _unwrap_around(mc[:, i], self.x[i]) if p == "phase" else mc[:, i]
            out["mc_mean"][i] = values.mean()
            out["mc_std"][i] = values.std(ddof=1) if len(values) >= 2 else np.nan
            out["mc_ci_low"][i] = np.percentile(values, alpha)
            out["mc_ci_high"][i] = np.percentile(values, 100 - alpha)
        profiled = None
        if self.profile is not None:  # never narrower than the linearised interval (fmin/fmax skip its NaN), but a
            # loose parameter's own is its profile across its range (its linearised one is not valid: wider than the
            # range, or none at its edge)
            profiled = self.profile.profiled
            loose = loose_entries(L, u.at_bound, u.identifiable)
            low, high = (np.where(loose, np.nan, out[k]) for k in ("ci_low", "ci_high"))
            out["ci_low"] = np.where(profiled, np.fmin(low, self.profile.low), out["ci_low"])
            out["ci_high"] = np.where(profiled, np.fmax(high, self.profile.high), out["ci_high"])
        finite = np.isfinite(out["ci_low"]) & np.isfinite(out["ci_high"])
        out["interval"], out["loose"] = interval_basis(L, u.at_bound, u.identifiable, finite, profiled)
        return out

    def ranges(self) -> tuple[Array, Array]:
        """lower, upper of each entry of theta [SI]: its parameter's range, -pi and pi for a phase."""
        if self.read_columns is not None:
            return self.read_columns["lower"], self.read_columns["upper"]
        L = self.layout
        bounds = dict(zip(L.parameters, zip(L.lower, L.upper))) | {"phase": (-np.pi, np.pi)}
        return tuple(np.array([bounds[p][k] for p, _ in L.entries()], float) for k in (0, 1))

    def table(self) -> pd.DataFrame:
        """The parameter table (parameters.tsv), one row per entry of theta, columns ``TABLE_COLUMNS`` (SI):
        parameter, run ("all" for a shared one in a joint fit, the run itself in a per-run fit), kind ("shared",
        "per_run", "physical" in a per-run fit, "nuisance" for the phases), unit, value, normalised, the
        ``statistics``, lower, upper (the range), source. ``from_table`` reads it back."""
        L, (lower, upper) = self.layout, self.ranges()
        single = L.n_runs == 1
        parameters, runs = [p for p, _ in L.entries()], [r for _, r in L.entries()]
        columns = {
            "parameter": parameters, "run": [L.runs[0] if single else r for r in runs],
            "kind": ["nuisance" if p == "phase" else "physical" if single else "shared" if r == "all" else "per_run"
                     for p, r in L.entries()],
            "unit": ["rad" if p == "phase" else self.units.get(p, "") for p in parameters],
            "value": np.asarray(self.x, float), "normalised": np.where(L.is_phase, np.nan, self.theta),
            **self.statistics(), "lower": lower, "upper": upper, "source": self.source,
        }
        return pd.DataFrame({name: columns[name] for name in TABLE_COLUMNS})

    @classmethod
    def from_table(cls, table: pd.DataFrame, parameters: Sequence[str] | None = None) -> Identification:
        """The exact inverse of ``table()`` (``result.table()`` equals ``table``, values bit for bit), for what the
        table holds: the layout (runs, shared and per-run parameters, ranges), x, theta, units, source and the
        ``statistics``. Columns other than ``TABLE_COLUMNS`` (a per-run fit's note) are ignored.

        parameters: the libraries' parameter order, which the table does not hold (default: the shared ones,
        then the per-run ones); the phases' keyphasor priors are not held either (all taken as arbitrary)."""
        missing = [c for c in TABLE_COLUMNS if c not in table]
        if missing:
            raise ValueError(f"not a parameter table (Identification.table): no column(s) {missing}")
        rows = table.reset_index(drop=True)
        names, kinds, runs = (rows[c].astype(str).tolist() for c in ("parameter", "kind", "run"))
        phase = np.array([p == "phase" for p in names])
        if [k == "nuisance" for k in kinds] != phase.tolist():
            raise ValueError("parameter table: the rows of kind 'nuisance' must be exactly the phases")
        fit_runs = list(dict.fromkeys(r for r, is_phase in zip(runs, phase) if is_phase))
        single = set(kinds) <= {"physical", "nuisance"}
        if single and len(fit_runs) != 1:
            raise ValueError(f"parameter table: kind 'physical' is a per-run fit's, but it has the phases of runs "
                             f"{fit_runs}")
        local = [] if single else list(dict.fromkeys(p for p, k in zip(names, kinds) if k == "per_run"))
        shared = list(dict.fromkeys(p for p, k in zip(names, kinds) if k in ("shared", "physical")))
        order = list(parameters) if parameters is not None else shared + local
        if sorted(order) != sorted(shared + local):
            raise ValueError(f"parameter table: parameters {shared + local} are not the given order {order}")
        first = {p: i for i, p in reversed(list(enumerate(names)))}
        lower, upper = (rows[c].to_numpy(float) for c in ("lower", "upper"))
        layout = Layout.build(order, [lower[first[p]] for p in order], [upper[first[p]] for p in order], fit_runs,
                              local)
        expected = [(p, fit_runs[0] if single else r) for p, r in layout.entries()]
        if expected != list(zip(names, runs)):
            raise ValueError("parameter table: its rows are not in the order Identification.table writes them "
                             f"(expected {expected[:4]}..., got {list(zip(names, runs))[:4]}...)")
        sources = set(rows["source"].astype(str))
        if len(sources) != 1:
            raise ValueError(f"parameter table: one source expected, got {sorted(sources)}")
        x = rows["value"].to_numpy(float)
        read = {c: rows[c].astype(str).tolist() if c in _TEXT else rows[c].to_numpy(bool if c in _FLAGS else float)
                for c in STATISTICS + ("lower", "upper")}
        units = {p: u for p, u, is_phase in zip(names, rows["unit"].tolist(), phase) if not is_phase}
        return cls(layout, None, None, x, np.where(phase, x, rows["normalised"].to_numpy(float)), math.nan, math.nan,
                   None, None, 0, "read from a parameter table", None, math.nan, [], None, units, sources.pop(),
                   read_columns=read)

    def correlation_table(self) -> pd.DataFrame:
        self._require_fit("the correlation table")
        names = [p if r == "all" else f"{p}[{r}]" for p, r in self.layout.entries()]
        return pd.DataFrame(self.uncertainty.correlation, index=names, columns=names)

    def history_table(self) -> pd.DataFrame:
        """Loss (eq. 9) of every trial on the measured data after each iteration (long format)."""
        self._require_fit("the loss history")
        h = self.protocol.trials.history
        trial, iteration = np.nonzero(np.isfinite(h))
        return pd.DataFrame({"trial": trial, "iteration": iteration, "loss": h[trial, iteration],
                             "selected": trial == self.protocol.best})

    @property
    def n_residuals(self) -> int:
        """The residuals chi^2 and dof count: the data's (``ArrowProblem.n_data``) and one per keyphasor phase prior
        (a pseudo-measurement), so that n_residuals - dof is the number of fitted entries, phases included."""
        return int(self.problem.n_data + np.count_nonzero(self.layout.phase_prior))

    def summary(self) -> dict:
        self._require_fit("the summary")
        u, tr = self.uncertainty, self.protocol.trials
        at_best = np.isclose(tr.loss, tr.loss[self.protocol.best], rtol=1e-6, atol=1e-12)
        return {"runs": list(self.layout.runs), "shared": list(self.layout.shared),
                "per_run": list(self.layout.local), "keyphasor_runs": self.layout.absolute_runs,
                "n_data": self.n_residuals, "dof": int(u.dof),
                "chi2": float(u.chi2), "chi2_dof": float(u.chi2_dof), "loss": float(self.loss),
                "cost": float(self.cost), "status": int(self.status), "message": self.message,
                "collinearity_index": float(u.collinearity_index), "trials": int(len(tr.loss)),
                "trials_at_best": int(at_best.sum()), "monte_carlo": int(len(self.protocol.monte_carlo)),
                "lm_problems": int(self.protocol.n_lm), "seconds": float(self.protocol.seconds),
                "sparsity": float(self.problem.sparsity),
                "notes": list(u.notes) + (list(self.profile.notes) if self.profile is not None else [])}


def _unwrap_around(phases: Array, centre: float) -> Array:
    return centre + wrap(phases - centre)


def identify(models: Sequence[HarmonicModel], data: Sequence[RunData], per_run: Sequence[str] = (),
             options: ProtocolOptions = ProtocolOptions(), model_error: Mapping[str, float] | None = None,
             extra_starts: Array | None = None, units: Mapping[str, str] | None = None,
             scale_by_residual: bool = True) -> Identification:
    """Identify from R runs jointly (R = 1: a per-run fit): the protocol, then uncertainty at the best trial.

    models: one per run (libraries' ``SensorSurrogate`` or the full solver's
    ``SolverModel``), all with the same parameters and ranges; per_run: the
    parameters estimated per run (the others are shared); model_error: relative
    library error per run, added to the weights (``total_sigma``).
    """
    data = list(data)
    H = min(min(d.H for d in data), min(m.H for m in models))
    data = [replace(d, X=d.X[:H], sigma=d.sigma[:H]) for d in data]
    first = models[0]
    layout = Layout.for_data(first.parameters, first.lower, first.upper, data, per_run)
    errors = model_error or {}
    sigma = np.stack([total_sigma(d, errors.get(d.run, 0.0)) for d in data])
    X = np.stack([d.X for d in data])
    problem = ArrowProblem(models, layout, sigma, options.sparsity, options.l1_epsilon)
    protocol = run_protocol(problem, X, np.stack([d.sigma for d in data]), options, extra_starts)
    return conclude(problem, protocol, data, X, options.confidence, units, scale_by_residual)


def conclude(problem: ArrowProblem, protocol: ProtocolResult, data: Sequence[RunData], X: Array,
             confidence: float = 0.95, units: Mapping[str, str] | None = None,
             scale_by_residual: bool = True) -> Identification:
    """The result object at the protocol's best trial: residuals, Jacobian [SI], uncertainty."""
    layout = problem.layout
    theta = protocol.theta
    ev = problem.evaluate(theta[None], X[None])
    prior_J, prior_r = problem.prior_rows(theta)  # the keyphasor phases' prior counts as data here
    J = np.vstack([problem.dense_jacobian(ev), prior_J])
    r = np.concatenate([ev.r[0].reshape(-1), prior_r])
    uncertainty = analyse_uncertainty(J, r, theta, layout, scale_by_residual)
    status = int(protocol.trials.status[protocol.best])
    return Identification(layout, problem, protocol, layout.to_si(theta), theta,
                          float(protocol.trials.cost[protocol.best]), float(protocol.trials.loss[protocol.best]),
                          r, J / layout.scale(), status, STATUS_MESSAGES[status], uncertainty, confidence,
                          list(data), X, dict(units or {}),
                          "solver" if any(isinstance(m, SolverModel) for m in problem.models) else "library")


def write_parameters(table: pd.DataFrame, path: str | Path) -> None:
    """A parameter table (``Identification.table``, parameters.tsv) as TSV, 9 significant digits."""
    table.to_csv(path, sep="\t", index=False, float_format="%.9g")


def read_parameters(path: str | Path) -> pd.DataFrame:
    """A parameter table written by ``write_parameters``: names, runs and units as text (run "001" stays "001",
    unit "1" a string, an empty unit ""), ``TABLE_COLUMNS``' numbers as floats; ``Identification.from_table``
    reads the result. Other columns (a per-run fit's note, a refit's effect) come as pandas reads them."""
    text = {"parameter", "run", "kind", "unit", "interval", "loose", "source", "note", "effect", "validation_run"}
    header = pd.read_csv(path, sep="\t", nrows=0).columns
    table = pd.read_csv(path, sep="\t", dtype={c: str for c in text}, keep_default_na=False,
                        na_values={c: ["", "nan", "NaN", "NA"] for c in header if c not in text})
    for column in set(TABLE_COLUMNS).difference(text, _FLAGS).intersection(header):
        table[column] = table[column].astype(float)
    return table


def theta_from_table(table: pd.DataFrame, layout: Layout) -> Array | None:
    """theta of ``layout`` from a parameter table (``Identification.table``: parameter, run, value [SI]),
    values normalised with the layout's own ranges; None when an entry is missing or not finite."""
    values = {(str(r.parameter), str(r.run)): float(r.value) for r in table.itertuples()}
    if any(e not in values for e in layout.entries()):
        return None
    theta = np.array([values[(p, run)] if p == "phase" else float(layout.normalise(p, values[(p, run)]))
                      for p, run in layout.entries()])
    return np.clip(theta, *layout.bounds()) if np.isfinite(theta).all() else None


# --- workflow configuration -------------------------------------------------------------

#: the ``identification:`` section's defaults (config/config.yaml; schema in workflow/schemas)
DEFAULTS: dict = {
    "trials": 50,  # tau, random trials per fit (paper sec. 4.1)
    "monte_carlo": 1000,  # n_MC repeats per per-run fit
    # where a per-run fit's repeats start: the k best distinct optima of its trials on the measured data
    # (hybridtwin.identify.protocol; 0: tau fresh random starts per repeat, the paper's literal protocol, ~15x the time)
    "monte_carlo_starts": 8,
    "sparsity": {"expansion": 0.1},  # lambda per variant (eq. 11); 0 for the others
    "l1_epsilon": 1e-3,
    "seed": 1,
    "per_run": ["q_x", "q_y"],  # joint fit: estimated per run; the other unknowns are shared
    "model_error": "median_error_pct",  # library error added to the weights (library_validation.tsv column | none)
    "confidence": 0.95,
    "max_iterations": 100,
    # the joint fit's protocol; its repeats also start at the k best distinct optima of its trials (0: fresh
    # random starts each, the literal protocol, 6-13x the time of the library stage of identify_joint)
    "joint": {"trials": 50, "monte_carlo": 100, "monte_carlo_starts": 8},
    "polish": {"joint": True, "runs": False, "max_iterations": 60, "nested": True},
    "keyphasor": True,  # runs with a keyphasor: absolute phases, phase prior N(0, (Omega sigma_t)^2); false: free
    "validation_bow": "law",  # per-run parameters of validation runs: law (c0 + c1 W^2 + c2 W^2 m_e) | mean
    # a shared parameter of the joint fit at a range edge or not identifiable: the shared parameters' intervals over
    # it (hybridtwin.identify.profile); false: the linearised ones, marked conditional on it
    "profile": True,
}


def runs_with_role(sheet: str | Path, role: str) -> list[str]:
    """Runs of a runs sheet with this role (no role column: every run is a fit run), read as check-data reads it."""
    from ..data.measurements import runs_with_role as read_role  # the one reader of runs sheets

    return read_role(sheet, role)


def settings(config: Mapping, variant: str) -> dict:
    """The identification options for ``variant``: defaults, then the config's section; lambda resolved; the
    variant's own ``per_run`` (its entry under ``variants:``) over ``identification.per_run``."""
    given = dict(config.get("identification") or {})
    out = {**DEFAULTS, **given}
    own = ((config.get("variants") or {}).get(variant) or {}).get("per_run")
    if own is not None:
        out["per_run"] = list(own)
    for key in ("joint", "polish"):
        out[key] = {**DEFAULTS[key], **(given.get(key) or {})}
    sparsity = out["sparsity"]
    out["lambda"] = float(sparsity.get(variant, 0.0) if isinstance(sparsity, Mapping) else sparsity)
    return out


def rule_settings(config: Mapping, variant: str, rule: str) -> dict:
    """The part of ``settings`` a workflow rule depends on (its params: a change reruns only that rule)."""
    options = settings(config, variant)
    common = {k: options[k] for k in ("lambda", "l1_epsilon", "seed", "model_error", "confidence", "max_iterations",
                                      "keyphasor")}
    if rule == "run":
        polish_runs = options["polish"]["runs"]
        return common | {"trials": options["trials"], "monte_carlo": options["monte_carlo"],
                         "monte_carlo_starts": options["monte_carlo_starts"],
                         "polish": options["polish"]["max_iterations"] if polish_runs else False}
    polish_joint = options["polish"]["max_iterations"] if options["polish"]["joint"] else False
    if rule == "joint":
        # polish: nested changes the job's input files (the nested fits), which reruns it by itself
        return common | {"joint": options["joint"], "per_run": options["per_run"], "polish": polish_joint,
                         "profile": bool(options["profile"])}
    return {"validation_bow": options["validation_bow"], "model_error": options["model_error"],
            "solver": bool(options["polish"]["joint"]), "keyphasor": options["keyphasor"],
            "per_run": options["per_run"]}  # per_run: a failing validation run's refit with the fit runs


def protocol_options(options: Mapping, joint: bool = False) -> ProtocolOptions:
    """ProtocolOptions from ``settings``; ``joint`` takes the joint fit's trials, repeats and their starts."""
    source = options["joint"] if joint else options
    return ProtocolOptions(trials=int(source["trials"]), monte_carlo=int(source["monte_carlo"]),
                           sparsity=float(options["lambda"]), l1_epsilon=float(options["l1_epsilon"]),
                           seed=int(options["seed"]), confidence=float(options["confidence"]),
                           lm=LMOptions(max_iterations=int(options["max_iterations"])),
                           monte_carlo_starts=int(source["monte_carlo_starts"]))


def units(variant) -> dict[str, str]:
    """Parameter units of a variant ("1" for dimensionless)."""
    return {name: p.unit for name, p in variant.model.parameters.items()}
