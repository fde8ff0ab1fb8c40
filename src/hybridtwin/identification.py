"""Grey-box identification on the sPGD libraries (paper sec. 2.3, eq. 9-11; sec. 4.1).

The unknown parameters p of a variant are found by minimising, over the
parameters normalised to x = 2 (p - lo) / (hi - lo) - 1 in [-1, 1],

    L(x, phi) = L2 + L1,                                                       (eq. 9)
    L2 = (1 / n_r) sum_{run, h = 1..H, c = x, y} |X_hc - exp(i h phi_run) M_hc(x)|^2 / s_hc^2,   (eq. 10)
    L1 = lambda sum_j |p_j| / max(|lo_j|, |hi_j|),                            (eq. 11)

with X_hc the measured sensor harmonics (results/data/harmonics.tsv), M_hc the
library's (``Library``: response and exact Jacobian), s_hc the standard
uncertainty of each real and imaginary part (the measured sigma, plus, by
default, the library's own error, see ``total_sigma``) and n_r = 4 H per run
the number of real residuals. How the paper's loss is made precise here:

- eq. 10 is a sum of squares weighted by the uncertainties (a chi^2 per
  residual), so L2 ~ 1 when the model explains the data to within its noise;
  the paper's unweighted norm becomes that when the noise is white.
- Nuisances. Without a keyphasor the time origin of each record is arbitrary:
  a per-run phase phi rotates harmonic h by exp(i h phi) and is estimated with
  the parameters (it is never a physical result). With a keyphasor the phases
  are absolute (the unbalance on +x at the mark, measurement-format.md), known
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

Optimiser: Levenberg-Marquardt batched over trials (``levenberg_marquardt``):
every trial (random start, Monte Carlo repeat) advances in the same numpy
operations, with its own damping factor mu (Nielsen's update), Marquardt's
scaling diag(J^T J), and trials that have converged are masked out. Bounds
[-1, 1] are handled by projection with an active set (no transform, so the
Jacobian at the optimum is the model's): a parameter on a bound whose gradient
points outwards is held fixed; if the coupled damped Gauss-Newton step still
pushes a bound parameter out, it is held too and the step solved again; a
step that would leave the box is shortened along its direction to end on
the box (projecting it entry by entry would turn it, and in a correlated
valley it would then no longer descend), and an entry ending within ``SNAP``
of a bound lands on it (no creeping in ever shorter steps).
Stopping: scipy's ftol/xtol/gtol, plus a stall rule (chi^2 fell by less than
0.01 over 5 iterations: points along a flat valley are statistically
equivalent, and per-run problems are such valleys). Optional geodesic
acceleration (Transtrum & Sethna) is used by the full-solver polish.

Runs are joined in one block-arrow problem: shared physical parameters
(k_b, zeta_s, ...), and per run a block of local parameters (q_x, q_y by
default) and its phase. The normal matrix [[A, B], [B^T, C]] has one small
C_r per run and is solved by the Schur complement, so a joint fit of R runs
costs R small solves, not one dense n x n one (``arrow_solve``). A per-run fit
is the same problem with one run and every parameter "shared".

The paper's protocol (``ProtocolOptions``): tau = 50 random trials, the
lowest-loss trial kept; n_MC = 1000 Monte Carlo repeats on data re-sampled
with the measured sigmas (X + sigma (N(0,1) + i N(0,1))); lambda = 0 for the
Geometric model, 0.1 for the Expansion model. The estimate reported is the
best trial on the measured data; the Monte Carlo repeats give the paper's
average and a distribution that checks the linearised uncertainty.

Uncertainty and identifiability (``analyse_uncertainty``): covariance
s^2 V S^-2 V^T from the SVD of the weighted Jacobian of the free parameters,
s^2 = max(1, chi^2 / dof); parameters at a bound are held fixed (their covariance is
not valid, and the others' include their uncertainty, computed as if free); correlation matrix;
collinearity index (Brun et al. 2001) of the unit-normalised sensitivities of
the physical parameters with the phases projected out; flags for
non-identifiable parameters and estimates at a range edge ("revise the range").
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd

from .library import Library
from .pod import feature_index
from .scenarios import intermediate_speeds

Array = np.ndarray

CHANNELS = ("x", "y")
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
#: an estimate within this distance of a range edge (0.1 % of the range) is "at the bound"
BOUND_TOLERANCE = 2e-3
#: collinearity index above which a parameter set is poorly identifiable (Brun et al. 2001: 10-15)
COLLINEARITY_LIMIT = 15.0
#: singular values below this fraction of the largest are treated as zero (non-identifiable directions)
RCOND = 1e-12


class IdentificationWarning(UserWarning):
    """An identification result a user must look at (estimate at a bound, non-identifiable parameter)."""


# --- measured data ----------------------------------------------------------------------


@dataclass(frozen=True)
class RunData:
    """One run's measured sensor harmonics h = 1..H (DC excluded) and their uncertainties.

    X: (H, 2) complex [m], channels x, y; sigma: (H, 2) [m], standard uncertainty of
    each of the real and imaginary parts (measured, from the synchronous analysis).
    """

    run: str
    rpm: float
    eccentric_mass_g: float
    role: str
    X: Array
    sigma: Array
    usable: bool = True
    note: str = "ok"
    phase_sigma: float = math.inf  # [rad] uncertainty of X's absolute phase (keyphasor); inf: arbitrary origin

    @property
    def H(self) -> int:
        return self.X.shape[0]


def read_harmonics(path: str | Path) -> pd.DataFrame:
    """The preprocessed table (results/data/harmonics.tsv), run ids as strings."""
    return pd.read_csv(path, sep="\t", dtype={"run": str})


def table_harmonics(table: pd.DataFrame) -> int:
    """Highest harmonic H present in a harmonics table (columns x{h}_re_m)."""
    h = 0
    while f"x{h + 1}_re_m" in table:
        h += 1
    if h == 0:
        raise ValueError("the harmonics table has no x1_re_m column (not results/data/harmonics.tsv?)")
    return h


def run_data(table: pd.DataFrame, run: str, harmonics: int | None = None, keyphasor: bool = True) -> RunData:
    """The measured harmonics of ``run`` from the preprocessed table (h = 1..H, SI).

    With ``keyphasor`` (the default), a run whose phases were referred to its keyphasor mark
    (``phase_reference`` "keyphasor") has absolute phases: phase_sigma = Omega sigma_t, and sigma is
    the noise's alone (the origin's share, ``preprocessing.origin_share``, taken out of the table's).
    """
    rows = table[table["run"] == run]
    if len(rows) != 1:
        raise ValueError(f"the harmonics table has {len(rows)} rows for run {run!r} (expected 1)")
    row = rows.iloc[0]
    H = table_harmonics(table) if harmonics is None else min(harmonics, table_harmonics(table))
    X = np.array([[row[f"{c}{h}_re_m"] + 1j * row[f"{c}{h}_im_m"] for c in CHANNELS] for h in range(1, H + 1)])
    sigma = np.array([[row[f"{c}{h}_sigma_m"] for c in CHANNELS] for h in range(1, H + 1)], float)
    rpm = float(row.get("rpm_true", row["rpm"]))
    phase_sigma = math.inf
    if keyphasor and str(row.get("phase_reference", "arbitrary")) == "keyphasor":
        from .preprocessing import origin_share

        omega, sigma_t = rpm * math.pi / 30.0, float(row["phase_origin_sigma_s"])
        share = origin_share(np.vstack([np.zeros((1, 2)), X]).T, omega, sigma_t).T[1:]  # (H, 2)
        sigma = np.sqrt(np.maximum(sigma**2 - share**2, (1e-3 * sigma) ** 2))
        phase_sigma = max(omega * sigma_t, 1e-9)
    usable = bool(row.get("usable", True)) and np.isfinite(X).all() and np.isfinite(sigma).all()
    return RunData(str(run), rpm, float(row["eccentric_mass_g"]), str(row.get("role", "fit")), X, sigma, usable,
                   str(row.get("note", "ok")), phase_sigma)


def total_sigma(data: RunData, relative_model_error: float = 0.0) -> Array:
    """Residual weights s_hc (eq. 10): the measured sigma and a relative model error in quadrature.

    A library with relative error e (its validation table's median) misses each
    harmonic by about e |X_hc|, i.e. e |X_hc| / sqrt(2) per real and imaginary part.
    """
    return np.sqrt(data.sigma**2 + 0.5 * (relative_model_error * np.abs(data.X)) ** 2)


def model_errors(validation: pd.DataFrame | None, runs: Sequence[str], column: str | None = "median_error_pct"
                 ) -> dict[str, float]:
    """Relative library error per run (fraction) from library_validation.tsv; 0 without a table or column."""
    if validation is None or column in (None, "none"):
        return {r: 0.0 for r in runs}
    table = validation.set_index(validation["run"].astype(str))
    out = {}
    for run in runs:
        value = table[column].get(run, np.nan) if column in table else np.nan
        out[run] = 0.0 if not np.isfinite(value) else float(value) / 100.0
    return out


# --- the response models ----------------------------------------------------------------


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
        self.sigma = np.asarray(sigma, float)  # (R, H, 2)
        self.sparsity = float(sparsity)
        self.l1_epsilon = float(l1_epsilon)
        self.l1_a, self.l1_b = layout.l1_scale()
        self.h = np.arange(1, self.H + 1)

    @property
    def n_data(self) -> int:
        """Real data residuals per trial, n_r of eq. 10."""
        return self.layout.n_runs * 4 * self.H

    def model_response(self, theta: Array, r: int, jacobian: bool) -> tuple[Array, Array | None, Array]:
        """Run r's harmonics in the record's frame e^{ih phi} M (N, H, 2), d/dx (N, H, 2, d), rotation."""
        x, phi = self.layout.run_parameters(theta, r)
        M, dM = self.models[r].evaluate(x, jacobian)
        rotation = np.exp(1j * np.outer(phi, self.h))[:, :, None]  # (N, H, 1)
        M = rotation * M[:, : self.H]
        return M, (None if dM is None else rotation[..., None] * dM[:, : self.H]), rotation

    def evaluate(self, theta: Array, X: Array, jacobian: bool = True) -> Evaluation:
        """Residuals (and Jacobian) at theta (N, n) for data X (N, R, H, 2) complex."""
        N, R, L = theta.shape[0], self.layout.n_runs, self.layout
        m = 4 * self.H
        r = np.empty((N, R, m))
        Js = np.empty((N, R, m, L.n_shared)) if jacobian else None
        Jl = np.empty((N, R, m, L.n_block)) if jacobian else None
        for k in range(R):
            M, dM, _ = self.model_response(theta, k, jacobian)
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
    """Complex (N, H, 2, ...) -> real (N, 4H, ...) as [Re (H, 2) flattened, Im (H, 2) flattened]."""
    N = z.shape[0]
    flat = z.reshape((N, z.shape[1] * z.shape[2]) + z.shape[3:])
    return np.concatenate([flat.real, flat.imag], axis=1)


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
    def assemble(cls, ev: Evaluation, layout: Layout) -> "Normal":
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


def _jvp(ev: Evaluation, delta: Array, layout: Layout) -> tuple[Array, Array]:
    """J delta: the data part (N, R, m) and the sparsity part (N, n)."""
    ds = layout.n_shared
    N, R = ev.r.shape[:2]
    dl = delta[:, ds:].reshape(N, R, layout.n_block)
    return (np.einsum("nrmi,ni->nrm", ev.Js, delta[:, :ds]) + np.einsum("nrmi,nri->nrm", ev.Jl, dl),
            ev.jd * delta)


def _jtv(ev: Evaluation, v: Array, v_rho: Array, layout: Layout) -> tuple[Array, Array]:
    """J^T v as (shared (N, d_s), blocks (N, R, k))."""
    N, R = ev.r.shape[:2]
    ds = layout.n_shared
    gs = np.einsum("nrmi,nrm->ni", ev.Js, v) + ev.jd[:, :ds] * v_rho[:, :ds]
    gl = np.einsum("nrmi,nrm->nri", ev.Jl, v) + (ev.jd[:, ds:] * v_rho[:, ds:]).reshape(N, R, layout.n_block)
    return gs, gl


def _linearised(ev: Evaluation, delta: Array, layout: Layout) -> Array:
    """||r + J delta||^2 + ||rho + jd delta||^2 (the Gauss-Newton model of the objective) (N,)."""
    jr, jrho = _jvp(ev, delta, layout)
    r, rho = ev.r + jr, ev.rho + jrho
    return np.einsum("nrm,nrm->n", r, r) + np.einsum("ni,ni->n", rho, rho)


def _geodesic(problem: "ArrowProblem", ev: Evaluation, normal: Normal, theta: Array, delta: Array, X: Array,
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


def levenberg_marquardt(problem: ArrowProblem, theta0: Array, X: Array, options: LMOptions = LMOptions()
                        ) -> LMResult:
    """Minimise ||r||^2 + ||rho||^2 (eq. 9-11) from every start theta0 (T, n), trial t on data X[t] (T, R, H, 2).

    Batched projected Levenberg-Marquardt (module docstring), in batches of ``options.batch`` trials.
    """
    parts = [_lm_batch(problem, theta0[s], X[s], options)
             for s in _batches(theta0.shape[0], options.batch)]
    return LMResult.concatenate(parts)


def _batches(n: int, size: int) -> list[slice]:
    return [slice(i, min(i + size, n)) for i in range(0, n, max(int(size), 1))]


def _lm_batch(problem: ArrowProblem, theta0: Array, X: Array, options: LMOptions) -> LMResult:
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
        free = ~(((th <= lower) & (g > 0)) | ((th >= upper) & (g < 0)))
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


# --- the paper's protocol: tau trials, n_MC Monte Carlo repeats -------------------------


@dataclass(frozen=True)
class ProtocolOptions:
    """The paper's protocol (sec. 2.3, 4.1): tau trials, n_MC repeats, lambda; LM stopping rules."""

    trials: int = 50  # tau
    monte_carlo: int = 1000  # n_MC
    sparsity: float = 0.0  # lambda (eq. 11): 0 Geometric, 0.1 Expansion
    l1_epsilon: float = 1e-3
    seed: int = 0
    confidence: float = 0.95
    lm: LMOptions = LMOptions()


@dataclass
class ProtocolResult:
    """Trials on the measured data (repeat 0) and the best trial of every Monte Carlo repeat.

    trials: LMResult of repeat 0's trials (with loss histories); best: index of the
    lowest-loss one; monte_carlo: (n_MC, n) best theta of each repeat;
    monte_carlo_loss: (n_MC,); seconds: wall time of the whole protocol.
    """

    trials: LMResult
    best: int
    monte_carlo: Array
    monte_carlo_loss: Array
    seconds: float
    n_lm: int  # LM problems solved in all

    @property
    def theta(self) -> Array:
        return self.trials.x[self.best]


def random_starts(layout: Layout, n: int, rng: np.random.Generator) -> Array:
    """n uniform random starts in [-1, 1] for the physical entries (phases set later), (n, layout.n)."""
    theta = rng.uniform(-1.0, 1.0, (n, layout.n))
    theta[:, layout.is_phase] = 0.0
    return theta


def run_protocol(problem: ArrowProblem, X: Array, sigma_noise: Array, options: ProtocolOptions = ProtocolOptions(),
                 extra_starts: Array | None = None) -> ProtocolResult:
    """tau random trials (+ ``extra_starts``) on the data and on n_MC re-sampled copies, one batched LM.

    X, sigma_noise: (R, H, 2) measured harmonics and the measured sigmas used for
    re-sampling (X + sigma (N(0,1) + i N(0,1)), independently per repeat).
    """
    start = time.perf_counter()
    rng = np.random.default_rng(options.seed)
    layout = problem.layout
    extra = np.zeros((0, layout.n)) if extra_starts is None else np.atleast_2d(extra_starts)
    per_repeat = options.trials + extra.shape[0]
    if per_repeat < 1:
        raise ValueError("the protocol needs at least one trial")
    repeats = 1 + options.monte_carlo
    noise = rng.standard_normal((options.monte_carlo, *X.shape)) + 1j * rng.standard_normal(
        (options.monte_carlo, *X.shape))
    data = np.concatenate([X[None], X[None] + sigma_noise[None] * noise])  # (repeats, R, H, 2)
    theta0 = np.concatenate([np.concatenate([random_starts(layout, options.trials, rng), extra])
                             for _ in range(repeats)])
    data_t = np.repeat(data, per_repeat, axis=0)
    theta0 = _initial_phases(problem, theta0, data_t, extra.shape[0], per_repeat)
    result = levenberg_marquardt(problem, theta0, data_t, options.lm)
    loss = result.loss.reshape(repeats, per_repeat)
    best = loss.argmin(1)
    best_theta = result.x.reshape(repeats, per_repeat, -1)[np.arange(repeats), best]
    return ProtocolResult(result.take(np.arange(per_repeat)), int(best[0]), best_theta[1:],
                          loss[np.arange(repeats), best][1:], time.perf_counter() - start, theta0.shape[0])


def _initial_phases(problem: ArrowProblem, theta0: Array, data: Array, n_extra: int, per_repeat: int) -> Array:
    """Random starts get 1X-aligned phases; extra starts keep theirs unless they are zero."""
    out = theta0.copy()
    aligned = np.concatenate([problem.initial_phases(theta0[s], data[s]) for s in _batches(len(theta0), 20000)])
    is_extra = (np.arange(len(theta0)) % per_repeat) >= per_repeat - n_extra
    phase = problem.layout.is_phase
    keep = is_extra[:, None] & phase[None, :] & (theta0 != 0)
    out[:, phase] = np.where(keep[:, phase], theta0[:, phase], aligned[:, phase])
    return out


# --- uncertainty and identifiability ----------------------------------------------------


@dataclass
class Uncertainty:
    """Linearised uncertainty at the optimum (entries of theta; SI through ``scale``).

    covariance (n, n) [SI^2], NaN for entries held at a bound; chi2, dof,
    chi2_dof = chi^2 / dof (the residual noise the covariance is scaled by);
    singular_values of the weighted Jacobian of the free entries;
    collinearity_index of the physical free entries (phases projected out);
    vif: variance inflation of each physical entry; identifiable, at_bound flags;
    notes: sentences for the log and the summary.
    """

    covariance: Array
    stderr: Array
    correlation: Array
    chi2: float
    dof: int
    singular_values: Array
    collinearity_index: float
    vif: Array
    at_bound: Array
    identifiable: Array
    null_loading: Array
    notes: list[str] = field(default_factory=list)

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")


def analyse_uncertainty(J: Array, r: Array, theta: Array, layout: Layout, scale_by_residual: bool = True,
                        rcond: float = RCOND) -> Uncertainty:
    """Covariance from the SVD of the weighted Jacobian J (m, n) at theta, scaled by chi^2/dof (module docstring).

    The scale is max(1, chi^2/dof) (Birge ratio): residuals above the stated
    noise widen the intervals; below it (chance, dof finite) they never shrink
    them under what the measured sigmas allow.
    J is d r / d theta (normalised parameters, phases in rad), so the SVD
    compares dimensionless directions; the covariance is converted to SI after.
    Entries at a bound have no valid interval of their own; the covariance is
    computed with them as if free, so the others' intervals include their
    uncertainty rather than being conditional on the edge values (said in
    ``notes``). Directions with a
    singular value below rcond * the largest are numerically null: left out of
    the pseudo-inverse, and the entries loading on them flagged. A parameter is
    identifiable when it is free, not on a null direction, and its 95 %
    interval is narrower than its range.
    """
    n = layout.n
    scale = layout.scale()
    lo, hi = layout.bounds()
    undefined = ~np.isfinite(J).all(0)  # a sensitivity the model could not give (no solution either side)
    J = np.where(undefined, 0.0, J)
    at_bound = (theta <= lo + BOUND_TOLERANCE) | (theta >= hi - BOUND_TOLERANCE)
    free = ~at_bound
    chi2 = float(r @ r)
    dof = int(J.shape[0] - free.sum())
    s2 = max(chi2 / dof, 1.0) if (scale_by_residual and dof > 0) else 1.0
    # all entries, those at a bound as if free: the free ones' intervals then include how little the data fix
    # the bound ones (conservative), instead of being conditional on the edge values
    U, S, Vt = np.linalg.svd(J, full_matrices=False)
    keep = S > rcond * (S[0] if S.size else 1.0)
    inverse = np.where(keep, 1.0 / np.where(keep, S, 1.0) ** 2, 0.0)
    covariance = s2 * (Vt.T * inverse) @ Vt * np.outer(scale, scale)
    covariance[at_bound, :] = np.nan  # an interval around an estimate pinned at a range edge is not valid
    covariance[:, at_bound] = np.nan
    stderr = np.sqrt(np.diag(covariance).clip(min=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(stderr, stderr)
    null = (Vt[~keep] ** 2).sum(0) if (~keep).any() else np.zeros(n)
    gamma, vif = _collinearity(J, free, layout)
    width = np.where(layout.is_phase, np.inf, 2.0 * scale)  # the range width [SI]
    identifiable = free & (null < 0.1) & (2 * 1.96 * stderr < width) & np.isfinite(stderr)
    notes = _uncertainty_notes(layout, at_bound, identifiable, gamma, chi2, dof)
    if undefined.any():
        names = [p if run == "all" else f"{p}[{run}]" for (p, run), u in zip(layout.entries(), undefined) if u]
        notes.append(f"no sensitivity for {', '.join(names)} (the model has no solution next to the estimate): "
                     "treated as not identifiable")
    return Uncertainty(covariance, stderr, correlation, chi2, dof, S, gamma, vif, at_bound, identifiable, null,
                       notes)


def _collinearity(J: Array, free: Array, layout: Layout) -> tuple[float, Array]:
    """Brun's collinearity index of the free physical entries, phases projected out, and their VIFs."""
    phys = free & ~layout.is_phase
    vif = np.full(layout.n, np.nan)
    if not phys.any():
        return float("nan"), vif
    S = J[:, phys]
    phases = J[:, free & layout.is_phase]
    if phases.size:
        Q, _ = np.linalg.qr(phases)
        S = S - Q @ (Q.T @ S)
    norms = np.linalg.norm(S, axis=0)
    if (norms <= 0).any():
        vif[phys] = np.where(norms > 0, np.nan, np.inf)
        return float("inf"), vif
    Sn = S / norms
    sv = np.linalg.svd(Sn, compute_uv=False)
    gamma = float(1.0 / sv[-1]) if sv[-1] > 0 else float("inf")
    try:
        vif[phys] = np.diag(np.linalg.inv(Sn.T @ Sn))
    except np.linalg.LinAlgError:
        vif[phys] = np.inf
    return gamma, vif


def _uncertainty_notes(layout: Layout, at_bound: Array, identifiable: Array, gamma: float, chi2: float,
                       dof: int) -> list[str]:
    notes = []
    names = [p if run == "all" else f"{p}[{run}]" for p, run in layout.entries()]
    bound = [n for n, b, ph in zip(names, at_bound, layout.is_phase) if b and not ph]
    if bound:
        caveat = (" (the parameters are poorly identifiable together here, so an edge estimate may only mean "
                  "that the data do not determine it)" if np.isfinite(gamma) and gamma > COLLINEARITY_LIMIT else "")
        notes.append(f"estimate at a range edge for {', '.join(bound)}: revise the range (widen it and rebuild "
                     "the library); their own intervals are not valid there, and the others' include their "
                     f"uncertainty (computed as if they were free){caveat}")
    weak = [n for n, ok, b, ph in zip(names, identifiable, at_bound, layout.is_phase) if not ok and not b and not ph]
    if weak:
        notes.append(f"not identifiable from these data: {', '.join(weak)} (null direction of the Jacobian or "
                     "95 % interval wider than the range)")
    if np.isfinite(gamma) and gamma > COLLINEARITY_LIMIT:
        notes.append(f"collinearity index {gamma:.1f} > {COLLINEARITY_LIMIT:g}: the physical parameters are "
                     "poorly identifiable together (their effects on the response nearly compensate)")
    if dof > 0 and chi2 / dof > 4.0:
        notes.append(f"chi^2/dof = {chi2 / dof:.3g}: the residuals exceed the stated noise (model or library "
                     "error); the covariance is scaled up by it")
    return notes


def student_t(confidence: float, dof: int) -> float:
    """Two-sided quantile of Student's t (the normal one for dof > 1000)."""
    from scipy.stats import t

    return float(t.ppf(0.5 + 0.5 * confidence, max(dof, 1)))


# --- results ----------------------------------------------------------------------------


@dataclass
class Identification:
    """An identification (one run or several jointly), scipy-like: x [SI] per entry of the layout,
    cost, fun (weighted data residuals), jac (d fun / d p, SI), status, message; plus the protocol,
    the uncertainty and the tables."""

    layout: Layout
    problem: ArrowProblem
    protocol: ProtocolResult
    x: Array
    theta: Array
    cost: float
    loss: float
    fun: Array
    jac: Array
    status: int
    message: str
    uncertainty: Uncertainty
    confidence: float
    data: list[RunData]
    X: Array  # (R, H, 2) measured harmonics used
    units: dict[str, str] = field(default_factory=dict)
    source: str = "library"  # the response model: "library" (sPGD) or "solver" (full harmonic balance)

    @property
    def success(self) -> bool:
        return self.status > 0

    @property
    def chi2_dof(self) -> float:
        return self.uncertainty.chi2_dof

    def values(self, run: str | None = None) -> dict[str, float]:
        """Physical values [SI] of the shared parameters and of ``run``'s local ones (first run by default)."""
        run = self.layout.runs[0] if run is None else run
        return {p: float(v) for (p, r), v in zip(self.layout.entries(), self.x) if p != "phase"
                and r in ("all", run)}

    def fitted(self, trial_theta: Array | None = None) -> Array:
        """The fitted harmonics in each record's frame (R, H, 2) complex [m]."""
        theta = (self.theta if trial_theta is None else trial_theta)[None]
        return np.stack([self.problem.model_response(theta, k, False)[0][0] for k in range(self.layout.n_runs)])

    def table(self) -> pd.DataFrame:
        """parameter, run, kind, unit, value, normalised, stderr, ci_low, ci_high, at_bound, identifiable,
        lower, upper, mc_mean, mc_std, mc_ci_low, mc_ci_high, vif (SI; one row per entry of theta)."""
        u, L = self.uncertainty, self.layout
        t = student_t(self.confidence, u.dof)
        mc = self.layout.to_si(self.protocol.monte_carlo) if len(self.protocol.monte_carlo) else None
        alpha = 100 * (0.5 - 0.5 * self.confidence)
        rows = []
        bounds = {p: (lo, hi) for p, lo, hi in zip(L.parameters, L.lower, L.upper)}
        single = L.n_runs == 1
        for i, (p, run) in enumerate(L.entries()):
            phase = p == "phase"
            lo, hi = (-np.pi, np.pi) if phase else bounds[p]
            values = None if mc is None else (_unwrap_around(mc[:, i], self.x[i]) if phase else mc[:, i])
            rows.append({
                "parameter": p, "run": L.runs[0] if single else run,
                "kind": "nuisance" if phase else ("physical" if single else ("shared" if run == "all" else "per_run")),
                "unit": "rad" if phase else self.units.get(p, ""), "value": self.x[i],
                "normalised": np.nan if phase else self.theta[i],
                "stderr": u.stderr[i], "ci_low": self.x[i] - t * u.stderr[i], "ci_high": self.x[i] + t * u.stderr[i],
                "at_bound": bool(u.at_bound[i]) and not phase, "identifiable": bool(u.identifiable[i]),
                "lower": lo, "upper": hi,
                "mc_mean": np.nan if values is None else values.mean(),
                "mc_std": np.nan if values is None or len(values) < 2 else values.std(ddof=1),
                "mc_ci_low": np.nan if values is None else np.percentile(values, alpha),
                "mc_ci_high": np.nan if values is None else np.percentile(values, 100 - alpha),
                "vif": u.vif[i], "source": self.source,
            })
        return pd.DataFrame(rows)

    def correlation_table(self) -> pd.DataFrame:
        names = [p if r == "all" else f"{p}[{r}]" for p, r in self.layout.entries()]
        return pd.DataFrame(self.uncertainty.correlation, index=names, columns=names)

    def history_table(self) -> pd.DataFrame:
        """Loss (eq. 9) of every trial on the measured data after each iteration (long format)."""
        h = self.protocol.trials.history
        trial, iteration = np.nonzero(np.isfinite(h))
        return pd.DataFrame({"trial": trial, "iteration": iteration, "loss": h[trial, iteration],
                             "selected": trial == self.protocol.best})

    def trials_table(self) -> pd.DataFrame:
        """One row per trial on the measured data: final loss, status, iterations and parameters [SI]."""
        tr = self.protocol.trials
        si = self.layout.to_si(tr.x)
        out = pd.DataFrame({"trial": np.arange(len(tr.loss)), "loss": tr.loss, "status": tr.status,
                            "iterations": tr.nit, "selected": np.arange(len(tr.loss)) == self.protocol.best})
        for i, (p, run) in enumerate(self.layout.entries()):
            out[p if run == "all" or self.layout.n_runs == 1 else f"{p}[{run}]"] = si[:, i]
        return out

    def summary(self) -> dict:
        u, tr = self.uncertainty, self.protocol.trials
        at_best = np.isclose(tr.loss, tr.loss[self.protocol.best], rtol=1e-6, atol=1e-12)
        return {"runs": list(self.layout.runs), "shared": list(self.layout.shared),
                "per_run": list(self.layout.local), "keyphasor_runs": self.layout.absolute_runs,
                "n_data": int(self.problem.n_data), "dof": int(u.dof),
                "chi2": float(u.chi2), "chi2_dof": float(u.chi2_dof), "loss": float(self.loss),
                "cost": float(self.cost), "status": int(self.status), "message": self.message,
                "collinearity_index": float(u.collinearity_index), "trials": int(len(tr.loss)),
                "trials_at_best": int(at_best.sum()), "monte_carlo": int(len(self.protocol.monte_carlo)),
                "lm_problems": int(self.protocol.n_lm), "seconds": float(self.protocol.seconds),
                "sparsity": float(self.problem.sparsity), "notes": list(u.notes)}


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


# --- validation runs: predicted, never fitted -------------------------------------------


def bow_law(table: pd.DataFrame, parameter: str, law: str = "law"
            ) -> tuple[Array, Callable[[Array, Array], Array]]:
    """A per-run parameter as a function of speed and unbalance, from its per-run estimates.

    law "law": weighted least squares of q = c0 + c1 Omega^2 + c2 Omega^2 m_e (the
    first-order form of the paper's eq. 35-37: bow grows with speed, and with the
    unbalance when there is one); "mean": the weighted mean. Needs rows with
    rpm, eccentric_mass_g, value, stderr. Returns (coefficients, predict(rpm, mass_g)).
    """
    omega2 = (np.asarray(table["rpm"], float) * 2 * np.pi / 60) ** 2
    mass = np.asarray(table["eccentric_mass_g"], float) * 1e-3
    stderr = np.asarray(table["stderr"], float)
    w = 1.0 / np.where(np.isfinite(stderr) & (stderr > 0), stderr, np.nanmax(np.append(stderr, 1.0))) ** 2
    y = np.asarray(table["value"], float)
    if law == "law" and len(y) >= 4:
        A = np.column_stack([np.ones_like(omega2), omega2, omega2 * mass])
        coef = np.linalg.lstsq(A * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]

        def predict(rpm: Array, mass_g: Array) -> Array:
            o2 = (np.asarray(rpm, float) * 2 * np.pi / 60) ** 2
            return coef[0] + coef[1] * o2 + coef[2] * o2 * np.asarray(mass_g, float) * 1e-3
        return coef, predict
    mean = float((w * y).sum() / w.sum())
    return np.array([mean]), lambda rpm, mass_g: np.full(np.shape(rpm), mean)


def _with_dc(z: Array, fill: float = 0.0) -> Array:
    """(H, 2) h = 1..H -> (2, H+1) with an h = 0 column (``fit_phase``'s layout; h = 0 is ignored there)."""
    return np.vstack([np.full((1, 2), fill, z.dtype), z]).T


def keyphasor_phase(X: Array, M: Array, sigma: Array, phase_sigma: float, iterations: int = 3) -> float:
    """The phase [rad] of a record with absolute phases: phi minimising
    sum |X - e^{ih phi} M|^2 / s^2 + (phi / phase_sigma)^2 (the fit's prior), by Gauss-Newton from 0."""
    h = np.arange(1, X.shape[0] + 1)[:, None]
    phi = 0.0
    for _ in range(iterations):
        rotated = np.exp(1j * h * phi) * M
        r, d = (X - rotated) / sigma, 1j * h * rotated / sigma  # residual and its -d/dphi
        phi += float(((np.conj(d) * r).real.sum() - phi / phase_sigma**2) / ((np.abs(d) ** 2).sum()
                                                                          + 1.0 / phase_sigma**2))
    return phi


def predict_run(model: HarmonicModel, data: RunData, values: Mapping[str, float], model_error: float = 0.0
                ) -> dict:
    """A run predicted with given parameter values [SI]: only its phase (a nuisance) is aligned (within its
    prior when it is absolute: ``keyphasor_phase``).

    Returns error_rel (relative L2 error of the signals' h >= 1 part, Parseval),
    chi2_per_residual (with the measured sigmas and the library error), the
    phase, 1X amplitudes measured and predicted, and the predicted harmonics.
    """
    from .preprocessing import fit_phase

    H = min(data.H, model.H)
    x = np.array([2 * (values[p] - lo) / (hi - lo) - 1 for p, lo, hi in zip(model.parameters, model.lower,
                                                                             model.upper)])
    outside = [p for p, v in zip(model.parameters, x) if abs(v) > 1 + 1e-9]
    M = model.evaluate(np.clip(x, -1, 1)[None], jacobian=False)[0][0, :H]  # (H, 2)
    X, sigma = data.X[:H], total_sigma(data, model_error)[:H]
    if math.isfinite(data.phase_sigma):
        phi = keyphasor_phase(X, M, sigma, data.phase_sigma)
    else:
        phi = fit_phase(_with_dc(X), _with_dc(M), _with_dc(sigma, fill=1.0))
    aligned = M * np.exp(1j * np.arange(1, H + 1) * phi)[:, None]
    error = np.sqrt((np.abs(X - aligned) ** 2).sum() / (np.abs(X) ** 2).sum())
    residual = (X - aligned) / sigma
    return {"run": data.run, "rpm": data.rpm, "eccentric_mass_g": data.eccentric_mass_g,
            "error_rel": float(error), "chi2_per_residual": float((np.abs(residual) ** 2).sum() / (4 * H)),
            "phase_rad": float(wrap(phi)), "x1_amp_measured_m": abs(X[0, 0]), "x1_amp_predicted_m": abs(M[0, 0]),
            "y1_amp_measured_m": abs(X[0, 1]), "y1_amp_predicted_m": abs(M[0, 1]),
            "outside_range": ",".join(outside), "fitted": aligned}


# --- the full solver as a model (polish) ------------------------------------------------


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


def polish(fit: Identification, solver_models: Sequence[HarmonicModel], max_iterations: int = 60,
           starts: Array | None = None) -> Identification:
    """Refine a library optimum with the full solver (no surrogate error), the result and its uncertainty.

    LM from fit.theta (and any extra ``starts``, all advanced in the same batched
    solves), on the same data weighted by the measured sigmas only (the solver
    has no library error to allow for). The uncertainty is recomputed from the
    solver's Jacobian (forward differences).
    """
    sigma = np.stack([d.sigma[: fit.X.shape[1]] for d in fit.data])
    exact = ArrowProblem(solver_models, fit.layout, sigma, fit.problem.sparsity, fit.problem.l1_epsilon)
    theta0 = fit.theta[None] if starts is None else np.vstack([fit.theta[None], starts])
    options = LMOptions(max_iterations=max_iterations, ftol=1e-8, xtol=1e-8, gtol=1e-10, stall_chi2=1e-3,
                        geodesic=True)  # one extra solve per iteration, 2-3x fewer iterations in the valleys
    result = levenberg_marquardt(exact, theta0, np.repeat(fit.X[None], len(theta0), axis=0), options)
    best = int(np.argmin(np.where(np.isfinite(result.loss), result.loss, np.inf)))  # a start may not solve
    protocol = ProtocolResult(result, best, np.zeros((0, fit.layout.n)), np.zeros(0), result.seconds, len(theta0))
    return conclude(exact, protocol, fit.data, fit.X, fit.confidence, fit.units)


def next_best_trials(fit: Identification, n: int = 4, distinct: float = 1e-3) -> Array:
    """Extra polish starts: the protocol's next-best trials on the measured data (distinct from the best by
    more than ``distinct`` in normalised units), so that the polish survives a best trial where the full
    solver has no solution."""
    trials = fit.protocol.trials
    order = np.argsort(np.where(np.isfinite(trials.loss), trials.loss, np.inf))
    chosen: list[Array] = []
    for i in order[1:]:
        if not np.isfinite(trials.loss[i]) or len(chosen) == n:
            break
        if all(np.abs(trials.x[i] - c).max() > distinct for c in chosen + [fit.theta]):
            chosen.append(trials.x[i])
    return np.array(chosen).reshape(-1, fit.layout.n)


def compare_polish(library_fit: Identification, polished: Identification) -> pd.DataFrame:
    """Library optimum vs full-solver optimum per entry: difference in SI, relative, and in standard errors."""
    a, b = library_fit.table(), polished.table()
    out = a[["parameter", "run", "unit"]].copy()
    out["library_value"], out["solver_value"] = a["value"], b["value"]
    out["difference"] = b["value"] - a["value"]
    out["difference_rel"] = out["difference"] / b["value"].abs().where(b["value"] != 0)
    out["difference_in_stderr"] = out["difference"] / b["stderr"]
    out["stderr"] = b["stderr"]
    return out


# --- per-run drift and plots ------------------------------------------------------------


def drift_table(per_run: Sequence[pd.DataFrame], runs: pd.DataFrame) -> pd.DataFrame:
    """The per-run fits side by side (one row per run and parameter) with speed and unbalance.

    A physical constant that drifts with speed means the model misses something
    (the per-run fits' diagnostic); ``spread_in_stderr``: |value - weighted mean| / stderr.
    """
    rows = []
    for table in per_run:
        rows.append(table[table["kind"] != "nuisance"])
    if not rows:
        return pd.DataFrame()
    out = pd.concat(rows, ignore_index=True)
    out = out.merge(runs[["run", "rpm", "eccentric_mass_g"]], on="run", how="left", suffixes=("", "_sheet"))
    for p, group in out.groupby("parameter"):
        w = 1.0 / group["stderr"].where(group["stderr"] > 0) ** 2
        mean = (w * group["value"]).sum() / w.sum() if w.notna().any() else group["value"].mean()
        out.loc[group.index, "weighted_mean"] = mean
        out.loc[group.index, "spread_in_stderr"] = (group["value"] - mean).abs() / group["stderr"]
    return out


def plot_per_run(drift: pd.DataFrame, joint: pd.DataFrame | None,
                 title: str) -> "matplotlib.figure.Figure":  # noqa: F821
    """Per-run estimates vs speed (the paper's Fig. 9) with their intervals, and the joint values.

    The axes span each parameter's range (an interval wider than the range is cut at it); open markers
    are estimates the uncertainty analysis calls not identifiable, crosses estimates at a range edge.
    """
    from .plots import plt

    names = list(dict.fromkeys(drift["parameter"])) if len(drift) else []
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(3.2 * max(len(names), 1), 3.4), squeeze=False)
    for ax, p in zip(axes[0], names):
        group = drift[drift["parameter"] == p]
        lo, hi = float(group["lower"].iloc[0]), float(group["upper"].iloc[0])
        for colour, (mass, sub) in enumerate(group.groupby("eccentric_mass_g")):
            low, high = sub["ci_low"].clip(lo, hi), sub["ci_high"].clip(lo, hi)
            err = np.nan_to_num(np.vstack([sub["value"] - low, high - sub["value"]]).clip(min=0))
            ok = sub["identifiable"].astype(bool).to_numpy()
            edge = sub["at_bound"].astype(bool).to_numpy()
            ax.errorbar(sub["rpm"], sub["value"], yerr=err, fmt="none", color=f"C{colour}", capsize=2, lw=0.8)
            ax.plot(sub["rpm"][ok], sub["value"][ok], "o", ms=4, color=f"C{colour}", label=f"{mass:g} g")
            ax.plot(sub["rpm"][~ok & ~edge], sub["value"][~ok & ~edge], "o", ms=4, mfc="none", color=f"C{colour}")
            ax.plot(sub["rpm"][edge], sub["value"][edge], "x", ms=5, color=f"C{colour}")
        if joint is not None:
            shared = joint[(joint["parameter"] == p) & (joint["run"] == "all")]
            for row in shared.itertuples():
                ax.axhline(row.value, color="k", lw=1, label="joint")
                ax.axhspan(max(row.ci_low, lo), min(row.ci_high, hi), color="k", alpha=0.1)
            local = joint[(joint["parameter"] == p) & (joint["run"] != "all")].merge(
                drift[["run", "rpm"]].drop_duplicates(), on="run")
            if len(local):
                ax.plot(local["rpm"], local["value"], "k+", label="joint")
        pad = 0.05 * (hi - lo)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(p)
        ax.set_xlabel("speed [RPM]")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"variant {title}: per-run estimates (95 % intervals; open: not identifiable, x: at a range "
                 "edge) and the joint fit", fontsize=9)
    fig.tight_layout()
    return fig


def write_fit(path: str | Path, fit: Identification, rpm: Sequence[float], cycles: int = 2, n_time: int = 200) -> None:
    """The fitted response for plotting (zarr v3): per run, measured and fitted harmonics h = 1..H in the
    record's frame, sigmas, and two revolutions of x, y (measured synchronous average and fitted)."""
    import zarr

    group = zarr.open_group(str(path), mode="w")
    fitted = fit.fitted()
    H = fit.X.shape[1]
    angle = np.linspace(0, 2 * np.pi * cycles, n_time, endpoint=False)
    wave = np.exp(1j * np.outer(angle, np.arange(1, H + 1)))  # (T, H)
    arrays = {
        "harmonic": np.arange(1, H + 1), "angle_rad": angle,
        "measured_re_m": fit.X.real, "measured_im_m": fit.X.imag,
        "fitted_re_m": fitted.real, "fitted_im_m": fitted.imag,
        "sigma_m": fit.problem.sigma,
        "measured_wave_m": np.einsum("th,rhc->rtc", wave, fit.X).real,
        "fitted_wave_m": np.einsum("th,rhc->rtc", wave, fitted).real,
    }
    for name, data in arrays.items():
        group.create_array(name, data=np.asarray(data, float))
    group.attrs.update({"runs": list(fit.layout.runs), "rpm": [float(v) for v in rpm],
                        "channels": list(CHANNELS), "chi2_dof": float(fit.chi2_dof),
                        "values": {k: float(v) for k, v in fit.values().items()},
                        "layout": "arrays (run, harmonic, channel); waves (run, time, channel); angle = Omega t"})


def warn_notes(notes: Sequence[str], where: str) -> None:
    for note in notes:
        warnings.warn(f"{where}: {note}", IdentificationWarning, stacklevel=2)


# --- workflow configuration -------------------------------------------------------------

#: the ``identification:`` section's defaults (config/config.yaml; schema in workflow/schemas)
DEFAULTS: dict = {
    "trials": 50,  # tau, random trials per fit (paper sec. 4.1)
    "monte_carlo": 1000,  # n_MC repeats per per-run fit
    "sparsity": {"expansion": 0.1},  # lambda per variant (eq. 11); 0 for the others
    "l1_epsilon": 1e-3,
    "seed": 1,
    "per_run": ["q_x", "q_y"],  # joint fit: estimated per run; the other unknowns are shared
    "model_error": "median_error_pct",  # library error added to the weights (library_validation.tsv column | none)
    "confidence": 0.95,
    "max_iterations": 100,
    "joint": {"trials": 50, "monte_carlo": 100},
    "polish": {"joint": True, "runs": False, "max_iterations": 60, "nested": True},
    "keyphasor": True,  # runs with a keyphasor: absolute phases, phase prior N(0, (Omega sigma_t)^2); false: free
    "validation_bow": "law",  # per-run parameters of validation runs: law (c0 + c1 W^2 + c2 W^2 m_e) | mean
}


def runs_with_role(sheet: str | Path, role: str) -> list[str]:
    """Runs of a runs sheet with this role (no role column: every run is a fit run)."""
    table = pd.read_csv(sheet, sep="\t", dtype={"run": str})
    roles = table["role"].fillna("fit") if "role" in table else pd.Series("fit", index=table.index)
    return table.loc[roles == role, "run"].tolist()


def settings(config: Mapping, variant: str) -> dict:
    """The identification options for ``variant``: defaults, then the config's section; lambda resolved."""
    given = dict(config.get("identification") or {})
    out = {**DEFAULTS, **given}
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
                         "polish": options["polish"]["max_iterations"] if polish_runs else False}
    polish_joint = options["polish"]["max_iterations"] if options["polish"]["joint"] else False
    if rule == "joint":
        # polish: nested changes the job's input files (the nested fits), which reruns it by itself
        return common | {"joint": options["joint"], "per_run": options["per_run"], "polish": polish_joint}
    return {"validation_bow": options["validation_bow"], "model_error": options["model_error"],
            "solver": bool(options["polish"]["joint"]), "keyphasor": options["keyphasor"]}


def protocol_options(options: Mapping, joint: bool = False) -> ProtocolOptions:
    """ProtocolOptions from ``settings``; ``joint`` takes the joint fit's trials and repeats."""
    source = options["joint"] if joint else options
    return ProtocolOptions(trials=int(source["trials"]), monte_carlo=int(source["monte_carlo"]),
                           sparsity=float(options["lambda"]), l1_epsilon=float(options["l1_epsilon"]),
                           seed=int(options["seed"]), confidence=float(options["confidence"]),
                           lm=LMOptions(max_iterations=int(options["max_iterations"])))


def units(variant) -> dict[str, str]:
    """Parameter units of a variant ("1" for dimensionless)."""
    return {name: p.unit for name, p in variant.model.parameters.items()}


def start_from_runs(layout: Layout, per_run: Mapping[str, pd.DataFrame]) -> Array | None:
    """A joint start from the per-run fits: shared entries at the median of the runs' estimates,
    local ones and phases from each run's own fit (None when a run has no usable fit)."""
    theta = np.zeros(layout.n)
    for i, (p, run) in enumerate(layout.entries()):
        if run == "all":
            values = [t.loc[t["parameter"] == p, "normalised"].item() for t in per_run.values()]
            values = [v for v in values if np.isfinite(v)]
            if not values:
                return None
            theta[i] = float(np.median(values))
            continue
        table = per_run.get(run)
        if table is None or not (table["parameter"] == p).any():
            return None
        column = "value" if p == "phase" else "normalised"
        theta[i] = table.loc[table["parameter"] == p, column].item()
    return theta if np.isfinite(theta).all() else None


def excluded_table(data: RunData, parameters: Sequence[str], units_: Mapping[str, str]) -> pd.DataFrame:
    """The parameter table of a run that cannot be fitted (not usable): NaN values and the reason."""
    rows = [{"parameter": p, "run": data.run, "kind": "shared", "unit": units_.get(p, ""), "value": np.nan,
             "normalised": np.nan, "stderr": np.nan, "ci_low": np.nan, "ci_high": np.nan, "at_bound": False,
             "identifiable": False, "note": data.note} for p in list(parameters) + ["phase"]]
    rows[-1].update(kind="nuisance", unit="rad")
    return pd.DataFrame(rows)


def validation_values(joint: pd.DataFrame, run: RunData, law: str = "law", runs: pd.DataFrame | None = None
                      ) -> dict[str, float]:
    """Parameter values [SI] to predict a validation run with: the shared estimates, and each per-run
    parameter from its law over the fitted runs (``bow_law``); m_e from the sheet when it is per run."""
    physical = joint[joint["kind"] != "nuisance"]
    values = {r.parameter: float(r.value) for r in physical.itertuples() if r.run == "all"}
    local = physical[physical["run"] != "all"]
    if runs is not None and len(local):
        local = local.drop(columns=[c for c in ("rpm", "eccentric_mass_g") if c in local]).merge(
            runs[["run", "rpm", "eccentric_mass_g"]], on="run", how="left")
    for p, group in local.groupby("parameter", sort=False):
        if p == "m_e" and np.isfinite(run.eccentric_mass_g):
            values[p] = run.eccentric_mass_g * 1e-3
            continue
        _, predict = bow_law(group, p, law)
        values[p] = float(predict(run.rpm, run.eccentric_mass_g))
    return values
