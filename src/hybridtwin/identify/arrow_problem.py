"""The identification's least-squares problem in block-arrow form (paper eq. 9-11; the loss and how it is made
precise: ``hybridtwin.identify.identification``).

``Layout``: where each unknown sits in theta = [shared, run 1 block, ..., run R block] (a run's block: its local
parameters, then its phase), the normalisation of the physical parameters to [-1, 1] and the phases' keyphasor
prior. ``ArrowProblem``: the weighted residuals of eq. 10, the smoothed L1 term of eq. 11 as residuals, and the
Jacobian in the layout's block-arrow form (shared columns, one block per run) that the batched Levenberg-Marquardt
(``hybridtwin.identify.lm``) solves by the Schur complement. ``wrap``: angles to (-pi, pi].

Runout offsets. A transient record's slow-roll runout is estimated once (``hybridtwin.data.slow_roll``) and
subtracted from all of its bands, so the estimate's error delta (per harmonic h and channel c, complex, each part
~ N(0, s^2), s the band's ``RunData.runout_sigma``) is one and the same in every band of the record. With
r_i = (X_i - M_i) / sigma_i band i's weighted residual (sigma_i its own sigma, s taken out: sqrt(sigma^2 - s^2)),
the generalised-least-squares chi^2 with that common error is, per record, harmonic, channel and part,

    chi^2_GLS = r^T (I + s^2 u u^T)^-1 r = min over delta of sum_i |r_i - delta / sigma_i|^2 + |delta / s|^2,

u_i = 1 / sigma_i (the minimum over delta in closed form gives the left side): the fit minimises the right side,
with delta as a parameter added to every band's model and the prior row delta / s. We keep delta as parameters
rather than profiling it out per step because the
profiled residuals would couple every band of a record in every block column and break the block-arrow form, while
the parameters keep it: they sit in the shared block (theta's entries for them are delta / s, prior N(0, 1), start
0), zero Jacobian outside their record's bands. They are nuisance entries (``Layout.is_nuisance``: never physical,
never "loose", kind "nuisance" in the parameter table, value in metres). They switch on only for records with at
least two bands in a fit: for a single band the offset and the quadrature sum of ``slow_roll.compensate`` give the
same fit, so a per-run fit and data without runout sigmas (steady runs) keep their layout, bit for bit. The
Monte Carlo repeats draw delta once per record and repeat (``protocol.resample``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .forward import HarmonicModel, evaluate_runs
from ..data.measured import RunData
from ..data.record_columns import harmonic_stem
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
    # runout offsets (module docstring): (record, stem, h, c, s) per complex offset, stem its harmonic's column stem
    # (x1), c the channel's column, s [m] its prior sigma; two entries each ("runout_<stem>_re"/"_im", record)
    offsets: tuple[tuple[str, str, int, int, float], ...] = ()
    run_records: tuple[str, ...] = ()  # each run's record ("" none), with offsets

    def __post_init__(self) -> None:
        if not self.phase_sigma:
            object.__setattr__(self, "phase_sigma", (math.inf,) * len(self.runs))
        if len(self.phase_sigma) != len(self.runs):
            raise ValueError(f"phase_sigma has {len(self.phase_sigma)} entries for {len(self.runs)} runs")
        if not self.run_records:
            object.__setattr__(self, "run_records", ("",) * len(self.runs))
        if len(self.run_records) != len(self.runs):
            raise ValueError(f"run_records has {len(self.run_records)} entries for {len(self.runs)} runs")
        if any(not s > 0 for *_, s in self.offsets):
            raise ValueError("a runout offset's prior sigma must be positive")
        both = set(self.shared) & set(self.local)
        if both or set(self.shared) | set(self.local) != set(self.parameters):
            raise ValueError(f"shared {list(self.shared)} and per-run {list(self.local)} parameters must split "
                             f"the libraries' parameters {list(self.parameters)} exactly")

    @classmethod
    def build(cls, parameters: Sequence[str], lower: Sequence[float], upper: Sequence[float],
              runs: Sequence[str], per_run: Sequence[str] = (), phase_sigma: Sequence[float] = (),
              offsets: Sequence[tuple] = (), run_records: Sequence[str] = ()) -> "Layout":
        local = tuple(p for p in parameters if p in set(per_run))
        shared = tuple(p for p in parameters if p not in set(local))
        return cls(tuple(parameters), tuple(map(float, lower)), tuple(map(float, upper)), shared, local,
                   tuple(runs), tuple(map(float, phase_sigma)),
                   tuple((str(r), str(n), int(h), int(c), float(s)) for r, n, h, c, s in offsets),
                   tuple(map(str, run_records)) if offsets else ())

    @classmethod
    def for_data(cls, parameters: Sequence[str], lower: Sequence[float], upper: Sequence[float],
                 data: Sequence[RunData], per_run: Sequence[str] = (), runout: bool = True) -> "Layout":
        """The layout of a fit of ``data``: a phase prior for the runs with absolute (keyphasor) phases, and the
        runout offsets (module docstring) of each record with at least two bands carrying a runout sigma (none
        with ``runout`` False: a problem that does not model them, the online twin's)."""
        offsets, records = runout_offsets(data) if runout else ([], [])
        return cls.build(parameters, lower, upper, [d.run for d in data], per_run,
                         [d.phase_sigma for d in data], offsets, records)

    @property
    def n_offsets(self) -> int:
        """Real entries of the runout offsets (two per complex offset), after the shared parameters."""
        return 2 * len(self.offsets)

    @property
    def n_shared(self) -> int:
        """Columns of the shared block: the shared parameters, then the runout offsets' entries."""
        return len(self.shared) + self.n_offsets

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
        """(parameter, run) of every entry of theta; run "all" for shared ones, parameter "phase" for phases;
        a runout offset's two: ("runout_<stem>_re", record), ("runout_<stem>_im", record)."""
        out = [(p, "all") for p in self.shared]
        out += [(f"{OFFSET_PREFIX}{stem}_{part}", record) for record, stem, *_ in self.offsets for part in ("re", "im")]
        for run in self.runs:
            out += [(p, run) for p in self.local] + [("phase", run)]
        return out

    @property
    def is_phase(self) -> Array:
        return np.array([p == "phase" for p, _ in self.entries()])

    @property
    def is_offset(self) -> Array:
        """The runout offsets' entries (module docstring)."""
        out = np.zeros(self.n, bool)
        out[len(self.shared): self.n_shared] = True
        return out

    @property
    def is_nuisance(self) -> Array:
        """Entries that are not physical parameters: the phases and the runout offsets."""
        return self.is_phase | self.is_offset

    @property
    def offset_sigma(self) -> Array:
        """Each entry's runout offset prior sigma s [m] (its two parts), NaN for other entries."""
        out = np.full(self.n, np.nan)
        out[len(self.shared): self.n_shared] = np.repeat([s for *_, s in self.offsets], 2)
        return out

    @property
    def phase_prior(self) -> Array:
        """The prior's weight on each entry: 1 / phase_sigma [1/rad] for the phases of runs with a keyphasor, 1 for
        the runout offsets (theta = delta / s, prior N(0, 1)), else 0."""
        sigma = dict(zip(self.runs, self.phase_sigma))
        out = np.array([1.0 / sigma[run] if p == "phase" else 0.0 for p, run in self.entries()])
        out[self.is_offset] = 1.0
        return out

    def run_offsets(self, r: int) -> list[tuple[int, int, int, float]]:
        """Run r's runout offsets: (column of the offset's re entry in theta, h, c, s)."""
        record = self.run_records[r] if self.offsets else ""
        return [(len(self.shared) + 2 * i, h, c, s) for i, (rec, _, h, c, s) in enumerate(self.offsets)
                if record and rec == record]

    def own_sigma(self, sigma: Array) -> Array:
        """The bands' sigmas (R, H, C) [m] with each runout offset's share s taken out where it applies (module
        docstring): sqrt(sigma^2 - s^2), at least 1e-3 sigma; ``sigma`` itself without offsets."""
        if not self.offsets:
            return sigma
        out = np.array(sigma, float, copy=True)
        for k in range(self.n_runs):
            for _, h, c, s in self.run_offsets(k):
                if h <= out.shape[1]:
                    total = out[k, h - 1, c]
                    out[k, h - 1, c] = math.sqrt(max(total**2 - s**2, (1e-3 * total) ** 2))
        return out

    def theta_of(self, entry: tuple[str, str], value: float) -> float:
        """An entry's theta from its value as ``to_si`` gives it (phase [rad], offset [m], parameter [SI])."""
        p, _ = entry
        if p == "phase":
            return float(value)
        if p.startswith(OFFSET_PREFIX):
            return float(value) / float(self.offset_sigma[self.entries().index(entry)])
        return float(self.normalise(p, value))

    @property
    def absolute_runs(self) -> list[str]:
        """The runs whose phases are absolute (a keyphasor): their phase has a prior."""
        return [run for run, sigma in zip(self.runs, self.phase_sigma) if math.isfinite(sigma)]

    def bounds(self) -> tuple[Array, Array]:
        """Bounds of theta: [-1, 1] for physical parameters, +-inf for phases and runout offsets."""
        lo = np.where(self.is_nuisance, -np.inf, -1.0)
        return lo, -lo

    def scale(self) -> Array:
        """dp/dtheta: (hi - lo) / 2 for physical entries [SI], 1 for phases [rad], s for runout offsets [m]."""
        half = {p: 0.5 * (hi - lo) for p, lo, hi in zip(self.parameters, self.lower, self.upper)}
        out = np.array([1.0 if p == "phase" or p not in half else half[p] for p, _ in self.entries()])
        return np.where(self.is_offset, self.offset_sigma, out)

    def to_si(self, theta: Array) -> Array:
        """theta (..., n) -> physical values [SI] (phases unchanged, wrapped to (-pi, pi]; offsets in metres)."""
        lo = {p: v for p, v in zip(self.parameters, self.lower)}
        hi = {p: v for p, v in zip(self.parameters, self.upper)}
        out = np.array(theta, dtype=float, copy=True)
        offset, s = self.is_offset, self.offset_sigma
        for i, (p, _) in enumerate(self.entries()):
            if offset[i]:
                out[..., i] = out[..., i] * s[i]
            else:
                out[..., i] = wrap(out[..., i]) if p == "phase" else lo[p] + 0.5 * (out[..., i] + 1.0) * (hi[p] - lo[p])
        return out

    def normalise(self, name: str, value: Array | float) -> Array:
        i = self.index(name)
        return 2.0 * (np.asarray(value, float) - self.lower[i]) / (self.upper[i] - self.lower[i]) - 1.0

    def run_parameters(self, theta: Array, r: int) -> tuple[Array, Array]:
        """Run r's normalised library parameters x (N, d) and phase (N,) from theta (N, n)."""
        N = theta.shape[0]
        x = np.empty((N, len(self.parameters)))
        x[:, self.shared_index] = theta[:, : len(self.shared)]
        block = theta[:, self.block(r)]
        x[:, self.local_index] = block[:, :-1]
        return x, block[:, -1]

    def l1_scale(self) -> tuple[Array, Array]:
        """s = a theta + b, the paper's normalisation p / max|range| (eq. 11) of each entry.

        a = b = 0 (no L1 term) for phases and for parameters whose range excludes 0
        (e.g. the bow q in [1, 10] mm: sparsity means switching a term off).
        """
        a, b = np.zeros(self.n), np.zeros(self.n)
        nuisance = self.is_nuisance
        for i, (p, _) in enumerate(self.entries()):
            if nuisance[i]:
                continue
            k = self.index(p)
            lo, hi = self.lower[k], self.upper[k]
            if not lo <= 0.0 <= hi:  # a term that cannot be switched off is not penalised
                continue
            top = max(abs(lo), abs(hi))
            a[i], b[i] = 0.5 * (hi - lo) / top, (lo + 0.5 * (hi - lo)) / top
        return a, b


#: the runout offsets' entry names: runout_<stem>_re, runout_<stem>_im (module docstring)
OFFSET_PREFIX = "runout_"


def runout_offsets(data: Sequence[RunData]) -> tuple[list[tuple[str, str, int, int, float]], list[str]]:
    """The runout offsets of a fit of ``data`` (``Layout.offsets``) and each run's record ("" none): one per record
    with at least two runs carrying a runout sigma, harmonic h <= the data's H and channel where s > 0."""
    records = [d.record if d.record and d.runout_sigma is not None else "" for d in data]
    count = {r: records.count(r) for r in set(records) if r}
    records = [r if count.get(r, 0) >= 2 else "" for r in records]
    offsets, seen = [], set()
    for d, record in zip(data, records):
        if not record or record in seen:
            continue
        seen.add(record)
        s = np.asarray(d.runout_sigma, float)[: d.H]
        offsets += [(record, harmonic_stem(d.channels[c], h + 1), h + 1, c, float(s[h, c]))
                    for h in range(s.shape[0]) for c in range(s.shape[1]) if s[h, c] > 0]
    used = {r for r, *_ in offsets}
    return offsets, [r if r in used else "" for r in records]


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
        # (R, H, C), C channels (the sensors; x, y on the VARM); a runout offset's s leaves its bands' sigma
        self.sigma = layout.own_sigma(np.asarray(sigma, float))
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
        """Run r's harmonics in the record's frame e^{ih phi} M + delta (N, H, C) (delta: its record's runout
        offsets, module docstring), d/dx (N, H, C, d), rotation."""
        x, phi = self.layout.run_parameters(theta, r)
        M, dM = self.models[r].evaluate(x, jacobian)
        rotation = np.exp(1j * np.outer(phi, self.h))[:, :, None]  # (N, H, 1)
        M = rotation * M[:, : self.H] + self.offset(theta, r)
        return M, (None if dM is None else rotation[..., None] * dM[:, : self.H]), rotation

    def offset(self, theta: Array, r: int) -> Array | float:
        """Run r's runout offsets delta (N, H, C) complex [m] at theta (N, n); 0 without any."""
        found = [(i, h, c, s) for i, h, c, s in self.layout.run_offsets(r) if h <= self.H]
        if not found:
            return 0.0
        out = np.zeros((theta.shape[0], self.H, self.C), complex)
        for i, h, c, s in found:
            out[:, h - 1, c] = s * (theta[:, i] + 1j * theta[:, i + 1])
        return out

    def responses(self, theta: Array, jacobian: bool) -> list[tuple[Array, Array | None]]:
        """Every run's ``model_response`` (M, dM) at theta (N, n), the models evaluated together where they can
        be batched across runs (``forward.evaluate_runs``)."""
        xs, phis = zip(*(self.layout.run_parameters(theta, k) for k in range(self.layout.n_runs)))
        out = []
        for k, (M, dM) in enumerate(evaluate_runs(self.models, xs, jacobian)):
            rotation = np.exp(1j * np.outer(phis[k], self.h))[:, :, None]  # (N, H, 1)
            out.append((rotation * M[:, : self.H] + self.offset(theta, k),
                        None if dM is None else rotation[..., None] * dM[:, : self.H]))
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
                Js[:, k, :, : len(L.shared)] = _real(dM[..., L.shared_index])
                Jl[:, k, :, :-1] = _real(dM[..., L.local_index])
                turned = M - self.offset(theta, k)  # the rotated model: the offsets do not turn with phi
                Jl[:, k, :, -1] = _real(-1j * self.h[None, :, None] * turned / self.sigma[k])
                if L.n_offsets:
                    Js[:, k, :, len(L.shared):] = self._offset_jacobian(k)
        rho, jd = self._sparsity(theta, jacobian)
        prior = self.layout.phase_prior  # the keyphasor phases' prior, phi / (Omega sigma_t), on other entries
        return Evaluation(r, rho + prior * theta, Js, Jl, None if jd is None else jd + prior)

    def _offset_jacobian(self, k: int) -> Array:
        """d r / d theta of run k's rows for the offsets' entries (m, n_offsets): -s / sigma at each offset's
        (h, c), in the real part's row for its re entry and the imaginary part's for its im entry."""
        L, HC = self.layout, self.H * self.C
        out = np.zeros((2 * HC, L.n_offsets))
        for i, h, c, s in L.run_offsets(k):
            if h <= self.H:
                row, col = (h - 1) * self.C + c, i - len(L.shared)
                out[row, col] = out[HC + row, col + 1] = -s / self.sigma[k, h - 1, c]
        return out

    def prior_rows(self, theta: Array) -> tuple[Array, Array]:
        """The phase prior (and the runout offsets') as pseudo-measurements at theta (n,): rows (p, n) of
        d rho / d theta, residuals (p,)."""
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
