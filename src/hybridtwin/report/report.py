"""Comparing model and measurements: where a variant fails (the "report" stage).

Everything here starts from the identification outputs of a variant: the joint
fit (``identification/fit.zarr``, ``parameters.tsv``, ``identification/summary.yaml``),
the per-run fits (``identification/per_run.tsv``) and the validation runs, which
are predicted with the joint estimates, never fitted (``validation.tsv``, their
harmonics in ``validation_harmonics.tsv``: the report does not predict again). The
figures and tables show, per run and over runs, how far the model is from the
measurements in units of the measurement noise, and whether a constant of the
model has to change from run to run to fit (``hybridtwin.report.drift``). The
tables and their statistics are here; the figures drawn from them are ``hybridtwin.report.report_plots``'.

Conventions (stated once):

- Model frame. Without a keyphasor each record has an arbitrary time origin,
  estimated as the run's phase phi (``parameters.tsv``, parameter ``phase``):
  record = exp(i h phi) model for harmonic h. The measured harmonics are
  rotated back, X_h exp(-i h phi), so that measured and model phases compare
  and t = 0 is when the unbalance points to +x (README conventions).
- Whirl. z(t) = x(t) + i y(t) = sum_h F_h exp(i h Omega t) + B_h exp(-i h Omega t)
  with F_h = (X_h + i Y_h) / 2 (forward, turning with the shaft) and
  B_h = conj(X_h - i Y_h) / 2 (backward); a harmonic's noise alone has an
  RMS magnitude sqrt((s_x^2 + s_y^2) / 2) in each (``whirl_noise``).
- Normalised error chi^2 / dof, with chi^2 = sum |X - M|^2 / s^2 over h = 1..H
  and the C channels (the residuals of the fit, each real and imaginary part
  weighted by its standard uncertainty s): 1 is the noise floor. A fit run's
  dof is its share of the joint fit's, 2 C H dof / n_data, so the runs' chi^2
  and dof add up to the joint fit's; a validation run has 2 C H - 1 (only its
  phase aligned). ``p_value``: the probability of a chi^2 at least as large if
  the model were right and the sigmas correct; below ``ALPHA`` the run is
  "beyond noise".
- Relative error: ||X - M|| / ||X|| over h = 1..H and all channels, the
  relative L2 error of the signals' periodic part (Parseval).
- Drift of a constant: ``hybridtwin.report.drift`` (the per-run estimates tested for one common value
  and for a trend along speed, at ``ALPHA``).
- BIC = chi^2 + k ln n, n = n_data real residuals, k = n_data - dof the
  fitted entries (shared and per-run parameters and phases not held at a
  bound).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables
from ..identify import identification as idn
from ..data.measurements import trial_angles
from ..identify import validation as val
from ..identify.uncertainty import ALPHA  # the false-alarm rate of one test (a run beyond noise, a drifting parameter)

Array = np.ndarray

#: chi^2 / dof of a model that explains the data to within the noise
NOISE_FLOOR = 1.0
#: columns of ``error_table`` (errors.tsv, validation_errors.tsv): the table layer's
ERROR_COLUMNS = list(tables.ERRORS.columns)


# --- one run: measured and model harmonics ---------------------------------------------


@dataclass(frozen=True)
class RunComparison:
    """A run's measured and model harmonics h = 1..H in the model's frame (module docstring).

    measured, model: (H, C) complex [m], one column per channel (``channels``, the
    sensors: x, y on the VARM); sigma: (H, C) [m], standard uncertainty of each real
    and imaginary part (the weights of the fit); dof: the run's degrees of freedom;
    role: ``fit`` or ``validate``; source: the response model (``solver`` or
    ``library``). The run's figure (``plot_run``) draws each consecutive pair of
    channels as an orbit: a plane's x, y probes when the machine declares them so.
    """

    run: str
    role: str
    rpm: float
    eccentric_mass_g: float
    measured: Array
    model: Array
    sigma: Array
    dof: float
    source: str
    channels: tuple[str, ...] = idn.CHANNELS
    eccentric_mass_angle_deg: float = 0.0  # the trial mass's angle (the runs sheet's; 0: on +x at the mark)

    @property
    def H(self) -> int:
        return self.measured.shape[0]

    def select(self, channels: Sequence[str]) -> "RunComparison":
        """The run with only ``channels``, in that order, taken by name; a name it lacks is a ValueError."""
        missing = [name for name in channels if name not in self.channels]
        if missing:
            raise ValueError(f"run {self.run}: channel(s) {', '.join(missing)} not among its channels "
                             f"{', '.join(self.channels)}")
        cols = [self.channels.index(name) for name in channels]
        return replace(self, measured=self.measured[:, cols], model=self.model[:, cols], sigma=self.sigma[:, cols],
                       channels=tuple(channels))

    @property
    def residual(self) -> Array:
        return self.measured - self.model

    @property
    def chi2(self) -> float:
        return float((np.abs(self.residual / self.sigma) ** 2).sum())

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof

    @property
    def signal_m(self) -> float:
        """||X|| over h = 1..H and every channel [m]."""
        return float(np.linalg.norm(self.measured))

    @property
    def error_rel(self) -> float:
        return float(np.linalg.norm(self.residual)) / self.signal_m


def to_model_frame(X: Array, phase_rad: float) -> Array:
    """Harmonics (H, ...) in a record's frame rotated to the model's: X_h exp(-i h phi)."""
    h = np.arange(1, X.shape[0] + 1).reshape((-1,) + (1,) * (X.ndim - 1))
    return X * np.exp(-1j * h * phase_rad)


def fit_comparisons(fit_path: str | Path, parameters: pd.DataFrame, summary: Mapping,
                    harmonics: pd.DataFrame) -> list[RunComparison]:
    """The fit runs of a joint fit (``run_fits.write_fit``'s store), in the model's frame.

    parameters: the joint table (parameters.tsv, for the phases and the source);
    summary: the final block of summary.yaml (n_data, dof); harmonics: the
    preprocessed table (for the eccentric masses).
    """
    from ..offline.stores import open_verified

    group = open_verified(fit_path, "fit store")
    measured = group["measured_re_m"][:] + 1j * group["measured_im_m"][:]
    model = group["fitted_re_m"][:] + 1j * group["fitted_im_m"][:]
    sigma = group["sigma_m"][:]
    phases = parameters[parameters["parameter"] == "phase"].set_index("run")["value"]
    masses = harmonics.set_index("run")["eccentric_mass_g"]
    angles = pd.Series(trial_angles(harmonics), index=harmonics["run"])
    source = str(parameters["source"].iloc[0])
    channels = tuple(group.attrs.get("channels", idn.CHANNELS))
    dof = 2 * measured.shape[2] * measured.shape[1] * summary["dof"] / summary["n_data"]  # a run's share
    return [RunComparison(run, "fit", float(rpm), float(masses[run]), to_model_frame(measured[k], phases[run]),
                          to_model_frame(model[k], phases[run]), sigma[k], dof, source, channels,
                          float(angles[run]))
            for k, (run, rpm) in enumerate(zip(group.attrs["runs"], group.attrs["rpm"]))]


def validation_comparison(prediction: val.PredictedRun, data: idn.RunData, model_error: float) -> RunComparison:
    """A validation run as the predict_validation rule predicted it (``validation.PredictedRun``, read from
    validation_harmonics.tsv: joint values, only the phase aligned), in the model's frame."""
    H = prediction.harmonics.shape[0]
    phase = prediction.phase_rad
    return RunComparison(data.run, "validate", data.rpm, data.eccentric_mass_g, to_model_frame(data.X[:H], phase),
                         to_model_frame(prediction.harmonics, phase), idn.total_sigma(data, model_error)[:H],
                         2 * prediction.harmonics.size - 1, prediction.model, tuple(data.channels),
                         float(data.eccentric_mass_angle_deg))


def comparison_table(comparisons: Sequence[RunComparison]) -> pd.DataFrame:
    """Long table, one row per run, harmonic and channel (results/{variant}/report/harmonics.tsv)."""
    rows = []
    for c in comparisons:
        for h in range(c.H):
            for j, channel in enumerate(c.channels):
                rows.append({"run": c.run, "role": c.role, "rpm": c.rpm, "eccentric_mass_g": c.eccentric_mass_g,
                             "eccentric_mass_angle_deg": c.eccentric_mass_angle_deg, "source": c.source, "dof": c.dof, "harmonic": h + 1, "channel": channel,
                             "measured_re_m": c.measured[h, j].real, "measured_im_m": c.measured[h, j].imag,
                             "model_re_m": c.model[h, j].real, "model_im_m": c.model[h, j].imag,
                             "sigma_m": c.sigma[h, j]})
    return pd.DataFrame(rows)


def read_comparisons(table: pd.DataFrame) -> list[RunComparison]:
    """``comparison_table``'s rows back to RunComparison (runs in the table's order; a table without
    eccentric_mass_angle_deg, written before trial angles were, reads as angle 0)."""
    out = []
    for run, rows in table.groupby("run", sort=False):
        channels, rows = val.channel_order(rows)  # the table's order: the sensors'
        first = rows.iloc[0]
        C = len(channels)
        out.append(RunComparison(str(run), str(first["role"]), float(first["rpm"]),
                                 float(first["eccentric_mass_g"]),
                                 _grid(rows, "measured_re_m", C) + 1j * _grid(rows, "measured_im_m", C),
                                 _grid(rows, "model_re_m", C) + 1j * _grid(rows, "model_im_m", C),
                                 _grid(rows, "sigma_m", C), float(first["dof"]), str(first["source"]), channels,
                                 float(first.get("eccentric_mass_angle_deg", 0.0))))
    return out


def write_comparisons(comparisons: Sequence[RunComparison], path: str | Path) -> None:
    """The comparison table (results/{variant}/report/harmonics.tsv, ``comparison_table``): ``load_comparisons``
    reads it back."""
    tables.COMPARISONS.write(comparison_table(comparisons), path)


def load_comparisons(path: str | Path) -> list[RunComparison]:
    """The comparisons of a table written by ``write_comparisons``, run ids as strings."""
    return read_comparisons(tables.COMPARISONS.read(path))


def _grid(rows: pd.DataFrame, column: str, channels: int) -> Array:
    """A column of one run's rows (sorted by harmonic, channel) as (H, C)."""
    return rows[column].to_numpy(float).reshape(-1, channels)


# --- errors per run ---------------------------------------------------------------------


def error_table(comparisons: Sequence[RunComparison]) -> pd.DataFrame:
    """Per-run errors: run, rpm, eccentric_mass_g, role, source, chi2, dof, chi2_dof, p_value, beyond_noise,
    error_pct (relative error, %), signal_m (||X||, to pool relative errors); module docstring."""
    rows = []
    for c in comparisons:
        p = float(stats.chi2.sf(c.chi2, c.dof))
        rows.append({"run": c.run, "rpm": c.rpm, "eccentric_mass_g": c.eccentric_mass_g, "role": c.role,
                     "source": c.source, "chi2": c.chi2, "dof": c.dof, "chi2_dof": c.chi2_dof, "p_value": p,
                     "beyond_noise": p < ALPHA, "error_pct": 100.0 * c.error_rel, "signal_m": c.signal_m})
    return pd.DataFrame(rows, columns=ERROR_COLUMNS)


def write_errors(table: pd.DataFrame, path: str | Path) -> None:
    """An error table (``error_table``: report/errors.tsv, report/validation_errors.tsv): ``read_errors`` reads it."""
    tables.ERRORS.write(table, path)


def read_errors(path: str | Path) -> pd.DataFrame:
    """An error table written by ``write_errors``: run ids and roles as text, beyond_noise as bool (one way:
    ``measured.flags``), the rest as numbers."""
    return tables.ERRORS.read(path)


def pooled(errors: pd.DataFrame) -> dict[str, float]:
    """chi^2 / dof and relative error (%) of several runs taken together (sum chi^2 / sum dof, ||X - M|| / ||X||)."""
    if errors.empty:
        return {"chi2_dof": math.nan, "error_pct": math.nan}
    residual = (errors["error_pct"] * errors["signal_m"]) ** 2
    return {"chi2_dof": float(errors["chi2"].sum() / errors["dof"].sum()),
            "error_pct": float(np.sqrt(residual.sum() / (errors["signal_m"] ** 2).sum()))}


# --- spectra and waveforms --------------------------------------------------------------


def whirl(Z: Array) -> tuple[Array, Array]:
    """Forward and backward components (H,) of z = x + i y from harmonics Z (H, 2) [m] (module docstring)."""
    x, y = Z[:, 0], Z[:, 1]
    return 0.5 * (x + 1j * y), 0.5 * np.conj(x - 1j * y)


def whirl_noise(sigma: Array) -> Array:
    """RMS magnitude (H,) of a forward or backward component made of noise alone, sqrt((s_x^2 + s_y^2) / 2)."""
    return np.sqrt(0.5 * (sigma[:, 0] ** 2 + sigma[:, 1] ** 2))


def waveform(Z: Array, revolutions: float = 2.0, n_time: int = 240) -> tuple[Array, Array]:
    """x, y over ``revolutions`` from harmonics Z (H, 2): angle Omega t (T,) [rad] and signals (T, 2) [m]."""
    angle = np.linspace(0.0, 2 * np.pi * revolutions, n_time)
    wave = np.exp(1j * np.outer(angle, np.arange(1, Z.shape[0] + 1)))
    return angle, (wave @ Z).real


def waveform_noise(sigma: Array) -> Array:
    """Standard deviation (2,) of x(t), y(t) rebuilt from harmonics with independent noise: sqrt(sum_h s_h^2)."""
    return np.sqrt((sigma**2).sum(0))


# --- the ledger -------------------------------------------------------------------------


def bic(chi2: float, n_data: int, dof: int) -> float:
    """Bayesian information criterion chi^2 + k ln n, k = n_data - dof fitted entries (module docstring)."""
    return float(chi2 + (n_data - dof) * math.log(n_data))


#: the ledger's columns (results/ledger.tsv; workflow/report/ledger.rst), then chi2_dof_{run} per run
LEDGER_COLUMNS = list(tables.LEDGER_COLUMNS)


def ledger_row(variant: str, description: str, summary: Mapping, errors: pd.DataFrame) -> dict:
    """One variant's ledger row (``LEDGER_COLUMNS`` but delta_bic, then ``chi2_dof_{run}`` per run).

    summary: the final block of summary.yaml (n_data, dof, chi2); errors: the
    variant's ``error_table`` (fit and validation runs).
    """
    fit, validate = errors[errors["role"] == "fit"], errors[errors["role"] == "validate"]
    n, dof, chi2 = int(summary["n_data"]), int(summary["dof"]), float(summary["chi2"])
    row = {"variant": variant, "description": description, "source": _source(errors), "n_data": n,
           "k": n - dof, "dof": dof, "chi2": chi2, "chi2_dof": chi2 / dof,
           "excess_over_noise_pct": 100.0 * (chi2 / dof / NOISE_FLOOR - 1.0), "bic": bic(chi2, n, dof),
           "error_pct": pooled(fit)["error_pct"], "run_chi2_dof_median": float(fit["chi2_dof"].median()),
           "run_chi2_dof_max": float(fit["chi2_dof"].max()), "worst_run": _worst(fit),
           "runs_beyond_noise": int(fit["beyond_noise"].sum()),
           "validation_chi2_dof": pooled(validate)["chi2_dof"], "validation_error_pct": pooled(validate)["error_pct"],
           "worst_validation_run": _worst(validate)}
    return row | {f"chi2_dof_{r.run}": r.chi2_dof for r in errors.itertuples()}


def _source(errors: pd.DataFrame) -> str:
    return ",".join(dict.fromkeys(errors["source"].astype(str))) if len(errors) else ""


def _worst(errors: pd.DataFrame) -> str:
    return str(errors.loc[errors["chi2_dof"].idxmax(), "run"]) if len(errors) else ""


def ledger_table(rows: Sequence[Mapping]) -> pd.DataFrame:
    """The ledger (results/ledger.tsv), variants in the given (config) order, delta_bic to the lowest BIC."""
    table = pd.DataFrame(list(rows))
    table["delta_bic"] = table["bic"] - table["bic"].min()
    per_run = [c for c in table if c not in LEDGER_COLUMNS]
    return table[LEDGER_COLUMNS + per_run]


def write_ledger(ledger: pd.DataFrame, path: str | Path) -> None:
    """The ledger (``ledger_table``, results/ledger.tsv): ``read_ledger`` reads it back."""
    tables.LEDGER.write(ledger, path)


def read_ledger(path: str | Path) -> pd.DataFrame:
    """The ledger written by ``write_ledger``: variant names, descriptions and run ids as text, the rest as
    numbers."""
    return tables.LEDGER.read(path)
