"""The sPGD library of one run: response and exact Jacobian for any parameter set (paper sec. 2.1).

A library joins the POD basis of a run's snapshots (eq. 4-5) with an sPGD
model of the reduced coordinates (eq. 6-7): q(p) = Phi alpha(x), x the
parameters normalised to [-1, 1]. It returns the sensor harmonics U_h, V_h
(or the whole field) and their derivatives with respect to the parameters in
SI units, batched, in microseconds per parameter set.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import zarr

from . import snapshots
from .effects import Array
from .pod import POD, feature_index, from_features, load_pod, pod, to_features
from .sensor import observable, sensor_dofs
from .shaft import Shaft
from .spgd import SparsePGD, chebyshev_basis, fit_spgd
from .variants import Variant

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
    model: SparsePGD
    n_harmonics: int  # H + 1
    n_dof: int
    sensor_dofs: list[int]
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        h = np.arange(self.n_harmonics)
        rows = [feature_index(h, dof, self.n_harmonics, self.n_dof, imaginary)
                for imaginary in (False, True) for dof in self.sensor_dofs]
        self._sensor_modes = self.modes[np.concatenate(rows)]  # (2 * 2 * (H+1), m_d)

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
        """Sensor harmonics (N, H+1, 2) complex [U_h, V_h]; with ``jacobian`` also d/dp (N, H+1, 2, d) [m / SI].

        The sPGD amplitudes are projected on the sensor rows of the POD basis once (the response is
        linear in them), so a batch costs the factors and one product with (K, 4 (H+1)) amplitudes.
        """
        x = self.normalise(values)
        y, J = self.model.evaluate(x, self._sensor_amplitudes(), jacobian)
        if not jacobian:
            return self._to_sensor(y)
        J *= (2.0 / (self.upper - self.lower))[:, None, None]
        return self._to_sensor(y), np.moveaxis(self._to_sensor(J), 0, -1)

    def _sensor_amplitudes(self) -> Array:
        """a_k Phi_sensor^T (K, 4 (H+1)), cached for the current amplitudes."""
        amplitudes = self.model.amplitudes
        if getattr(self, "_sensor_cache", (None,))[0] is not amplitudes:
            self._sensor_cache = (amplitudes, np.ascontiguousarray(amplitudes @ self._sensor_modes.T))
        return self._sensor_cache[1]

    def _to_sensor(self, features: Array) -> Array:
        """(..., 2 * 2 * (H+1)) [Re U, Re V, Im U, Im V] -> (..., H+1, 2) complex."""
        H1 = self.n_harmonics
        parts = features.reshape(features.shape[:-1] + (2, 2, H1))
        return np.moveaxis(parts[..., 0, :, :] + 1j * parts[..., 1, :, :], -2, -1)

    def at_operating_point(self, run: str, rpm: float, eccentric_mass_g: float) -> "Library":
        """A global library (``build_global_library``) sliced at one run's operating point: that run's
        library over the unknowns alone, exact.

        With x_rpm and x_me fixed, each term's last two factors are numbers (eq. 6-7):
        a_k prod_j F_j^k = (a_k F_rpm^k(x_rpm) F_me^k(x_me)) prod_{j <= d} F_j^k.
        """
        if self.parameters[-len(OPERATING_POINT):] != OPERATING_POINT:
            raise ValueError(f"library {self.run} is not a global library (parameters {self.parameters})")
        d = len(self.parameters) - len(OPERATING_POINT)
        point = np.array([rpm, eccentric_mass_g], float)
        low, high = self.lower[d:], self.upper[d:]
        if np.any(point < low - 1e-9 * np.abs(low)) or np.any(point > high + 1e-9 * np.abs(high)):
            raise ValueError(f"run {run}: operating point {rpm:g} RPM, {eccentric_mass_g:g} g is outside the "
                             f"global library's range ({low[0]:g}-{high[0]:g} RPM, {low[1]:g}-{high[1]:g} g)")
        x = np.clip(2.0 * (point - low) / (high - low) - 1.0, -1.0, 1.0)
        C = self.model.coefficients
        factors = np.einsum("jb,kjb->kj", chebyshev_basis(x, C.shape[-1] - 1), C[:, d:])
        model = SparsePGD.from_arrays(self.model.amplitudes * factors.prod(axis=1)[:, None], C[:, :d])
        info = {**self.info, "scope": "global", "operating_point": {"rpm": float(rpm),
                                                                    "eccentric_mass_g": float(eccentric_mass_g)}}
        return Library(run, self.parameters[:d], self.lower[:d], self.upper[:d], self.modes, self.singular_values,
                       model, self.n_harmonics, self.n_dof, self.sensor_dofs, info)

    def field(self, values: Array) -> Array:
        """Harmonics of all DOFs (N, H+1, n) for parameter values (N, d)."""
        return from_features(self.model.predict(self.normalise(values)) @ self.modes.T, self.n_harmonics, self.n_dof)

    def save(self, path: str | Path) -> None:
        """Write as a zarr v3 group."""
        group = zarr.open_group(str(path), mode="w")
        arrays = {"modes": self.modes, "singular_values": self.singular_values, "lower": self.lower,
                  "upper": self.upper, **self.model.to_arrays()}
        for name, data in arrays.items():
            group.create_array(name, data=np.asarray(data))
        group.attrs.update({"run": self.run, "parameters": self.parameters, "n_harmonics": self.n_harmonics,
                            "n_dof": self.n_dof, "sensor_dofs": self.sensor_dofs,
                            "info": json.loads(json.dumps(self.info, default=float))})

    @classmethod
    def load(cls, path: str | Path) -> "Library":
        group = zarr.open_group(str(path), mode="r")
        attrs = dict(group.attrs)
        model = SparsePGD.from_arrays(group["amplitudes"][:], group["coefficients"][:])
        return cls(attrs["run"], list(attrs["parameters"]), group["lower"][:], group["upper"][:], group["modes"][:],
                   group["singular_values"][:], model, attrs["n_harmonics"], attrs["n_dof"],
                   list(attrs["sensor_dofs"]), attrs.get("info", {}))


def build_library(run: str, basis: POD, harmonics: Array, values: Array, split: Array, usable: Array,
                  parameters: list[str], lower: Array, upper: Array, sensor_dofs: list[int],
                  **spgd_options) -> Library:
    """sPGD (eq. 6-7) of one run's reduced coordinates alpha = Phi^T q on its POD basis.

    harmonics (S, H+1, n), values (S, d) SI, split (S,) in train/validation/test,
    usable (S,): converged and observable scenarios (the others are left out and
    counted in ``info``). Fitted on "train", its size chosen on "validation";
    weights 1 / ||sensor signal||^2 make the least squares relative, scenario by
    scenario, in the norm the library is judged and used in (``sensor_weights``).
    """
    S, H1, n = harmonics.shape
    usable = np.asarray(usable, bool)
    train, val = usable & (split == "train"), usable & (split == "validation")
    if train.sum() < 10 or val.sum() < 2:
        raise ValueError(f"run {run}: too few usable scenarios to build a library "
                         f"({train.sum()} training, {val.sum()} validation)")
    features = np.where(usable[:, None], to_features(np.nan_to_num(harmonics)), 0.0)
    alpha = basis.project(features)
    x = 2.0 * (values - lower) / (upper - lower) - 1.0
    weight = sensor_weights(features, H1, n, sensor_dofs)
    model = fit_spgd(x[train], alpha[train], x[val], alpha[val], weight[train], weight[val], **spgd_options)
    info = {"n_train": int(train.sum()), "n_validation": int(val.sum()),
            "n_left_out": {s: int(((split == s) & ~usable).sum()) for s in ("train", "validation", "test")},
            "n_modes": basis.n_modes, "n_terms": model.n_terms, "spgd_degree": model.degree,
            "validation_error": model.history.validation_error}
    return Library(run, list(parameters), np.asarray(lower, float), np.asarray(upper, float), basis.modes,
                   basis.singular_values, model, H1, n, list(sensor_dofs), info)


def build_global_library(snaps: snapshots.Snapshots, fit_runs: Sequence[str], lower: Array, upper: Array,
                         shaft: Shaft, sensor_range_m: float, energy_tolerance: float, **spgd_options) -> Library:
    """One library for every run: an sPGD over the unknowns and the operating point (rpm, eccentric mass).

    The library-scope option of the offline stage (``offline.scope: global``): the observable snapshots of
    ``fit_runs`` stacked (each scenario at each run is one sample, its run's speed as solved and its
    eccentric mass appended to the unknowns), one POD of their training share (eq. 4-5), one sPGD
    (eq. 6-7) fitted on "train" and sized on "validation", with the sensor weights of ``build_library``.
    Runs that are not fitted (validation runs) are never seen: ``at_operating_point`` predicts them. The
    operating range spans every run of the store (a range of one value is widened by 1 RPM or 1 g each way).
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
        usable = snaps.success[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
        x_point = 2.0 * (point[r] - op_lower) / (op_upper - op_lower) - 1.0
        X.append(np.hstack([x_unknown[usable], np.broadcast_to(x_point, (usable.sum(), 2))]))
        F.append(to_features(snaps.harmonics[r][usable]))
        split.append(snaps.split[usable])
    X, F, split = np.concatenate(X), np.concatenate(F), np.concatenate(split)
    train, val = split == "train", split == "validation"
    if train.sum() < 10 or val.sum() < 2:
        raise ValueError(f"too few usable scenarios to build a global library ({train.sum()} training, "
                         f"{val.sum()} validation)")
    basis = pod(F[train], energy_tolerance)
    alpha = basis.project(F)
    H1, n = snaps.harmonics.shape[2:]
    dofs = sensor_dofs(shaft)
    weight = sensor_weights(F, H1, n, dofs)
    model = fit_spgd(X[train], alpha[train], X[val], alpha[val], weight[train], weight[val], **spgd_options)
    info = {"scope": "global", "fit_runs": [snaps.runs[r] for r in fit_rows], "n_train": int(train.sum()),
            "n_validation": int(val.sum()), "n_modes": basis.n_modes, "n_terms": model.n_terms,
            "spgd_degree": model.degree, "validation_error": model.history.validation_error}
    return Library("global", list(snaps.parameters) + OPERATING_POINT, np.concatenate([lower, op_lower]),
                   np.concatenate([upper, op_upper]), basis.modes, basis.singular_values, model, H1, n, dofs, info)


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


def build_run_library(variant: Variant, run: str, snapshots_path: str, pod_path: str, sensor_range_m: float,
                      spgd_options: dict) -> Library:
    """The library of ``run`` from the gathered snapshots and that run's POD."""
    snaps = snapshots.load(snapshots_path, run)
    basis, usable = load_pod(pod_path, run)
    lower, upper = variant.bounds(snaps.parameters)
    library = build_library(run, basis, snaps.harmonics[0], snaps.values, snaps.split, usable, snaps.parameters,
                            lower, upper, sensor_dofs(variant.model.shaft), **spgd_options)
    library.info["sensor_range_m"] = sensor_range_m
    return library


def build_variant_global_library(variant: Variant, snapshots_path: str, runs: pd.DataFrame, sensor_range_m: float,
                                 energy_tolerance: float, spgd_options: dict) -> Library:
    """The global library of a variant from its gathered snapshots, trained on the runs with role "fit"."""
    snaps = snapshots.load(snapshots_path)
    roles = runs.set_index("run")["role"] if "role" in runs else pd.Series("fit", index=runs["run"])
    fit_runs = [run for run in snaps.runs if roles.get(run, "fit") == "fit"]
    lower, upper = variant.bounds(snaps.parameters)
    library = build_global_library(snaps, fit_runs, lower, upper, variant.model.shaft, sensor_range_m,
                                   energy_tolerance, **spgd_options)
    library.info["sensor_range_m"] = sensor_range_m
    return library


def global_run_library(global_path: str, snapshots_path: str, run: str) -> Library:
    """The library of ``run``: the global library sliced at the run's speed (as solved) and eccentric mass."""
    return Library.load(global_path).at_operating_point(run, *snapshots.operating_point(snapshots_path, run))


def validate_libraries(libraries: list[Library], snapshots_path: str, runs: pd.DataFrame, shaft: Shaft,
                       sensor_range_m: float) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Each library against the full solver on its run's test scenarios.

    Returns the per-run table (with an "all runs" row) and the parity data
    (1X amplitudes, full solver vs library) for plotting.
    """
    snaps = snapshots.load(snapshots_path)
    plan = runs.set_index("run")
    rows, parity, pooled = [], [], []
    for library in libraries:
        r = snaps.run_index(library.run)
        test = snaps.split == "test"
        usable = test & snaps.success[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
        reference = snaps.harmonics[r][usable][:, :, library.sensor_dofs]
        predicted = library.sensor(snaps.values[usable])
        error = relative_sensor_error(predicted, reference)
        pooled.append(error)
        # the same errors relative to the run's median response instead of each scenario's own
        # (which is large where the response nearly cancels at the sensor)
        size = sensor_signal_norm(reference)
        typical = error * size / np.median(size) if size.size else error
        rows.append({"run": library.run, "rpm": plan.loc[library.run, "rpm"],
                     "eccentric_mass_g": plan.loc[library.run, "eccentric_mass_g"],
                     **_error_stats(error),
                     "p95_error_of_median_response_pct": 100 * float(np.percentile(typical, 95)) if size.size else np.nan,
                     "n_failed": int((test & ~snaps.success[r]).sum()),
                     "observable_fraction": float(usable.sum() / max(test.sum(), 1)),
                     "n_modes": library.n_modes, "n_terms": library.model.n_terms,
                     "spgd_degree": library.info.get("spgd_degree", np.nan)})
        parity.append(pd.DataFrame({"run": library.run, "eccentric_mass_g": rows[-1]["eccentric_mass_g"],
                                    "solver_x_m": np.abs(reference[:, 1, 0]), "library_x_m": np.abs(predicted[:, 1, 0]),
                                    "solver_y_m": np.abs(reference[:, 1, 1]), "library_y_m": np.abs(predicted[:, 1, 1])}))
    error = np.concatenate(pooled)
    rows.append({"run": "all runs", "rpm": np.nan, "eccentric_mass_g": np.nan, **_error_stats(error),
                 "p95_error_of_median_response_pct": np.nan,
                 "n_failed": sum(r["n_failed"] for r in rows), "observable_fraction": np.nan,
                 "n_modes": np.nan, "n_terms": np.nan, "spgd_degree": np.nan})
    return pd.DataFrame(rows), pd.concat(parity, ignore_index=True)


def _error_stats(error: Array) -> dict:
    if error.size == 0:
        return {"n_test": 0, "median_error_pct": np.nan, "p95_error_pct": np.nan, "max_error_pct": np.nan}
    return {"n_test": int(error.size), "median_error_pct": 100 * float(np.median(error)),
            "p95_error_pct": 100 * float(np.percentile(error, 95)), "max_error_pct": 100 * float(error.max())}
