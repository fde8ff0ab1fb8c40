"""The sPGD library of one run: response and exact Jacobian for any parameter set (paper sec. 2.1).

A library joins the POD basis of a run's snapshots (eq. 4-5) with an sPGD
model of the reduced coordinates (eq. 6-7): q(p) = Phi alpha(x), x the
parameters normalised to [-1, 1]. It returns the sensor harmonics U_h, V_h
(or the whole field) and their derivatives with respect to the parameters in
SI units, batched, in microseconds per parameter set.
"""

from __future__ import annotations

import json
import multiprocessing
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import zarr
from threadpoolctl import threadpool_limits

from .. import tables
from . import snapshots
from ..model.effect_base import Array
from .piecewise_spgd import PiecewiseSPGD, fit_piecewise, model_from_arrays, piece_index
from .pod import MIN_TRAIN, MIN_VALIDATION, POD, feature_index, from_features, load_pod, pod, to_features
from ..model.sensor import observable, sensor_dofs
from ..model.shaft import Shaft
from .spgd import SparsePGD, fit_spgd, relative_error
from .stores import open_verified, write_manifest
from ..model.variants import Variant
from ..progress import Progress

#: the extra sPGD dimensions of a global library, after the unknowns (SI/boundary units: RPM, g)
OPERATING_POINT = ["rpm", "eccentric_mass_g"]


@dataclass
class Library:
    """Surrogate of one run's steady state over the variant's unknown parameters."""

    run: str
    parameters: list[str]
    lower: Array
    upper: Array
    modes: Array  # POD basis Phi (features, m_d)
    singular_values: Array
    model: SparsePGD | PiecewiseSPGD
    n_harmonics: int  # H + 1
    n_dof: int
    sensor_dofs: list[int]
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        h = np.arange(self.n_harmonics)
        rows = [feature_index(h, dof, self.n_harmonics, self.n_dof, imaginary)
                for imaginary in (False, True) for dof in self.sensor_dofs]
        self._sensor_modes = self.modes[np.concatenate(rows)]  # (2 C (H+1), m_d), C sensor channels

    @property
    def n_modes(self) -> int:
        return self.modes.shape[1]

    def normalise(self, values: Array) -> Array:
        """SI parameter values (N, d) -> x in [-1, 1]."""
        values = np.atleast_2d(np.asarray(values, dtype=float))
        if values.shape[-1] != len(self.parameters):
            raise ValueError(f"library {self.run}: expected {len(self.parameters)} parameters "
                             f"{self.parameters}, got {values.shape[-1]}")
        return 2.0 * (values - self.lower) / (self.upper - self.lower) - 1.0

    def sensor(self, values: Array, jacobian: bool = False) -> Array | tuple[Array, Array]:
        """Sensor harmonics (N, H+1, C) complex, one per sensor of ``sensor_dofs`` (U_h, V_h on the VARM); with
        ``jacobian`` also d/dp (N, H+1, C, d) [m / SI].

        The sPGD amplitudes are projected on the sensor rows of the POD basis once (the response is
        linear in them), so a batch costs the factors and one product with (K, 2 C (H+1)) amplitudes.
        """
        x = self.normalise(values)
        y, J = self._sensor_model().evaluate(x, jacobian=jacobian)
        if not jacobian:
            return self._to_sensor(y)
        J *= (2.0 / (self.upper - self.lower))[:, None, None]
        return self._to_sensor(y), np.moveaxis(self._to_sensor(J), 0, -1)

    def _sensor_model(self) -> SparsePGD | PiecewiseSPGD:
        """The sPGD projected on the sensor rows, a_k Phi_sensor^T (K, 2 C (H+1)), cached for the current model."""
        if getattr(self, "_sensor_cache", (None,))[0] is not self.model:
            self._sensor_cache = (self.model, self.model.projected(self._sensor_modes.T))
        return self._sensor_cache[1]

    def _to_sensor(self, features: Array) -> Array:
        """(..., 2 * C * (H+1)) [Re U, Re V, Im U, Im V] -> (..., H+1, C) complex, C = len(sensor_dofs)."""
        H1 = self.n_harmonics
        parts = features.reshape(features.shape[:-1] + (2, len(self.sensor_dofs), H1))
        return np.moveaxis(parts[..., 0, :, :] + 1j * parts[..., 1, :, :], -2, -1)

    def at_operating_point(self, run: str, rpm: float, eccentric_mass_g: float) -> "Library":
        """A global library (``build_global_library``) sliced at one run's operating point: that run's
        library over the unknowns alone, exact.

        With x_rpm and x_me fixed, each term's last two factors are numbers (eq. 6-7):
        a_k prod_j F_j^k = (a_k F_rpm^k(x_rpm) F_me^k(x_me)) prod_{j <= d} F_j^k.
        """
        outside = self.outside_operating_range(rpm, eccentric_mass_g)
        if outside:
            raise ValueError(f"run {run}: operating point {outside}")
        d = len(self.parameters) - len(OPERATING_POINT)
        point = np.array([rpm, eccentric_mass_g], float)
        low, high = self.lower[d:], self.upper[d:]
        x = np.clip(2.0 * (point - low) / (high - low) - 1.0, -1.0, 1.0)
        model = self.model.with_trailing_fixed(x)
        info = {**self.info, "scope": "global", "operating_point": {"rpm": float(rpm),
                                                                    "eccentric_mass_g": float(eccentric_mass_g)}}
        return Library(run, self.parameters[:d], self.lower[:d], self.upper[:d], self.modes, self.singular_values,
                       model, self.n_harmonics, self.n_dof, self.sensor_dofs, info)

    def outside_operating_range(self, rpm: float, eccentric_mass_g: float) -> str:
        """Why a global library cannot be sliced at this operating point (outside the range it was fitted over, to
        1e-9 relative), or "" where it can; ``ValueError`` for a library that is not a global one."""
        if self.parameters[-len(OPERATING_POINT):] != OPERATING_POINT:
            raise ValueError(f"library {self.run} is not a global library (parameters {self.parameters})")
        d = len(self.parameters) - len(OPERATING_POINT)
        point = np.array([rpm, eccentric_mass_g], float)
        low, high = self.lower[d:], self.upper[d:]
        if np.any(point < low - 1e-9 * np.abs(low)) or np.any(point > high + 1e-9 * np.abs(high)):
            return (f"{rpm:g} RPM, {eccentric_mass_g:g} g is outside the global library's range ({low[0]:g}-"
                    f"{high[0]:g} RPM, {low[1]:g}-{high[1]:g} g)")
        return ""

    def field(self, values: Array) -> Array:
        """Harmonics of all DOFs (N, H+1, n) for parameter values (N, d)."""
        return from_features(self.model.predict(self.normalise(values)) @ self.modes.T, self.n_harmonics, self.n_dof)

    def save(self, path: str | Path) -> None:
        """Write as a zarr v3 group, its checksum manifest last (``hybridtwin.offline.stores``)."""
        group = zarr.open_group(str(path), mode="w")
        arrays = {"modes": self.modes, "singular_values": self.singular_values, "lower": self.lower,
                  "upper": self.upper, **self.model.to_arrays()}
        for name, data in arrays.items():
            group.create_array(name, data=np.asarray(data))
        group.attrs.update({"run": self.run, "parameters": self.parameters, "n_harmonics": self.n_harmonics,
                            "n_dof": self.n_dof, "sensor_dofs": self.sensor_dofs,
                            "info": json.loads(json.dumps(self.info, default=float))})
        write_manifest(path)

    @classmethod
    def load(cls, path: str | Path) -> "Library":
        """Read a library store, verified against its manifest first (``stores.CorruptStoreError``)."""
        group = open_verified(path, "library store")
        attrs = dict(group.attrs)
        with warnings.catch_warnings():  # Snakemake's directory marker and the manifest are not zarr members
            warnings.filterwarnings("ignore", message=r"Object at (\.snakemake_timestamp|manifest\.sha256) is not "
                                    "recognized")
            names = list(group.array_keys())
        model = model_from_arrays({name: group[name][:] for name in names})
        return cls(attrs["run"], list(attrs["parameters"]), group["lower"][:], group["upper"][:], group["modes"][:],
                   group["singular_values"][:], model, attrs["n_harmonics"], attrs["n_dof"],
                   list(attrs["sensor_dofs"]), attrs.get("info", {}))


def build_library(run: str, basis: POD, harmonics: Array, values: Array, split: Array, usable: Array,
                  parameters: list[str], lower: Array, upper: Array, sensor_dofs: list[int],
                  kinks: tuple[int, Array] | None = None, **spgd_options) -> Library:
    """sPGD (eq. 6-7) of one run's reduced coordinates alpha = Phi^T q on its POD basis.

    harmonics (S, H+1, n), values (S, d) SI, split (S,) in train/validation/test,
    usable (S,): converged and observable scenarios (the others are left out and
    counted in ``info``). Fitted on "train", its size chosen on "validation";
    weights 1 / ||sensor signal||^2 make the least squares relative, scenario by
    scenario, in the norm the library is judged and used in (``sensor_weights``).
    kinks: (parameter index, normalised values) where the response has a kink
    (``mode_scaling_kinks``): one sPGD per interval between them (``pieces``).
    """
    S, H1, n = harmonics.shape
    usable = np.asarray(usable, bool)
    train, val = usable & (split == "train"), usable & (split == "validation")
    if train.sum() < MIN_TRAIN or val.sum() < MIN_VALIDATION:
        raise ValueError(f"run {run}: too few usable scenarios to build a library "
                         f"({train.sum()} training, {val.sum()} validation)")
    features = np.where(usable[:, None], to_features(np.nan_to_num(harmonics)), 0.0)
    alpha = basis.project(features)
    x = 2.0 * (values - lower) / (upper - lower) - 1.0
    weight = sensor_weights(features, H1, n, sensor_dofs)
    model = _fit(x, alpha, weight, train, val, kinks, spgd_options)
    info = {"n_train": int(train.sum()), "n_validation": int(val.sum()),
            "n_left_out": {s: int(((split == s) & ~usable).sum()) for s in ("train", "validation", "test")},
            "n_modes": basis.n_modes, **_model_info(model, x[val], alpha[val], weight[val], parameters, lower, upper)}
    return Library(run, list(parameters), np.asarray(lower, float), np.asarray(upper, float), basis.modes,
                   basis.singular_values, model, H1, n, list(sensor_dofs), info)


def build_global_library(snaps: snapshots.Snapshots, fit_runs: Sequence[str], lower: Array, upper: Array,
                         shaft: Shaft, sensor_range_m: float, energy_tolerance: float,
                         kinks: tuple[int, Array] | None = None, **spgd_options) -> Library:
    """One library for every run: an sPGD over the unknowns and the operating point (rpm, eccentric mass).

    The library-scope option of the offline stage (``offline.scope: global``): the observable snapshots of
    ``fit_runs`` stacked (each scenario at each run is one sample, its run's speed as solved and its
    eccentric mass appended to the unknowns), one POD of their training share (eq. 4-5), one sPGD
    (eq. 6-7) fitted on "train" and sized on "validation", with the sensor weights of ``build_library``.
    Runs that are not fitted (validation runs) are never seen: ``at_operating_point`` predicts them. The
    operating range spans every run of the store (a range of one value is widened by 1 RPM or 1 g each way).
    kinks: along an unknown, as in ``build_library``.
    """
    fit_rows = [r for r, run in enumerate(snaps.runs) if run in set(fit_runs)]
    if not fit_rows:
        raise ValueError(f"none of the fit runs {list(fit_runs)} is in the snapshots (runs {snaps.runs})")
    point = np.c_[snaps.rpm, snaps.eccentric_mass_g]
    op_lower, op_upper = point.min(axis=0), point.max(axis=0)
    widen = np.where(op_upper - op_lower < 1e-9, 1.0, 0.0)
    op_lower, op_upper = op_lower - widen, op_upper + widen
    x_unknown = 2.0 * (snaps.values - lower) / (upper - lower) - 1.0
    X, F, split = [], [], []
    for r in fit_rows:
        usable = snaps.steady[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
        x_point = 2.0 * (point[r] - op_lower) / (op_upper - op_lower) - 1.0
        X.append(np.hstack([x_unknown[usable], np.broadcast_to(x_point, (usable.sum(), 2))]))
        F.append(to_features(snaps.harmonics[r][usable]))
        split.append(snaps.split[usable])
    X, F, split = np.concatenate(X), np.concatenate(F), np.concatenate(split)
    train, val = split == "train", split == "validation"
    if train.sum() < MIN_TRAIN or val.sum() < MIN_VALIDATION:
        raise ValueError(f"too few usable scenarios to build a global library ({train.sum()} training, "
                         f"{val.sum()} validation)")
    basis = pod(F[train], energy_tolerance)
    alpha = basis.project(F)
    H1, n = snaps.harmonics.shape[2:]
    dofs = sensor_dofs(shaft)
    weight = sensor_weights(F, H1, n, dofs)
    model = _fit(X, alpha, weight, train, val, kinks, spgd_options)
    parameters = list(snaps.parameters) + OPERATING_POINT
    lower, upper = np.concatenate([lower, op_lower]), np.concatenate([upper, op_upper])
    info = {"scope": "global", "fit_runs": [snaps.runs[r] for r in fit_rows], "n_train": int(train.sum()),
            "n_validation": int(val.sum()), "n_modes": basis.n_modes,
            **_model_info(model, X[val], alpha[val], weight[val], parameters, lower, upper)}
    return Library("global", parameters, lower, upper, basis.modes, basis.singular_values, model, H1, n, dofs, info)


#: fewest training / validation scenarios of an sPGD piece; a thinner piece is joined to its neighbour
MIN_PIECE = (10, 2)


def _fit(x: Array, alpha: Array, weight: Array, train: Array, val: Array, kinks: tuple[int, Array] | None,
         spgd_options: dict) -> SparsePGD | PiecewiseSPGD:
    """One sPGD, or one per interval between the kinks (the kinks that would leave a piece with fewer than
    ``MIN_PIECE`` training or validation scenarios are dropped)."""
    if kinks is not None:
        axis, at = kinks
        edges = np.concatenate([[-1.0], np.sort(np.asarray(at, float)), [1.0]])
        while edges.size > 2:
            n_train = np.bincount(piece_index(x[train, axis], edges), minlength=edges.size - 1)
            n_val = np.bincount(piece_index(x[val, axis], edges), minlength=edges.size - 1)
            thin = np.flatnonzero((n_train < MIN_PIECE[0]) | (n_val < MIN_PIECE[1]))
            if thin.size == 0:
                return fit_piecewise(x[train], alpha[train], x[val], alpha[val], weight[train], weight[val],
                                     axis, edges, **spgd_options)
            edges = np.delete(edges, thin[0] if thin[0] > 0 else 1)
    return fit_spgd(x[train], alpha[train], x[val], alpha[val], weight[train], weight[val], **spgd_options)


def _model_info(model: SparsePGD | PiecewiseSPGD, x_val: Array, alpha_val: Array, weight_val: Array,
                parameters: list[str], lower: Array, upper: Array) -> dict:
    """n_terms, spgd_degree (the chosen degree cap; per piece, e.g. "12/8*"), the validation error per number of
    terms (of the whole model, one value, for pieces) and the pieces' parameter and edges [SI]."""
    if isinstance(model, SparsePGD):
        return {"n_terms": model.n_terms, "spgd_degree": model.degree,
                "validation_error": model.history.validation_error}
    a = model.axis
    return {"n_terms": model.n_terms, "spgd_degree": model.degree,
            "validation_error": [relative_error(alpha_val - model.predict(x_val), alpha_val, weight_val)],
            "pieces": {"parameter": parameters[a],
                       "edges": (lower[a] + (model.edges + 1.0) * (upper[a] - lower[a]) / 2).tolist()}}


def pieces_note(info: Mapping) -> str:
    """'' or ', one sPGD per side of <parameter> = <switches>' for a library's ``info`` (rule logs)."""
    pieces = info.get("pieces")
    if not pieces:
        return ""
    return f", one sPGD per side of {pieces['parameter']} = " + ", ".join(f"{e:.6g}" for e in pieces["edges"][1:-1])


def sensor_weights(features: Array, n_harmonics: int, n_dof: int, sensor_dofs: list[int],
                   floor: float = 1e-2) -> Array:
    """Least-squares weight per scenario: 1 / ||x, y||^2 of its sensor signals over a period (Parseval).

    The fit then minimises the relative sensor error, the measure of ``relative_sensor_error``.
    Measured against weights 1 / ||q||^2 of the whole field (benchmarks/library_benchmark.py,
    geometric, 5 runs): pooled test error about the same (median 0.031 -> 0.030 %, p95 2.48 ->
    2.47 %), r900_m0p0 better (median 0.71 -> 0.48 %, p95 2.9 -> 1.85 %), r350 and r700 slightly
    worse on the median (+10 %), and fewer terms (32-40 instead of 44-59). The squared norm is floored at ``floor`` times its median, so that scenarios whose
    sensor response nearly cancels do not dominate the fit.
    """
    h = np.arange(n_harmonics)
    parseval = np.where(h == 0, 1.0, 0.5)
    energy = np.zeros(features.shape[0])
    for imaginary in (False, True):
        for dof in sensor_dofs:
            part = features[:, feature_index(h, dof, n_harmonics, n_dof, imaginary)]
            energy += (part * part) @ parseval
    positive = energy[energy > 0]
    floor_value = floor * float(np.median(positive)) if positive.size else 1.0
    return 1.0 / np.maximum(energy, max(floor_value, 1e-300))


def sensor_signal_norm(harmonics: Array) -> Array:
    """RMS-type L2 norm over a period of x(t), y(t) from (N, H+1, 2) harmonics (Parseval).

    ||x||^2 = X_0^2 + 1/2 sum_{h>=1} |X_h|^2, summed over x and y.
    """
    weights = np.full(harmonics.shape[1], 0.5)
    weights[0] = 1.0
    return np.sqrt(np.einsum("h,nhc->n", weights, np.abs(harmonics) ** 2))


def relative_sensor_error(predicted: Array, reference: Array) -> Array:
    """Relative L2 error over a period of the sensor signals x(t), y(t), per scenario (Parseval)."""
    return sensor_signal_norm(predicted - reference) / sensor_signal_norm(reference)


def mode_scaling_kinks(variant: Variant, parameters: list[str], lower: Array, upper: Array,
                       n_probe: int = 512) -> tuple[int, Array] | None:
    """Where the bow force's mode scaling changes node inside the box, if one parameter alone decides it.

    Phi_1 is scaled so that its entry of largest magnitude is +1 (``docs/model.md``, eq. 30); where
    that entry moves to another node, every response to the bow has a kink (Geometric: k_b = 2753 N/m;
    ``benchmarks/spgd_smoothness_study.py``), across which polynomial factors converge slowly. The node is
    computed at ``n_probe`` points of the box (seeded, uniform; a property of the model and the box, not of
    the scenarios: the same for every run). If, sorted by one parameter, each node occupies one interval,
    the switches are located by bisection on the model (the other parameters at the box centre) to 1e-12
    of the range: (that parameter's index, the switches in normalised coordinates). None when the node
    never changes, or when no single parameter decides it (one sPGD then).
    """
    def node(v: Array) -> Array:
        return variant.model.mode_peak_node(variant.values(dict(zip(parameters, np.atleast_2d(v).T))))

    x = 2.0 * np.random.default_rng(0).random((n_probe, len(parameters))) - 1.0
    nodes = node(lower + (x + 1.0) * (upper - lower) / 2.0)
    if np.unique(nodes).size == 1:
        return None
    deciding = []
    for j in range(x.shape[1]):
        ordered = nodes[np.argsort(x[:, j], kind="stable")]
        changes = np.flatnonzero(ordered[1:] != ordered[:-1])
        if changes.size == np.unique(nodes).size - 1:
            deciding.append((j, changes))
    if len(deciding) != 1:
        return None
    j, changes = deciding[0]
    xs = np.sort(x[:, j])
    centre = (lower + upper) / 2.0
    at = []
    for c in changes:
        lo, hi = xs[c], xs[c + 1]
        probe = np.tile(centre, (2, 1))
        probe[:, j] = lower[j] + (np.array([lo, hi]) + 1.0) * (upper[j] - lower[j]) / 2.0
        below, above = node(probe)
        if below == above:
            return None  # the switch is not where the scenarios put it at the centre: not one parameter's
        while hi - lo > 1e-12:
            mid = 0.5 * (lo + hi)
            probe = centre.copy()
            probe[j] = lower[j] + (mid + 1.0) * (upper[j] - lower[j]) / 2.0
            lo, hi = (mid, hi) if node(probe)[0] == below else (lo, mid)
        at.append(0.5 * (lo + hi))
    return j, np.array(at)


def build_run_library(variant: Variant, run: str, snapshots_path: str, pod_path: str, sensor_range_m: float,
                      spgd_options: dict, pieces: str = "mode_scaling") -> Library:
    """The library of ``run`` from the gathered snapshots and that run's POD; pieces: "mode_scaling" (one sPGD
    per side of the mode scaling's kinks, ``mode_scaling_kinks``) or "none"."""
    snaps = snapshots.load(snapshots_path, run)
    basis, usable = load_pod(pod_path, run)
    lower, upper = variant.bounds(snaps.parameters)
    kinks = _kinks(variant, snaps, lower, upper, pieces)
    library = build_library(run, basis, snaps.harmonics[0], snaps.values, snaps.split, usable, snaps.parameters,
                            lower, upper, sensor_dofs(variant.model.shaft), kinks, **spgd_options)
    library.info["sensor_range_m"] = sensor_range_m
    return library


def build_run_libraries(make_variant: Callable[[], Variant], runs: Sequence[str], snapshots_path: str,
                        pod_path: str, outputs: Sequence[str], sensor_range_m: float, spgd_options: dict,
                        pieces: str = "mode_scaling", workers: int = 1, log=None) -> list[dict]:
    """``build_run_library`` for every run of ``runs``, each saved to its path in ``outputs``, on ``workers``
    processes: the libraries of a variant in one workflow job (one job per run paid the start-up, the
    snapshots' loading and the mode-scaling probe once per run, for a fit of a few seconds). The runs with the
    most usable scenarios go first (the enrichment runs near the resonance fit several times longer than the
    others: started last, one would run alone at the end). The variant is rebuilt in each process by
    ``make_variant`` (a picklable callable, e.g. ``functools.partial(hybridtwin.config.variant, config, name)``: its
    effects do not pickle). The processes are forked (a spawned
    one would run the calling Snakemake script again; zarr resets its I/O loop in a forked child). Returns the
    libraries' ``info``, in the order of ``runs``. ``log``: a logger for the progress after each run's library (the
    count, the time so far and an estimate of the time left: ``Progress``)."""
    if len(outputs) != len(runs):
        raise ValueError(f"{len(runs)} runs for {len(outputs)} library paths")
    jobs = [(make_variant, run, snapshots_path, pod_path, path, sensor_range_m, spgd_options, pieces)
            for run, path in zip(runs, outputs)]
    size = [int(np.sum(load_pod(pod_path, run)[1])) for run in runs]
    order = sorted(range(len(runs)), key=lambda i: -size[i])
    progress = Progress(log, len(runs), "runs' libraries")
    done = {}
    if workers <= 1 or len(runs) == 1:
        for i in order:
            done[i] = _build_and_save(jobs[i])
            progress.done(note=f"{runs[i]}: {done[i]['n_terms']} sPGD terms")
    else:
        context = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(min(workers, len(runs)), mp_context=context) as pool:
            futures = {pool.submit(_build_and_save, jobs[i]): i for i in order}
            for future in as_completed(futures):
                i = futures[future]
                done[i] = future.result()
                progress.done(note=f"{runs[i]}: {done[i]['n_terms']} sPGD terms")
    return [done[i] for i in range(len(runs))]


def _build_and_save(job: tuple) -> dict:
    """One run's library built and saved (a worker of ``build_run_libraries``, BLAS on one thread): its info
    with n_modes and n_terms."""
    make_variant, run, snapshots_path, pod_path, path, sensor_range_m, spgd_options, pieces = job
    with threadpool_limits(1):
        library = build_run_library(make_variant(), run, snapshots_path, pod_path,
                                    sensor_range_m, spgd_options, pieces)
        library.save(path)
    return {**library.info, "n_modes": library.n_modes, "n_terms": library.model.n_terms}


def build_variant_global_library(variant: Variant, snapshots_path: str, runs: pd.DataFrame, sensor_range_m: float,
                                 energy_tolerance: float, spgd_options: dict, pieces: str = "mode_scaling") -> Library:
    """The global library of a variant from its gathered snapshots, trained on the runs with role "fit"."""
    snaps = snapshots.load(snapshots_path)
    roles = runs.set_index("run")["role"] if "role" in runs else pd.Series("fit", index=runs["run"])
    fit_runs = [run for run in snaps.runs if roles.get(run, "fit") == "fit"]
    lower, upper = variant.bounds(snaps.parameters)
    library = build_global_library(snaps, fit_runs, lower, upper, variant.model.shaft, sensor_range_m,
                                   energy_tolerance, _kinks(variant, snaps, lower, upper, pieces), **spgd_options)
    library.info["sensor_range_m"] = sensor_range_m
    return library


def _kinks(variant: Variant, snaps: snapshots.Snapshots, lower: Array, upper: Array,
           pieces: str) -> tuple[int, Array] | None:
    if pieces not in ("mode_scaling", "none"):
        raise ValueError(f"offline.pieces must be mode_scaling or none, not {pieces!r}")
    return mode_scaling_kinks(variant, snaps.parameters, lower, upper) if pieces == "mode_scaling" else None


def global_run_library(global_path: str, snapshots_path: str, run: str) -> Library:
    """The library of ``run``: the global library sliced at the run's speed (as solved) and eccentric mass."""
    return Library.load(global_path).at_operating_point(run, *snapshots.operating_point(snapshots_path, run))


def write_library_validation(table: pd.DataFrame, path: str | Path) -> None:
    """library_validation.tsv (``validate_libraries``' per-run table): ``read_library_validation`` reads it."""
    tables.LIBRARY_VALIDATION.write(table, path)


def read_library_validation(path: str | Path) -> pd.DataFrame:
    """library_validation.tsv as ``write_library_validation`` wrote it, run ids as strings."""
    return tables.LIBRARY_VALIDATION.read(path)


def validate_libraries(libraries: list[Library], snapshots_path: str, runs: pd.DataFrame, shaft: Shaft,
                       sensor_range_m: float) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Each library against the full solver on its run's test scenarios.

    Returns the per-run table (with an "all runs" row) and the parity data
    (1X amplitudes, full solver vs library, of the first two channels: x, y on the VARM) for plotting. The
    errors are over every sensor.
    """
    snaps = snapshots.load(snapshots_path)
    plan = runs.set_index("run")
    rows, parity, pooled = [], [], []
    for library in libraries:
        r = snaps.run_index(library.run)
        test = snaps.split == "test"
        usable = test & snaps.steady[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
        reference = snaps.harmonics[r][usable][:, :, library.sensor_dofs]
        predicted = library.sensor(snaps.values[usable])
        error = relative_sensor_error(predicted, reference)
        pooled.append(error)
        # the same errors relative to the run's median response instead of each scenario's own
        # (which is large where the response nearly cancels at the sensor)
        size = sensor_signal_norm(reference)
        typical = error * size / np.median(size) if size.size else error
        # the speed the run was solved at (offline.speed: measured, refined from its record), not the sheet's
        rows.append({"run": library.run, "rpm": float(snaps.rpm[r]),
                     "eccentric_mass_g": plan.loc[library.run, "eccentric_mass_g"],
                     **_error_stats(error),
                     "p95_error_of_median_response_pct": 100 * float(np.percentile(typical, 95)) if size.size else np.nan,
                     "n_failed": int((test & ~snaps.success[r]).sum()),
                     "n_unstable": int((test & snaps.success[r] & ~snaps.stable[r]).sum()),
                     "observable_fraction": float(usable.sum() / max(test.sum(), 1)),
                     "n_modes": library.n_modes, "n_terms": library.model.n_terms,
                     "spgd_degree": library.info.get("spgd_degree", np.nan)})
        parity.append(pd.DataFrame({"run": library.run, "eccentric_mass_g": rows[-1]["eccentric_mass_g"],
                                    "solver_x_m": np.abs(reference[:, 1, 0]), "library_x_m": np.abs(predicted[:, 1, 0]),
                                    "solver_y_m": np.abs(reference[:, 1, 1]), "library_y_m": np.abs(predicted[:, 1, 1])}))
    error = np.concatenate(pooled)
    rows.append({"run": "all runs", "rpm": np.nan, "eccentric_mass_g": np.nan, **_error_stats(error),
                 "p95_error_of_median_response_pct": np.nan,
                 "n_failed": sum(r["n_failed"] for r in rows), "n_unstable": sum(r["n_unstable"] for r in rows),
                 "observable_fraction": np.nan,
                 "n_modes": np.nan, "n_terms": np.nan, "spgd_degree": np.nan})
    return pd.DataFrame(rows), pd.concat(parity, ignore_index=True)


def _error_stats(error: Array) -> dict:
    if error.size == 0:
        return {"n_test": 0, "median_error_pct": np.nan, "p95_error_pct": np.nan, "max_error_pct": np.nan}
    return {"n_test": int(error.size), "median_error_pct": 100 * float(np.median(error)),
            "p95_error_pct": 100 * float(np.percentile(error, 95)), "max_error_pct": 100 * float(error.max())}
