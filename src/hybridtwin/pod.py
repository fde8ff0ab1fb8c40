"""Proper orthogonal decomposition of the snapshots (paper eq. 4-5).

A snapshot is one scenario's steady state: the complex harmonics Q_h
(h = 0..H) of all DOFs, stored as real features [Re Q, Im Q] (2 (H+1) n).
The snapshot matrix S (features x scenarios) is decomposed by the SVD
S = Phi Sigma W^T (eq. 4) and truncated to the m_d modes that hold a fraction
1 - epsilon of the energy sum sigma_i^2 (eq. 5); a scenario is then
q = Phi alpha with alpha = Phi^T q its reduced coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import zarr

from . import snapshots
from .effect_base import Array
from .sensor import observable
from .shaft import Shaft
from .stores import open_verified, write_manifest


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
                energy_tolerance: float) -> pd.DataFrame:
    """POD per run of the observable (converged, stable, inside the sensor range) training snapshots.

    Writes a zarr v3 group per run (modes, singular_values, usable mask), the store's
    manifest last (``hybridtwin.stores``), and returns the summary table: training
    snapshots (of which from the enrichment), the observable share of the first design
    (the box's share a rig can measure at that run), failed solves, unstable steady
    states (converged, left out: the machine would not stay on them), m_d and the
    singular value ratios.
    """
    snaps = snapshots.load(snapshots_path)
    store = zarr.open_group(out_path, mode="w")
    rows = []
    first_design, solved = snaps.design == "hypercube", snaps.solved
    for r, run in enumerate(snaps.runs):
        usable = snaps.steady[r] & observable(snaps.harmonics[r], shaft, sensor_range_m)
        train = usable & (snaps.split == "train")
        basis = pod(to_features(snaps.harmonics[r][train]), energy_tolerance)
        group = store.create_group(run)
        group.create_array("modes", data=basis.modes)
        group.create_array("singular_values", data=basis.singular_values)
        group.create_array("usable", data=usable)
        group.attrs["energy_tolerance"] = energy_tolerance
        ratios = np.pad(basis.ratios, (0, 3))
        rows.append({"run": run, "n_snapshots": int(train.sum()), "n_enriched": int((train & ~first_design).sum()),
                     "observable_fraction": float(usable[first_design].mean()),
                     "n_failed": int((~snaps.success[r] & solved[r]).sum()),
                     "n_unstable": int((snaps.success[r] & ~snaps.stable[r]).sum()), "n_modes": basis.n_modes,
                     "sigma2_over_sigma1": ratios[1], "sigma3_over_sigma1": ratios[2],
                     "sigma4_over_sigma1": ratios[3]})
    write_manifest(out_path)
    return pd.DataFrame(rows)


def load_pod(path: str, run: str) -> tuple[POD, Array]:
    """One run's POD basis and its usable-scenario mask (the store verified against its manifest first)."""
    group = open_verified(path, "POD store")
    if run not in group:
        raise KeyError(f"run {run!r} is not in the POD store {path}")
    group = group[run]
    return POD(group["modes"][:], group["singular_values"][:], group.attrs["energy_tolerance"]), group["usable"][:]
