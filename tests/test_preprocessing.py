"""Preprocessing recovers what the virtual rig put into its records (speed, harmonics, offsets) within the
uncertainty it states, with and without a keyphasor, and a phase-aligned comparison ignores the nuisances."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.data.measurements import read_runs
from hybridtwin.data.records import Record, read_record
from hybridtwin.data.plausibility import LINE_SIGNIFICANCE, SIGNIFICANCE, dominant_rpm
from hybridtwin.data.preprocessing import (
    PhaseOrigin, SpeedEstimate, analyse_record, fit_phase, order_analysis, phase_aligned_residuals, phase_origin,
    preprocess_run, quantisation_sigma, waveforms,
)
from hybridtwin.rig.rig import Imperfections, RigSpec, generate

H = 5
PLAN = pd.DataFrame({
    "run": ["r350", "r650", "r1000", "v900"], "rpm": [350.0, 650.0, 1000.0, 900.0],
    "eccentric_mass_g": [25.9, 14.8, 0.0, 7.6], "role": ["fit", "fit", "fit", "validate"],
})


def _generate(folder, keyphasor):
    # the default truth (Geometric + slope spring) and imperfections, 3 s records
    spec = RigSpec(imperfections=Imperfections(duration_s=3.0, keyphasor=keyphasor), seed=11, harmonics=H)
    truth = generate(PLAN, spec, folder)
    runs = read_runs(folder / "runs.tsv")
    analyses = [analyse_record(read_record(r), rpm, H) for r, rpm in zip(runs["record"], runs["rpm"])]
    return truth, analyses


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return _generate(tmp_path_factory.mktemp("plain"), keyphasor=False)


@pytest.fixture(scope="module")
def with_keyphasor(tmp_path_factory):
    return _generate(tmp_path_factory.mktemp("keyphasor"), keyphasor=True)


def truth_harmonics(row: pd.Series) -> np.ndarray:
    """(2, H+1) truth harmonics in the model frame (t = 0 with the unbalance on +x)."""
    return np.array([[row[f"{c}{h}_re_m"] + 1j * row[f"{c}{h}_im_m"] for h in range(H + 1)] for c in "xy"])


def in_record_frame(row: pd.Series, origin_s: float) -> np.ndarray:
    """The truth as the record shows it, phases referred to record time ``origin_s``, offsets in h = 0."""
    angle = 2 * np.pi * row["rpm_true"] / 60 * origin_s + row["phase_origin_rad"]
    X = truth_harmonics(row) * np.exp(1j * np.arange(H + 1) * angle)
    X[:, 0] += [row["offset_x_m"], row["offset_y_m"]]
    return X


def z_scores(estimate: np.ndarray, truth: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    z = (estimate - truth) / sigma
    return np.concatenate([z.real.ravel(), z.imag.ravel()])


# Tolerances. The estimates are means over K = 17..50 revolutions and sigma comes from the revolution scatter,
# so (estimate - truth) / sigma is close to standard normal: |z| < 4 (a 6e-5 two-sided chance per value, for
# ~100 values) catches a bias or an underestimated sigma; 0.5 < mean z^2 < 2 (mean of ~100 chi^2_1 values:
# 1 +- 0.14) also catches a sigma that is too large, which |z| < 4 alone would not.


def test_harmonics_and_offsets_recovered_within_the_stated_uncertainty(plain):
    truth, analyses = plain
    z = np.concatenate([z_scores(a.orders.harmonics, in_record_frame(row, a.origin.time_s), a.orders.sigma)
                        for a, (_, row) in zip(analyses, truth.iterrows())])
    assert z.size == len(PLAN) * 2 * (H + 1) * 2
    assert np.abs(z).max() < 4.0
    assert 0.5 < np.mean(z**2) < 2.0
    for a in analyses:  # sigma is about noise * sqrt(2 / samples): 0.05 mm * sqrt(2 / 6000) ~ 1 um
        assert np.all(a.orders.sigma[:, 1] < 3e-6) and np.all(a.orders.sigma[:, 1] > 3e-7)


def test_true_speed_recovered_within_its_uncertainty(plain):
    truth, analyses = plain
    z = np.array([(a.speed.rpm - row["rpm_true"]) / a.speed.sigma_rpm for a, (_, row) in zip(analyses,
                                                                                            truth.iterrows())])
    assert np.abs(z).max() < 4.0
    offset = np.abs(truth["rpm_true"] - truth["rpm"]).to_numpy()
    sigma = np.array([a.speed.sigma_rpm for a in analyses])
    # the rig's speed error (0.1 % rms) is resolved: nominal speed is far outside the estimate's uncertainty
    assert np.all(sigma < 1e-4 * truth["rpm"].to_numpy()) and np.median(offset / sigma) > 10


def test_speed_of_a_long_record_found_in_bounded_memory():
    """A 60 s record at 2 kHz (120 000 samples; the speed search's grid then has 481 frequencies): the search
    works on blocks of the (frequency x sample) matrices, not whole ones (481 x 120 000 complex, 0.9 GB each,
    two at once: a 60 s record at 10 kHz needed 9 GB and died). Reference: the record's own speed, a sine
    of known frequency with noise; the estimate within 4 of its stated sigma (as the rig records above)."""
    import tracemalloc

    from hybridtwin.data.preprocessing import refine_speed

    rng = np.random.default_rng(3)
    rpm_true, fs, duration = 603.7, 2000.0, 60.0
    t = np.arange(int(fs * duration)) / fs
    w = 2 * np.pi * rpm_true / 60
    x = 5e-4 * np.cos(w * t + 0.3) + 2e-5 * np.cos(2 * w * t) + rng.normal(0, 5e-5, t.size)
    y = 4e-4 * np.sin(w * t + 0.3) + rng.normal(0, 5e-5, t.size)
    record = Record(Path("long.csv"), t, {"x": x, "y": y}, None, "mm")
    tracemalloc.start()
    estimate = refine_speed(record, 600.0, harmonics=H)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert abs(estimate.rpm - rpm_true) < 4 * estimate.sigma_rpm
    assert peak < 300e6  # blocks of 16 MiB and the record's few-MB arrays; 1.8 GB before


def test_noise_level_and_whole_revolutions(plain):
    truth, analyses = plain
    for a, (_, row) in zip(analyses, truth.iterrows()):
        # residual std estimates the rig's 0.05 mm noise from >= 6000 samples: +-3 % covers it (sd 0.9 %)
        np.testing.assert_allclose(a.orders.noise_m, [row["noise_x_m"], row["noise_y_m"]], rtol=0.03)
        assert a.orders.n_revolutions == int(3.0 * row["rpm_true"] / 60)  # every whole revolution, none more
        assert a.origin.source == "arbitrary"


@pytest.mark.parametrize("rpm, marks", [(700.0, 40), (350.0, 23), (1000.0, 66)])
def test_keyphasor_origin_sigma_is_the_rms_error_of_rounded_marks(rpm, marks):
    """quantisation_sigma against a Monte Carlo of the estimator itself: events at u + k T / dt samples
    (u random), marks rounded to the 2 kHz grid, the origin from numpy's polyfit. 4000 draws give the RMS
    to about 1.1 % (1 / sqrt(2 n)), so 5 % is a 4-sigma tolerance."""
    dt, period = 5e-4, 60.0 / rpm
    k = np.arange(marks)
    k_c = marks // 2
    weights = 1.0 / marks + (k_c - k.mean()) * (k - k.mean()) / ((k - k.mean()) ** 2).sum()
    rng = np.random.default_rng(3)
    errors = []
    for u in rng.uniform(0, 1, 4000):
        events = u + k * period / dt  # [samples]
        slope, intercept = np.polyfit(k, np.round(events) * dt, 1)
        errors.append(intercept + slope * k_c - events[k_c] * dt)
    reference = np.sqrt(np.mean(np.square(errors)))
    assert quantisation_sigma(weights, k, period / dt, dt) == pytest.approx(reference, rel=0.05)


def test_keyphasor_pulses_wider_than_a_sample_are_one_mark_each():
    """A record made in memory whose keyphasor is high for 3 samples per turn: phase_origin takes the rising edges
    (the first sample of each pulse), the origin of one-sample marks there, exactly; before, the second sample of
    the first pulse was "two marks within one revolution"."""
    fs, rpm = 2000.0, 610.0
    t = np.arange(4000) / fs
    angle = 2 * np.pi * rpm / 60 * t
    x, y = 1e-3 * np.cos(angle), 1e-3 * np.sin(angle)
    edges = np.ceil(np.arange(21) * 60 / rpm * fs - 1e-9).astype(int)
    single, wide = np.zeros(t.size, bool), np.zeros(t.size, bool)
    single[edges] = True
    for k in range(3):
        wide[edges + k] = True
    speed = SpeedEstimate(rpm, 0.0)
    origin = phase_origin(Record.xy("wide.csv", t, x, y, wide), speed)
    assert origin == phase_origin(Record.xy("single.csv", t, x, y, single), speed)
    assert origin.source == "keyphasor" and origin.n_marks == 21


def test_keyphasor_gives_absolute_phases(plain, with_keyphasor):
    truth, analyses = with_keyphasor
    z = np.concatenate([z_scores(a.orders.harmonics[:, 1:], truth_harmonics(row)[:, 1:], a.orders.sigma[:, 1:])
                        for a, (_, row) in zip(analyses, truth.iterrows())])
    assert np.abs(z).max() < 4.0 and 0.5 < np.mean(z**2) < 2.0  # model frame directly, no phase fitted
    for a, (_, row) in zip(analyses, truth.iterrows()):
        assert a.origin.source == "keyphasor"
        # marks on the nearest sample: each mark's error lies in +-dt/2, so the least-squares period over K marks
        # errs by at most sum|k - mean k| (dt/2) / sum (k - mean k)^2 ~ 1.5 dt / K (a hard bound: near-integer
        # T/dt makes the errors correlated, and the statistical dt / sqrt(K^3) would be too optimistic)
        K, period = a.origin.n_marks, 60 / row["rpm_true"]
        assert 0 < abs(a.origin.rpm_keyphasor / row["rpm_true"] - 1) < 1.5 * 5e-4 / (K * period)
    # without a keyphasor the same comparison fails: the phase origin is random (a nuisance)
    truth_plain, plain_analyses = plain
    misfit = [np.abs(z_scores(a.orders.harmonics[:, 1:2], truth_harmonics(row)[:, 1:2], a.orders.sigma[:, 1:2]))
              for a, (_, row) in zip(plain_analyses, truth_plain.iterrows())]
    assert np.median(np.concatenate(misfit)) > 20


def test_phase_aligned_comparison_ignores_time_origin_and_offsets(plain):
    truth, analyses = plain
    a, row = analyses[2], truth.iloc[2]  # 0 g at 1000 RPM: the largest response, 3X visible
    model = truth_harmonics(row)
    r, phi = phase_aligned_residuals(a.orders.harmonics, a.orders.sigma, model)
    assert np.abs(r).max() < 4.0
    expected = 2 * np.pi * row["rpm_true"] / 60 * a.origin.time_s + row["phase_origin_rad"]
    assert np.angle(np.exp(1j * (phi - expected))) == pytest.approx(0.0, abs=1e-3)  # the record's phase origin
    # the same run recorded from another instant and with other sensor offsets
    record = a.record
    cut = slice(137, None)
    shifted = Record.xy(record.path, record.time_s[cut] - record.time_s[137], record.x_m[cut] + 2e-4,
                        record.y_m[cut] - 1e-4, None, record.unit)
    b = analyse_record(shifted, row["rpm"], H)
    r_b, phi_b = phase_aligned_residuals(b.orders.harmonics, b.orders.sigma, model)
    assert np.abs(r_b).max() < 4.0 and phi_b != pytest.approx(phi, abs=1e-2)  # a different nuisance phase
    np.testing.assert_allclose(np.abs(b.orders.harmonics[:, 1:]), np.abs(a.orders.harmonics[:, 1:]),
                               atol=4 * a.orders.sigma[:, 1:].max())
    assert b.orders.harmonics[0, 0].real - a.orders.harmonics[0, 0].real == pytest.approx(2e-4, abs=1e-5)


def test_fit_phase_is_exact_on_a_rotated_copy():
    rng = np.random.default_rng(5)
    model = rng.normal(size=(2, H + 1)) + 1j * rng.normal(size=(2, H + 1))
    for phi in (0.3, 2.9, 5.5):
        measured = model * np.exp(1j * np.arange(H + 1) * phi)
        assert fit_phase(measured, model) == pytest.approx(phi, abs=1e-8)


def test_per_run_table_and_two_cycle_waveforms(plain, tmp_path):
    truth, analyses = plain
    a = analyses[1]
    wave = waveforms(a)
    period = 60 / a.speed.rpm
    assert list(wave.columns) == ["time_s", "angle_rad", "x_m", "y_m", "x_raw_m", "y_raw_m"]
    assert wave["time_s"].iloc[0] >= 0 and wave["time_s"].iloc[-1] < 2 * period
    assert len(wave) == pytest.approx(2 * period * 2000, abs=1)
    # the clean waveform is the raw one without noise: their difference has the noise's std (+-15 %, ~370 samples)
    np.testing.assert_allclose((wave["x_raw_m"] - wave["x_m"]).std(), truth["noise_x_m"].iloc[1], rtol=0.15)
    sheet = read_runs(a.record.path.parents[1] / "runs.tsv")
    table, _ = preprocess_run(sheet.iloc[1].to_dict(), H)
    assert len(table) == 1 and table["run"].iloc[0] == "r650" and table["usable"].iloc[0]
    for column in ("rpm_true", "rpm_true_sigma", "x1_re_m", "x1_im_m", "x1_sigma_m", "y5_amp_m", "noise_y_m",
                   "offset_x_m", "phase_reference", "eccentric_mass_g", "role"):
        assert column in table
    assert table["x1_re_m"].iloc[0] == pytest.approx(a.orders.harmonics[0, 1].real)
    # the sheet's own columns are carried through, also one named like a column of the analysis (kept apart)
    entry = sheet.iloc[1].to_dict() | {"note": "first try", "usable": "maybe", "operator": "AB"}
    table, _ = preprocess_run(entry, H)
    assert table["note"].iloc[0] == "ok" and bool(table["usable"].iloc[0])
    assert (table["sheet_note"].iloc[0], table["sheet_usable"].iloc[0], table["operator"].iloc[0]) == (
        "first try", "maybe", "AB")
    # a sheet column named record (the name of the resolved record path read_runs adds) is kept as sheet_record
    own = pd.read_csv(a.record.path.parents[1] / "runs.tsv", sep="\t", dtype=str, keep_default_na=False)
    own["record"] = [f"take {i}" for i in range(len(own))]
    own.to_csv(tmp_path / "runs.tsv", sep="\t", index=False)
    for name in own["path"]:
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_bytes((a.record.path.parents[1] / name).read_bytes())
    sheet = read_runs(tmp_path / "runs.tsv")
    assert sheet["sheet_record"].tolist() == own["record"].tolist()
    assert Path(sheet["record"].iloc[1]) == tmp_path / own["path"].iloc[1]
    table, _ = preprocess_run(sheet.iloc[1].to_dict(), H)
    assert table["sheet_record"].iloc[0] == "take 1" and "record" not in table


# --- plausibility (hybridtwin.data.plausibility, docs/data-checks.md) -------------------------


def test_rig_records_raise_no_flag_and_their_strongest_line_is_the_true_speed(plain, with_keyphasor):
    for truth, analyses in (plain, with_keyphasor):
        for a, (_, row) in zip(analyses, truth.iterrows()):
            assert a.usable and a.findings == [] and a.note == "ok"
            rpm, contrast = dominant_rpm(a.record)
            # parabolic peak of a Hann-windowed, 8x zero-padded spectrum: on the 22 bundled records it lies within
            # 0.0012 frequency bins (60 / T RPM) of the true speed; 0.01 bin leaves room, a bin-sized bias fails
            assert abs(rpm - row["rpm_true"]) < 0.01 * 60 / a.record.duration_s
            assert contrast > 10 * LINE_SIGNIFICANCE  # judged (the weakest, 0.27 mm at 350 RPM: 3e4)


def test_1x_significance_of_noise_alone_follows_its_f_distribution():
    """|X_1|^2 / sigma^2 = 2 F(2, 2K - 2) for noise alone (sigma from the scatter of K revolutions), so
    P(|X_1| / sigma > r) = (1 + r^2 / (2K - 2))^-(K - 1). 400 noise-only channels (K = 20): the count above
    r = 2 is binomial, expected 59.6 +- 7.1, checked to 4 standard deviations; above the flag's threshold 5 the
    chance is 6.7e-5 per channel (4e-6 as K grows), so none of them is taken for a response."""
    rng = np.random.default_rng(7)
    rpm, fs, K = 600.0, 2000.0, 20
    t = np.arange(int(K * 60 / rpm * fs)) / fs
    ratios = []
    for _ in range(200):
        record = Record.xy(Path("noise.csv"), t, *(5e-5 * rng.standard_normal((2, t.size))), None, "mm")
        orders = order_analysis(record, SpeedEstimate(rpm, 0.0), PhaseOrigin(0.0, 0.0, "arbitrary"), 5)
        assert orders.n_revolutions == K
        ratios += list(np.abs(orders.harmonics[:, 1]) / orders.sigma[:, 1])
    ratios = np.array(ratios)
    expected = len(ratios) * (1 + 4 / (2 * K - 2)) ** -(K - 1)
    spread = np.sqrt(expected * (1 - expected / len(ratios)))
    assert abs((ratios > 2).sum() - expected) < 4 * spread
    assert (ratios >= SIGNIFICANCE).sum() == 0
