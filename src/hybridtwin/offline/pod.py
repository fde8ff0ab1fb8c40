"""Proper orthogonal decomposition of the snapshots (paper eq. 4-5).

A snapshot is one scenario's steady state: the complex harmonics Q_h
(h = 0..H) of all DOFs, stored as real features [Re Q, Im Q] (2 (H+1) n).
The snapshot matrix S (features x scenarios) is decomposed by the SVD
S = Phi Sigma W^T (eq. 4) and truncated to the m_d modes that hold a fraction
1 - epsilon of the energy sum sigma_i^2 (eq. 5); a scenario is then
q = Phi alpha with alpha = Phi^T q its reduced coordinates.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import pandas as pd
import zarr

from . import snapshots
from ..model.effect_base import Array
from ..model.sensor import observable
from ..model.shaft import Shaft
from .stores import open_verified, write_manifest

#: the fewest usable (steady, observable) scenarios a run's library is built from: training, validation
MIN_TRAIN, MIN_VALIDATION = 10, 2


class ThinLibraryError(ValueError):
    """Runs whose usable scenarios are too few for a library. ``runs``: a table, one row per such run (run, rpm,
    eccentric_mass_g, the usable and solved training and validation scenarios, and where the other fitting
    scenarios went: beyond_range, unstable, failed; observable_share of the first design); the message is a
    line per run, then what to change."""

    def __init__(self, runs: pd.DataFrame, sensor_range_m: float):
        self.runs = runs
        self.lines = [
            f"run {row.run} ({row.rpm:.6g} RPM, {row.eccentric_mass_g:.6g} g): {row.usable_train} of {row.train} "
            f"training and {row.usable_validation} of {row.validation} validation scenarios usable (a library needs "
            f"{MIN_TRAIN} and {MIN_VALIDATION}); the others: {row.beyond_range} beyond the sensor range "
            f"({sensor_range_m * 1e3:.6g} mm), {row.unstable} unstable, {row.failed} without a solution; observable "
            f"share of the first design {row.observable_share:.0%}"
            + ("; the data checks keep this run out of the fit and even its steady scenarios are too few: "
               "leave it out of the runs sheet" if getattr(row, "kept_out", False) else "")
            for row in runs.itertuples()]
        self.lines.append(
            "the variant's ranges put these runs' responses out of what can be measured or solved for most "
            "scenarios (near a resonance, typically). Either: more scenarios where these runs can be measured "
            "(offline.enrichment: observable_below above the run's observable share, n_scenarios > 0; or a "
            "larger offline.n_scenarios), offline.sensor_range_mm set to the probes' real range, ranges of the "
            "variant's unknowns narrowed to what the machine can be, or the runs left out of the runs sheet")
        super().__init__("\n".join(self.lines))


def to_features(harmonics: Array) -> Array:
    """(S, H+1, n) complex -> (S, 2 (H+1) n) real [Re, Im]."""
    S = harmonics.shape[0]
    return np.concatenate([harmonics.real.reshape(S, -1), harmonics.imag.reshape(S, -1)], axis=1)


def from_features(features: Array, n_harmonics: int, n_dof: int) -> Array:
    """Inverse of ``to_features``: (..., 2 (H+1) n) -> (..., H+1, n) complex."""
    half = n_harmonics * n_dof
    shape = features.shape[:-1] + (n_harmonics, n_dof)
    return features[..., :half].reshape(shape) + 1j * features[..., half:].reshape(shape)


def feature_index(harmonic: Array, dof: Array, n_harmonics: int, n_dof: int, imaginary: bool) -> Array:
    """Position of Re/Im Q_h[dof] in the feature vector."""
    return (n_harmonics * n_dof if imaginary else 0) + np.asarray(harmonic) * n_dof + np.asarray(dof)


@dataclass
class POD:
    """Truncated POD basis of a snapshot set."""

    modes: Array  # Phi, (features, m_d), orthonormal columns
    singular_values: Array  # all sigma_i, descending
    energy_tolerance: float

    @property
    def n_modes(self) -> int:
        return self.modes.shape[1]

    @property
    def ratios(self) -> Array:
        """sigma_i / sigma_1, the decay the paper reports (its Geometric model: sigma_2/sigma_1 = 0.0012)."""
        return self.singular_values / self.singular_values[0]

    def project(self, features: Array) -> Array:
        """alpha = Phi^T q, (S, m_d)."""
        return features @ self.modes

    def reconstruct(self, coefficients: Array) -> Array:
        """q = Phi alpha, (S, features)."""
        return coefficients @ self.modes.T


def pod(features: Array, energy_tolerance: float = 1e-10, max_modes: int | None = None) -> POD:
    """POD of snapshots (S, features): keep the fewest modes with sum sigma^2 >= (1 - eps) total (eq. 5)."""
    if features.shape[0] < 2:
        raise ValueError(f"POD needs at least 2 snapshots, got {features.shape[0]}")
    if not np.isfinite(features).all():
        raise ValueError("POD snapshots contain NaN or inf (failed scenarios must be excluded first)")
    U, sigma, _ = np.linalg.svd(features.T, full_matrices=False)
    energy = np.cumsum(sigma**2) / np.sum(sigma**2)
    m_d = int(np.searchsorted(energy, 1.0 - energy_tolerance) + 1)
    m_d = min(m_d, max_modes or m_d, sigma.size)
    return POD(U[:, :m_d], sigma, energy_tolerance)


def pod_of_runs(snapshots_path: str, out_path: str, shaft: Shaft, sensor_range_m: float,
                energy_tolerance: float, kept_out: Collection[str] = (), for_libraries: bool = True) -> pd.DataFrame:
    """POD per run of the observable (converged, stable, inside the sensor range) training snapshots.

    A run of ``kept_out`` (the data checks kept it out of the fit: its library is never fitted to) whose
    observable snapshots are too few takes every steady one instead, so that the variant's libraries are
    built; any other run with too few is a ``ThinLibraryError`` (``_check_enough``). ``for_libraries`` False:
    the POD alone, which needs 2 snapshots per run (``pod``), no library's minimum.

    Writes a zarr v3 group per run (modes, singular_values, usable mask), the store's
    manifest last (``hybridtwin.offline.stores``), and returns the summary table: training
    snapshots (of which from the enrichment), the observable share of the first design
    (the box's share a rig can measure at that run), failed solves, unstable steady
    states (converged, left out: the machine would not stay on them), m_d and the
    singular value ratios.
    """
    snaps = snapshots.load(snapshots_path)
    measurable = [snaps.steady[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
                  for r in range(len(snaps.runs))]
    usable_all = list(measurable)
    thin = set(_too_few(snaps, usable_all)["run"])
    for r, run in enumerate(snaps.runs):
        if run in thin and run in set(kept_out):
            usable_all[r] = snaps.steady[r]  # not fitted: beyond the sensor range is no reason to leave it out
    if for_libraries:
        _check_enough(snaps, usable_all, sensor_range_m, kept_out)
    store = zarr.open_group(out_path, mode="w")
    rows = []
    first_design, solved = snaps.design == "hypercube", snaps.solved
    for r, run in enumerate(snaps.runs):
        usable = usable_all[r]
        train = usable & (snaps.split == "train")
        basis = pod(to_features(snaps.harmonics[r][train]), energy_tolerance)
        group = store.create_group(run)
        group.create_array("modes", data=basis.modes)
        group.create_array("singular_values", data=basis.singular_values)
        group.create_array("usable", data=usable)
        group.attrs["energy_tolerance"] = energy_tolerance
        ratios = np.pad(basis.ratios, (0, 3))
        rows.append({"run": run, "n_snapshots": int(train.sum()), "n_enriched": int((train & ~first_design).sum()),
                     "observable_fraction": float(measurable[r][first_design].mean()),
                     "n_failed": int((~snaps.success[r] & solved[r]).sum()),
                     "n_unstable": int((snaps.success[r] & ~snaps.stable[r]).sum()), "n_modes": basis.n_modes,
                     "sigma2_over_sigma1": ratios[1], "sigma3_over_sigma1": ratios[2],
                     "sigma4_over_sigma1": ratios[3]})
    write_manifest(out_path)
    return pd.DataFrame(rows)


def _check_enough(snaps: snapshots.Snapshots, usable: list[Array], sensor_range_m: float,
                  kept_out: Collection[str] = ()) -> None:
    """ThinLibraryError naming every run with fewer than MIN_TRAIN usable training or MIN_VALIDATION validation
    scenarios (among those solved at the run), with where the others went and what to change."""
    rows = _too_few(snaps, usable)
    if len(rows):
        rows["kept_out"] = rows["run"].isin(list(kept_out))
        raise ThinLibraryError(rows, sensor_range_m)


def _too_few(snaps: snapshots.Snapshots, usable: list[Array]) -> pd.DataFrame:
    """The runs with fewer than MIN_TRAIN usable training or MIN_VALIDATION validation scenarios: their counts."""
    rows = []
    first = snaps.design == "hypercube"
    for r, run in enumerate(snaps.runs):
        train, validation = ((snaps.split == split) & snaps.solved[r] for split in ("train", "validation"))
        n_train, n_validation = int((usable[r] & train).sum()), int((usable[r] & validation).sum())
        if n_train >= MIN_TRAIN and n_validation >= MIN_VALIDATION:
            continue
        fitting = train | validation
        rows.append({"run": run, "rpm": snaps.rpm[r], "eccentric_mass_g": snaps.eccentric_mass_g[r],
                     "usable_train": n_train, "train": int(train.sum()), "usable_validation": n_validation,
                     "validation": int(validation.sum()),
                     "beyond_range": int((fitting & snaps.steady[r] & ~usable[r]).sum()),
                     "unstable": int((fitting & snaps.success[r] & ~snaps.stable[r]).sum()),
                     "failed": int((fitting & ~snaps.success[r]).sum()),
                     "observable_share": float(usable[r][first].mean())})
    return pd.DataFrame(rows, columns=["run", "rpm", "eccentric_mass_g", "usable_train", "train",
                                       "usable_validation", "validation", "beyond_range", "unstable", "failed",
                                       "observable_share"])


def load_pod(path: str, run: str) -> tuple[POD, Array]:
    """One run's POD basis and its usable-scenario mask (the store verified against its manifest first)."""
    group = open_verified(path, "POD store")
    if run not in group:
        raise KeyError(f"run {run!r} is not in the POD store {path}")
    group = group[run]
    return POD(group["modes"][:], group["singular_values"][:], group.attrs["energy_tolerance"]), group["usable"][:]
