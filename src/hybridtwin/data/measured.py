"""A run's measured sensor harmonics as the identification reads them (results/data/harmonics.tsv).

One channel per sensor of the machine, in its order (``Machine.sensors``) (x, y on the VARM): ``RunData.X`` and
``RunData.sigma`` are (H, C), ``RunData.channels`` the channels' names; the table's columns are
``preprocessing.run_row``'s (``harmonic_column``), its channels ``preprocessing.table_channels``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .measurements import trial_angles
from .preprocessing import harmonic_column, origin_share, table_channels
from .record_columns import highest_harmonic
from .slow_roll import RUNOUT_HARMONICS, runout_sigma_column
from ..model.sensor import DEFAULT_CHANNELS
from ..tables import HARMONICS, HARMONICS_FLAGS, flags  # noqa: F401 (re-exported: read one way everywhere)

Array = np.ndarray

#: the VARM's channels (a run's own: ``RunData.channels``)
CHANNELS = DEFAULT_CHANNELS  # the VARM's


@dataclass(frozen=True)
class RunData:
    """One run's measured sensor harmonics h = 1..H (DC excluded) and their uncertainties.

    X: (H, C) complex [m], one column per channel (``channels``: x, y on the VARM); sigma: (H, C) [m],
    standard uncertainty of each of the real and imaginary parts (measured, from the synchronous analysis).
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
    channels: tuple[str, ...] = CHANNELS  # the sensors' names, one per column of X
    # the harmonics from which a slow-roll runout was subtracted (a transient record's band): the model is then
    # compensated alike (forward.SolverModel's slow_roll_harmonics); () for a steady run
    slow_roll_harmonics: tuple[int, ...] = ()
    # the speed [RPM] a coast-down's band is reached from (its record's nominal start): the model follows the
    # run-down branch from there (forward.SolverModel's sweep_from_rpm); None for a steady run or a run-up's band
    sweep_from_rpm: float | None = None
    # the trial mass's angle [deg] at the keyphasor mark, from +x towards +y (the sheet's eccentric_mass_angle_deg)
    eccentric_mass_angle_deg: float = 0.0
    # a transient band's record (the sheet's run, its ``parent_run``) and the sigma [m] (H, C) of the record's
    # slow-roll runout estimate that the band's sigma holds in quadrature (0 where none was subtracted): an error
    # common to all of the record's bands, which the identification fits as one offset per record (arrow_problem's
    # "runout offsets"); None for a steady run or a table written before these columns
    record: str | None = None
    runout_sigma: Array | None = None
    # a transient band's sweep rate [RPM/s, signed] where its record is fitted with the swept forward model
    # (the bands' sweep_model "first_order": forward.SolverModel's sweep_rpm_s); 0 for a steady run or a band fitted
    # quasi-steadily
    sweep_rpm_s: float = 0.0

    @property
    def H(self) -> int:
        return self.X.shape[0]


def write_harmonics(table: pd.DataFrame, path: str | Path) -> None:
    """A harmonics table (the preprocessing's per-run table, a record's bands, results/data/harmonics.tsv) as TSV
    with enough digits for metres: ``read_harmonics`` reads it back."""
    HARMONICS.write(table, path)


def read_harmonics(path: str | Path) -> pd.DataFrame:
    """A harmonics table written by ``write_harmonics`` (results/data/harmonics.tsv): run ids as strings, the
    true/false columns (``HARMONICS_FLAGS``) as bool, the rest as pandas reads it."""
    return HARMONICS.read(path)


def kept_out(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of the runs the data checks kept out of the fit (results/data/harmonics.tsv's usable false)."""
    return table.loc[~flags(table["usable"])].reset_index(drop=True)


def table_harmonics(table: pd.DataFrame) -> int:
    """Highest harmonic H present in a harmonics table for every channel (columns x1_re_m, ... on the VARM)."""
    channels = table_channels(table)
    if not channels:
        raise ValueError("the harmonics table has no channels (columns noise_<sensor>_m, offset_<sensor>_m and "
                         "x1_re_m, ...; not results/data/harmonics.tsv?)")
    h = highest_harmonic(table, channels)
    if h == 0:
        raise ValueError(f"the harmonics table has no {harmonic_column(channels[0], 1, 're')} column (not "
                         "results/data/harmonics.tsv?)")
    return h


def run_data(table: pd.DataFrame, run: str, harmonics: int | None = None, keyphasor: bool = True,
             channels: Sequence[str] | None = None) -> RunData:
    """The measured harmonics of ``run`` from the preprocessed table (h = 1..H, SI).

    With ``keyphasor`` (the default), a run whose phases were referred to its keyphasor mark
    (``phase_reference`` "keyphasor") has absolute phases: phase_sigma = Omega sigma_t, and sigma is
    the noise's alone (the origin's share, ``preprocessing.origin_share``, taken out of the table's).
    The channels are the table's (``preprocessing.table_channels``: every sensor of the machine); with
    ``channels`` (the model's sensors, ``sensor.sensor_names``), taken by name in that order, and a table whose
    channels are others is a ValueError naming both: a fit never compares one probe with another's model.
    """
    rows = table[table["run"] == run]
    if len(rows) != 1:
        raise ValueError(f"the harmonics table has {len(rows)} rows for run {run!r} (expected 1)")
    row = rows.iloc[0]
    H = table_harmonics(table) if harmonics is None else min(harmonics, table_harmonics(table))
    found = table_channels(table)
    if channels is None:
        channels = found
    elif sorted(channels) != sorted(found):
        raise ValueError(f"the harmonics table's channels are {', '.join(found)}, the model's sensors "
                         f"{', '.join(channels)}: the records and the machine in the config disagree")
    channels = tuple(channels)
    X = np.array([[row[harmonic_column(c, h, "re")] + 1j * row[harmonic_column(c, h, "im")] for c in channels]
                  for h in range(1, H + 1)])
    sigma = np.array([[row[harmonic_column(c, h, "sigma")] for c in channels] for h in range(1, H + 1)], float)
    rpm = float(row.get("rpm_true", row["rpm"]))
    phase_sigma = math.inf
    if keyphasor and str(row.get("phase_reference", "arbitrary")) == "keyphasor":
        omega, sigma_t = rpm * math.pi / 30.0, float(row["phase_origin_sigma_s"])
        share = origin_share(np.vstack([np.zeros((1, len(channels))), X]).T, omega, sigma_t).T[1:]  # (H, C)
        sigma = np.sqrt(np.maximum(sigma**2 - share**2, (1e-3 * sigma) ** 2))
        phase_sigma = max(omega * sigma_t, 1e-9)
    usable = bool(row.get("usable", True)) and np.isfinite(X).all() and np.isfinite(sigma).all()
    compensated = str(row.get("slowroll_compensated", False)).strip().lower() in ("true", "1")
    down = str(row.get("kind", "")).strip().lower() == "coastdown"
    record, runout = None, None
    columns = [[runout_sigma_column(c, h) for c in channels] for h in range(1, H + 1)]
    parent = str(row.get("parent_run", "") if pd.notna(row.get("parent_run", "")) else "").strip()
    if compensated and parent and any(name in table for part in columns for name in part):
        runout = np.array([[float(row.get(name, 0.0)) for name in part] for part in columns])
        runout = np.where(np.isfinite(runout) & (runout > 0), runout, 0.0)
        record = parent if runout.any() else None
        runout = runout if runout.any() else None
    return RunData(str(run), rpm, float(row["eccentric_mass_g"]), str(row.get("role", "fit")), X, sigma, usable,
                   str(row.get("note", "ok")), phase_sigma, channels, RUNOUT_HARMONICS if compensated else (),
                   float(row["rpm_start"]) if down else None, float(trial_angles(rows)[0]), record, runout,
                   band_sweep_rate(row) if parent else 0.0)


def band_sweep_rate(row: pd.Series) -> float:
    """A band's sweep rate [RPM/s] for the forward model: its measured rate (``sweep_rpm_per_s``) where its record
    is fitted with the swept model (``sweep_model`` "first_order", ``run_kinds.SWEEP_MODELS``), else 0 (the steady
    state: a band of a table written before the swept model, or of a record fitted quasi-steadily)."""
    rate = pd.to_numeric(row.get("sweep_rpm_per_s", math.nan), errors="coerce")
    swept = str(row.get("sweep_model", "")).strip().lower() == "first_order"
    return float(rate) if swept and np.isfinite(rate) else 0.0


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


