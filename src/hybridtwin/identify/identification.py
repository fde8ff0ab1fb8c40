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
is the same problem with one run and every parameter "shared". The problem (``Layout``, ``ArrowProblem``):
``hybridtwin.identify.arrow_problem``; here, the fit's result (``Identification``), its parameter table and
the workflow's settings.

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

from ..tables import PARAMETER_COLUMNS, PARAMETER_FLAGS, PARAMETERS
from .arrow_problem import OFFSET_PREFIX, ArrowProblem, Layout, wrap
from ..data.measurements import runs_with_role as read_role  # the one reader of runs sheets
from ..data.record_columns import split_stem
from .forward import HarmonicModel, SolverModel
from ..data.measured import (  # noqa: F401 (the measured harmonics: hybridtwin.data.measured, also read from here)
    CHANNELS, RunData, model_errors, read_harmonics, run_data, table_harmonics, total_sigma,
)
from .lm import STATUS_MESSAGES, LMOptions
from .protocol import ProtocolOptions, ProtocolResult, run_protocol
from .uncertainty import Profiled, Uncertainty, analyse_uncertainty, interval_basis, loose_entries, student_t

Array = np.ndarray


# --- results ----------------------------------------------------------------------------


#: the columns of ``Identification.table`` (parameters.tsv), in order: the table layer's
TABLE_COLUMNS = PARAMETER_COLUMNS
#: the per-entry statistics among them (``Identification.statistics``); at_bound and identifiable are flags,
#: interval (a code of ``uncertainty.INTERVAL_CODES``), loose (parameter names, comma-separated) and mc_note (a code
#: of ``MC_NOTES``, "" when none applies) text
STATISTICS = ("stderr", "ci_low", "ci_high", "interval", "loose", "at_bound", "identifiable", "mc_mean", "mc_std",
              "mc_ci_low", "mc_ci_high", "mc_note", "vif")
_FLAGS = PARAMETER_FLAGS
_TEXT = ("interval", "loose", "mc_note")
#: parameters.tsv's ``mc_note``: when the Monte Carlo repeats' mean (``mc_mean``) is not the estimate's spread ("" when
#: it is, or without repeats). On the bundled run (main job at 6f13abf) 27 rows had mc_mean of the other sign than
#: value: loose parameters near zero of per-run fits (sign), per-run fits whose repeats mostly land at another optimum
#: (elsewhere: expansion r600_m25p9's k6 475 against the repeats' -319 [-902, 445]) and polished joint fits (polished).
MC_NOTES = {
    "sign": "mc_mean has the opposite sign of value, which lies inside mc_ci_low..mc_ci_high: the data do not fix "
            "the sign (a loose parameter near zero); read the interval, not the mean",
    "elsewhere": "value lies outside mc_ci_low..mc_ci_high: the repeats settle mostly at another optimum (a "
                 "multimodal fit); mc_mean and its interval describe that optimum, not the estimate's spread",
    "polished": "value lies outside mc_ci_low..mc_ci_high, the library fit's repeats: the full solver's polish (source "
                "solver) moved the estimate from the library's optimum (a library error); its uncertainty is stderr, "
                "ci_low..ci_high",
}


def mc_notes(value: Array, mean: Array, low: Array, high: Array, phase: Array, polished: Array) -> list[str]:
    """Per entry, the ``MC_NOTES`` code of the Monte Carlo statistics against the estimate ``value`` ("" when none
    applies, or without repeats: ``mean`` NaN): when the value lies outside ``low``..``high``, "polished" where the
    entry was ``polished`` (the repeats are the library fit's), else "elsewhere"; inside, "sign" when ``mean`` has the
    opposite sign (never for a ``phase``, an angle)."""
    value, mean, low, high = (np.asarray(a, float) for a in (value, mean, low, high))
    with np.errstate(invalid="ignore"):
        outside = np.isfinite(mean) & ((value < low) | (value > high))
        flipped = np.isfinite(mean) & (np.sign(mean) * np.sign(value) < 0) & ~np.asarray(phase, bool)
    return ["polished" if o and p else "elsewhere" if o else "sign" if f else ""
            for o, p, f in zip(outside, np.broadcast_to(np.asarray(polished, bool), outside.shape), flipped)]


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
        percentile interval (phases unwrapped around the estimate; NaN without repeats), when their mean is not the
        estimate's spread (``mc_note``, ``mc_notes``) and the variance inflation factor vif."""
        if self.read_columns is not None:
            return {name: self.read_columns[name] for name in STATISTICS}
        u, L = self.uncertainty, self.layout
        t = student_t(self.confidence, u.dof)
        mc = L.to_si(self.protocol.monte_carlo) if len(self.protocol.monte_carlo) else None
        alpha = 100 * (0.5 - 0.5 * self.confidence)
        out = {name: np.full(L.n, np.nan) for name in STATISTICS if name not in _FLAGS + _TEXT}
        out["at_bound"] = np.asarray(u.at_bound, bool) & ~L.is_nuisance
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
        out["mc_note"] = mc_notes(self.x, out["mc_mean"], out["mc_ci_low"], out["mc_ci_high"], L.is_nuisance,
                                  self.source == "solver")
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
        """lower, upper of each entry of theta [SI]: its parameter's range, -pi and pi for a phase, -s and s for a
        runout offset (its prior's sigma [m], not a range: ``from_table`` reads s back from it)."""
        if self.read_columns is not None:
            return self.read_columns["lower"], self.read_columns["upper"]
        L = self.layout
        bounds = dict(zip(L.parameters, zip(L.lower, L.upper))) | {"phase": (-np.pi, np.pi)}
        s = L.offset_sigma
        return tuple(np.array([(-s[i], s[i])[k] if off else bounds[p][k]
                               for i, ((p, _), off) in enumerate(zip(L.entries(), L.is_offset))], float)
                     for k in (0, 1))

    def table(self) -> pd.DataFrame:
        """The parameter table (parameters.tsv), one row per entry of theta, columns ``TABLE_COLUMNS`` (SI):
        parameter, run ("all" for a shared one in a joint fit, the run itself in a per-run fit), kind ("shared",
        "per_run", "physical" in a per-run fit, "nuisance" for the phases and the runout offsets, whose
        normalised value is delta / s), unit, value, normalised, the
        ``statistics``, lower, upper (the range), source. ``from_table`` reads it back."""
        L, (lower, upper) = self.layout, self.ranges()
        single = L.n_runs == 1
        parameters, runs = [p for p, _ in L.entries()], [r for _, r in L.entries()]
        columns = {
            "parameter": parameters, "run": [L.runs[0] if single else r for r in runs],
            "kind": ["nuisance" if nuisance else "physical" if single else "shared" if r == "all" else "per_run"
                     for (p, r), nuisance in zip(L.entries(), L.is_nuisance)],
            "unit": ["rad" if p == "phase" else "m" if off else self.units.get(p, "")
                     for p, off in zip(parameters, L.is_offset)],
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
        offset = np.array([p.startswith(OFFSET_PREFIX) and k == "nuisance" for p, k in zip(names, kinds)])
        if [k == "nuisance" for k in kinds] != (phase | offset).tolist():
            raise ValueError("parameter table: the rows of kind 'nuisance' must be exactly the phases and the "
                             "runout offsets")
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
        # a runout offset's (record, stem, h, channel column, s): s is its "upper" (``ranges``); a read result has no
        # problem, so h and the channel's column (numbered in order of appearance) only label its layout
        stems = [(r, p[len(OFFSET_PREFIX):-3], hi) for p, r, off, hi in zip(names, runs, offset, upper)
                 if off and p.endswith("_re")]
        channels = list(dict.fromkeys(split_stem(stem)[0] for _, stem, _ in stems))
        offsets = [(r, stem, split_stem(stem)[1], channels.index(split_stem(stem)[0]), hi) for r, stem, hi in stems]
        layout = Layout.build(order, [lower[first[p]] for p in order], [upper[first[p]] for p in order], fit_runs,
                              local, (), offsets, [""] * len(fit_runs))
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
        units = {p: u for p, u, is_phase in zip(names, rows["unit"].tolist(), phase | offset) if not is_phase}
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


def fit_runs(table: pd.DataFrame) -> list[str]:
    """The fit's runs in its order, from its parameter table (``Identification.table``): those with a phase. A
    transient record's runout offsets are nuisance rows too, but per record (their run is the record's name)."""
    return list(dict.fromkeys(table.loc[table["parameter"].astype(str) == "phase", "run"].astype(str)))


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
    """A parameter table (``Identification.table``, parameters.tsv) as TSV, 9 significant digits
    (``tables.PARAMETERS``)."""
    PARAMETERS.write(table, path)


def read_parameters(path: str | Path) -> pd.DataFrame:
    """A parameter table written by ``write_parameters``: names, runs and units as text (run "001" stays "001",
    unit "1" a string, an empty unit ""), ``TABLE_COLUMNS``' numbers as floats; ``Identification.from_table``
    reads the result. Other columns (a per-run fit's note, a refit's effect) come as pandas reads them. A table written
    before ``mc_note`` existed gets it from its own columns (``mc_notes``)."""
    table = PARAMETERS.read(path)
    header = table.columns
    if "mc_note" not in header and {"value", "mc_mean", "mc_ci_low", "mc_ci_high"} <= set(header):  # written before it
        table.insert(list(table.columns).index("mc_ci_high") + 1, "mc_note", mc_notes(
            table["value"], table["mc_mean"], table["mc_ci_low"], table["mc_ci_high"], table["parameter"] == "phase",
            table["source"] == "solver" if "source" in table else False))
    return table


def theta_from_table(table: pd.DataFrame, layout: Layout) -> Array | None:
    """theta of ``layout`` from a parameter table (``Identification.table``: parameter, run, value [SI]),
    values normalised with the layout's own ranges; None when an entry is missing or not finite."""
    values = {(str(r.parameter), str(r.run)): float(r.value) for r in table.itertuples()}
    if any(e not in values for e in layout.entries()):
        return None
    theta = np.array([layout.theta_of((p, run), values[(p, run)]) for p, run in layout.entries()])
    return np.clip(theta, *layout.bounds()) if np.isfinite(theta).all() else None


# --- workflow configuration -------------------------------------------------------------

def runs_with_role(sheet: str | Path, role: str) -> list[str]:
    """Runs of a runs sheet with this role (no role column: every run is a fit run), read as check-data reads it."""
    return read_role(sheet, role)


def protocol_options(options: Mapping, joint: bool = False) -> ProtocolOptions:
    """ProtocolOptions from a fit's options (``hybridtwin.settings.IdentificationSettings.rule``); ``joint`` takes
    the joint fit's trials, repeats and their starts."""
    source = options["joint"] if joint else options
    return ProtocolOptions(trials=int(source["trials"]), monte_carlo=int(source["monte_carlo"]),
                           sparsity=float(options["lambda"]), l1_epsilon=float(options["l1_epsilon"]),
                           seed=int(options["seed"]), confidence=float(options["confidence"]),
                           lm=LMOptions(max_iterations=int(options["max_iterations"])),
                           monte_carlo_starts=int(source["monte_carlo_starts"]))


def units(variant) -> dict[str, str]:
    """Parameter units of a variant ("1" for dimensionless)."""
    return {name: p.unit for name, p in variant.model.parameters.items()}
