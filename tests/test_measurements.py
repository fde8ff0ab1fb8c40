"""Reading and checking measured runs: every bad-input case fails the way it should, naming file and problem."""

import dataclasses
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.cli import main
from hybridtwin.data.measurements import DataError, DataWarning, check_coverage, read_runs, sheet_entry
from hybridtwin.data.records import SATURATED_SAMPLES, Record, check_length, detect_saturation, read_record
from hybridtwin.data.preprocessing import analyse_record

RPM = 600.0


def write_record(path: Path, rpm: float = RPM, seconds: float = 2.0, fs: float = 2000.0, amplitude_mm: float = 1.0,
                 noise_mm: float = 0.05, unit: str = "mm", seed: int = 0) -> Path:
    """A clean synthetic record: 1X orbit + 3X + offset + noise (no model solve needed here)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    angle = 2 * np.pi * rpm / 60 * t
    x = amplitude_mm * np.cos(angle) + 0.02 * np.cos(3 * angle) + 0.3 + noise_mm * rng.standard_normal(t.size)
    y = amplitude_mm * np.sin(angle) - 0.1 + noise_mm * rng.standard_normal(t.size)
    scale = 1.0 if unit == "mm" else 1e-3
    table = pd.DataFrame({"time_s": t, f"x_{unit}": x * scale, f"y_{unit}": y * scale})
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False, float_format="%.8f")
    return path


def edit_line(path: Path, line: int, column: int, value: str) -> None:
    """Replace one cell (1-based line number as in the messages, 0-based column)."""
    lines = path.read_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[column] = value
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def write_sheet(folder: Path, text: str) -> Path:
    path = folder / "runs.tsv"
    path.write_text(text.replace("|", "\t"))
    return path


@pytest.fixture
def dataset(tmp_path):
    """A valid two-run data set."""
    write_record(tmp_path / "records" / "a.csv")
    write_record(tmp_path / "records" / "b.csv", rpm=700.0, seed=1)
    sheet = write_sheet(tmp_path, "run|rpm|eccentric_mass_g|path|role|operator\n"
                                  "a|600|14.8|records/a.csv|fit|ann\nb|700|7.6|records/b.csv|validate|bob\n")
    return sheet


# --- the runs sheet ---------------------------------------------------------------------


def test_valid_sheet_is_read_with_records_resolved_and_extra_columns_kept(dataset):
    runs = read_runs(dataset)
    assert runs["run"].tolist() == ["a", "b"]
    assert runs["rpm"].tolist() == [600.0, 700.0]
    assert runs["eccentric_mass_g"].tolist() == [14.8, 7.6]
    assert runs["role"].tolist() == ["fit", "validate"]
    assert runs["operator"].tolist() == ["ann", "bob"]  # extra columns carried through
    assert Path(runs["record"].iloc[0]) == dataset.parent / "records" / "a.csv"  # relative to the sheet's folder
    entry = sheet_entry(dataset, "b")
    assert entry["eccentric_mass_g"] == 7.6 and entry["rpm"] == 700.0


def test_unknown_mass_is_nan_for_the_library_but_an_error_for_the_workflow(dataset):
    dataset.write_text(dataset.read_text().replace("|7.6|".replace("|", "\t"), "\t\t"))
    assert np.isnan(read_runs(dataset)["eccentric_mass_g"].iloc[1])  # the library reader: unknown
    with pytest.raises(DataError, match=r"column eccentric_mass_g: missing value \(empty or NaN; the libraries are "
                                        r"built per speed and eccentric mass: write 0 for no added mass\) on 1 "
                                        r"line\(s\): line 3"):
        read_runs(dataset, require_mass=True)  # what check-data and the workflow read
    with pytest.raises(DataError, match="line 3"):
        sheet_entry(dataset, "b")


def test_sheet_with_misnamed_column(tmp_path):
    sheet = write_sheet(tmp_path, "run|speed_rpm|eccentric_mass_g|path\na|600|0|a.csv\n")
    with pytest.raises(DataError) as err:
        read_runs(sheet, check_files=False)
    message = str(err.value)
    assert str(sheet) in message and "line 1" in message and "'rpm'" in message and "'speed_rpm'" in message


def test_sheet_with_duplicate_run_ids_names_both_lines(tmp_path):
    sheet = write_sheet(tmp_path, "run|rpm|eccentric_mass_g|path\na|600|0|a.csv\nb|650|0|b.csv\na|700|0|c.csv\n")
    with pytest.raises(DataError, match=r"lines 2, 4, column run: duplicate run id 'a'"):
        read_runs(sheet, check_files=False)


def test_sheet_with_missing_record_names_line_and_path(dataset):
    (dataset.parent / "records" / "b.csv").unlink()
    with pytest.raises(DataError) as err:
        read_runs(dataset)
    assert "line 3, column path" in str(err.value) and "records/b.csv" in str(err.value)
    assert "does not exist" in str(err.value) and str(dataset) in str(err.value)


def test_sheet_lists_every_bad_cell_at_once(tmp_path):
    sheet = write_sheet(tmp_path, "run|rpm|eccentric_mass_g|path|role\n"
                                  "a b|600|0|a.csv|fit\nc|fast|0|c.csv|fit\nd|-5|x|d.csv|test\ne|700|0||fit\n")
    with pytest.raises(DataError) as err:
        read_runs(sheet, check_files=False)
    message = str(err.value)
    assert "problems" in message  # all of them, not just the first
    assert "line 2, column run: 'a b' is not a valid run id" in message
    assert "column rpm: not a number on 1 line(s): line 3 ('fast')" in message
    assert "line 4, column rpm: -5 is not a positive speed" in message
    assert "column eccentric_mass_g: not a number on 1 line(s): line 4 ('x')" in message
    assert "line 4, column role: 'test' is not a role" in message
    assert "line 5, column path: empty" in message


def test_speeds_and_masses_outside_the_covered_ranges(dataset):
    runs = read_runs(dataset)
    check_coverage(runs, rpm_range=(350, 1000), mass_range_g=None)  # covered: no error
    with pytest.raises(DataError) as err:
        check_coverage(runs, rpm_range=(350, 650), mass_range_g=(0, 10), source=dataset)
    message = str(err.value)
    assert str(dataset) in message
    assert "line 3, run 'b': speed 700 RPM is outside the covered range [350, 650] RPM" in message
    assert "line 2, run 'a': eccentric mass 14.8 g is outside the covered range [0, 10] g" in message
    runs.loc[1, "eccentric_mass_g"] = np.nan
    with pytest.raises(DataError, match="line 3, run 'b': eccentric mass unknown"):  # cannot be shown covered
        check_coverage(runs, mass_range_g=(0, 10))


def test_check_data_cli_exit_status_and_coverage(dataset, capsys):
    assert main(["check-data", str(dataset)]) == 0
    out, err = capsys.readouterr()
    assert "rpm_true" in out and "x1X_mm" in out and "2 ok" in err
    assert main(["check-data", str(dataset), "--rpm-range", "350", "650"]) == 1
    out, err = capsys.readouterr()
    assert "error" in err and "speed 700 RPM is outside the covered range" in err


# --- a record ---------------------------------------------------------------------------


def test_valid_record_in_mm_and_in_metres_read_in_si(tmp_path):
    in_mm = read_record(write_record(tmp_path / "mm.csv"))
    in_m = read_record(write_record(tmp_path / "m.csv", unit="m"))
    assert in_mm.unit == "mm" and in_m.unit == "m"
    assert in_mm.n_samples == 4000 and in_mm.sample_rate_hz == pytest.approx(2000.0)
    np.testing.assert_allclose(in_mm.x_m, in_m.x_m, rtol=0, atol=1e-8)  # same signal; 1e-8 m: the m file resolution
    assert 0.5e-3 < in_mm.x_m.max() < 2e-3  # 1 mm amplitude + 0.3 mm offset, read as metres
    assert in_mm.keyphasor is None


@pytest.mark.parametrize("header, expected", [
    ("time,x_mm,y_mm", "missing column(s) 'time_s' (found 'time': misnamed?)"),
    ("time_s,x_in,y_in", "unknown unit 'in' (use x_mm or x_m)"),
    ("time_s,x_mm,yy_mm", "missing column y_mm (or y_m) (found 'yy_mm': misnamed?)"),
    ("time_s,x_mm,x_m,y_mm", "more than one x displacement column"),
])
def test_record_with_misnamed_columns_or_unknown_units(tmp_path, header, expected):
    path = write_record(tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    body = lines[1:] if header.count(",") == 2 else [line + ",0" for line in lines[1:]]
    path.write_text("\n".join([header] + body) + "\n")
    with pytest.raises(DataError) as err:
        read_record(path)
    assert str(path) in str(err.value) and "line 1 (header)" in str(err.value) and expected in str(err.value)


def test_record_with_non_numeric_cell_names_line_and_column(tmp_path):
    path = write_record(tmp_path / "r.csv")
    edit_line(path, 101, 1, "1.2.3")
    with pytest.raises(DataError, match=r"r\.csv: column x_mm: not a number on 1 line\(s\): line 101 \('1\.2\.3'\)"):
        read_record(path)


@pytest.mark.parametrize("cell", ["", "NaN", "nan"])
def test_record_with_nan_or_empty_cell(tmp_path, cell):
    path = write_record(tmp_path / "r.csv")
    edit_line(path, 57, 2, cell)
    with pytest.raises(DataError, match=r"column y_mm: missing value \(empty or NaN\) on 1 line\(s\): line 57"):
        read_record(path)


def test_record_with_blank_lines_skips_them_and_keeps_line_numbers(tmp_path):
    path = write_record(tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:9] + ["", " , ,"] + lines[9:]) + "\n\n\n")  # blank lines 10, 11 and at the end
    assert read_record(path).n_samples == 4000  # a blank line carries no sample: nothing is lost
    edit_line(path, 57, 2, "abc")  # file line 57 is sample 54 (lines 10 and 11 are blank)
    with pytest.raises(DataError, match=r"column y_mm: not a number on 1 line\(s\): line 57 \('abc'\)"):
        read_record(path)


def test_record_with_non_increasing_time(tmp_path):
    path = write_record(tmp_path / "r.csv")
    edit_line(path, 31, 0, "0.0100")  # line 31 holds t = 0.0145 s; 0.0100 s goes back in time
    with pytest.raises(DataError, match=r"column time_s: not increasing on 1 line\(s\): line 31"):
        read_record(path)


def test_record_with_a_gap(tmp_path):
    path = write_record(tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:200] + lines[210:]) + "\n")  # 10 samples missing after line 200
    with pytest.raises(DataError, match=r"column time_s: gap \(missing samples\) on 1 line\(s\): line 201 "
                                        r"\(0\.0055 s = 11\.0 steps"):
        read_record(path)


def test_record_with_non_uniform_time(tmp_path):
    path = write_record(tmp_path / "r.csv")
    edit_line(path, 500, 0, "0.24905")  # 0.2490 s + 10 % of a step: beyond the 5 % of jitter tolerated
    # the stamps need 5 decimals (0.24905): their rounding is +-5e-6 s, the tolerance 5e-6 + 5 % of 5e-4 s = 3e-5 s
    with pytest.raises(DataError, match=r"column time_s: non-uniform step \(dt 0\.0005 s, the least-squares fit "
                                        r"t0 \+ n dt; tolerance half a unit of the last decimal written, 5e-06 s, "
                                        r"plus 5 % of a step: 3e-05 s\) on 1 line\(s\): line 500 \(0\.24905 s is "
                                        r"\+5e-05 s = \+10\.0 % of a step off\)"):
        read_record(path)


def test_record_with_a_repeated_time_stamp(tmp_path):
    path = write_record(tmp_path / "r.csv")
    edit_line(path, 31, 0, "0.0140")  # line 30's time again (line 31 holds 0.0145 s): a duplicated stamp
    with pytest.raises(DataError, match=r"column time_s: not increasing on 1 line\(s\): line 31 \(0\.014 s after "
                                        r"0\.014 s\)"):
        read_record(path)


def _write_times(path: Path, times: Sequence[str]) -> None:
    """Replace the time_s column of a record by the given cells (the other cells as written)."""
    table = pd.read_csv(path, dtype=str)
    table["time_s"] = times
    table.to_csv(path, index=False)


def _harmonics(record) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        analysis = analyse_record(record, RPM)
    return analysis.orders.harmonics, analysis.orders.sigma


@pytest.mark.parametrize("fs, decimals", [(2560.0, 5), (3000.0, 4)])
def test_time_stamps_rounded_to_few_decimals_are_uniform_and_read_as_t0_plus_n_dt(tmp_path, fs, decimals):
    """An analyser's 2560 Hz written with 5 decimals (steps 0.00039 and 0.0004 s), 3000 Hz with 4 (0.0003 and
    0.0004 s): uniform sampling, the steps differ by the stamps' rounding only. They were rejected as non-uniform
    (1 % of the median step); now the record is read with the least-squares base t0 + n dt in their place."""
    path = write_record(tmp_path / "r.csv", fs=fs)
    exact = np.arange(int(2.0 * fs)) / fs
    _write_times(path, [f"{t:.{decimals}f}" for t in exact])
    record = read_record(path)
    # each stamp is rounded by at most q / 2 (q = 10^-decimals); were the roundings independent (sigma q / sqrt(12)),
    # the fitted line would err by about 2 sigma / sqrt(N) at its ends: 2 q / sqrt(N) is 3.5 times that (measured:
    # 8e-9 s and 1.1e-8 s, the roundings of n / fs being periodic in n, against the bounds 2.8e-7 s and 2.6e-6 s)
    q = 10.0**-decimals
    bound = 2 * q / np.sqrt(exact.size)
    assert np.abs(record.time_s - exact).max() < bound
    assert record.sample_rate_hz == pytest.approx(fs, rel=2 * bound / (exact[-1] - exact[0]))  # ends off by < bound
    # what the analysis sees: the harmonics of the exact base. A base error dt_max rotates hX by h Omega dt_max:
    # at most 5 x 62.8 rad/s x 2.6e-6 s = 8e-4 of |X| (1X: 1 mm, 0.8 um, against sigma ~ 1 um): 1 sigma bounds it
    # (measured: 1e-7 sigma). With the rounded stamps themselves, the 3000 Hz record's median step (0.0003 s)
    # makes it turn at 667 RPM: the speed check rejects it.
    X, sigma = _harmonics(record)
    X_exact, _ = _harmonics(dataclasses.replace(record, time_s=exact))
    assert np.abs(X - X_exact)[:, 1:].max() < sigma[:, 1:].min()


@pytest.mark.parametrize("jitter", ["normal 1 us", "uniform 4 %"])
def test_time_stamp_jitter_within_5_percent_of_a_step_is_accepted(tmp_path, jitter):
    """Random timing jitter of the stamps well below a step (the probe's 1 us = 0.2 % of a step at 2 kHz, and up to
    +-4 %) is no gap and no missing sample: the record is read with the least-squares base t0 + n dt."""
    path = write_record(tmp_path / "r.csv")
    exact = np.arange(4000) / 2000.0
    rng = np.random.default_rng(5)
    if jitter == "normal 1 us":
        sigma_t = 1e-6
        error = rng.normal(0.0, sigma_t, exact.size)
    else:
        sigma_t = 0.04 * 5e-4 / np.sqrt(3.0)
        error = rng.uniform(-0.04, 0.04, exact.size) * 5e-4
    _write_times(path, [f"{t:.10f}" for t in exact + error])
    record = read_record(path)
    # independent errors of sigma_t: the fitted line errs by about 2 sigma_t / sqrt(N) at its ends; 5 times that
    assert np.abs(record.time_s - exact).max() < 5 * 2 * sigma_t / np.sqrt(exact.size)
    assert record.sample_rate_hz == pytest.approx(2000.0, rel=1e-5)


def test_time_stamp_jitter_beyond_5_percent_of_a_step_is_rejected(tmp_path):
    path = write_record(tmp_path / "r.csv")
    exact = np.arange(4000) / 2000.0
    error = np.random.default_rng(5).uniform(-0.08, 0.08, exact.size) * 5e-4  # +-8 %: about 3/8 of them beyond 5 %
    _write_times(path, [f"{t:.10f}" for t in exact + error])
    with pytest.raises(DataError, match=r"column time_s: non-uniform step \(dt 0\.0005 s.* plus 5 % of a step: "
                                        r"2\.5e-05 s\) on \d{4} line\(s\)"):
        read_record(path)


def test_record_too_short_for_a_few_revolutions(tmp_path):
    record = read_record(write_record(tmp_path / "r.csv", seconds=0.4))  # 4 revolutions at 600 RPM
    with pytest.raises(DataError, match=r"too short: 800 samples, 0\.4 s = 4\.0 revolution\(s\) at 600 RPM nominal; "
                                        r"at least 5"):
        check_length(record, RPM)
    check_length(record, 900.0)  # 6 revolutions at 900 RPM: long enough


def test_keyphasor_column_must_hold_marks(tmp_path):
    path = write_record(tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0] + ",keyphasor"] + [line + ",0" for line in lines[1:]]) + "\n")
    with pytest.raises(DataError, match="column keyphasor: no mark"):
        read_record(path)
    edit_line(path, 3, 3, "yes")
    with pytest.raises(DataError, match=r"column keyphasor: not a level of a two-level signal: 0/1 \(or 0\.0/1\.0, "
                                        r"true/false\), 0/5 V .* on 1 line\(s\): line 3 \('yes'\)"):
        read_record(path)


KEYPHASOR_RPM = 610.0  # not a divisor of 2 kHz x 60: the marks fall between samples


def _keyphasor_record(path: Path, high: str = "1", low: str = "0", width: int = 1, missed: Sequence[int] = ()
                      ) -> tuple[Path, np.ndarray]:
    """A record at KEYPHASOR_RPM with a keyphasor column: a pulse ``width`` samples wide at ``high`` from the first
    sample at or after each instant the unbalance points to +x (x = cos(Omega t)), ``low`` elsewhere; the pulses
    numbered in ``missed`` left out. Returns the path and the samples of the rising edges."""
    write_record(path, rpm=KEYPHASOR_RPM)
    period, dt = 60.0 / KEYPHASOR_RPM, 1 / 2000.0
    starts = np.ceil(np.arange(int(2.0 / period) + 1) * period / dt - 1e-9).astype(int)
    starts = np.delete(starts[starts < 4000], list(missed))
    levels = np.full(4000, low, dtype=object)
    for start in starts:
        levels[start:start + width] = high
    table = pd.read_csv(path, dtype=str)
    table["keyphasor"] = levels
    table.to_csv(path, index=False)
    return path, starts


@pytest.mark.parametrize("high, low, width", [
    ("1", "0", 1), ("1.0", "0.0", 1), ("True", "False", 1), ("true", "false", 3), ("5", "0", 1), ("5", "0", 3),
    ("4.98", "0.02", 2), ("1", "0", 4),
])
def test_any_two_level_keyphasor_is_read_as_marks_at_its_rising_edges(tmp_path, high, low, width):
    """0.0/1.0, true/false, a 0/5 V TTL signal, pulses several samples wide: a mark at the first sample of each
    high pulse; the analysis is then that of the one-sample 0/1 marks, exactly (the same marks)."""
    path, starts = _keyphasor_record(tmp_path / "r.csv", high, low, width)
    record = read_record(path)
    assert np.array_equal(np.flatnonzero(record.keyphasor), starts)
    reference = read_record(_keyphasor_record(tmp_path / "ref.csv")[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        analysis, expected = analyse_record(record, KEYPHASOR_RPM), analyse_record(reference, KEYPHASOR_RPM)
    assert analysis.origin == expected.origin and analysis.origin.n_marks == starts.size == 21
    assert np.array_equal(analysis.orders.harmonics, expected.orders.harmonics)
    # the phases are absolute: 1X of x = cos(Omega t) is real, to within the mark's lateness (at most one step,
    # Omega dt = 0.032 rad) plus its noise (sigma / |X| = 1e-3 rad; 5 sigma)
    X1 = analysis.orders.harmonics[0, 1]
    assert abs(np.angle(X1)) < 2 * np.pi * KEYPHASOR_RPM / 60 / 2000 + 5 * analysis.orders.sigma[0, 1] / abs(X1)


def test_keyphasor_missed_mark_tolerated_spurious_mark_an_error_on_its_file_lines(tmp_path):
    path, starts = _keyphasor_record(tmp_path / "r.csv", "5", "0", width=3, missed=[7])  # TTL, one mark missed
    record = read_record(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        assert analyse_record(record, KEYPHASOR_RPM).origin.n_marks == starts.size == 20
    lines = path.read_text().splitlines()
    spurious = starts[3] + 50  # a quarter turn after the fourth mark (49 samples per revolution)
    lines[spurious + 1] = lines[spurious + 1].rsplit(",", 1)[0] + ",5"
    path.write_text("\n".join(lines[:10] + [""] + lines[10:]) + "\n")  # a blank line 11: samples shift one line down
    with pytest.raises(DataError, match=rf"column keyphasor: two marks within one revolution at lines "
                                        rf"{starts[3] + 3} and {spurious + 3} \(period"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataWarning)
            analyse_record(read_record(path), KEYPHASOR_RPM)


def test_keyphasor_with_more_than_two_levels_is_an_analogue_signal_and_an_error(tmp_path):
    path = write_record(tmp_path / "r.csv")
    table = pd.read_csv(path, dtype=str)
    table["keyphasor"] = [f"{v:.3f}" for v in 2.5 + 2.5 * np.sin(2 * np.pi * 10 * np.arange(len(table)) / 2000.0)]
    table.to_csv(path, index=False)
    with pytest.raises(DataError, match=r"column keyphasor: 101 distinct levels \('2\.500' \(line 2\), '2\.579' "
                                        r"\(line 3\), '2\.657' \(line 4\), \.\.\.\), an analogue signal; a keyphasor "
                                        r"column holds a two-level signal: 0/1"):
        read_record(path)


def test_keyphasor_pulse_already_high_on_the_first_sample(tmp_path):
    from hybridtwin.data.record_columns import keyphasor_marks
    wide = np.array([1, 1, 0, 0, 0, 1, 1, 1, 0, 0, 0, 1, 1, 1, 0], bool)
    assert np.flatnonzero(keyphasor_marks(wide)).tolist() == [5, 11]  # its rising edge came before the record
    whole = np.array([1, 1, 1, 0, 0, 1, 1, 1, 0, 0, 1, 1, 1, 0], bool)
    assert np.flatnonzero(keyphasor_marks(whole)).tolist() == [0, 5, 10]  # as wide as the others: a whole pulse
    single = np.array([1, 0, 0, 0, 1, 0, 0, 0, 1, 0], bool)
    assert np.flatnonzero(keyphasor_marks(single)).tolist() == [0, 4, 8]  # one-sample marks are their own edges


def test_empty_and_missing_files(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DataError, match="empty.csv: file is empty"):
        read_record(tmp_path / "empty.csv")
    with pytest.raises(DataError, match="nowhere.csv: file does not exist"):
        read_record(tmp_path / "nowhere.csv")


# --- flat and clipped signals -----------------------------------------------------------


def _clip(path: Path, column: int, limit_mm: float) -> None:
    table = pd.read_csv(path)
    name = table.columns[column]
    table[name] = table[name].clip(-limit_mm, limit_mm)
    table.to_csv(path, index=False, float_format="%.8f")


def test_clipped_channel_is_detected_warned_and_excluded(tmp_path):
    path = write_record(tmp_path / "r.csv", amplitude_mm=2.0)
    _clip(path, 1, 1.9)  # x saturates at +1.9 mm (its positive peaks reach 2.3 mm)
    record = read_record(path)
    with pytest.warns(DataWarning, match=r"channel x is clipped at \+1\.9000 mm: \d+ samples .* flat top"):
        found = detect_saturation(record)
    assert [(f.channel, f.kind) for f in found] == [("x", "clipped")]
    assert found[0].n_flat_tops >= 15  # one flat top per revolution, 20 revolutions
    with pytest.warns(DataWarning):
        analysis = analyse_record(record, RPM)
    assert analysis.saturated and not analysis.usable and "excluded (saturated" in analysis.note


def test_noisy_unclipped_record_is_not_flagged(tmp_path):
    record = read_record(write_record(tmp_path / "r.csv", amplitude_mm=2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # any warning fails the test
        assert detect_saturation(record) == []


def test_a_quiet_channel_written_in_coarse_steps_is_not_clipped_unless_its_top_piles_up():
    """10 kHz, 0.27 mm at 1X, noise 0.5 um, values written to the micrometre (a common logger resolution): the
    peaks repeat their written value for dozens of samples without any clipping (noise below one step); that is
    no saturation. The same signal clipped at 99 % of its amplitude is: its top piles up at one written level.
    Reference: the clipping is made by construction (np.clip), the unclipped record has none."""
    rng = np.random.default_rng(5)
    fs, rpm = 10_000.0, 350.0
    t = np.arange(40_000) / fs
    w = 2 * np.pi * rpm / 60
    clean = 0.27e-3 * np.cos(w * t) + 0.1e-3 + rng.normal(0, 0.5e-6, t.size)
    y = 0.25e-3 * np.sin(w * t) + rng.normal(0, 0.5e-6, t.size)

    def written(v):  # to the micrometre, as a file with 3 decimals in mm
        return np.round(v * 1e6) * 1e-6

    record = Record(Path("quiet.csv"), t, {"x": written(clean), "y": written(y)}, None, "mm")
    peak = written(clean).max()
    assert np.sum(written(clean) == peak) >= SATURATED_SAMPLES  # the old rule's premise fails here
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        assert detect_saturation(record) == []
    limit = 0.1e-3 + 0.99 * 0.27e-3
    clipped = Record(Path("clipped.csv"), t, {"x": written(np.minimum(clean, limit)), "y": written(y)}, None, "mm")
    with pytest.warns(DataWarning, match="channel x is clipped"):
        found = detect_saturation(clipped)
    assert [(f.channel, f.kind) for f in found] == [("x", "clipped")]


def test_clipping_at_a_known_sensor_range(tmp_path):
    record = read_record(write_record(tmp_path / "r.csv", amplitude_mm=2.0))
    with pytest.warns(DataWarning, match="channel x is clipped"):
        # x peaks reach 2.32 mm + noise, y only -2.1 mm - noise
        found = detect_saturation(record, sensor_range_m=2.35e-3)
    assert {f.channel for f in found} == {"x"}


def test_flat_channel_is_excluded_with_a_warning_and_the_cli_reports_it(tmp_path, capsys):
    path = write_record(tmp_path / "records" / "dead.csv")
    table = pd.read_csv(path)
    table["y_mm"] = 3.25
    table.to_csv(path, index=False)
    write_record(tmp_path / "records" / "ok.csv", seed=3)
    sheet = write_sheet(tmp_path, "run|rpm|eccentric_mass_g|path\ndead|600|0|records/dead.csv\n"
                                  "ok|600|0|records/ok.csv\n")
    with pytest.warns(DataWarning, match=r"channel y is flat \(constant 3\.2500 mm"):
        analysis = analyse_record(read_record(path), RPM)
    assert analysis.flat and not analysis.usable and analysis.orders is None and analysis.note == "excluded: y flat"
    assert main(["check-data", str(sheet)]) == 0  # flagged, not invalid: the run is kept and reported
    out, err = capsys.readouterr()
    assert "excluded: y flat" in out and "channel y is flat" in err and "1 flagged" in err
    assert main(["check-data", str(sheet), "--strict"]) == 1


def test_check_data_cli_reports_an_invalid_record_and_keeps_checking(dataset, capsys):
    edit_line(dataset.parent / "records" / "a.csv", 12, 1, "abc")
    assert main(["check-data", str(dataset)]) == 1
    out, err = capsys.readouterr()
    assert "run a:" in err and "a.csv: column x_mm: not a number" in err and "line 12 ('abc')" in err
    assert "1 ok" in err and "1 invalid" in err  # run b still checked and summarised


def _fast_and_careful(path: Path):
    from hybridtwin.data.records import _checked_record, _clean_record

    names = ("x", "y")
    return _clean_record(path, names), _checked_record(path, names)


@pytest.mark.parametrize("number", ["%.6f", "%.17g", "%.4e", "%g"])
def test_the_fast_record_reader_reads_what_the_careful_one_reads_bit_for_bit(tmp_path, number):
    """A clean all-numeric record (record_columns.fast_numeric_table, the C parser) gives the careful cell-by-cell
    reader's values to the last bit, its line numbers and its keyphasor marks, whatever the number format (the
    careful reader is the reference: pd.to_numeric, correctly rounded, as round_trip is)."""
    rng = np.random.default_rng(5)
    n = 2000
    t = np.arange(n) / 2000.0
    x, y = rng.normal(0, 1.3, n), rng.normal(0, 0.02, n) * 10.0 ** rng.integers(-8, 3, n)
    keyphasor = (np.arange(n) % 37 == 3).astype(int)
    path = tmp_path / "r.csv"
    with open(path, "w") as f:
        f.write("Time_s, x_mm ,y_mm,keyphasor\n")  # header spacing and case as a user may write them
        for row in zip(t, x, y, keyphasor):
            f.write(",".join([f"{row[0]:.6f}", number % row[1], number % row[2], str(row[3])]) + "\r\n")
    fast, careful = _fast_and_careful(path)
    assert fast is not None  # the premise: this file takes the fast path
    for column in careful[0]:
        assert np.array_equal(fast[0][column], careful[0][column]), column
    assert np.array_equal(fast[1], careful[1]) and fast[1].sum() == keyphasor.sum()
    assert np.array_equal(fast[2], careful[2]) and fast[3:] == careful[3:]


@pytest.mark.parametrize("change", ["quotes", "blank line", "trailing comma", "nan", "empty", "decimal comma",
                                    "unit", "true/false keyphasor", "true as a displacement", "one level keyphasor"])
def test_a_record_the_fast_reader_cannot_vouch_for_is_read_cell_by_cell(tmp_path, change):
    """Anything but a clean all-numeric file goes to the careful reader (fast_numeric_table returns None, or the
    keyphasor has no two levels with a rising edge), which reads it or names the problem as before: the fast path
    never accepts what the careful one would refuse, nor reads a value differently."""
    from hybridtwin.data.records import _clean_record

    lines = ["time_s,x_mm,y_mm,keyphasor"] + [f"{i / 1000:.3f},{np.sin(i / 7):.5f},{np.cos(i / 7):.5f},"
                                              f"{int(i % 20 == 1)}" for i in range(200)]
    edit = {"quotes": lambda s: s.replace("time_s", '"time_s"'),
            "blank line": lambda s: s.replace("\n", "\n\n", 5).replace("\n\n", "\n", 4),
            "trailing comma": lambda s: s.replace("\n", ",\n"),
            "nan": lambda s: s[::-1].replace(",", ",nan"[::-1], 1)[::-1],
            "empty": lambda s: s.replace(",1\n", ",\n", 1),
            "decimal comma": lambda s: s.replace("0.5", "0,5", 1),
            "unit": lambda s: s.replace(",0.0", ",0.0 mm", 1),
            "true/false keyphasor": lambda s: s.replace(",0\n", ",false\n").replace(",1\n", ",true\n"),
            "true as a displacement": lambda s: s.replace(",0.00000,", ",true,", 1),
            "one level keyphasor": lambda s: s.replace(",1\n", ",0\n")}[change]
    path = tmp_path / "r.csv"
    path.write_text(edit("\n".join(lines) + "\n"))
    assert _clean_record(path, ("x", "y")) is None
    try:
        careful = _fast_and_careful(path)[1]
    except DataError as err:
        with pytest.raises(DataError) as again:
            read_record(path)
        assert str(again.value) == str(err)
    else:
        record = read_record(path)
        assert np.array_equal(record.x_m, careful[0]["x_mm"] * 1e-3)


def test_a_harmonic_stem_reads_back_to_its_channel_and_harmonic():
    """split_stem is harmonic_stem's inverse, for channel names with and without a trailing digit or underscore
    (x1 -> x, 1; x1_1 -> x1, 1; probe_a12 -> probe_a, 12): a runout offset's row of parameters.tsv is read back by
    it. A wrong split would give another channel or harmonic for one of these."""
    from hybridtwin.data.record_columns import harmonic_stem, split_stem

    for channel in ("x", "y", "x1", "probe_a", "p_12", "p12"):
        for h in (1, 2, 12):
            assert split_stem(harmonic_stem(channel, h)) == (channel, h)
