"""The report stage (hybridtwin.report.report): the numbers the figures and the ledger show, on synthetic fits with known
harmonics, and that every figure is written (seconds, no solver); the report's first page (hybridtwin.report.summary) on
known tables; and `snakemake --report report.html` on a small run of the workflow (about a minute)."""

import base64
import html as htmllib
import io
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import stats

from hybridtwin import tables
from hybridtwin.identify import identification as idn
from hybridtwin.report import report
from hybridtwin.report import drift, report_plots
from hybridtwin.report import interactive_pages
from hybridtwin.report import summary
from hybridtwin.identify import validation as val
from hybridtwin.identify.run_fits import write_fit

ROOT = Path(__file__).resolve().parents[1]
H = 3
RUNS = ["a", "b"]
RPM = [500.0, 800.0]
MASS = {"a": 25.9, "b": 0.0}
PHASES = {"a": 0.7, "b": -2.1}


def _model() -> np.ndarray:
    """Model harmonics (2 runs, H, 2): a forward circular 1X of radius 1 mm and 2 mm, a small 3X."""
    M = np.zeros((2, H, 2), complex)
    for k, radius in enumerate((1e-3, 2e-3)):
        M[k, 0] = radius * np.array([1.0, -1j])  # x = r cos, y = r sin: forward whirl
        M[k, 2] = 1e-5 * np.array([1.0 + 0.5j, 0.3j])
    return M


def _residual() -> np.ndarray:
    """Known misfit in the model's frame: run a on the noise floor, run b a backward 3X of 40 um."""
    rng = np.random.default_rng(3)
    R = 1e-6 * (rng.standard_normal((2, H, 2)) + 1j * rng.standard_normal((2, H, 2)))
    R[1, 2] += 40e-6 * np.array([1.0, 1j])  # x = c cos 3wt, y = -c sin 3wt: backward
    return R


def _rotate(Z: np.ndarray, phase: float) -> np.ndarray:
    return Z * np.exp(1j * np.arange(1, H + 1) * phase)[:, None]


@pytest.fixture
def synthetic(tmp_path):
    """A joint fit stored by run_fits.write_fit (duck-typed result), its parameters, summary and sheet."""
    M, R = _model(), _residual()
    fitted = np.stack([_rotate(M[k], PHASES[r]) for k, r in enumerate(RUNS)])
    measured = np.stack([_rotate(M[k] + R[k], PHASES[r]) for k, r in enumerate(RUNS)])
    sigma = np.full((2, H, 2), 1e-6)
    fit = SimpleNamespace(X=measured, fitted=lambda: fitted, problem=SimpleNamespace(sigma=sigma),
                          layout=SimpleNamespace(runs=tuple(RUNS)), chi2_dof=1.0, values=lambda: {"k": 1.0})
    write_fit(tmp_path / "fit.zarr", fit, RPM)
    parameters = pd.DataFrame({"parameter": ["k"] + ["phase"] * 2, "run": ["all"] + RUNS,
                               "kind": ["shared", "nuisance", "nuisance"], "value": [1.0, *PHASES.values()],
                               "source": "solver"})
    summary = {"n_data": 4 * H * 2, "dof": 4 * H * 2 - 5}
    sheet = pd.DataFrame({"run": RUNS, "eccentric_mass_g": [MASS[r] for r in RUNS]})
    comparisons = report.fit_comparisons(tmp_path / "fit.zarr", parameters, summary, sheet)
    return SimpleNamespace(comparisons=comparisons, M=M, R=R, sigma=sigma, summary=summary, parameters=parameters)


def test_whirl_splits_circular_and_elliptic_orbits():
    forward, backward = report.whirl(np.array([[1.0, -1j]]))  # x = cos, y = sin
    assert forward[0] == pytest.approx(1.0) and abs(backward[0]) < 1e-15
    forward, backward = report.whirl(np.array([[1.0, 1j]]))  # x = cos, y = -sin
    assert abs(forward[0]) < 1e-15 and backward[0] == pytest.approx(1.0)
    Z = np.array([[3.0, -2j], [0.0, 0.0]])  # ellipse x = 3 cos, y = 2 sin: forward 2.5, backward 0.5
    forward, backward = report.whirl(Z)
    assert abs(forward[0]) == pytest.approx(2.5) and abs(backward[0]) == pytest.approx(0.5)
    angle, xy = report.waveform(Z, 1.0, 50)
    z = xy[:, 0] + 1j * xy[:, 1]
    assert np.allclose(z, forward[0] * np.exp(1j * angle) + backward[0] * np.exp(-1j * angle))


def test_whirl_noise_is_the_rms_of_a_noise_only_component():
    rng = np.random.default_rng(0)
    sigma = np.array([[2.0, 1.0]])
    n = 200000
    noise = sigma * (rng.standard_normal((n, 1, 2)) + 1j * rng.standard_normal((n, 1, 2)))
    forward, backward = report.whirl(noise[:, 0, :].reshape(n, 2))
    expected = report.whirl_noise(sigma)[0]
    assert np.sqrt(np.mean(np.abs(forward) ** 2)) == pytest.approx(expected, rel=0.01)
    assert np.sqrt(np.mean(np.abs(backward) ** 2)) == pytest.approx(expected, rel=0.01)


def test_fit_runs_return_to_the_model_frame_with_the_known_residual(synthetic):
    for k, c in enumerate(synthetic.comparisons):
        assert c.run == RUNS[k] and c.role == "fit" and c.rpm == RPM[k] and c.eccentric_mass_g == MASS[c.run]
        assert np.allclose(c.model, synthetic.M[k], atol=1e-15)
        assert np.allclose(c.residual, synthetic.R[k], atol=1e-15)
        assert c.chi2 == pytest.approx((np.abs(synthetic.R[k]) ** 2).sum() / 1e-12)
    # the residual spectrum shows what was put in: run b's backward 3X of 40 um, nothing forward above noise
    forward, backward = report.whirl(synthetic.comparisons[1].residual)
    assert abs(backward[2]) == pytest.approx(40e-6, rel=0.1)
    assert abs(forward[2]) < 5e-6


def test_run_dofs_add_up_to_the_joint_fit(synthetic):
    errors = report.error_table(synthetic.comparisons)
    assert errors["dof"].sum() == pytest.approx(synthetic.summary["dof"])
    total = sum(c.chi2 for c in synthetic.comparisons)
    assert report.pooled(errors)["chi2_dof"] == pytest.approx(total / synthetic.summary["dof"])
    dof = 4 * H * synthetic.summary["dof"] / synthetic.summary["n_data"]
    assert errors["chi2_dof"].tolist() == pytest.approx([c.chi2 / dof for c in synthetic.comparisons])
    assert errors["p_value"].tolist() == pytest.approx([stats.chi2.sf(c.chi2, dof) for c in synthetic.comparisons])
    assert errors["beyond_noise"].tolist() == [False, True]
    relative = [np.linalg.norm(synthetic.R[k]) / np.linalg.norm(synthetic.M[k] + synthetic.R[k]) for k in range(2)]
    assert errors["error_pct"].tolist() == pytest.approx([100 * e for e in relative])


def test_comparison_table_round_trip(synthetic):
    back = report.read_comparisons(report.comparison_table(synthetic.comparisons))
    for a, b in zip(synthetic.comparisons, back):
        assert (a.run, a.role, a.rpm, a.eccentric_mass_g, a.dof, a.source) == (b.run, b.role, b.rpm,
                                                                                b.eccentric_mass_g, b.dof, b.source)
        assert np.array_equal(a.measured, b.measured) and np.array_equal(a.model, b.model)


class _Fixed:
    """A HarmonicModel returning fixed harmonics (the validation path without a library)."""

    parameters, lower, upper, H = ["k"], np.array([0.0]), np.array([2.0]), H

    def __init__(self, M: np.ndarray):
        self.M = M

    def evaluate(self, x, jacobian=True):
        return np.repeat(self.M[None], len(np.atleast_2d(x)), axis=0), None


def _predicted(M: np.ndarray, data: idn.RunData, model: str = "library") -> val.PredictedRun:
    """What predict_validation writes for a run of the fixed model M."""
    return val.PredictedRun.from_prediction(val.predict_run(_Fixed(M), data, {"k": 1.0}), model)


def test_validation_run_is_scored_like_predict_validation():
    M, R = _model()[0], _residual()[1]
    sigma = np.full((H, 2), 1e-6)
    data = idn.RunData("v", 700.0, 19.5, "validate", _rotate(M + R, 1.3), sigma)
    c = report.validation_comparison(_predicted(M, data), data, 0.0)
    scored = val.predict_run(_Fixed(M), data, {"k": 1.0})
    assert c.role == "validate" and c.dof == 4 * H - 1 and c.source == "library"
    assert c.error_rel == pytest.approx(scored["error_rel"])
    assert c.chi2 == pytest.approx(scored["chi2_per_residual"] * 4 * H)
    assert np.allclose(c.model, M, atol=1e-12)  # the model is in its own frame, the measurement rotated to it
    clean = idn.RunData("v", 700.0, 19.5, "validate", _rotate(M, 1.3), sigma)
    exact = report.validation_comparison(_predicted(M, clean), clean, 0.0)
    assert np.allclose(exact.measured, M, atol=1e-12) and exact.chi2 < 1e-12


def test_predicted_harmonics_file_round_trips_exactly(tmp_path):
    """validation_harmonics.tsv: read_predictions is write_predictions' exact inverse (bit for bit, several runs
    and both models of a run, channel order as written), and the report's validation run from the file is the one
    from the prediction itself, which is what the report computed when it predicted the run again."""
    M, R = _model()[0], _residual()[1]
    sigma = np.full((H, 2), 1e-6)
    runs = [idn.RunData("v1", 650.0, 19.5, "validate", _rotate(M + R, 0.4), sigma),
            idn.RunData("007", 900.0, 0.0, "validate", _rotate(1.1 * M - R, -2.9), sigma)]  # a run name like a number
    predictions = [_predicted(M, runs[0], "library"), _predicted(M, runs[0], "solver"), _predicted(0.9 * M, runs[1])]
    path = tmp_path / "validation_harmonics.tsv"
    val.write_predictions(path, predictions)
    back = val.read_predictions(path)
    assert [(p.run, p.model) for p in back] == [("v1", "library"), ("v1", "solver"), ("007", "library")]
    for a, b in zip(predictions, back):
        assert a.phase_rad == b.phase_rad and np.array_equal(a.harmonics, b.harmonics)
        assert b.harmonics.shape == (H, 2)
    assert val.prediction_table(back).equals(pd.read_csv(path, sep="\t", dtype={"run": str}))
    for data, a, b in zip([runs[0], runs[0], runs[1]], predictions, back):
        direct, from_file = (report.validation_comparison(p, data, 0.02) for p in (a, b))
        assert from_file.chi2 == direct.chi2 and from_file.error_rel == direct.error_rel
        assert np.array_equal(from_file.model, direct.model) and np.array_equal(from_file.measured, direct.measured)
        # the re-prediction the report made before: predict_run again, its harmonics rotated to the model frame
        again = val.predict_run(_Fixed(M if b.run == "v1" else 0.9 * M), data, {"k": 1.0})
        assert np.array_equal(from_file.model, report.to_model_frame(again["fitted"], again["phase_rad"]))
    val.write_predictions(path, [])  # no usable validation run: an empty table, read back as none
    assert val.read_predictions(path) == []


def test_predicted_harmonics_reader_names_the_file_and_the_problem(tmp_path):
    path = tmp_path / "validation_harmonics.tsv"
    M = _model()[0]
    data = idn.RunData("v", 700.0, 19.5, "validate", M, np.full((H, 2), 1e-6))
    table = val.prediction_table([_predicted(M, data)])
    table.iloc[:-1].to_csv(path, sep="\t", index=False)  # a channel of the last harmonic missing
    with pytest.raises(ValueError, match=r"validation_harmonics.tsv: run v \(library\) needs harmonics"):
        val.read_predictions(path)
    table.drop(columns="phase_rad").to_csv(path, sep="\t", index=False)
    with pytest.raises(ValueError, match=r"validation_harmonics.tsv: .*\['phase_rad'\] missing"):
        val.read_predictions(path)


def test_drift_test_recovers_a_slope_and_flags_a_drift():
    rpm = np.linspace(400, 1000, 13)
    line = drift.drift_test(2.0 + 1e-3 * rpm, np.full(13, 0.01), rpm)
    assert line["slope_per_rpm"] == pytest.approx(1e-3)
    assert line["slope_stderr_per_rpm"] == pytest.approx(0.01 / np.sqrt(((rpm - rpm.mean()) ** 2).sum()))
    assert line["drifts"]
    rng = np.random.default_rng(1)
    step = np.where(rpm > 700, 1.0, 0.0) * np.cos(rpm)  # no trend, but not one value
    assert drift.drift_test(5 + step + 0.05 * rng.standard_normal(13), np.full(13, 0.05), rpm)["drifts"]


def test_drift_test_reads_no_slope_into_runs_at_one_speed():
    """Runs all at about 600 RPM (refined speeds 598.9-601.0, masses differing): no slope is tested (there is no
    speed to slope along: the probe's k_b 'slope' of -387 +- 153 per RPM, p = 0.011, was noise over 2 RPM); the
    constancy test still is. The same values over 400-1000 RPM: the slope is tested."""
    rpm = np.array([598.9, 600.2, 601.0, 599.6])
    value = np.array([3.0, 2.6, 2.4, 2.8])
    one_speed = drift.drift_test(value, np.full(4, 0.3), rpm)
    assert np.isnan(one_speed["slope_per_rpm"]) and np.isnan(one_speed["slope_p_value"])
    assert np.isfinite(one_speed["p_value"]) and not one_speed["drifts"]
    spread = drift.drift_test(value, np.full(4, 0.3), np.array([400.0, 600.0, 1000.0, 800.0]))
    assert np.isfinite(spread["slope_per_rpm"]) and np.isfinite(spread["slope_p_value"])


def test_drift_test_false_alarm_rate_on_constants_with_noise():
    """Constants with Gaussian noise of the stated sigma: flagged at most ALPHA of the time (Bonferroni over the
    two tests, so between ALPHA / 2 and ALPHA); 4000 series, bounds at 3 binomial standard deviations."""
    rng = np.random.default_rng(2)
    rpm = np.linspace(350, 1000, 15)
    sigma = rng.uniform(0.5, 2.0, 15)
    n = 4000
    flags = sum(drift.drift_test(3.0 + sigma * rng.standard_normal(15), sigma, rpm)["drifts"] for _ in range(n))
    spread = 3 * np.sqrt(report.ALPHA * (1 - report.ALPHA) / n)
    assert report.ALPHA / 2 - spread < flags / n < report.ALPHA + spread


def _per_run(values: dict[str, np.ndarray], rpm: np.ndarray, at_bound: dict[str, np.ndarray]) -> pd.DataFrame:
    rows = []
    for p, v in values.items():
        for i, (r, value) in enumerate(zip(rpm, v)):
            rows.append({"parameter": p, "run": f"r{i}", "unit": "1", "value": value, "stderr": 1e3,
                         "mc_std": 0.1, "at_bound": bool(at_bound[p][i]), "rpm": r, "eccentric_mass_g": 10.0,
                         "lower": 0.0, "upper": 10.0})
    return pd.DataFrame(rows)


def test_drift_statistics_flag_only_drifting_constants():
    rpm = np.linspace(400, 1000, 10)
    rng = np.random.default_rng(4)
    noise = 0.1 * rng.standard_normal(10)
    bound = np.zeros(10, bool)
    bound[[2, 5]] = True
    per_run = _per_run({"k": 5 + 0.004 * (rpm - 700) + noise, "c": 5 + noise, "q": 1 + 0.004 * (rpm - 400)},
                       rpm, {"k": bound, "c": np.zeros(10, bool), "q": np.zeros(10, bool)})
    joint = pd.DataFrame({"parameter": ["k", "c"] + ["q"] * 10 + ["phase"] * 10,
                          "run": ["all", "all"] + [f"r{i}" for i in range(10)] * 2,
                          "kind": ["shared", "shared"] + ["per_run"] * 10 + ["nuisance"] * 10,
                          "value": [5.0, 5.0] + [1.0] * 10 + [0.0] * 10})
    table = drift.drift_statistics(per_run, joint).set_index("parameter")
    assert table.loc["k", "n_used"] == 8 and table.loc["k", "n_at_bound"] == 2  # edge estimates not tested
    assert table.loc["k", "sigma_source"] == "monte_carlo"  # the MC spread, not the (huge) linearised stderr
    assert table.loc["k", "flagged"] and not table.loc["c", "flagged"]
    assert table.loc["q", "drifts"] and not table.loc["q", "flagged"]  # per-run: allowed to vary
    assert table.loc["k", "slope_per_rpm"] == pytest.approx(0.004, rel=0.1)
    assert table.loc["k", "joint_value"] == 5.0 and np.isnan(table.loc["q", "joint_value"])


def test_bic_and_ledger_rows_from_known_inputs():
    assert report.bic(100.0, 40, 30) == pytest.approx(100.0 + 10 * np.log(40))
    errors = pd.DataFrame({
        "run": ["a", "b", "v"], "role": ["fit", "fit", "validate"], "source": "solver",
        "chi2": [10.0, 30.0, 57.0], "dof": [10.0, 10.0, 19.0], "chi2_dof": [1.0, 3.0, 3.0],
        "beyond_noise": [False, True, True], "error_pct": [1.0, 2.0, 4.0], "signal_m": [1.0, 1.0, 2.0]})
    rows = [report.ledger_row("base", "the base", {"n_data": 24, "dof": 20, "chi2": 40.0}, errors),
            report.ledger_row("better", "", {"n_data": 24, "dof": 18, "chi2": 19.0}, errors)]
    ledger = report.ledger_table(rows)
    assert list(ledger.columns[: len(report.LEDGER_COLUMNS)]) == report.LEDGER_COLUMNS
    assert ledger["variant"].tolist() == ["base", "better"]  # config order kept
    base = ledger.iloc[0]
    assert base["k"] == 4 and base["chi2_dof"] == pytest.approx(2.0) and base["excess_over_noise_pct"] == 100.0
    assert base["bic"] == pytest.approx(40 + 4 * np.log(24))
    assert ledger["delta_bic"].tolist() == pytest.approx([40 + 4 * np.log(24) - 19 - 6 * np.log(24), 0.0])
    assert base["error_pct"] == pytest.approx(np.sqrt((1 + 4) / 2))
    assert (base["run_chi2_dof_median"], base["run_chi2_dof_max"], base["worst_run"]) == (2.0, 3.0, "b")
    assert base["runs_beyond_noise"] == 1
    assert base["validation_chi2_dof"] == 3.0 and base["validation_error_pct"] == pytest.approx(4.0)
    assert (base["chi2_dof_a"], base["chi2_dof_b"], base["chi2_dof_v"]) == (1.0, 3.0, 3.0)


def test_figures_show_the_numbers_and_are_written(synthetic, tmp_path):
    M = _model()[0]
    data = idn.RunData("v", 650.0, 19.5, "validate", _rotate(M * 1.1, 0.4), np.full((H, 2), 1e-6))
    comparisons = synthetic.comparisons + [report.validation_comparison(_predicted(M, data, "solver"), data, 0.0)]
    errors = report.error_table(comparisons)
    # the error map colours each run by its chi^2/dof, fit runs and the validation run in separate markers
    error_map = report_plots.plot_error_map(errors, "synthetic")
    fit_points, validation_points = error_map.axes[0].collections[:2]
    assert np.allclose(fit_points.get_array(), errors.loc[errors["role"] == "fit", "chi2_dof"])
    assert np.allclose(validation_points.get_array(), errors.loc[errors["role"] == "validate", "chi2_dof"])
    # the run figure's residual bars are the residual's whirl components (backward -H..-1, forward 1..H) in um
    run_figure = report_plots.plot_run(comparisons[1], "synthetic")
    spectrum = run_figure.axes[-1]
    bars = {c.get_label(): [b.get_height() for b in c] for c in spectrum.containers}
    forward, backward = report.whirl(synthetic.R[1])
    expected = np.abs(np.concatenate([backward[::-1], forward])) * 1e6
    floor = spectrum.get_ylim()[0]
    assert np.allclose(bars["residual"], np.maximum(expected, floor))
    per_run = _per_run({"k": np.linspace(4, 6, 5)}, np.linspace(400, 800, 5), {"k": np.zeros(5, bool)})
    statistics = drift.drift_statistics(per_run, synthetic.parameters)
    figures = {"run": run_figure, "error_map": error_map,
               "drift": drift.plot_drift(per_run, statistics, synthetic.parameters, "synthetic"),
               "ledger": report_plots.plot_ledger(report.ledger_table([report.ledger_row(
                   "synthetic", "", {"n_data": 24, "dof": 19, "chi2": errors["chi2"][:2].sum()}, errors)]),
                   {"synthetic": errors})}
    for name, figure in figures.items():
        figure.savefig(tmp_path / f"{name}.png", dpi=40)
        report_plots.plt.close(figure)
        assert (tmp_path / f"{name}.png").stat().st_size > 1000


def test_two_fit_runs_and_no_validation_run(synthetic, tmp_path):
    """The smallest workflow: too few runs to test a drift, no validation run; tables and figures still made."""
    per_run = _per_run({"k": np.array([4.0, 6.0])}, np.array(RPM), {"k": np.zeros(2, bool)})
    statistics = drift.drift_statistics(per_run, synthetic.parameters)
    assert list(statistics.columns) == list(tables.DRIFT.columns)  # the same columns whatever the number of runs
    assert statistics["verdict"].tolist() == ["too few usable per-run estimates to test"]
    assert not statistics["flagged"].any()
    errors = report.error_table(synthetic.comparisons)
    row = report.ledger_row("v", "", {"n_data": 24, "dof": 19, "chi2": errors["chi2"].sum()}, errors)
    assert np.isnan(row["validation_chi2_dof"]) and row["worst_validation_run"] == ""
    figures = [drift.plot_drift(per_run, statistics, synthetic.parameters, "small"),
               report_plots.plot_error_map(errors, "small"),
               report_plots.plot_ledger(report.ledger_table([row]), {"v": errors})]
    for i, figure in enumerate(figures):
        figure.savefig(tmp_path / f"{i}.png", dpi=30)
        report_plots.plt.close(figure)


# --- the report's first page (hybridtwin.report.summary) ---------------------------------------------------------


def _errors(chi2_dof: dict[str, float], beyond: set[str], validation: tuple[str, ...] = ("v",)) -> pd.DataFrame:
    """An error table (report.ERROR_COLUMNS) with the given per-run chi^2/dof, 10 dof each."""
    runs = list(chi2_dof)
    return pd.DataFrame({"run": runs, "rpm": [400.0 + 100 * i for i in range(len(runs))],
                         "eccentric_mass_g": 14.8,
                         "role": ["validate" if r in validation else "fit" for r in runs], "source": "solver",
                         "chi2": [10 * chi2_dof[r] for r in runs], "dof": 10.0, "chi2_dof": list(chi2_dof.values()),
                         "p_value": 0.5, "beyond_noise": [r in beyond for r in runs], "error_pct": 1.0,
                         "signal_m": 1e-3})


BASE_EFFECTS = ["unbalance", "shaft_bow", "geometric_spring"]


@pytest.fixture
def three_variants():
    """A loop in progress: 'base' misses an effect, 'base_slope' (already in the config) fits, 'other' is
    recommended a variant nobody declared yet."""
    errors = {"base": _errors({"a": 1.1, "b": 40.0, "c": 300.0, "v": 80.0}, beyond={"b", "c", "v"}),
              "base_slope": _errors({"a": 0.9, "b": 1.2, "c": 1.0, "v": 1.1}, beyond=set()),
              "other": _errors({"a": 1.0, "b": 5.0, "c": 1.3, "v": 2.0}, beyond={"b"})}
    summaries = {"base": {"n_data": 36, "dof": 30, "chi2": 30 * 114.0},
                 "base_slope": {"n_data": 36, "dof": 28, "chi2": 28 * 1.03},
                 "other": {"n_data": 36, "dof": 29, "chi2": 29 * 2.4}}
    ledger = report.ledger_table([report.ledger_row(name, "", summaries[name], errors[name]) for name in errors])
    diagnoses = {"base": {"conclusion": "add slope_spring: it explains the discrepancy",
                          "recommended_variant": {"name": "base_slope_spring",
                                                  "spec": {"effects": BASE_EFFECTS + ["slope_spring"]}}},
                 "base_slope": {"conclusion": "no missing effect", "recommended_variant": None},
                 "other": {"conclusion": "add excitation_3x: it explains the discrepancy",
                           "recommended_variant": {"name": "other_excitation_3x",
                                                   "spec": {"effects": BASE_EFFECTS + ["excitation_3x"]}}}}
    variants = {"base": {"effects": BASE_EFFECTS}, "base_slope": {"effects": BASE_EFFECTS[::-1] + ["slope_spring"]},
                "other": {"effects": BASE_EFFECTS + ["moment_stiffness"]}}
    return SimpleNamespace(errors=errors, ledger=ledger, table=summary.summary_table(ledger, errors, diagnoses,
                                                                                     variants))


def test_summary_table_counts_failures_and_finds_a_recommendation_already_declared(three_variants):
    table = three_variants.table.set_index("variant")
    assert list(table.index) == ["base", "base_slope", "other"]  # config order, as the ledger
    assert list(three_variants.table.columns) == list(tables.SUMMARY.columns)
    assert table.loc["base", "chi2_dof"] == pytest.approx(114.0)
    assert (table.loc["base", "fit_runs"], table.loc["base", "fit_runs_beyond_noise"]) == (3, 2)
    assert (table.loc["base", "validation_runs"], table.loc["base", "validation_runs_beyond_noise"]) == (1, 1)
    assert (table.loc["base", "worst_run"], table.loc["base", "worst_run_chi2_dof"]) == ("c", 300.0)
    # chi^2 = 1.03 x 28 dof is well inside the noise; 114 x 30 is not (p of chi^2(dof) from scipy)
    assert table.loc["base_slope", "p_value"] == pytest.approx(stats.chi2.sf(28 * 1.03, 28))
    assert table.loc["base", "p_value"] < 1e-100
    # the same effects in another order are the same variant; a different set is not declared yet
    assert table.loc["base", "recommended_in_config"] == "base_slope"
    assert table.loc["other", "recommended_variant"] == "other_excitation_3x"
    assert table.loc["other", "recommended_in_config"] == ""
    assert table.loc["base_slope", "recommended_variant"] == ""
    assert summary.best_variant(three_variants.table)["variant"] == "base_slope"  # lowest BIC


def _links(html: str) -> list[str]:
    return re.findall(r"javascript:app\.showResultInfo\('([^']*)'\)", html)


def test_first_page_is_valid_rst_that_links_every_failing_run_to_its_figure(three_variants):
    from docutils.core import publish_parts

    page = summary.landing_rst(three_variants.table, three_variants.errors)
    # halt at a warning: a malformed table, an unescaped markup character or a broken link would raise here
    html = publish_parts(page, writer="html", settings_overrides={"halt_level": 2})["html_body"]
    text = re.sub(r"<[^>]+>", "", html)
    assert "(lowest BIC): base_slope, chi^2/dof 1.03" in text and "within the noise" in text
    links = _links(html)
    # every run beyond the noise, and only those, is linked to its per-run figure where the failures are listed
    failures = html[html.index("Where each variant fails"):]
    for variant, errors in three_variants.errors.items():
        for r in errors.itertuples():
            linked = summary.run_figure(variant, r.run) in _links(failures)
            assert linked == r.beyond_noise, (variant, r.run)
    assert "every run within the noise" in re.sub(r"<[^>]+>", "", failures).split("base_slope")[1]
    # worst runs first: c (300) before v (80) before b (40)
    base = [link.rsplit("/", 1)[1] for link in _links(failures) if "/base/report/runs/" in link]
    assert base == ["c.png", "v.png", "b.png"]
    # recommendations: the declared one by name, the undeclared one by the diagnosis.md holding its lines
    assert "add slope_spring (in the config as base_slope)" in text
    assert "results/other/diagnosis.md" in links
    assert {"results/ledger.tsv", "results/summary.png"} <= set(links)
    assert "kept out by the data checks" not in text  # none was


def test_first_page_names_the_runs_the_data_checks_kept_out(three_variants):
    """A run kept out (harmonics.tsv's usable false) is in no variant's errors: the first page names it, with its
    role and why, right after the headline, so that 'on its N fit runs' is not read as every run of the sheet."""
    from docutils.core import publish_parts

    harmonics = pd.DataFrame({"run": ["a", "r975", "v2"], "role": ["fit", "fit", "validate"],
                              "usable": [True, False, False],
                              "note": ["ok", "excluded (saturated, harmonics biased): x clipped at +14.000 mm",
                                       "excluded: y flat"]})
    excluded = summary.kept_out(harmonics)
    assert excluded["run"].tolist() == ["r975", "v2"]
    page = summary.landing_rst(three_variants.table, three_variants.errors, excluded)
    text = re.sub(r"<[^>]+>", "", publish_parts(page, writer="html", settings_overrides={"halt_level": 2})
                  ["html_body"])
    assert "2 runs kept out by the data checks" in text and "r975 (fit: excluded (saturated" in text
    assert "v2 (validate: excluded: y flat)" in text
    assert text.index("kept out") < text.index("The ledger")
    # read back from the table as written (usable as text True/False)
    written = pd.read_csv(io.StringIO(harmonics.to_csv(sep="\t", index=False)), sep="\t", dtype={"run": str})
    assert summary.kept_out(written)["run"].tolist() == ["r975", "v2"]


def test_first_page_says_why_a_validation_run_fails(three_variants, tmp_path):
    """validation.tsv's explanation (hybridtwin.identify.validation_refit) follows the failing validation run: the
    parameters it pins when the fit runs leave them loose; nothing for a variant that misfits its fit runs."""
    from docutils.core import publish_parts

    from hybridtwin.identify.validation_refit import EXPLANATIONS, VALIDATION_COLUMNS

    written = tmp_path / "validation.tsv"
    rows = pd.DataFrame({"run": ["v", "v"], "model": ["library", "solver"], "explanation": "not_pinned",
                         "pinned": "zeta_bup,k_b"}).reindex(columns=["run", "model", *VALIDATION_COLUMNS])
    rows.assign(explanation="not_pinned", pinned="zeta_bup,k_b").to_csv(written, sep="\t", index=False)
    read = pd.read_csv(written, sep="\t", dtype={"run": str, "pinned": str}, keep_default_na=False)
    assert summary.explanations(read) == {"v": "the fit runs do not pin zeta_bup, k_b; this run does"}
    misfit = read.assign(explanation="misfit")
    assert summary.explanations(misfit) == {} and set(summary.WHY) < set(EXPLANATIONS)
    why = {"base": summary.explanations(read), "other": {"b": "not a validation run"}}
    page = summary.landing_rst(three_variants.table, three_variants.errors, why=why)
    text = re.sub(r"<[^>]+>", "", publish_parts(page, writer="html", settings_overrides={"halt_level": 2})
                  ["html_body"])
    failures = text[text.index("Where each variant fails"):]
    assert "v (validation) 80 (the fit runs do not pin zeta_bup, k_b; this run does)" in failures
    assert "not a validation run" not in failures  # only validation runs are explained


def test_first_page_names_the_next_runs_to_take(three_variants, tmp_path):
    """design/next_runs.tsv and intervals.tsv of the best variant (hybridtwin.identify.design), as written and read
    back: the runs in order and the expected half-widths of the parameters of interest only."""
    from docutils.core import publish_parts

    from hybridtwin.identify.design import CHOSEN_COLUMNS, INTERVAL_COLUMNS

    chosen = pd.DataFrame([[1, 1000.0, 7.6, True, 3.2, 9.8, 3.2], [2, 975.0, 0.0, False, 1.1, 10.9, 1.12]],
                          columns=CHOSEN_COLUMNS)
    intervals = pd.DataFrame([["zeta_bup", "1", 0.0138, 0.0119, 0.0157, "linear", 0.0, 0.05, 1.9e-3, 1.7e-4, 11.0, True],
                              ["k_b", "N/m", 2411.6, 2410.7, 2412.5, "linear", 2000.0, 3500.0, 0.86, 0.35, 2.5, False]],
                             columns=INTERVAL_COLUMNS)
    for name, frame in (("chosen", chosen), ("intervals", intervals)):
        frame.to_csv(tmp_path / f"{name}.tsv", sep="\t", index=False)
    line = summary.next_runs_line("base_slope", *(pd.read_csv(tmp_path / f"{n}.tsv", sep="\t")
                                                  for n in ("chosen", "intervals")))
    page = summary.landing_rst(three_variants.table, three_variants.errors, next_runs=line)
    import html as markup

    html = publish_parts(page, writer="html", settings_overrides={"halt_level": 2})["html_body"]
    text = markup.unescape(re.sub(r"<[^>]+>", "", html))
    assert "1000 RPM, 7.6 g with a keyphasor; 975 RPM, 0 g;" in text
    assert "zeta_bup +-0.0019 -> +-0.00017" in text and "k_b +-" not in text
    assert "results/base_slope/design/design.png" in _links(html)
    assert summary.next_runs_line("x", chosen.iloc[:0], intervals) == ""


def test_first_page_says_what_the_best_variants_estimates_assume(three_variants):
    """diagnosis.yaml's intervals over the candidates (hybridtwin.diagnose.form_intervals), as the diagnosis writes
    them and read back: a parameter whose interval over the candidates is more than ASSUMED wider than its own is
    named with the candidate that widens it most and both intervals (to the digits that tell them apart), the
    widest first; one widened less is not named; none widened, no line."""
    from docutils.core import publish_parts

    from hybridtwin.diagnose.diagnosis_report import read_diagnosis_summary, write_diagnosis_summary

    rows = [{"parameter": "k_b", "estimate": 2411.6, "own_low": 2410.7, "own_high": 2412.5, "low": 2410.6,
             "high": 2412.6, "widened_by": "lower_bearing_compliance"},  # 11 % wider: not named
            {"parameter": "zeta_s", "estimate": 0.0245, "own_low": 0.02407, "own_high": 0.02494, "low": 0.01945,
             "high": 0.02494, "widened_by": "speed_damping, expansion_k6"},
            {"parameter": "zeta_bup", "estimate": 0.0138, "own_low": 0.01188, "own_high": 0.01571, "low": 0.01188,
             "high": 0.01683, "widened_by": "expansion_k6, slope_spring"}]
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        write_diagnosis_summary({"intervals_over_candidates": rows}, Path(tmp) / "diagnosis.yaml")
        diagnosis = read_diagnosis_summary(Path(tmp) / "diagnosis.yaml")
    line = summary.assumptions_line("base_slope", diagnosis)
    page = summary.landing_rst(three_variants.table, three_variants.errors, assumptions=line)
    html = publish_parts(page, writer="html", settings_overrides={"halt_level": 2})["html_body"]
    import html as markup

    text = markup.unescape(re.sub(r"<[^>]+>", "", html))
    first = "zeta_s [0.02407, 0.02494] holds if speed_damping is absent ([0.01945, 0.02494] over the candidates)"
    # digits by each interval's own width: zeta_s's is 3.5 % of its estimate (4 digits), zeta_bup's 28 % (3)
    second = "zeta_bup [0.0119, 0.0157] holds if expansion_k6 is absent ([0.0119, 0.0168] over the candidates)"
    assert first in text and second in text and text.index(first) < text.index(second)
    assert "k_b [" not in text
    assert summary.assumptions_line("base_slope", {"intervals_over_candidates": rows[:1]}) == ""
    assert summary.assumptions_line("base_slope", {}) == ""


def test_first_page_links_only_the_worst_runs_of_a_variant_failing_everywhere():
    chi2_dof = {f"r{i}": 10.0 + i for i in range(9)}
    errors = {"bad": _errors(chi2_dof, beyond=set(chi2_dof), validation=())}
    ledger = report.ledger_table([report.ledger_row("bad", "", {"n_data": 90, "dof": 80, "chi2": 1200.0},
                                                    errors["bad"])])
    table = summary.summary_table(ledger, errors, {}, {"bad": {"effects": []}})
    page = summary.landing_rst(table, errors)
    runs = [link.rsplit("/", 1)[1] for link in _links(page) if "/report/runs/" in link]
    assert runs[1:] == ["r8.png", "r7.png", "r6.png"]  # the worst run of the ledger, then the 3 worst
    assert "9 of 9 runs" in page and "and 6 more" in page and "beyond the noise (p < 1e-15)" in page


def test_summary_figure_shows_each_runs_error_per_variant(three_variants, tmp_path):
    figure = summary.plot_summary(three_variants.ledger, three_variants.errors)
    ax, ax_runs = figure.axes[:2]
    fit_line = ax.get_lines()[0]
    assert np.allclose(fit_line.get_ydata(), three_variants.ledger["chi2_dof"])
    cells = {(round(t.get_position()[1]), round(t.get_position()[0])): t for t in ax_runs.texts}
    order = summary.run_order(three_variants.errors)["run"].tolist()
    assert order[-1] == "v"  # validation runs last
    for j, (variant, errors) in enumerate(three_variants.errors.items()):
        for r in errors.itertuples():
            cell = cells[(order.index(r.run), j)]
            assert float(cell.get_text()) == pytest.approx(r.chi2_dof, rel=0.05)  # two significant digits
            assert (cell.get_fontweight() == "bold") == r.beyond_noise
    figure.savefig(tmp_path / "summary.png", dpi=30)
    assert (tmp_path / "summary.png").stat().st_size > 1000


def test_the_main_install_carries_what_the_report_command_needs():
    """`snakemake --report` needs pygments, which only the test extras pulled in (pytest requires it)."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    required = {re.split(r"[<>=!~ ;\[]", spec, maxsplit=1)[0].lower() for spec in pyproject["project"]["dependencies"]}
    assert {"snakemake", "pygments"} <= required


# --- `snakemake --report report.html` on a small run -----------------------------------------------------


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    """The loop's first step on four high-speed runs (Geometric misses the slope force: test_loop.py): the
    report before the summary is made, then after the whole workflow."""
    from test_loop import LOOP
    from test_loop import RUNS as LOOP_RUNS
    from test_workflow import _copy_workflow, _snakemake

    work = _copy_workflow(tmp_path_factory.mktemp("reported"), LOOP_RUNS, yaml.safe_dump(LOOP, sort_keys=False))
    early_targets = ["results/geometric/diagnosis.tsv", "results/ledger.tsv"]
    early = _snakemake(work, *early_targets)
    assert early.returncode == 0, early.stdout[-3000:] + early.stderr[-3000:]
    runs = {}
    for name, targets in (("early", early_targets), ("final", [])):
        if name == "final":
            done = _snakemake(work)
            assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        # a report of part of the workflow names its targets (Snakemake wants every report file of the DAG)
        command = subprocess.run([sys.executable, "-m", "snakemake", "--report", f"{name}.html", *targets],
                                 cwd=work, capture_output=True, text=True, check=False)
        assert command.returncode == 0, command.stdout[-3000:] + command.stderr[-3000:]
        runs[name] = (work / f"{name}.html").read_text()
    return work, runs


def _embedded(html: str, name: str):
    """A JSON value the report's page defines as ``var name = ...;``."""
    return json.loads(re.search(rf'^\s*var {name} = ([{{\["].*);$', html, re.MULTILINE).group(1))


def test_report_opens_on_the_ledger_the_recommendation_and_the_failing_runs(reported):
    work, pages = reported
    html = pages["final"]
    first, results = _embedded(html, "workflow_desc"), _embedded(html, "results")
    text = htmllib.unescape(re.sub(r"<[^>]+>", "", first))
    assert "System Message" not in first  # docutils reports its problems inside the page
    ledger = pd.read_csv(work / "results" / "ledger.tsv", sep="\t").set_index("variant")
    diagnosis = yaml.safe_load((work / "results" / "geometric" / "diagnosis.yaml").read_text())
    assert f"chi^2/dof {ledger.loc['geometric', 'chi2_dof']:.3g}" in text
    assert summary.verdict(diagnosis["conclusion"]) in text and summary.verdict(diagnosis["conclusion"]).startswith("add")
    assert diagnosis["recommended_variant"]["name"] in text
    # every link of the first page opens a file of the report; the worst run's figure among them
    links = _links(first)
    assert links and set(links) <= set(results), sorted(set(links) - set(results))
    errors = pd.read_csv(work / "results" / "geometric" / "report" / "errors.tsv", sep="\t")
    worst = errors.loc[errors["chi2_dof"].idxmax(), "run"]
    assert f"results/geometric/report/runs/{worst}.png" in links
    assert {"results/summary.png", "results/summary.tsv"} <= set(results)
    # the interactive figures beside their PNGs (hybridtwin.report.interactive), in the report as one page
    assert "results/interactive.html" in results


def _embedded_file(entry: dict) -> bytes:
    """The bytes of a file the report embeds (its data URI: "data:<mime>;...;base64,<the file>")."""
    return base64.b64decode(entry["data_uri"].split("base64,", 1)[1])


def test_the_report_embeds_plotly_once_in_one_page_of_every_interactive_figure(reported):
    """Issue 55: the report embeds plotly.js once (packed), in results/interactive.html, which holds every interactive
    figure (the summary's, and each variant's six), read back equal to its own page's; no figure's own page is
    embedded.
    The report's size: a few MB besides that one page (the PNGs and tables of the small run)."""
    work, runs = reported
    report_html = runs["final"]
    results = _embedded(report_html, "results")
    marker = interactive_pages.packed_plotly_js()[:2000].encode()  # plotly.js as a page stores it, packed
    holders = [path for path, entry in results.items() if marker in _embedded_file(entry)]
    assert holders == ["results/interactive.html"]
    assert interactive_pages.read_plotly_js(work / "results" / "interactive.html") == interactive_pages.plotly_js()
    assert not [path for path in results if path.endswith(".html") and path != "results/interactive.html"]
    gallery = interactive_pages.read_gallery(work / "results" / "interactive.html")
    figures = {"runs": "report/runs.html", "bode": "report/bode.html", "polar": "report/polar.html",
               "campbell": "report/campbell.html", "mode_shapes": "report/mode_shapes.html",
               "diagnosis": "diagnosis.html"}
    expected = {"summary": work / "results" / "summary.html"} | {
        f"geometric/{name}": work / "results" / "geometric" / path for name, path in figures.items()}
    assert {key for key, _, _ in gallery} >= set(expected)
    for key, _, fig in gallery:
        if key in expected:
            own = interactive_pages.read_figure(expected[key])
            assert json.loads(fig.to_json()) == json.loads(own.to_json()), key
    page = len(results["results/interactive.html"]["data_uri"])
    # plotly.js once, packed (base64 of gzip: about 2 MB), and the figures' data packed; the report's base64: 4/3
    assert page < (len(interactive_pages.packed_plotly_js()) + 2e6) * 4 / 3
    assert len(report_html) - page < 20e6


def test_report_made_before_the_end_says_so_instead_of_failing(reported):
    _, pages = reported
    first = _embedded(pages["early"], "workflow_desc")
    assert "is not there yet" in first and "System Message" not in first
    assert "results/summary.png" not in _embedded(pages["early"], "results")


@pytest.mark.parametrize("harmonics, panels", [(1, ["1X at the sensor"]),
                                               (3, ["1X at the sensor", "3X at the sensor"])])
def test_whitebox_sweep_figure_has_a_panel_per_harmonic_it_can_draw(harmonics, panels):
    """With H = 1 the sweep table has no 3X: one panel, not a blank half figure (probe)."""
    from hybridtwin.plots import plot_sweep

    rows = []
    for mass in (0.0, 14.8):
        for rpm in (400.0, 600.0, 800.0):
            row = {"run": f"r{rpm:g}_{mass:g}", "rpm": rpm, "eccentric_mass_g": mass, "success": True}
            for h in range(1, harmonics + 1):
                row |= {f"U{h}_re_m": 1e-4 * h, f"U{h}_im_m": 0.0, f"V{h}_re_m": 0.0, f"V{h}_im_m": -1e-4 * h}
            rows.append(row)
    fig = plot_sweep(pd.DataFrame(rows), "v")
    assert [ax.get_title() for ax in fig.axes if ax.get_visible()] == panels
    assert all(ax.lines for ax in fig.axes)
    report_plots.plt.close(fig)


def test_error_map_without_validation_runs_says_so_and_draws_no_empty_legend_entry():
    """A plan with fit runs only: the title says 'no validation run' (it printed 'validation runs nan (error nan
    %)') and the legend of the speed panel has no validation entry (probe)."""
    errors = _errors({"a": 1.1, "b": 2.0, "c": 0.9}, beyond={"b"}, validation=())
    fig = report_plots.plot_error_map(errors, "fit only")
    assert "no validation run" in fig._suptitle.get_text() and "nan" not in fig._suptitle.get_text()
    assert "validation" not in [t.get_text() for t in fig.axes[1].get_legend().get_texts()]  # the speed panel
    report_plots.plt.close(fig)
    with_v = report_plots.plot_error_map(_errors({"a": 1.1, "v": 3.0}, beyond=set()), "with one")
    assert "validation runs 3" in with_v._suptitle.get_text()
    report_plots.plt.close(with_v)


def test_first_page_counts_one_run_in_the_singular():
    errors = {"one": _errors({"a": 1.0}, beyond=set(), validation=())}
    ledger = report.ledger_table([report.ledger_row("one", "", {"n_data": 12, "dof": 6, "chi2": 6.0},
                                                    errors["one"])])
    page = summary.landing_rst(summary.summary_table(ledger, errors, {}, {"one": {"effects": []}}), errors)
    assert "on its 1 fit run (1 = the noise floor)" in page


def test_a_figure_saved_for_the_report_keeps_its_picture_in_256_colours(tmp_path):
    """``plots.save_png`` (every workflow PNG): a palette PNG of at most 256 colours, the same size in pixels as
    matplotlib's own render and the same picture to the eye (mean error below 2 of 255 levels; 99.9 % of the
    pixels' channels within 48 levels: only antialiased edges move), at most half the bytes, and the same bytes
    each time (the workflow's reruns compare results)."""
    from PIL import Image

    from hybridtwin.plots import PNG_COLOURS, save_png

    fig, ax = report_plots.plt.subplots(figsize=(8, 4))
    x = np.linspace(0.0, 10.0, 400)
    for k in range(6):
        ax.plot(x, np.sin(x + k) * (1 + k / 5), label=f"run {k}", lw=1.2)
    ax.fill_between(x, -0.3, 0.3, color="0.85")
    ax.legend(fontsize=7)
    ax.set_title("six runs, a band, text")
    full = io.BytesIO()
    fig.savefig(full, format="png", dpi=100)
    save_png(fig, tmp_path / "a.png", dpi=100)
    save_png(fig, tmp_path / "b.png", dpi=100)
    report_plots.plt.close(fig)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    saved, reference = Image.open(tmp_path / "a.png"), Image.open(io.BytesIO(full.getvalue()))
    assert saved.mode == "P" and len(saved.getcolors(maxcolors=1024)) <= PNG_COLOURS
    assert saved.size == reference.size
    error = np.abs(np.asarray(saved.convert("RGB"), float) - np.asarray(reference.convert("RGB"), float))
    assert error.mean() < 2.0 and np.percentile(error, 99.9) <= 48, (error.mean(), np.percentile(error, 99.9))
    assert (tmp_path / "a.png").stat().st_size < len(full.getvalue()) / 2
