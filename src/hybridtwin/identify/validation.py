"""Validation runs (predicted, never fitted).

A validation run is predicted with the joint fit's shared values and each
per-run parameter (the bow) from its law over the fitted runs (``bow_law``);
only its phase, a nuisance, is aligned. The per-run fits side by side and their
drift with speed (the sign of a missing effect): ``hybridtwin.report.drift``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..data.preprocessing import fit_phase, harmonic_stem
from ..tables import PREDICTIONS
from .arrow_problem import wrap
from .forward import HarmonicModel
from .identification import CHANNELS, RunData, total_sigma

Array = np.ndarray

def bow_law(table: pd.DataFrame, parameter: str, law: str = "law"
            ) -> tuple[Array, Callable[[Array, Array], Array]]:
    """A per-run parameter as a function of speed and unbalance, from its per-run estimates.

    law "law": weighted least squares of q = c0 + c1 Omega^2 + c2 Omega^2 m_e (the
    first-order form of the paper's eq. 35-37: bow grows with speed, and with the
    unbalance when there is one), with the terms the runs can determine only: the
    speed term when their Omega^2 span LAW_SPREAD of its largest, the unbalance
    term when their masses do (fit runs at one speed, or at one mass, made
    the law extrapolate along a direction they never varied: a validation run at
    900 RPM from runs at 600 RPM got twice the fitted bows), and a run more than
    the terms; else (and "mean") the weighted mean. The coefficients of the
    terms not used are 0. Needs rows with rpm, eccentric_mass_g, value, stderr.
    Returns (coefficients c0, c1, c2, predict(rpm, mass_g)).
    """
    coef = law_operator(table, law) @ np.asarray(table["value"], float)

    def predict(rpm: Array, mass_g: Array) -> Array:
        return law_terms(rpm, mass_g) @ coef
    return coef, predict


def law_terms(rpm: Array, mass_g: Array) -> Array:
    """The bow law's terms [1, Omega^2, Omega^2 m_e] at speeds ``rpm`` and masses ``mass_g`` (..., 3)."""
    omega2 = (np.asarray(rpm, float) * 2 * np.pi / 60) ** 2
    return np.stack(np.broadcast_arrays(np.ones_like(omega2), omega2, omega2 * np.asarray(mass_g, float) * 1e-3),
                    axis=-1)


def law_operator(table: pd.DataFrame, law: str = "law") -> Array:
    """The linear map (3, n) from the n runs' values of a per-run parameter to the coefficients c0, c1, c2 of its
    law (``bow_law``): the law is linear in the runs' values, so the coefficients' covariance is this map applied to
    the values' covariance (what ``hybridtwin.online`` uses to carry the twin's uncertainty to a new record)."""
    terms = law_terms(table["rpm"], table["eccentric_mass_g"])  # (n, 3)
    stderr = np.asarray(table["stderr"], float)
    w = 1.0 / np.where(np.isfinite(stderr) & (stderr > 0), stderr, np.nanmax(np.append(stderr, 1.0))) ** 2
    varied = {1: terms[:, 1], 2: np.asarray(table["eccentric_mass_g"], float)}  # the speed term, the unbalance term
    used = [0] + [k for k, values in varied.items() if spans(values, LAW_SPREAD)]
    operator = np.zeros((3, len(w)))
    if law == "law" and len(used) > 1 and len(w) >= max(4, len(used) + 1):
        root = np.sqrt(w)
        operator[used] = np.linalg.pinv(terms[:, used] * root[:, None]) * root[None, :]
    else:
        operator[0] = w / w.sum()
    return operator


#: a bow-law term is fitted when the runs' values of it span at least this fraction of the largest (``bow_law``)
LAW_SPREAD = 0.1


def spans(values: Array, fraction: float) -> bool:
    """Whether the runs' ``values`` (speeds, Omega^2, masses) span at least ``fraction`` of the largest: what a
    law along them (the bow law), a slope (the drift test) or a diagnosis needs; all at one value do not."""
    values = np.asarray(values, float)
    top = float(np.max(np.abs(values), initial=0.0))
    return top > 0 and float(np.ptp(values)) >= fraction * top


def _with_dc(z: Array, fill: float = 0.0) -> Array:
    """(H, C) h = 1..H -> (C, H+1) with an h = 0 column (``fit_phase``'s layout; h = 0 is ignored there)."""
    return np.vstack([np.full((1, z.shape[1]), fill, z.dtype), z]).T


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
    H = min(data.H, model.H)
    x = np.array([2 * (values[p] - lo) / (hi - lo) - 1 for p, lo, hi in zip(model.parameters, model.lower,
                                                                             model.upper)])
    outside = [p for p, v in zip(model.parameters, x) if abs(v) > 1 + 1e-9]
    M = model.evaluate(np.clip(x, -1, 1)[None], jacobian=False)[0][0, :H]  # (H, C)
    X, sigma = data.X[:H], total_sigma(data, model_error)[:H]
    if math.isfinite(data.phase_sigma):
        phi = keyphasor_phase(X, M, sigma, data.phase_sigma)
    else:
        phi = fit_phase(_with_dc(X), _with_dc(M), _with_dc(sigma, fill=1.0))
    aligned = M * np.exp(1j * np.arange(1, H + 1) * phi)[:, None]
    error = np.sqrt((np.abs(X - aligned) ** 2).sum() / (np.abs(X) ** 2).sum())
    residual = (X - aligned) / sigma
    amplitudes = {}
    for j, channel in enumerate(data.channels):  # x1_amp_measured_m, ... (channel x1: x1_1_amp_measured_m)
        stem = f"{harmonic_stem(channel, 1)}_amp"
        amplitudes |= {f"{stem}_measured_m": abs(X[0, j]), f"{stem}_predicted_m": abs(M[0, j])}
    return {"run": data.run, "rpm": data.rpm, "eccentric_mass_g": data.eccentric_mass_g,
            "error_rel": float(error), "chi2_per_residual": float((np.abs(residual) ** 2).sum() / (2 * X.size)),
            "phase_rad": float(wrap(phi)), **amplitudes, "outside_range": ",".join(outside), "fitted": aligned}


#: columns of validation_harmonics.tsv (``write_predictions``): one row per run, model, harmonic and channel
PREDICTION_COLUMNS = list(PREDICTIONS.columns)


@dataclass(frozen=True)
class PredictedRun:
    """A validation run's predicted harmonics h = 1..H as the predict_validation rule computed them.

    model: the response model (``library`` or ``solver``); phase_rad: the run's aligned phase
    (``predict_run``'s, wrapped); harmonics: (H, C) complex [m], one column per channel (``channels``, the
    sensors: x, y on the VARM), in the record's frame (the prediction rotated by the phase, what the
    measurement is scored against).
    """

    run: str
    model: str
    phase_rad: float
    harmonics: Array
    channels: tuple[str, ...] = CHANNELS

    @classmethod
    def from_prediction(cls, row: Mapping, model: str, channels: Sequence[str] = CHANNELS) -> "PredictedRun":
        """From ``predict_run``'s result (its ``fitted`` harmonics and phase); ``channels``: the run's
        (``RunData.channels``)."""
        return cls(str(row["run"]), model, float(row["phase_rad"]), np.asarray(row["fitted"], complex),
                   tuple(channels))


def prediction_table(predictions: Sequence[PredictedRun]) -> pd.DataFrame:
    """Long table of predicted harmonics (``PREDICTION_COLUMNS``; results/{variant}/validation_harmonics.tsv)."""
    rows = []
    for p in predictions:
        for h in range(p.harmonics.shape[0]):
            for j, channel in enumerate(p.channels):
                rows.append({"run": p.run, "model": p.model, "phase_rad": p.phase_rad, "harmonic": h + 1,
                             "channel": channel, "model_re_m": p.harmonics[h, j].real,
                             "model_im_m": p.harmonics[h, j].imag})
    return pd.DataFrame(rows, columns=PREDICTION_COLUMNS)


def write_predictions(path: str | Path, predictions: Sequence[PredictedRun]) -> None:
    """Write the predicted harmonics with 17 significant digits (``read_predictions`` gives them back exactly)."""
    PREDICTIONS.write(prediction_table(predictions), path)


def channel_order(rows: pd.DataFrame) -> tuple[tuple[str, ...], pd.DataFrame]:
    """A long table's channels in the order they first appear (the sensors'), and its rows sorted by harmonic then
    that channel order (a (H, C) grid when reshaped)."""
    channels = tuple(dict.fromkeys(rows["channel"].astype(str)))
    return channels, rows.assign(j=rows["channel"].astype(str).map(channels.index)).sort_values(["harmonic", "j"])


def read_predictions(path: str | Path) -> list[PredictedRun]:
    """``write_predictions``'s file back to PredictedRun (runs and models in the file's order), bit for bit."""
    exact = {c: float for c in ("phase_rad", "model_re_m", "model_im_m")}  # Python's float: round-trip on any pandas
    table = PREDICTIONS.read(path, converters=exact)
    missing = [c for c in PREDICTION_COLUMNS if c not in table]
    if missing:
        raise ValueError(f"{path}: not a validation_harmonics table, columns {missing} missing")
    out = []
    for (run, model), rows in table.groupby(["run", "model"], sort=False):
        H = int(rows["harmonic"].max())
        channels, order = channel_order(rows)
        C = len(channels)
        counts = rows.groupby("harmonic")["channel"].agg(list)
        if (len(rows) != C * H or set(counts.index) != set(range(1, H + 1))
                or any(tuple(v) != channels for v in counts) or rows["phase_rad"].nunique() != 1):
            raise ValueError(f"{path}: run {run} ({model}) needs harmonics 1..{H} on every channel "
                             f"{list(channels)} and one phase")
        harmonics = np.empty((H, C), complex)
        harmonics.real, harmonics.imag = (order[c].to_numpy(float).reshape(H, C) for c in ("model_re_m", "model_im_m"))
        out.append(PredictedRun(str(run), str(model), float(rows["phase_rad"].iloc[0]), harmonics, channels))
    return out


def validation_values(joint: pd.DataFrame, run: RunData, law: str = "law", runs: pd.DataFrame | None = None
                      ) -> dict[str, float]:
    """Parameter values [SI] to predict a validation run with: the shared estimates, and each per-run
    parameter from its law over the fitted runs (``bow_law``); m_e from the sheet when it is per run."""
    return values_at(joint, run.rpm, run.eccentric_mass_g, law, runs)


def values_at(joint: pd.DataFrame, rpm: float, eccentric_mass_g: float, law: str = "law",
              runs: pd.DataFrame | None = None) -> dict[str, float]:
    """``validation_values`` at any speed and eccentric mass: the shared estimates, each per-run parameter from
    its law over the fitted runs (their rpm and mass from ``runs`` when given). For many points (a sweep), build
    the laws once with ``values_along``."""
    return values_along(joint, law, runs)(rpm, eccentric_mass_g)


def values_along(joint: pd.DataFrame, law: str = "law", runs: pd.DataFrame | None = None
                 ) -> Callable[[float, float], dict[str, float]]:
    """``values_at`` as a function of (rpm, eccentric_mass_g), each per-run parameter's law (``bow_law``) fitted
    once."""
    physical = joint[joint["kind"] != "nuisance"]
    shared = {r.parameter: float(r.value) for r in physical.itertuples() if r.run == "all"}
    local = physical[physical["run"] != "all"]
    if runs is not None and len(local):
        local = local.drop(columns=[c for c in ("rpm", "eccentric_mass_g") if c in local]).merge(
            runs[["run", "rpm", "eccentric_mass_g"]], on="run", how="left")
    laws = {p: bow_law(group, p, law)[1] for p, group in local.groupby("parameter", sort=False)}

    def at(rpm: float, eccentric_mass_g: float) -> dict[str, float]:
        values = dict(shared)
        for p, predict in laws.items():
            values[p] = eccentric_mass_g * 1e-3 if p == "m_e" and np.isfinite(eccentric_mass_g) else \
                float(predict(rpm, eccentric_mass_g))
        return values
    return at
