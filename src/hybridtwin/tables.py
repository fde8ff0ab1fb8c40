"""The tables between the workflow's rules, declared once: each its file, columns, text columns, layout and float
format, written by one writer and read by its inverse (issue 52).

A table is a ``Table``: ``write`` writes a frame as tab-separated text (the project's one separator for tables,
``SEP``) with the table's float format, ``read`` reads such a file back with the table's text columns as text, so
that writing what was read gives the same bytes again (tests/test_contracts.py checks this for every table of
``TABLES``). A table whose columns are fixed declares them, and its writer refuses a frame with other columns; a
table whose columns follow the data (a parameter per column, a channel per harmonic) says so in its ``layout``.

The harmonics of a run at its channels are one quantity in three layouts across the workflow; the long form,
(run, harmonic, channel, re_m, im_m, sigma_m) a row, is ``HARMONICS_LONG``: ``run_harmonics`` makes it from a
run's harmonics, ``wide_harmonics`` is its wide view, the harmonic columns of results/data/harmonics.tsv (a run a
row, a column per channel, harmonic and part, named by ``harmonic_column``; the preprocessing writes them through
the long form and this view), and ``long_harmonics`` the long form again from a wide table.

The module sits below every stage (it imports none): the stages declare their tables here and write them here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

#: the separator of every table between rules (tab-separated values)
SEP = "\t"

#: the float formats in use, from the fewest digits to every digit: a table's format is one of these
SHORT = "%.6g"  # figures for people: the ledger, summaries, statistics
FIT = "%.9g"  # fit results: estimates, starts, histories
REFIT = "%.12g"  # tables a later fit starts from (refits, intervals, scenarios)
METRES = "%.9e"  # measured and solved displacements [m]: 10 significant digits at any magnitude
SHEET = "%.10g"  # the runs sheet the rig writes
EXACT = "%.17g"  # every bit of a double (predictions, responses other rules compute from)


def shortest_repr(value: float) -> str:
    """A float as its shortest exact repr (``0.0``, ``1e-05``: a float stays a float, to the last bit)."""
    return repr(float(value))


FORMATS = (None, SHORT, FIT, REFIT, METRES, SHEET, EXACT, shortest_repr)


#: the cells a number column reads as NaN when text cells are kept as written (``Table.na_text``)
NA_CELLS = ("", "nan", "NaN", "NA")


def flags(column: pd.Series) -> pd.Series:
    """A true/false column as written (True/False, true/false, 1/0, in any case; empty or NaN: false) as bool."""
    return column.map(lambda v: str(v).strip().lower() in ("true", "1", "1.0")).astype(bool)


class TableError(ValueError):
    """A frame that is not the table it is written as (its columns differ from the declared ones)."""


@dataclass(frozen=True)
class Table:
    """One table between rules: ``name`` its file (under results/, {variant} and {run} its wildcards), ``columns``
    its columns in order (None: they follow the data, see ``layout``), ``text`` the columns read as text (the
    others as numbers or, where they hold True/False, booleans), ``float_format`` its floats' format (None: pandas'
    shortest repr), ``index`` whether the first column is the frame's index (a matrix), ``layout`` one line on its
    rows and columns; ``na_text``: the text columns' cells kept as written (an empty one "", not NaN), ``flags``:
    the columns of True/False read as bool."""

    name: str
    columns: tuple[str, ...] | None
    float_format: str | None
    layout: str
    text: tuple[str, ...] = ()
    index: bool = False
    na_text: bool = False  # text cells as written ("", "NA", "None" stay text); a number's NaN is NA_CELLS
    flags: tuple[str, ...] = ()  # true/false columns, read as bool (``flags``)
    floats: tuple[str, ...] | None = ()  # number columns read as float also when all empty (None: every other one)
    extra: Mapping = field(default_factory=dict)  # further to_csv keywords (a line terminator)

    def __post_init__(self):
        if self.float_format not in FORMATS:
            raise TableError(f"{self.name}: float format {self.float_format!r} is none of {FORMATS}")

    def check(self, frame: pd.DataFrame) -> None:
        """Raise ``TableError`` when the table declares its columns and ``frame`` has others."""
        if self.columns is not None and list(frame.columns) != list(self.columns):
            raise TableError(f"{self.name}: columns {list(frame.columns)}, declared {list(self.columns)}")

    def write(self, frame: pd.DataFrame, path: str | Path) -> None:
        """``frame`` as this table at ``path`` (its folder made)."""
        self.check(frame)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, sep=SEP, index=self.index, float_format=self.float_format, **self.extra)

    def read(self, path: str | Path, **options) -> pd.DataFrame:
        """The table at ``path`` as written by ``write``: text columns as text, the first column as the index of
        a matrix. ``options``: further ``pandas.read_csv`` keywords (converters, an engine)."""
        header = pd.read_csv(path, sep=SEP, nrows=0).columns
        text = {c: str for c in header if c in self.text}
        if self.na_text:
            options = {"keep_default_na": False, "na_values": {c: list(NA_CELLS) for c in header
                                                               if c not in text and c not in self.flags}} | options
        table = pd.read_csv(path, sep=SEP, dtype=text or None, index_col=0 if self.index else None, **options)
        for column in [c for c in table.columns if c in self.flags]:
            table[column] = flags(table[column])
        numbers = [c for c in table.columns if c not in text and c not in self.flags] if self.floats is None else [
            c for c in self.floats if c in table.columns and c not in text]
        for column in numbers:
            table[column] = table[column].astype(float)
        return table


def write(table: Table, frame: pd.DataFrame, path: str | Path) -> None:
    """Write ``frame`` as ``table`` (``Table.write``)."""
    table.write(frame, path)


def read(table: Table, path: str | Path, **options) -> pd.DataFrame:
    """Read ``table`` at ``path`` (``Table.read``)."""
    return table.read(path, **options)


# --- the offline library ------------------------------------------------------------------------------------

FAILURES = Table("{variant}/failures.tsv", ("run", "scenario", "split", "message", "reason"), None,
                 "a (run, scenario) without a steady state a row: reason FAILED or UNSTABLE, the solver's message",
                 text=("run", "split", "message", "reason"))
FAILURE_SUMMARY = Table("{variant}/failures_summary.tsv", ("run", "split", "reason", "n_scenarios", "first_scenario",
                                                             "first_message"), None,
                        "the failures counted, a (run, split, reason) a row: how many scenarios, the first of them "
                        "and its message (the report's view of failures.tsv: ``snapshots.failure_summary``)",
                        text=("run", "split", "reason", "first_message"))
ENRICHMENT_SUMMARY = Table("{variant}/enrichment_summary.tsv", None, None,
                           "a run the enrichment sampled more scenarios for a row (offline.sample_enrichment's "
                           "summary)", text=("run",))
SCENARIOS = Table("{variant}/scenarios.tsv", None, REFIT,
                  "a scenario a row: scenario, split (train or validate), one column per unknown (the values the "
                  "chunks solve)", text=("split",))
ENRICHMENT_SCENARIOS = Table("{variant}/enrichment.tsv", None, None,
                             "an enrichment scenario a row: scenario, split, eccentric_mass_g, one column per unknown "
                             "(every digit)", text=("split",))
LIBRARY_VALIDATION = Table("{variant}/library_validation.tsv", None, SHORT,
                           "a run a row: its library's errors against the full solver on held-out scenarios",
                           text=("run",))
POD = Table("{variant}/pod.tsv", None, SHORT, "a run a row: the POD's modes and its energy captured")
WHITEBOX = Table("{variant}/whitebox/sweep.tsv", None, METRES,
                 "a run of the white-box sweep a row: the solver's sensor harmonics, a column per channel and part",
                 text=("run", "message"))

# --- the identification -----------------------------------------------------------------------------------

#: a parameter table's columns (``identification.Identification.table``), in order
PARAMETER_COLUMNS = ("parameter", "run", "kind", "unit", "value", "normalised", "stderr", "ci_low", "ci_high",
                     "interval", "loose", "at_bound", "identifiable", "lower", "upper", "mc_mean", "mc_std",
                     "mc_ci_low", "mc_ci_high", "mc_note", "vif", "source")
#: its true/false columns (read as pandas reads True/False) and its text ones (with the columns other tables of
#: parameters add: a per-run fit's note, a refit's effect or validation run)
PARAMETER_FLAGS = ("at_bound", "identifiable")
PARAMETER_TEXT = ("parameter", "run", "kind", "unit", "interval", "loose", "mc_note", "source", "note", "effect",
                  "validation_run")
PARAMETERS = Table("{variant}/parameters.tsv", None, FIT,
                   "an entry of the fit (a parameter; per run: one per run; a phase) a row, ``PARAMETER_COLUMNS`` "
                   "(SI); also library_parameters.tsv, runs/{run}/parameters.tsv (with a note), the drift table "
                   "(identification/per_run.tsv), validation_refits.tsv (validation_run first)",
                   text=PARAMETER_TEXT, na_text=True,
                   floats=tuple(c for c in PARAMETER_COLUMNS if c not in PARAMETER_TEXT + PARAMETER_FLAGS))

#: validation.tsv's columns about why a run is predicted as it is (besides run, model, error_rel, chi2_per_residual)
VALIDATION_EXPLAINED = ("beyond_noise", "explanation", "explanation_note", "pinned", "refit_chi2_per_residual",
                        "fit_runs_chi2_rise", "allowed_chi2_rise")
#: validation.tsv's columns, in order (a prediction's own, e.g. <parameter>_used, come between)
VALIDATION_COLUMNS = ("run", "rpm", "eccentric_mass_g", "model", "error_rel", "chi2_per_residual", "note",
                      *VALIDATION_EXPLAINED)
VALIDATION = Table("{variant}/validation.tsv", None, FIT,
                   "a (validation run, model) a row: ``VALIDATION_COLUMNS``, a prediction's own columns between "
                   "(<parameter>_used); every declared column also when no run could be predicted",
                   text=("run", "model", "note", "explanation", "explanation_note", "pinned", "outside_range"),
                   na_text=True, flags=("beyond_noise",))
VALIDATION_REFITS = Table("{variant}/validation_refits.tsv", ("validation_run", *PARAMETER_COLUMNS), FIT,
                          "the parameter table of each refit with a validation run included, and which run",
                          text=PARAMETER_TEXT, na_text=True, floats=PARAMETERS.floats)
PREDICTIONS = Table("{variant}/validation_harmonics.tsv",
                    ("run", "model", "phase_rad", "harmonic", "channel", "model_re_m", "model_im_m"), EXACT,
                    "long form: a (validation run, model, harmonic, channel) a row, the predicted harmonic [m] and "
                    "the phase it was aligned by", text=("run", "model", "channel"))
#: the design's true/false columns (read one way: ``flags``) and its text ones
DESIGN_FLAGS = ("keyphasor", "feasible", "interest")
_DESIGN_TEXT = ("parameter", "unit", "interval", "reason")
DESIGN_NEXT_RUNS = Table("{variant}/design/next_runs.tsv",
                         ("step", "rpm", "eccentric_mass_g", "keyphasor", "gain", "log_det", "gain_with_keyphasor"),
                         SHORT, "a run to take next a row, in the order chosen, with its gain (log det)",
                         text=_DESIGN_TEXT, flags=DESIGN_FLAGS)
DESIGN_INTERVALS = Table("{variant}/design/intervals.tsv",
                         ("parameter", "unit", "value", "ci_low", "ci_high", "interval", "lower", "upper",
                          "linear_half_width", "expected_half_width", "shrink", "interest"), SHORT,
                         "a shared parameter a row: its interval now and the one expected after the next runs",
                         text=_DESIGN_TEXT, flags=DESIGN_FLAGS)
DESIGN_CANDIDATES = Table("{variant}/design/candidates.tsv",
                          ("rpm", "eccentric_mass_g", "keyphasor", "feasible", "reason", "peak_mm", "floquet_radius",
                           "gain"), SHORT, "a candidate run (speed, mass, keyphasor) a row: feasible or why not, gain",
                          text=_DESIGN_TEXT, flags=DESIGN_FLAGS)
POLISH = Table("{variant}/identification/polish.tsv",
               ("parameter", "run", "unit", "library_value", "solver_value", "difference", "difference_rel",
                "difference_in_stderr", "stderr"), FIT,
               "a parameter (per run: one per run) a row: the library's estimate, the polished one, their difference",
               text=("parameter", "run", "unit"))
POLISH_STARTS = Table("{variant}/identification/polish_starts.tsv",
                      ("start", "chi2_start", "chi2", "chi2_dof", "iterations", "status", "selected"), FIT,
                      "a start of the polish a row: its chi^2 before and after, whether it was selected",
                      text=("start", "status"))
PROFILE = Table("{variant}/identification/profile.tsv",
                ("parameter", "side", "round", "value", "normalised", "chi2_rise", "threshold", "status"), FIT,
                "a fit of the intervals' profile over a loose parameter a row", text=("parameter", "side", "status"))
CORRELATION = Table("{variant}/identification/correlation.tsv", None, SHORT,
                    "the estimates' correlation matrix: a parameter (p or p[run]) a row and a column", index=True)
HISTORY = Table("{variant}/identification/history.tsv", ("trial", "iteration", "loss", "selected"), FIT,
                "the loss of every trial after each iteration a row (long form; also runs/{run}/history.tsv)")

# --- the diagnosis ----------------------------------------------------------------------------------------

FINGERPRINT = Table("{variant}/diagnosis_fingerprint.tsv", ("scope", "key", "quantity", "value"), FIT,
                    "long form: scope (all, run, harmonic), key (a run's name, a harmonic), quantity, value "
                    "(also an online assessment's fingerprint.tsv)", text=("scope", "key", "quantity"), na_text=True)
DIAGNOSIS = Table("{variant}/diagnosis.tsv", None, SHORT,
                  "a candidate effect a row, ranked: its score test, refit, verdict (verdict_code and its sentence)")
DIAGNOSIS_INTERVALS = Table("{variant}/diagnosis_intervals.tsv",
                            ("parameter", "candidate", "estimate", "low", "high", "beta_low", "beta_high"), REFIT,
                            "a (shared parameter, candidate) a row: the parameter's interval with the candidate in "
                            "(candidate empty: the fit's own)", text=("parameter", "candidate"), na_text=True)
DIAGNOSIS_REFITS = Table("{variant}/diagnosis_refits.tsv", None, REFIT,
                         "every refit's parameter table (effect first, then a parameter table's columns)",
                         text=("effect", "parameter", "run", "kind", "unit", "interval", "source"), na_text=True)

# --- the report -------------------------------------------------------------------------------------------

COMPARISONS = Table("{variant}/report/harmonics.tsv", None, FIT,
                    "long form: a (run, harmonic, channel) a row: run, role, rpm, eccentric_mass_g, "
                    "eccentric_mass_angle_deg, source, dof, harmonic, channel, measured_re_m, measured_im_m, "
                    "model_re_m, model_im_m, sigma_m (the fitted model against the measured harmonics)",
                    text=("run",))
ERRORS = Table("{variant}/report/errors.tsv",
               ("run", "rpm", "eccentric_mass_g", "role", "source", "chi2", "dof", "chi2_dof", "p_value",
                "beyond_noise", "error_pct", "signal_m"), SHORT,
               "a run a row: its chi^2, p-value, beyond the noise or not, relative error (also "
               "report/validation_errors.tsv)", text=("run", "role", "source"), flags=("beyond_noise",))
#: the ledger's columns (results/ledger.tsv; workflow/report/ledger.rst), then chi2_dof_{run} per run
LEDGER_COLUMNS = ("variant", "description", "source", "n_data", "k", "dof", "chi2", "chi2_dof",
                  "excess_over_noise_pct", "bic", "delta_bic", "error_pct", "run_chi2_dof_median",
                  "run_chi2_dof_max", "worst_run", "runs_beyond_noise", "validation_chi2_dof",
                  "validation_error_pct", "worst_validation_run")
LEDGER = Table("ledger.tsv", None, SHORT, "a variant a row, in the config's order: ``LEDGER_COLUMNS``, then "
               "chi2_dof_{run} per run", text=("variant", "description", "source", "worst_run",
                                                "worst_validation_run"))
SUMMARY = Table("summary.tsv",
                ("variant", "chi2_dof", "p_value", "validation_chi2_dof", "delta_bic", "fit_runs",
                 "fit_runs_beyond_noise", "validation_runs", "validation_runs_beyond_noise", "worst_run",
                 "worst_run_chi2_dof", "conclusion", "status", "recommended_variant", "recommended_in_config"), SHORT,
                "a variant a row, the best first: its misfit, its runs beyond the noise, its diagnosis",
                text=("variant", "worst_run", "conclusion", "status", "recommended_variant"))
DRIFT = Table("{variant}/report/drift.tsv",
              ("parameter", "unit", "kind", "n_runs", "n_used", "n_at_bound", "sigma_source", "joint_value",
               "weighted_mean", "weighted_mean_stderr", "chi2", "dof", "chi2_dof", "p_value", "slope_per_rpm",
               "slope_centre_rpm", "slope_stderr_per_rpm", "slope_t", "slope_p_value", "drifts", "flagged",
               "verdict"), SHORT,
              "a per-run parameter a row: is its per-run estimate constant along speed",
              text=("parameter", "unit", "kind", "sigma_source", "verdict"))
TRANSIENT = Table("{variant}/report/transient.tsv",
                  ("run", "kind", "role", "eccentric_mass_g", "window", "t_start_s", "t_end_s", "rpm", "frame",
                   "channel", "harmonic", "measured_re_m", "measured_im_m", "sigma_m", "model_re_m", "model_im_m",
                   "z_re", "z_im", "z_abs", "status", "used"), EXACT,
                  "long form: a transient record's window, shown channel and harmonic a row, measured and model",
                  text=("run", "kind", "role", "frame", "channel", "status"))
RESPONSE = Table("{variant}/report/response.tsv", None, EXACT,
                 "long form: a (trial mass, sweep, speed, harmonic) a row: eccentric_mass_g, "
                 "eccentric_mass_angle_deg, sweep, rpm, harmonic, <c>_re_m, <c>_im_m per channel, stable, branch "
                 "(the fitted model by continuation)", text=("sweep", "branch"), na_text=True)
CAMPBELL = Table("{variant}/report/campbell.tsv", None, FIT,
                 "a (speed, mode) a row: its whirl frequency, damping, whirl and branch (model.campbell's table with "
                 "report.machine_plots' branches)", text=("whirl",))

# --- the twin online: an assessment's four tables, the trend of the assessments -----------------------------

ASSESSMENT = Table("online/{variant}/{record}/assessment.tsv",
                   ("record", "path", "kind", "timestamp", "timestamp_source", "twin", "verdict", "alpha", "n_runs",
                    "rpm_low", "rpm_high", "eccentric_mass_g", "n_data", "chi2", "dof", "chi2_dof", "p_value",
                    "p_fit", "move", "p_move", "changed", "alternatives", "best", "best_chi2", "best_dof",
                    "best_p_value", "twin_chi2_dof", "left_out", "route", "library", "library_verdict",
                    "library_p_low", "library_p_high", "library_bound", "library_seconds", "route_note", "seconds"),
                   FIT, "one row: the record, its verdict (RecordVerdict), the tests, the parameter that moved; where "
                   "the verdict came from (route: library or solver, the library's own verdict and p-value interval)",
                   text=("record", "path", "kind", "timestamp", "timestamp_source", "twin", "verdict", "move",
                         "changed", "alternatives", "best", "left_out", "route", "library", "library_verdict",
                         "route_note"), na_text=True, floats=None)
ASSESSMENT_PARAMETERS = Table("online/{variant}/{record}/parameters.tsv",
                              ("parameter", "run", "unit", "twin_value", "twin_stderr", "value", "stderr", "ci_low",
                               "ci_high", "change", "change_rel", "z", "statistic", "dof", "p_value", "explains",
                               "moved", "estimate", "note"), FIT,
                              "a parameter entry a row: the twin's value, the record's, the change and its test",
                              text=("parameter", "run", "unit", "estimate", "note"), na_text=True,
                              flags=("explains", "moved"), floats=None)
ASSESSMENT_HARMONICS = Table("online/{variant}/{record}/harmonics.tsv",
                             ("run", "rpm", "harmonic", "channel", "measured_re_m", "measured_im_m", "sigma_m",
                              "twin_re_m", "twin_im_m", "best_re_m", "best_im_m"), FIT,
                             "long form: a (run, harmonic, channel) a row: measured, the twin's prediction, the best "
                             "change's fit", text=("run", "channel"), na_text=True, floats=None)
ASSESSMENT_CANDIDATES = Table("online/{variant}/{record}/candidates.tsv",
                              ("candidate", "statistic", "dof", "p_value", "log_p", "beyond_range"), FIT,
                              "a candidate effect's score test a row, most significant first (empty unless a new "
                              "discrepancy)", text=("candidate",), na_text=True, flags=("beyond_range",), floats=None)
#: the trend's columns: the record's, then its parameter rows' (the parameter test's dof and p-value renamed)
TREND_RECORD_COLUMNS = ("timestamp", "record", "kind", "verdict", "alpha", "chi2_dof", "dof", "p_value", "changed")
TREND_ENTRY_COLUMNS = ("parameter", "run", "unit", "twin_value", "twin_stderr", "value", "stderr", "ci_low",
                       "ci_high", "z", "statistic", "test_dof", "test_p_value", "moved")
TREND = Table("online/{variant}/trend.tsv", TREND_RECORD_COLUMNS + TREND_ENTRY_COLUMNS, FIT,
              "a (record, parameter entry) a row, by time stamp: the record's verdict and tests, the entry's value "
              "and test", text=("timestamp", "record", "kind", "verdict", "changed", "parameter", "run", "unit"),
              na_text=True, flags=("moved",), floats=None)

# --- the harmonics: the long form and its wide view -------------------------------------------------------

MEASURED = Table("data/runs/{run}/spectrum.tsv", None, METRES,
                 "a preprocessing output in metres as it comes (a run's spectrum.tsv and waveforms.tsv, a record's "
                 "speed.tsv and runout.tsv, data/check.tsv): columns as the step writes them")
ORDERS = Table("data/records/{run}/orders.tsv", None, None,
               "a window of a transient record a row: its times, speed, revolutions, per channel its noise, offset, "
               "drift and per harmonic its order vector (``harmonic_column``); every float to its shortest exact "
               "repr (read exactly with the python parser)", extra={"lineterminator": "\n"})
RIG_RUNS = Table("rig/{name}/runs.tsv", None, SHEET,
                 "the virtual rig's runs sheet: a run a row (run, rpm, eccentric_mass_g, path, role, ...)",
                 text=("run", "path", "role"))
RIG_TRUTH = Table("rig/{name}/truth.tsv", None, METRES,
                  "the virtual rig's answer key: a run a row, its true conditions and the truth's harmonics",
                  text=("run", "role", "branch", "message"))
#: the true/false columns of a harmonics table, read one way (``flags``): a column a table lacks stays absent
HARMONICS_FLAGS = ("usable", "keyphasor", "flat", "saturated", "slowroll_compensated")
HARMONICS = Table("data/harmonics.tsv", None, METRES,
                  "the wide view: a run (a record's band, a window) a row: its conditions and checks, then per channel "
                  "noise_<c>_m, offset_<c>_m, offset_<c>_sigma_m and per harmonic <c><h>_re_m, _im_m, _amp_m, "
                  "_sigma_m (``harmonic_column``); also data/runs/{run}/harmonics.tsv and a record's bands.tsv",
                  text=("run",), flags=HARMONICS_FLAGS)
HARMONICS_LONG = Table("harmonics_long.tsv", ("run", "harmonic", "channel", "re_m", "im_m", "sigma_m"), METRES,
                       "long form: a (run, harmonic, channel) a row, the harmonic's real and imaginary parts [m] and "
                       "the standard uncertainty of each", text=("run", "channel"))
#: the whirl table (``model.whirl.whirl_table``; results/data/whirl.tsv): a speed [RPM] the check asked at, a plane's probes,
#: whether some model whirls backward there, and the model's description (``model.whirl.WhirlModel.describe``); the speed to
#: its shortest exact repr, so the preprocessing finds the very float the check asked at
WHIRL = Table("data/whirl.tsv", ("rpm", "x_probe", "y_probe", "backward_possible", "model"), None,
              "a speed the data check asked the whirl model at and a probe plane a row: whether some model of the "
              "machine whirls backward there", text=("x_probe", "y_probe", "model"), flags=("backward_possible",),
              floats=("rpm",))

def harmonic_stem(channel: str, h: int) -> str:
    """Channel ``channel``'s harmonic ``h`` in column names: x1 for channel x, x1_1 for channel x1."""
    return f"{channel}{'_' if channel[-1:].isdigit() else ''}{h}"


def harmonic_column(channel: str, h: int, part: str) -> str:
    """The wide harmonics table's column of channel ``channel``, harmonic ``h``, ``part`` re, im, amp or sigma [m]:
    x1_re_m for channel x (the VARM's), x1_1_re_m for channel x1 (an underscore when the name ends in a digit)."""
    return f"{harmonic_stem(channel, h)}_{part}_m"


def part_column(name: str, part: str) -> str:
    """A complex quantity's column in metres: <name>_re_m, <name>_im_m (a response's channel, a model's, a
    measured one's)."""
    return f"{name}_{part}_m"


def complex_values(table: pd.DataFrame, name: str) -> np.ndarray:
    """The complex values of quantity ``name`` of a long table, its <name>_re_m + i <name>_im_m columns [m]."""
    return table[part_column(name, "re")].to_numpy(float) + 1j * table[part_column(name, "im")].to_numpy(float)


def wide_channels(wide: pd.DataFrame, channels: Sequence[str]) -> list[tuple[str, int]]:
    """(channel, h) of every harmonic of ``channels`` the wide table holds (its re column), channel by channel."""
    out = []
    for c in channels:
        h = 1
        while harmonic_column(c, h, "re") in wide:
            out.append((c, h))
            h += 1
    return out


def long_harmonics(wide: pd.DataFrame, channels: Sequence[str]) -> pd.DataFrame:
    """The long form (``HARMONICS_LONG``) of a wide harmonics table's ``channels``: a (run, harmonic, channel) a row,
    the runs in the table's order, then harmonic, then channel in the order given."""
    pairs = wide_channels(wide, channels)
    harmonics = sorted({h for _, h in pairs})
    rows = []
    for _, row in wide.iterrows():
        for h in harmonics:
            for c in channels:
                if (c, h) in pairs:
                    rows.append((str(row["run"]), h, c, row[harmonic_column(c, h, "re")],
                                 row[harmonic_column(c, h, "im")], row[harmonic_column(c, h, "sigma")]))
    return pd.DataFrame(rows, columns=list(HARMONICS_LONG.columns)).astype(
        {"harmonic": int, "re_m": float, "im_m": float, "sigma_m": float})


def run_harmonics(run: str, channels: Sequence[str], X: np.ndarray, sigma: np.ndarray) -> pd.DataFrame:
    """The long form (``HARMONICS_LONG``) of one run's harmonics X (C, H+1) complex [m] at ``channels`` with their
    sigmas (C, H+1) [m] per part: a (harmonic, channel) a row for h = 1..H, harmonic by harmonic, the channels in
    the order given (h = 0, the offset, is no harmonic of the table)."""
    n_channels, n_harmonics = X.shape[0], X.shape[1] - 1
    h = np.repeat(np.arange(1, n_harmonics + 1), n_channels)
    c = np.tile(np.arange(n_channels), n_harmonics)
    return pd.DataFrame({"run": str(run), "harmonic": h, "channel": [channels[i] for i in c],
                         "re_m": X[c, h].real, "im_m": X[c, h].imag, "sigma_m": sigma[c, h]},
                        columns=list(HARMONICS_LONG.columns))


def wide_harmonics(long: pd.DataFrame) -> pd.DataFrame:
    """The wide view of a long harmonics table: a run a row (first seen first), per channel and harmonic its
    <c><h>_re_m, _im_m, _amp_m (the modulus) and _sigma_m columns, channel by channel, harmonic by harmonic; NaN
    where a run lacks that harmonic."""
    runs = list(dict.fromkeys(long["run"]))
    row = pd.Index(runs).get_indexer(long["run"])
    channel, harmonic = long["channel"].to_numpy(), long["harmonic"].to_numpy()
    values = {part: long[f"{part}_m"].to_numpy(float) for part in ("re", "im", "sigma")}
    out = {"run": runs}
    for c in dict.fromkeys(channel):
        for h in sorted(set(harmonic[channel == c])):
            at = (channel == c) & (harmonic == h)
            re_, im_, sigma = (np.full(len(runs), np.nan) for _ in range(3))
            for column, part in ((re_, "re"), (im_, "im"), (sigma, "sigma")):
                column[row[at]] = values[part][at]
            out |= {harmonic_column(c, h, "re"): re_, harmonic_column(c, h, "im"): im_,
                    harmonic_column(c, h, "amp"): np.hypot(re_, im_), harmonic_column(c, h, "sigma"): sigma}
    return pd.DataFrame(out)


# --- the command line's tables (hybridtwin campbell / modes / response --out) --------------------------------

MACHINE_VIEW = Table("{out}/campbell.tsv", None, shortest_repr,
                     "a command's table (campbell.tsv, critical_speeds.tsv, modes.tsv, mode_shapes.tsv, peaks.tsv "
                     "of ``hybridtwin campbell|modes|response --out``): every float as its shortest exact repr",
                     text=("whirl", "sweep", "channel"), na_text=True)

#: every table of the layer, by the name a rule writes it under
TABLES: dict[str, Table] = {t.name: t for t in (
    SCENARIOS, ENRICHMENT_SCENARIOS, LIBRARY_VALIDATION, FAILURES, FAILURE_SUMMARY, ENRICHMENT_SUMMARY, POD,
    WHITEBOX, PARAMETERS, VALIDATION, VALIDATION_REFITS, PREDICTIONS, DESIGN_NEXT_RUNS, DESIGN_INTERVALS,
    DESIGN_CANDIDATES, POLISH, POLISH_STARTS, PROFILE, CORRELATION, HISTORY, FINGERPRINT, DIAGNOSIS,
    DIAGNOSIS_INTERVALS, DIAGNOSIS_REFITS, COMPARISONS, ERRORS, LEDGER, SUMMARY, DRIFT, TRANSIENT, RESPONSE,
    CAMPBELL, ASSESSMENT, ASSESSMENT_PARAMETERS, ASSESSMENT_HARMONICS, ASSESSMENT_CANDIDATES, TREND, HARMONICS,
    HARMONICS_LONG, MEASURED, ORDERS, RIG_RUNS, RIG_TRUTH, MACHINE_VIEW)}
