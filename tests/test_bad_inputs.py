"""Nothing wrong gets through, nothing gets dropped (issue 22, docs/data-checks.md).

A good three-run data set (runs a and c fit, b validate; synthetic forward-whirl records, 2 s at 2 kHz) is broken
in one way per case. Each bad runs sheet must be an error naming the sheet, the line and column (or header) and
the problem, the same in ``hybridtwin check-data`` and in the workflow's parse-time reading; each bad record must
be an error naming the record and the problem (check-data exits 1, so the workflow's first job fails), or a flag
that keeps the run out of the fit, is printed on the console, and reaches the workflow (the preprocess rule's
table says usable False and the identification leaves the run out). Sheets written differently but meaning the
same (BOM, CRLF, white space, case, quotes, trailing blank lines or tabs) must read exactly like the clean one.
A real ``snakemake -n`` on a copy of the workflow confirms, for a few sheets, that the Snakefile reads them so.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pytest

from hybridtwin.cli import main
from hybridtwin.config import run_plan
from hybridtwin.identify.identification import run_data, runs_with_role
from hybridtwin.data.measurements import DataError, DataWarning, read_runs, sheet_entry
from hybridtwin.data.preprocessing import check_data, preprocess_run

sys.path.insert(0, str(Path(__file__).parent))
from test_workflow import SNAKEMAKE, _copy_workflow  # noqa: E402

HEADER = "run|rpm|eccentric_mass_g|path|role"
ROWS = ["a|600|14.8|records/a.csv|fit", "b|700|7.6|records/b.csv|validate", "c|650|25.9|records/c.csv|fit"]
RPM = {"a": 600.0, "b": 700.0, "c": 650.0}


def tsv(*lines: str) -> str:
    """Sheet text from lines written with '|' for the tabs."""
    return "\n".join(lines).replace("|", "\t") + "\n"


GOOD = tsv(HEADER, *ROWS)


def signals(rpm: float, seconds: float = 2.0, fs: float = 2000.0, amplitude_mm: float = 1.0, noise_mm: float = 0.05,
            seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.random.Generator]:
    """A forward 1X orbit (the shaft turns from +x to +y) with a small 3X, DC offsets and noise [s, mm, mm]."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    angle = 2 * np.pi * rpm / 60 * t
    x = amplitude_mm * np.cos(angle) + 0.02 * np.cos(3 * angle) + 0.3 + noise_mm * rng.standard_normal(t.size)
    y = 0.9 * amplitude_mm * np.sin(angle) - 0.1 + noise_mm * rng.standard_normal(t.size)
    return t, x, y, rng


def write_record(path: Path, t: np.ndarray, x: np.ndarray, y: np.ndarray, header: str = "time_s,x_mm,y_mm") -> Path:
    table = pd.DataFrame(np.column_stack([t, x, y]), columns=header.split(","))
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False, float_format="%.7g")
    return path


@pytest.fixture(scope="module")
def good_records(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("good") / "records"
    for seed, (run, rpm) in enumerate(RPM.items()):
        write_record(folder / f"{run}.csv", *signals(rpm, seed=seed)[:3])
    return folder


def data_set(folder: Path, good_records: Path, sheet: str | bytes = GOOD) -> Path:
    """The good records and ``sheet`` (text or raw bytes) as folder/runs.tsv."""
    shutil.copytree(good_records, folder / "records")
    path = folder / "runs.tsv"
    (path.write_bytes if isinstance(sheet, bytes) else path.write_text)(sheet)
    return path


# --- the parse-time reading of the workflow, and check-data -----------------------------


def workflow_reading(sheet: Path) -> tuple:
    """What the workflow reads of ``sheet`` before any job runs, with the calls its rules make:
    common.smk (read_runs with masses required, run_plan), identification.smk (runs_with_role),
    measurements.smk (the check_data rule's records, each preprocess job's sheet_entry).
    ("error", first line of the message) or ("ok", runs, fit runs, validation runs, rows)."""
    try:
        read_runs(sheet, require_mass=True)
        runs = list(run_plan({"runs": str(sheet)})["run"])
        fit, validate = runs_with_role(sheet, "fit"), runs_with_role(sheet, "validate")
        records = list(read_runs(sheet)["record"])
        rows = {run: sheet_entry(sheet, run) for run in runs}
    except DataError as err:
        return ("error", str(err).splitlines()[0])
    assert [rows[r]["record"] for r in runs] == records
    return ("ok", runs, fit, validate, {r: (row["rpm"], row["eccentric_mass_g"]) for r, row in rows.items()})


def check_data_reading(sheet: Path, capsys, tmp_path: Path) -> tuple:
    """What ``hybridtwin check-data`` makes of ``sheet``, in the form of ``workflow_reading``."""
    out = tmp_path / "check.tsv"
    status = main(["check-data", str(sheet), "--output", str(out)])
    _, err = capsys.readouterr()
    assert "Traceback" not in err
    if not out.exists():
        assert status == 1
        first = err.split("hybridtwin check-data: error: ", 1)[1].splitlines()[0]
        return ("error", first)
    table = pd.read_csv(out, sep="\t", dtype={"run": str})
    runs = table["run"].tolist()
    return ("ok", runs, table.loc[table["role"] == "fit", "run"].tolist(),
            table.loc[table["role"] == "validate", "run"].tolist(),
            {r: (rpm, m) for r, rpm, m in zip(runs, table["rpm"], table["eccentric_mass_g"])})


# --- bad runs sheets: errors ------------------------------------------------------------

SHEET_ERRORS = [
    # columns
    ("missing mass column", tsv("run|rpm|path|role", "a|600|records/a.csv|fit"),
     ["line 1 (header)", "missing column(s) 'eccentric_mass_g'"]),
    ("misnamed mass column", tsv("run|rpm|mass_g|path|role", "a|600|14.8|records/a.csv|fit"),
     ["line 1 (header)", "'eccentric_mass_g' (found 'mass_g': misnamed?)"]),
    ("mass column in kg", tsv("run|rpm|eccentric_mass_kg|path", "a|600|0.0148|records/a.csv"),
     ["line 1 (header)", "'eccentric_mass_g' (found 'eccentric_mass_kg': misnamed?)"]),
    ("missing rpm column", tsv("run|eccentric_mass_g|path", "a|14.8|records/a.csv"), ["missing column(s) 'rpm'"]),
    ("missing path column", tsv("run|rpm|eccentric_mass_g|role", "a|600|14.8|fit"), ["missing column(s) 'path'"]),
    ("no header", tsv(*ROWS), ["line 1 (header)", "missing column(s) 'run', 'rpm', 'eccentric_mass_g', 'path'"]),
    ("duplicated column", tsv(HEADER + "|rpm", *(r + "|600" for r in ROWS)),
     ["line 1 (header): column 'rpm' appears 2 times (columns 2, 6)"]),
    ("unnamed column with values", tsv(HEADER + "|", *(r + "|x" for r in ROWS)),
     ["line 1 (header): column 6 has no name but holds values"]),
    # separators and cells per line
    ("comma-separated", GOOD.replace("\t", ","), ["line 1 (header): not TSV (tab-separated)", "separated by commas"]),
    ("semicolon-separated", GOOD.replace("\t", ";"), ["separated by semicolons"]),
    ("space-aligned", GOOD.replace("\t", "   "), ["separated by spaces"]),
    ("spaces instead of a tab on one line", tsv(HEADER, ROWS[0], "b|700|7.6|records/b.csv validate", ROWS[2]),
     ["not 5 cells as in the header", "line 3 (4 cells)"]),
    ("a cell missing", tsv(HEADER, ROWS[0], "b|700|7.6|records/b.csv", ROWS[2]), ["line 3 (4 cells)"]),
    ("an extra cell", tsv(HEADER, ROWS[0] + "|oops", *ROWS[1:]), ["line 2 (6 cells)"]),
    # numbers
    ("decimal comma in the mass", tsv(HEADER, "a|600|14,8|records/a.csv|fit", *ROWS[1:]),
     ["column eccentric_mass_g: decimal comma", "line 2 ('14,8')"]),
    ("decimal comma in the speed", tsv(HEADER, "a|600,5|14.8|records/a.csv|fit", *ROWS[1:]),
     ["column rpm: decimal comma", "line 2 ('600,5')"]),
    ("thousands separator", tsv(HEADER, "a|1,000|14.8|records/a.csv|fit", *ROWS[1:]),
     ["column rpm: decimal comma or thousands separator", "line 2 ('1,000')"]),
    ("unit in the mass", tsv(HEADER, "a|600|14.8 g|records/a.csv|fit", *ROWS[1:]),
     ["column eccentric_mass_g: a unit inside the number", "line 2 ('14.8 g')"]),
    ("unit in the speed", tsv(HEADER, "a|600rpm|14.8|records/a.csv|fit", *ROWS[1:]),
     ["column rpm: a unit inside the number", "line 2 ('600rpm')"]),
    ("speed not a number", tsv(HEADER, "a|fast|14.8|records/a.csv|fit", *ROWS[1:]),
     ["column rpm: not a number", "line 2 ('fast')"]),
    ("speed empty", tsv(HEADER, "a||14.8|records/a.csv|fit", *ROWS[1:]), ["column rpm: missing value", "line 2"]),
    ("speed NaN", tsv(HEADER, "a|NaN|14.8|records/a.csv|fit", *ROWS[1:]), ["column rpm: missing value", "line 2"]),
    ("speed infinite", tsv(HEADER, "a|inf|14.8|records/a.csv|fit", *ROWS[1:]), ["column rpm: not finite", "line 2"]),
    ("speed zero", tsv(HEADER, "a|0|14.8|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column rpm: 0 is not a positive speed"]),
    ("speed negative", tsv(HEADER, ROWS[0], "b|-700|7.6|records/b.csv|validate", ROWS[2]),
     ["line 3, column rpm: -700 is not a positive speed"]),
    ("mass empty", tsv(HEADER, ROWS[0], "b|700||records/b.csv|validate", ROWS[2]),
     ["column eccentric_mass_g: missing value (empty or NaN; the libraries are built per speed and eccentric mass: "
      "write 0 for no added mass) on 1 line(s): line 3"]),
    ("mass NaN", tsv(HEADER, ROWS[0], "b|700|nan|records/b.csv|validate", ROWS[2]),
     ["column eccentric_mass_g: missing value", "line 3 ('nan')"]),
    ("mass negative", tsv(HEADER, "a|600|-14.8|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column eccentric_mass_g: -14.8 g is negative"]),
    ("mass in kilograms", tsv(HEADER, "a|600|0.0148|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column eccentric_mass_g: 0.0148 g looks like kilograms (14.8 g?)"]),
    # roles and run ids
    ("role misspelt", tsv(HEADER, ROWS[0], "b|700|7.6|records/b.csv|validation", ROWS[2]),
     ["line 3, column role: 'validation' is not a role: use fit or validate (did you mean 'validate'?)"]),
    ("role unknown", tsv(HEADER, "a|600|14.8|records/a.csv|train", *ROWS[1:]),
     ["line 2, column role: 'train' is not a role"]),
    ("run id with a space", tsv(HEADER, "a 1|600|14.8|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column run: 'a 1' is not a valid run id"]),
    ("run id with a slash", tsv(HEADER, "a/1|600|14.8|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column run: 'a/1' is not a valid run id"]),
    ("run id NA", tsv(HEADER, "NA|600|14.8|records/a.csv|fit", *ROWS[1:]),
     ["line 2, column run: 'NA' reads as a missing value in the result tables"]),
    ("run id None", tsv(HEADER, ROWS[0], "None|700|7.6|records/b.csv|validate", ROWS[2]),
     ["line 3, column run: 'None' reads as a missing value"]),
    ("run id empty", tsv(HEADER, "|600|14.8|records/a.csv|fit", *ROWS[1:]),
     ["column run: empty (every run needs an id) on 1 line(s): line 2"]),
    ("duplicated run", tsv(HEADER, *ROWS, "a|650|25.9|records/c.csv|fit"),
     ["lines 2, 5, column run: duplicate run id 'a'"]),
    ("run ids differing in case", tsv(HEADER, *ROWS, "A|650|25.9|records/A.csv|fit"),
     ["lines 2, 5, column run: run ids ['A', 'a'] differ only in case"]),
    # records
    ("path empty", tsv(HEADER, "a|600|14.8||fit", *ROWS[1:]), ["line 2, column path: empty"]),
    ("record missing", tsv(HEADER, "a|600|14.8|records/nowhere.csv|fit", *ROWS[1:]),
     ["line 2, column path: record 'records/nowhere.csv' of run 'a' does not exist"]),
    ("path to a folder", tsv(HEADER, "a|600|14.8|records|fit", *ROWS[1:]),
     ["line 2, column path: 'records' of run 'a' is a folder"]),
    ("two runs share a record", tsv(HEADER, ROWS[0], "b|700|7.6|records/a.csv|validate", ROWS[2]),
     ["lines 2, 3, column path: runs ['a', 'b'] share the record 'records/a.csv'"]),
    ("two runs share a record spelled otherwise", tsv(HEADER, ROWS[0], "b|700|7.6|./records//a.csv|validate", ROWS[2]),
     ["lines 2, 3, column path: runs ['a', 'b'] share the record './records//a.csv' = 'records/a.csv'"]),
    # sensor facts
    ("sensor range negative", tsv(HEADER + "|sensor_range_mm", *(r + "|-14" for r in ROWS)),
     ["line 2, column sensor_range_mm: -14 mm is not positive"]),
    ("sensor resolution not a number", tsv(HEADER + "|sensor_resolution_mm", ROWS[0] + "|fine", *(r + "|" for r in ROWS[1:])),
     ["column sensor_resolution_mm: not a number", "line 2 ('fine')"]),
    # the file itself
    ("empty file", "", ["file is empty"]),
    ("blank lines only", "\n\n  \n", ["file is empty"]),
    ("header only", tsv(HEADER), ["the runs sheet has no runs"]),
    ("Latin-1 encoded", tsv(HEADER + "|operator", *(r + "|Jos\u00e9" for r in ROWS)).encode("latin-1"),
     ["line 2: byte 0xe9 is not UTF-8 text", "save the file as UTF-8"]),
    ("a workbook", b"PK\x03\x04" + bytes(40), ["zip archive (an Excel or OpenDocument workbook?)"]),
    ("UTF-16 without BOM", GOOD.encode("utf-16-le"), ["line 1: binary content (NUL bytes)"]),
]


@pytest.mark.parametrize("content, expected", [pytest.param(c, e, id=i) for i, c, e in SHEET_ERRORS])
def test_bad_sheet_is_one_clear_error_in_check_data_and_the_workflow(tmp_path, good_records, capsys, content,
                                                                       expected):
    sheet = data_set(tmp_path, good_records, content)
    with pytest.raises(DataError) as err:
        read_runs(sheet, require_mass=True)
    message = str(err.value)
    assert message.startswith(f"{sheet}: ")  # the file, then the line / column and the problem
    for text in expected:
        assert text in message
    assert main(["check-data", str(sheet)]) == 1
    _, stderr = capsys.readouterr()
    assert "Traceback" not in stderr and all(text in stderr for text in expected)
    assert workflow_reading(sheet) == ("error", message.splitlines()[0])


def test_missing_sheet_and_reversed_or_missed_coverage(tmp_path, good_records, capsys):
    sheet = data_set(tmp_path, good_records)
    assert main(["check-data", str(tmp_path / "nowhere.tsv")]) == 1
    assert f"{tmp_path / 'nowhere.tsv'}: file does not exist" in capsys.readouterr().err
    assert main(["check-data", str(sheet), "--rpm-range", "1000", "300"]) == 1  # a setting, not the data
    assert "--rpm-range: [1000.0, 300.0] RPM is not [low, high] with low <= high" in capsys.readouterr().err
    assert main(["check-data", str(sheet), "--mass-range-g", "0", "10"]) == 1
    err = capsys.readouterr().err
    assert "line 2, run 'a': eccentric mass 14.8 g is outside the covered range [0, 10] g" in err
    assert "line 4, run 'c': eccentric mass 25.9 g" in err
    # without the options, the config's checks apply, as in the workflow's check_data rule: its coverage, its sensor
    # range (offline.sensor_range_mm), its harmonics
    config = tmp_path / "config.yaml"
    config.write_text("coverage: {eccentric_mass_g: [0, 10]}\n")
    assert main(["check-data", str(sheet), "--config", str(config)]) == 1
    err = capsys.readouterr().err
    assert "line 2, run 'a': eccentric mass 14.8 g is outside the covered range [0, 10] g" in err
    config.write_text("offline: {sensor_range_mm: 0.5}\nharmonics: 2\n")
    assert main(["check-data", str(sheet), "--config", str(config)]) == 1
    out, err = capsys.readouterr()
    assert "beyond the sensor range +-0.5 mm" in err and "3X" not in out
    assert main(["check-data", str(sheet), "--config", str(config), "--sensor-range-mm", "14"]) == 0  # option wins


def test_a_sheet_without_a_usable_fit_run_is_an_error(tmp_path, good_records, capsys):
    """Every run validation (or every fit run kept out): nothing could be identified. check-data says so and
    exits 1, as the workflow's check_data job stops before the offline stage (it stopped at identify_joint, after
    every library was built)."""
    sheet = data_set(tmp_path, good_records, tsv(HEADER, *(row.replace("|fit", "|validate") for row in ROWS)))
    assert main(["check-data", str(sheet)]) == 1
    err = capsys.readouterr().err
    assert f"error: no usable fit run in {sheet}" in err and "3 ok" in err


# --- sheets that mean the same as the clean one -----------------------------------------

SAME_SHEETS = [
    ("byte-order mark", b"\xef\xbb\xbf" + GOOD.encode()),
    ("UTF-16 with BOM", GOOD.encode("utf-16")),
    ("CRLF line ends", GOOD.replace("\n", "\r\n")),
    ("old Mac line ends", GOOD.replace("\n", "\r")),
    ("trailing blank lines", GOOD + "\n\n\t\t\n  \n"),
    ("blank line between runs", tsv(HEADER, ROWS[0], "", *ROWS[1:])),
    ("trailing space in a role", tsv(HEADER, "a|600|14.8|records/a.csv|fit ", *ROWS[1:])),
    ("white space around cells", tsv(" run | rpm |eccentric_mass_g | path| role",
                                     *("  " + r.replace("|", " | ") + " " for r in ROWS))),
    ("header and role in capitals", tsv("RUN|Rpm|Eccentric_Mass_G|PATH|Role", "a|600|14.8|records/a.csv|FIT",
                                        "b|700|7.6|records/b.csv|Validate", ROWS[2])),
    ("quoted cells", tsv('"run"|"rpm"|"eccentric_mass_g"|"path"|"role"',
                         *('"' + r.replace("|", '"|"') + '"' for r in ROWS))),
    ("trailing tabs", tsv(HEADER + "|", *(r + "|" for r in ROWS))),
    ("empty role cells", tsv(HEADER, "a|600|14.8|records/a.csv|", ROWS[1], "c|650|25.9|records/c.csv|")),
    ("no role column", tsv("run|rpm|eccentric_mass_g|path", "a|600|14.8|records/a.csv",
                           "b|700|7.6|records/b.csv|validate".rsplit("|", 1)[0], "c|650|25.9|records/c.csv")),
]


@pytest.mark.parametrize("content", [pytest.param(c, id=i) for i, c in SAME_SHEETS])
def test_sheets_written_differently_read_exactly_like_the_clean_one(tmp_path, good_records, content):
    clean = read_runs(data_set(tmp_path / "clean", good_records))
    sheet = read_runs(data_set(tmp_path / "case", good_records, content))
    columns = ["run", "rpm", "eccentric_mass_g", "path", "role"]
    expected = clean[columns].copy()
    if isinstance(content, str) and "role" not in content.splitlines()[0].lower():
        expected["role"] = "fit"  # no role column: every run fits
    pd.testing.assert_frame_equal(sheet[columns].reset_index(drop=True), expected.reset_index(drop=True))
    assert [Path(p).name for p in sheet["record"]] == ["a.csv", "b.csv", "c.csv"]


# --- the workflow and check-data agree on every sheet of this suite ---------------------


@pytest.mark.parametrize("content", [pytest.param(c, id=i) for i, c, _ in SHEET_ERRORS]
                         + [pytest.param(c, id=i) for i, c in SAME_SHEETS] + [pytest.param(GOOD, id="clean")])
def test_check_data_and_the_workflow_read_every_sheet_alike(tmp_path, good_records, capsys, content):
    sheet = data_set(tmp_path, good_records, content)
    workflow = workflow_reading(sheet)
    assert check_data_reading(sheet, capsys, tmp_path) == workflow
    if workflow[0] == "ok":  # every run of the sheet is in the workflow: none dropped
        assert sorted(workflow[2] + workflow[3]) == sorted(workflow[1]) and len(workflow[1]) == 3


# --- bad records: errors and flags ------------------------------------------------------


@dataclass(frozen=True)
class RecordCase:
    """One broken record (or sheet row) of run ``run``: an error or a flag, and what the message must say."""

    kind: str  # "error" or "flag"
    build: Callable[[Path], None]  # breaks the good data set in this folder
    expected: tuple[str, ...]
    run: str = "a"


def signal_case(kind: str, change: Callable, expected: tuple[str, ...], header: str = "time_s,x_mm,y_mm",
                run: str = "a", **options) -> RecordCase:
    """Run ``run``'s record rewritten as change(t, x_mm, y_mm, rng) -> (t, x, y) under ``header``."""
    def build(folder: Path) -> None:
        t, x, y, rng = signals(RPM[run], **options)
        write_record(folder / "records" / f"{run}.csv", *change(t, x, y, rng), header=header)
    return RecordCase(kind, build, expected, run)


def text_case(change: Callable[[str], str | bytes], expected: tuple[str, ...], run: str = "a") -> RecordCase:
    """Run ``run``'s record file rewritten as change(text)."""
    def build(folder: Path) -> None:
        path = folder / "records" / f"{run}.csv"
        new = change(path.read_text())
        (path.write_bytes if isinstance(new, bytes) else path.write_text)(new)
    return RecordCase("error", build, expected, run)


def sheet_case(old: str, new: str, expected: tuple[str, ...], run: str = "a", kind: str = "error") -> RecordCase:
    """The sheet's text with ``old`` replaced by ``new`` (the records stay good)."""
    def build(folder: Path) -> None:
        path = folder / "runs.tsv"
        path.write_text(path.read_text().replace(old.replace("|", "\t"), new.replace("|", "\t")))
    return RecordCase(kind, build, expected, run)


def clip(values: np.ndarray, level: float, rng: np.random.Generator, rail_noise: float = 0.01) -> np.ndarray:
    """A laser saturated at +-level whose output on the rail still carries +-rail_noise [mm]."""
    out = values.copy()
    on_rail = np.abs(out) >= level
    out[on_rail] = np.sign(out[on_rail]) * level + rng.uniform(-rail_noise, rail_noise, on_rail.sum())
    return out


def lines_edited(text: str, edit: Callable[[int, str], str]) -> str:
    lines = text.splitlines()
    return "\n".join(edit(n, line) for n, line in enumerate(lines, start=1)) + "\n"


def one_cell(text: str, line: int, column: int, value: str) -> str:
    def edit(n: int, row: str) -> str:
        if n != line:
            return row
        cells = row.split(",")
        cells[column] = value
        return ",".join(cells)
    return lines_edited(text, edit)


NOISE = 0.05
RECORD_CASES = {
    # units by magnitude, offsets and range: errors
    "metres under x_mm": signal_case("error", lambda t, x, y, r: (t, x * 1e-3, y * 1e-3),
                                     ("column x_mm: every value lies within +-0.014", "look like metres")),
    "millimetres under x_m": signal_case("error", lambda t, x, y, r: (t, x, y), header="time_s,x_m,y_m",
                                         amplitude_mm=10.0,
                                         expected=("column x_m: values up to", "they look like millimetres")),
    "x_mm with y_m holding mm": signal_case("error", lambda t, x, y, r: (t, x, y), header="time_s,x_mm,y_m",
                                            expected=("column y_m: values up to", "look like millimetres")),
    "y_mm holding metres": signal_case("error", lambda t, x, y, r: (t, x, y * 1e-3),
                                       ("column y_mm: every value lies within", "look like metres")),
    "micrometres under x_mm": signal_case("error", lambda t, x, y, r: (t, x * 1e3, y * 1e3),
                                          ("column x_mm: DC offset (median) 3", "mm, beyond the sensor range")),
    "micrometres under x_mm, about zero": signal_case("error", lambda t, x, y, r: (t, 50.0 * (x - 0.3), y),
                                                      ("column x_mm: beyond the sensor range", "look like um written as mm",
                                                       "name the column x_um")),
    "500 mm DC offset": signal_case("error", lambda t, x, y, r: (t, x + 500.0, y),
                                    ("column x_mm: DC offset (median) 500.3 mm, beyond the sensor range +-14 mm",)),
    "an excursion beyond the range": signal_case("error", lambda t, x, y, r: (t, np.where(
        (t > 1.0) & (t < 1.002), 20.0, x), y), ("column x_mm: beyond the sensor range +-14 mm", "on 3 line(s): line 2003 (+20.000 mm)")),
    "dead channel near zero": signal_case("error", lambda t, x, y, r: (t, x, 1e-4 * (np.arange(t.size) % 2)),
                                          ("column y_mm: every value lies within", "or the channel holds no signal")),
    # the speed: errors naming both
    "5000 RPM in the sheet for a 700 RPM record": sheet_case(
        "b|700|", "b|5000|", ("b.csv: the record turns at about 700.0 RPM", "the runs sheet says 5000 RPM (-86.0 %"),
        run="b"),
    "twice the speed in the sheet": sheet_case("a|600|", "a|1200|", ("turns at about 600.0 RPM", "says 1200 RPM")),
    "half the speed in the sheet": sheet_case("a|600|", "a|300|", ("turns at about 600.0 RPM", "says 300 RPM")),
    "speed off by 5 %": sheet_case("a|600|", "a|630|", ("turns at about 600.0 RPM", "says 630 RPM (-4.8 %, "
                                                                                       "tolerance +-2 %)")),
    "speed in Hz": sheet_case("a|600|", "a|10|", ("turns at about 600.0 RPM", "says 10 RPM")),
    "time in milliseconds": signal_case("error", lambda t, x, y, r: (t * 1e3, x, y),
                                        ("turns at about 0.6 RPM", "time_s not in seconds")),
    # the format of a record: errors naming line and column
    "decimal commas": text_case(lambda s: lines_edited(s, lambda n, row: row if n == 1 else row.replace(".", ",")),
                                ("not 3 cells as in the header (a decimal comma? use a point: 0.25)", "line 2")),
    "semicolon-separated": text_case(lambda s: s.replace(",", ";"), ("not CSV (comma-separated)", "semicolons")),
    "tab-separated": text_case(lambda s: s.replace(",", "\t"), ("not CSV (comma-separated)", "tabs")),
    "a NaN cell": text_case(lambda s: one_cell(s, 57, 2, "NaN"), ("column y_mm: missing value", "line 57")),
    "an empty cell": text_case(lambda s: one_cell(s, 58, 1, ""), ("column x_mm: missing value", "line 58")),
    "a text cell": text_case(lambda s: one_cell(s, 101, 1, "1.2.3"), ("column x_mm: not a number",
                                                                      "line 101 ('1.2.3')")),
    "a unit in a cell": text_case(lambda s: one_cell(s, 5, 1, "0.3mm"), ("column x_mm: a unit inside the number",)),
    "infinite value": text_case(lambda s: one_cell(s, 9, 2, "inf"), ("column y_mm: not finite", "line 9")),
    "time going back": text_case(lambda s: one_cell(s, 31, 0, "0.01"), ("column time_s: not increasing", "line 31")),
    "a gap": text_case(lambda s: "\n".join(s.splitlines()[:200] + s.splitlines()[210:]) + "\n",
                       ("column time_s: gap (missing samples)", "line 201")),
    "time jitter": text_case(lambda s: one_cell(s, 500, 0, "0.24905"), ("column time_s: non-uniform step",)),
    "too short": signal_case("error", lambda t, x, y, r: (t, x, y), ("too short", "4.0 revolution(s) at 600 RPM"),
                             seconds=0.4),
    "too coarsely sampled": signal_case("error", lambda t, x, y, r: (t, x, y),
                                        ("100 Hz sampling gives", "too few to resolve 5X"), fs=100.0, seconds=6.0),
    "keyphasor not 0/1": text_case(lambda s: lines_edited(s, lambda n, row: row + (",keyphasor" if n == 1 else
                                                                                    ",yes" if n == 3 else ",0")),
                                   ("column keyphasor: not a level of a two-level signal", "line 3 ('yes')")),
    "keyphasor without a mark": text_case(lambda s: lines_edited(s, lambda n, row: row + (",keyphasor" if n == 1
                                                                                           else ",0")),
                                          ("column keyphasor: no mark",)),
    "unknown unit": text_case(lambda s: s.replace("x_mm,y_mm", "x_in,y_in", 1), ("unknown unit 'in'",)),
    "unexpected column": text_case(lambda s: lines_edited(s, lambda n, row: row + (",temperature_c" if n == 1 else
                                                                                    ",21")),
                                   ("unexpected column(s) ['temperature_c']",)),
    "y column missing": text_case(lambda s: lines_edited(s, lambda n, row: row.rsplit(",", 1)[0]),
                                  ("missing column y_mm (or y_m)",)),
    "two x columns": text_case(lambda s: lines_edited(s, lambda n, row: row + (",x_m" if n == 1 else ",0")),
                               ("more than one x displacement column",)),
    "empty record": text_case(lambda s: "", ("file is empty",)),
    "header only": text_case(lambda s: s.splitlines()[0] + "\n", ("only 0 sample(s)",)),
    "binary record": text_case(lambda s: bytes(range(256)), ("binary content",)),
    "Latin-1 record": text_case(lambda s: one_cell(s, 7, 1, "0.2\u00b0").encode("latin-1"),
                                ("line 7: byte 0xb0 is not UTF-8 text",)),
    # flags: readable, kept out of the fit, said on the console
    "channel of noise only": signal_case("flag", lambda t, x, y, r: (t, x, 0.2 + NOISE * r.standard_normal(t.size)),
                                         ("channel y: its 1X", "is not significant", "noise only")),
    "both channels noise only": signal_case("flag", lambda t, x, y, r: (
        t, NOISE * r.standard_normal(t.size), NOISE * r.standard_normal(t.size)), ("channel x: its 1X",)),
    "x and y swapped": signal_case("flag", lambda t, x, y, r: (t, y, x), ("the 1X orbit whirls backward",
                                                                          "x and y swapped")),
    "y sign reversed": signal_case("flag", lambda t, x, y, r: (t, x, -y), ("whirls backward",
                                                                           "one channel's sign reversed")),
    "a single 13.9 mm spike": signal_case("flag", lambda t, x, y, r: (t, np.where(np.arange(t.size) == 1234, 13.9, x),
                                                                      y), ("channel x: spike(s)", "line 1236")),
    "three spikes": signal_case("flag", lambda t, x, y, r: (t, x, y + 3.0 * np.isin(np.arange(t.size), [10, 99, 3000])),
                                ("channel y: spike(s)", "on 3 line(s): line 12", "line 101", "line 3002")),
    "saturated with noise on the rail": signal_case("flag", lambda t, x, y, r: (t, clip(x, 14.0, r), y),
                                                    ("channel x is clipped at +14.0", "the sensor saturated"),
                                                    amplitude_mm=14.8),
    "saturated on the negative rail": signal_case("flag", lambda t, x, y, r: (t, x, clip(y - 6.0, 14.0, r)),
                                                  ("channel y is clipped at -13.99",), amplitude_mm=9.0),
    "flat tops at an exact value": signal_case("flag", lambda t, x, y, r: (t, np.minimum(x, 1.2), y),
                                               ("channel x is clipped at +1.2000 mm",)),
    "flat channel": signal_case("flag", lambda t, x, y, r: (t, x, np.full(t.size, 3.25)),
                                ("channel y is flat (constant 3.2500 mm",)),
    "flat within the resolution": signal_case("flag", lambda t, x, y, r: (t, x, 3.25 + 1e-3 * (np.arange(t.size) % 2)),
                                              ("channel y is flat",)),
    # the speed of a record with more than a 1X: a quiet run at half the sheet's speed (its 2X at the sheet's 1X;
    # before, analysed at the sheet's speed with its 2X taken for the 1X), and a loud one with a 2X (still caught)
    "a quiet run at half the sheet's speed": signal_case("error", lambda t, x, y, r: (t, *quiet_half_speed(t, r)),
                                                         ("the record turns at about 30", "not at the runs sheet's "
                                                          "600 RPM (1/2 of it)", "2 times the true one?")),
    # micrometres of vibration in mm, judged against the default 14 mm range: the message names the setting
    "micrometres of vibration, a sensor of smaller range not given": signal_case(
        "error", lambda t, x, y, r: (t, 8e-3 * (x - 0.3), 8e-3 * (y + 0.1)),
        ("column x_mm: every value lies within +-0.014", "the sensor's range is smaller than +-14 mm",
         "column sensor_range_mm of the runs sheet", "offline.sensor_range_mm", "check-data --sensor-range-mm")),
    # a channel copied into another (an export slip): an error naming both columns
    "y a copy of x": signal_case("error", lambda t, x, y, r: (t, x, x.copy()),
                                 ("columns x_mm and y_mm hold the same samples (", "export slip?")),
    "y a copy of x shifted by a constant": signal_case("error", lambda t, x, y, r: (t, x, x - 0.4),
                                                       ("columns x_mm and y_mm hold the same samples +0.4 mm apart",)),
    "y a copy of x, both metres under mm": signal_case(
        "error", lambda t, x, y, r: (t, x * 1e-3, x * 1e-3),
        ("3 problems", "column x_mm: every value lies within", "column y_mm: every value lies within",
         "columns x_mm and y_mm hold the same samples")),
}


def quiet_half_speed(t: np.ndarray, rng: np.random.Generator, rpm: float = 300.0) -> tuple[np.ndarray, np.ndarray]:
    """A quiet forward orbit at ``rpm`` [mm]: 1X 0.03 mm, 2X 0.02 mm, noise 0.05 mm (the probe's record). Both lines
    stand far above the threshold of a present line (their power is about 290 and 130 times their neighbourhood's
    median for 2 s at 2 kHz: 25 needed), below the 1000 of a line judged by its strength alone."""
    angle = 2 * np.pi * rpm / 60 * t
    x = 0.03 * np.cos(angle) + 0.02 * np.cos(2 * angle) + 0.3 + NOISE * rng.standard_normal(t.size)
    y = 0.03 * np.sin(angle) + 0.02 * np.sin(2 * angle) - 0.1 + NOISE * rng.standard_normal(t.size)
    return x, y


def _record_of_another_run(folder: Path) -> None:
    shutil.copy(folder / "records" / "b.csv", folder / "records" / "a.csv")  # the 700 RPM record filed as run a


RECORD_CASES["the record of another run"] = RecordCase(
    "error", _record_of_another_run, ("a.csv: the record turns at about 700.0 RPM", "says 600 RPM (+16.7 %"))


def _twice_the_speed_with_a_2x(folder: Path) -> None:
    t, x, y, _ = signals(600.0)
    angle = 2 * np.pi * 600.0 / 60 * t
    write_record(folder / "records" / "a.csv", t, x + 0.1 * np.cos(2 * angle), y + 0.1 * np.sin(2 * angle))
    path = folder / "runs.tsv"
    path.write_text(path.read_text().replace("a\t600\t", "a\t1200\t"))


# the sheet's 1X falls on the record's 2X (a line there): still caught, as the slower speed whose harmonics hold more
RECORD_CASES["twice the speed in the sheet, the record with a 2X"] = RecordCase(
    "error", _twice_the_speed_with_a_2x, ("turns at about 600.0 RPM", "1200 RPM"))


def _rail_of_a_5_mm_sensor(folder: Path) -> None:
    t, x, y, rng = signals(600.0, amplitude_mm=5.5)
    write_record(folder / "records" / "a.csv", t, clip(x, 5.0, rng), clip(y, 5.0, rng))
    path = folder / "runs.tsv"
    path.write_text(tsv(HEADER + "|sensor_range_mm", ROWS[0] + "|5", *(r + "|" for r in ROWS[1:])))


RECORD_CASES["rail of a 5 mm sensor given in the sheet"] = RecordCase(
    "flag", _rail_of_a_5_mm_sensor, ("channel x is clipped at +5.0", "channel y is clipped at -"))


def _beyond_a_5_mm_sensor(folder: Path) -> None:
    t, x, y, _ = signals(700.0, amplitude_mm=6.0, seed=1)
    write_record(folder / "records" / "b.csv", t, x, y)
    (folder / "runs.tsv").write_text(tsv(HEADER + "|sensor_range_mm", ROWS[0] + "|", ROWS[1] + "|5", ROWS[2] + "|"))


RECORD_CASES["beyond the range of a 5 mm sensor given in the sheet"] = RecordCase(
    "error", _beyond_a_5_mm_sensor, ("column x_mm: beyond the sensor range +-5 mm",), run="b")


@pytest.mark.parametrize("name", list(RECORD_CASES))
def test_bad_record_is_an_error_or_a_flag_the_workflow_keeps_out(tmp_path, good_records, capsys, name):
    case = RECORD_CASES[name]
    sheet = data_set(tmp_path, good_records)
    case.build(tmp_path)
    record = Path(sheet_entry(sheet, case.run)["record"])
    out = tmp_path / "check.tsv"
    status = main(["check-data", str(sheet), "--output", str(out)])
    _, stderr = capsys.readouterr()
    assert "Traceback" not in stderr
    summary = pd.read_csv(out, sep="\t", dtype={"run": str}).set_index("run")
    assert sorted(summary.index) == ["a", "b", "c"]  # every run summarised: nothing dropped
    others = summary.drop(case.run)
    assert (others["status"] == "ok").all()  # and only the broken one touched
    if case.kind == "error":
        assert status == 1 and summary.loc[case.run, "status"].startswith("invalid: ")
        message = stderr.split(f"error: run {case.run}: ", 1)[1]
        assert message.startswith(f"{record}: ")
        assert all(text in message for text in case.expected), message
        _, errors = check_data(sheet, sensor_range_m=14e-3)  # the workflow's check_data job: exits on errors
        assert list(errors) == [case.run] and message.startswith(errors[case.run])
        return
    assert status == 0 and "1 flagged (kept out of the fit)" in stderr
    assert not summary.loc[case.run, "usable"] and summary.loc[case.run, "status"].startswith("excluded")
    warning = next(line for line in stderr.splitlines() if line.startswith("hybridtwin check-data: warning: "))
    assert f"{record}: " in warning and all(text in stderr for text in case.expected), stderr
    assert "the run is kept out of the fit" in stderr
    assert main(["check-data", str(sheet), "--strict"]) == 1
    capsys.readouterr()
    # the workflow: the preprocess rule's call, then what the identification reads of its table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        table, _ = preprocess_run(sheet_entry(sheet, case.run), 5, 14e-3)
    assert not table["usable"].iloc[0] and table["note"].iloc[0] == summary.loc[case.run, "status"]
    if table["n_revolutions"].iloc[0] > 0:
        data = run_data(table, case.run)
        assert not data.usable and data.note == summary.loc[case.run, "status"]  # identify_* leave it out


def test_the_suite_holds_at_least_60_bad_inputs():
    errors = len(SHEET_ERRORS) + sum(c.kind == "error" for c in RECORD_CASES.values())
    flags = sum(c.kind == "flag" for c in RECORD_CASES.values())
    assert errors + flags >= 60 and flags >= 10


# --- a correct run whose 1X is not its strongest line: analysed, with a warning naming that line ---------------

STRONGER_LINES = {  # run a's speed [RPM], its 1X [mm] (x; y 0.9 of it), the stronger line [Hz], that line (t, angle)
    "50 Hz mains hum": (350.0, 0.27, 50.0, lambda t, angle: (0.3 * np.sin(2 * np.pi * 50.0 * t),
                                                             0.3 * np.sin(2 * np.pi * 50.0 * t + 1.0))),
    "a 2X response (misalignment)": (600.0, 0.2, 20.0, lambda t, angle: (0.6 * np.cos(2 * angle),
                                                                         0.6 * np.sin(2 * angle))),
    "a natural frequency at 15.3 Hz": (350.0, 0.27, 15.3, lambda t, angle: (0.4 * np.cos(2 * np.pi * 15.3 * t),
                                                                            0.4 * np.sin(2 * np.pi * 15.3 * t))),
}


@pytest.mark.parametrize("name", list(STRONGER_LINES))
def test_a_run_whose_strongest_line_is_not_its_1x_is_analysed_with_a_warning(tmp_path, good_records, capsys, name):
    """Before, each was an error blaming the sheet's rpm ("the record turns at about 3000.0 RPM (its strongest
    line)"): the 1X is there, so the run is analysed at its own speed, and the warning names the stronger line."""
    rpm, amplitude, line_hz, stronger = STRONGER_LINES[name]
    sheet = data_set(tmp_path, good_records)
    t, x, y, _ = signals(rpm, amplitude_mm=amplitude)
    dx, dy = stronger(t, 2 * np.pi * rpm / 60 * t)
    write_record(tmp_path / "records" / "a.csv", t, x + dx, y + dy)
    sheet.write_text(sheet.read_text().replace("a\t600\t", f"a\t{rpm:g}\t"))
    out = tmp_path / "check.tsv"
    assert main(["check-data", str(sheet), "--output", str(out), "--strict"]) == 0
    err = capsys.readouterr().err
    assert "3 ok, 0 flagged (kept out of the fit), 0 invalid" in err
    warning = next(line for line in err.splitlines() if "strongest spectral line" in line)
    assert warning.startswith(f"hybridtwin check-data: warning: {tmp_path / 'records' / 'a.csv'}: ")
    hz, rpm_line = map(float, re.search(r"lies at ([0-9.]+) Hz \(([0-9.]+) RPM", warning).groups())
    assert abs(hz - line_hz) < 0.05  # a tenth of the 0.5 Hz bin of 2 s: the interpolated peak of a clean line
    assert abs(rpm_line - 60 * line_hz) < 3.0 and "the 1X is there" in warning
    row = pd.read_csv(out, sep="\t", dtype={"run": str}).set_index("run").loc["a"]
    # its own speed, not the stronger line's: within a quarter of the +-2 % search (the 15.3 Hz line, not
    # synchronous, pulls the 11 revolutions' speed by 0.11 %)
    assert abs(row["rpm_true"] / rpm - 1) < 5e-3
    assert abs(row["x1_amp_m"] - amplitude * 1e-3) < 5 * row["x1_sigma_m"]  # and its 1X within 5 sigma


def test_micrometres_of_vibration_pass_with_the_sensors_range(tmp_path, good_records, capsys):
    """The record of the case "micrometres of vibration, a sensor of smaller range not given" passes once the
    sensor's range is given as its message says (2 mm: a channel is judged metres only within +-0.002)."""
    sheet = data_set(tmp_path, good_records)
    t, x, y, _ = signals(600.0)
    write_record(tmp_path / "records" / "a.csv", t, 8e-3 * (x - 0.3), 8e-3 * (y + 0.1))
    assert main(["check-data", str(sheet), "--sensor-range-mm", "2", "--strict"]) == 0
    assert "3 ok, 0 flagged (kept out of the fit), 0 invalid" in capsys.readouterr().err


def test_bundled_data_pass_unflagged(capsys):
    root = Path(__file__).resolve().parents[1]
    assert main(["check-data", str(root / "data" / "default" / "runs.tsv"), "--strict"]) == 0
    assert "22 run(s): 22 ok, 0 flagged (kept out of the fit), 0 invalid" in capsys.readouterr().err


# --- the real workflow: snakemake -n on a copy, for a few of the sheets above ------------

DRY_RUN_SHEETS = {  # sheet text from the copied data/small/runs.tsv (r400, r650 fit; v700 validate)
    "BOM, CRLF, 'fit ', 'Validate'": lambda s: b"\xef\xbb\xbf" + s.replace("\tfit\n", "\tfit \n").replace(
        "validate", "Validate").replace("\n", "\r\n").encode(),
    "missing mass column": lambda s: s.replace("eccentric_mass_g", "mass_g"),
    "empty mass": lambda s: s.replace("\t19.5\t", "\t\t"),
    "mass in kilograms": lambda s: s.replace("\t25.9\t", "\t0.0259\t", 1),
    "role misspelt": lambda s: s.replace("validate", "validation"),
}


@pytest.fixture(scope="module")
def workflow_copy(tmp_path_factory) -> tuple[Path, str]:
    """A copy of the workflow (tests/test_workflow.py's small one) and its clean runs sheet's text."""
    work = _copy_workflow(tmp_path_factory.mktemp("dry"))
    return work, (work / "data" / "small" / "runs.tsv").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("name", list(DRY_RUN_SHEETS))
def test_snakemake_dry_run_reads_the_sheet_as_check_data_does(workflow_copy, capsys, tmp_path, name):
    work, clean = workflow_copy
    sheet = work / "data" / "small" / "runs.tsv"
    new = DRY_RUN_SHEETS[name](clean)
    (sheet.write_bytes if isinstance(new, bytes) else sheet.write_text)(new)
    run = subprocess.run([*SNAKEMAKE, "-n", "--cores", "1"], cwd=work, capture_output=True, text=True)
    expected = check_data_reading(sheet, capsys, tmp_path)
    if expected[0] == "error":
        assert run.returncode == 1 and "Traceback" not in run.stderr
        assert f"error: {expected[1].replace(str(sheet), 'data/small/runs.tsv')}" in run.stderr
        return
    assert run.returncode == 0, run.stderr[-2000:]
    preprocessed = set(re.findall(r"results/data/runs/([\w-]+)/harmonics\.tsv", run.stdout))
    fitted = set(re.findall(r"results/\w+/runs/([\w-]+)/parameters\.tsv", run.stdout))
    assert preprocessed == set(expected[1]) and len(preprocessed) == 3  # every run preprocessed: none dropped
    assert fitted == set(expected[2]) == {"r400_m25p9", "r650_m25p9"}  # the fit runs of check-data ('fit ')
