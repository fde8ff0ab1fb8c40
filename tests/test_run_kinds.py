"""The runs sheet's transient rows (kind, rpm_start, rpm_end): read, refused with file and line, steady sheets as
before."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.data.measurements import DataError, read_runs
from hybridtwin.data.run_kinds import sheet_kinds


def write_sheet(folder: Path, text: str) -> Path:
    path = folder / "runs.tsv"
    path.write_text(text.replace("|", "\t"))
    for name in ("a", "b", "c"):
        (folder / f"{name}.csv").write_text("time_s,x_mm,y_mm\n")  # existence only: the sheet reader checks that
    return path


def test_mixed_sheet_reads_kinds_and_sweeps(tmp_path):
    sheet = write_sheet(tmp_path, "run|kind|rpm|rpm_start|rpm_end|eccentric_mass_g|path|role|operator\n"
                                  "a||600|||14.8|a.csv|fit|ann\n"
                                  "b|RunUp||300|1000|14.8|b.csv|fit|bob\n"
                                  "c|coastdown||1000|250|7.6|c.csv|validate|cy\n")
    runs = read_runs(sheet)
    assert runs["kind"].tolist() == ["steady", "runup", "coastdown"]
    assert runs["rpm"].iloc[0] == 600.0 and np.isnan(runs["rpm"].iloc[1]) and np.isnan(runs["rpm"].iloc[2])
    assert np.isnan(runs["rpm_start"].iloc[0]) and np.isnan(runs["rpm_end"].iloc[0])
    assert runs[["rpm_start", "rpm_end"]].iloc[1:].to_numpy().tolist() == [[300.0, 1000.0], [1000.0, 250.0]]
    assert runs["operator"].tolist() == ["ann", "bob", "cy"]  # extra columns carried
    assert runs["role"].tolist() == ["fit", "fit", "validate"]
    assert sheet_kinds(runs).tolist() == ["steady", "runup", "coastdown"]


def test_sheet_of_transients_needs_no_rpm_column(tmp_path):
    sheet = write_sheet(tmp_path, "run|kind|rpm_start|rpm_end|eccentric_mass_g|path\nb|runup|300|1000|14.8|b.csv\n")
    runs = read_runs(sheet)
    assert runs["kind"].tolist() == ["runup"] and np.isnan(runs["rpm"].iloc[0])


def test_steady_sheet_gets_no_new_columns(tmp_path):
    text = "run|rpm|eccentric_mass_g|path\na|600|14.8|a.csv\n"
    runs = read_runs(write_sheet(tmp_path, text))
    assert list(runs.columns) == ["run", "rpm", "eccentric_mass_g", "path", "role", "record"]
    assert sheet_kinds(runs).tolist() == ["steady"]


def test_bundled_default_sheet_reads_as_steady():
    runs = read_runs(Path(__file__).parents[1] / "data" / "default" / "runs.tsv", require_mass=True)
    assert "kind" not in runs and runs["rpm"].notna().all()


def test_steady_rpm_messages_unchanged_by_kind_column(tmp_path):
    """A steady row's empty rpm gives the same message with or without a kind column (the check is the same)."""
    plain = tmp_path / "plain"
    kinded = tmp_path / "kinded"
    plain.mkdir(), kinded.mkdir()
    with pytest.raises(DataError) as without:
        read_runs(write_sheet(plain, "run|rpm|eccentric_mass_g|path\na||14.8|a.csv\n"))
    with pytest.raises(DataError) as with_kind:
        read_runs(write_sheet(kinded, "run|kind|rpm|eccentric_mass_g|path\na|steady||14.8|a.csv\n"))
    assert str(without.value).split(": ", 1)[1] == str(with_kind.value).split(": ", 1)[1]
    assert "line 2" in str(with_kind.value) and "column rpm: missing value" in str(with_kind.value)


@pytest.mark.parametrize("row, expected", [
    ("a|ramp|600|||14.8|a.csv", "line 2, column kind: 'ramp' is not a kind of run"),
    ("a|runpu||300|1000|14.8|a.csv", "did you mean 'runup'?"),
    ("a|runup||||14.8|a.csv", "column rpm_start: missing value"),
    ("a|runup||300||14.8|a.csv", "column rpm_end: missing value"),
    ("a|runup||300|fast|14.8|a.csv", "column rpm_end: not a number"),
    ("a|runup||300 rpm|1000|14.8|a.csv", "column rpm_start: a unit inside the number"),
    ("a|runup||-300|1000|14.8|a.csv", "line 2, column rpm_start: -300 is not a positive speed"),
    ("a|runup||1000|300|14.8|a.csv", "a runup from 1000 RPM to 300 RPM slows down"),
    ("a|coastdown||300|1000|14.8|a.csv", "a coastdown from 300 RPM to 1000 RPM speeds up"),
    ("a|runup||600|600|14.8|a.csv", "a sweep that never leaves one speed (600 RPM to 600 RPM)"),
    ("a|coastdown||600|600|14.8|a.csv", "a sweep that never leaves one speed"),
    ("a||600|300|1000|14.8|a.csv", "column rpm_start: a speed on a steady row"),
    ("a|runup|abc|300|1000|14.8|a.csv", "column rpm: not a number"),
])
def test_bad_transient_rows_name_file_line_and_problem(tmp_path, row, expected):
    sheet = write_sheet(tmp_path, "run|kind|rpm|rpm_start|rpm_end|eccentric_mass_g|path\n" + row + "\n")
    with pytest.raises(DataError) as err:
        read_runs(sheet)
    message = str(err.value)
    assert str(sheet) in message and expected in message and "line 2" in message


def test_every_bad_row_reported_at_once(tmp_path):
    sheet = write_sheet(tmp_path, "run|kind|rpm_start|rpm_end|eccentric_mass_g|path\n"
                                  "a|runup|1000|300|14.8|a.csv\nb|spin|300|1000|14.8|b.csv\n")
    with pytest.raises(DataError) as err:
        read_runs(sheet)
    assert "2 problems" in str(err.value) and "line 2" in str(err.value) and "line 3" in str(err.value)


def test_rig_plan_without_path_accepts_transient_rows(tmp_path):
    sheet = write_sheet(tmp_path, "run|kind|rpm_start|rpm_end|eccentric_mass_g\nb|coastdown|1000|300|14.8\n")
    runs = read_runs(sheet, check_files=False, require_path=False)
    assert runs["kind"].tolist() == ["coastdown"] and runs["rpm_start"].tolist() == [1000.0]
    assert isinstance(runs, pd.DataFrame)


def test_row_schema_accepts_transient_rows_and_requires_their_sweep():
    import yaml
    from jsonschema import validators

    schema = yaml.safe_load((Path(__file__).parents[1] / "workflow" / "schemas" / "runs.schema.yaml").read_text())
    validator = validators.validator_for(schema)(schema)
    base = {"run": "a", "eccentric_mass_g": 14.8, "path": "a.csv"}
    assert not list(validator.iter_errors({**base, "rpm": 600.0}))  # a steady row as before
    assert not list(validator.iter_errors({**base, "kind": "runup", "rpm_start": 300.0, "rpm_end": 1000.0}))
    assert list(validator.iter_errors({**base, "kind": "runup", "rpm_start": 300.0}))  # rpm_end missing
    assert list(validator.iter_errors(base))  # a steady row without rpm
    assert list(validator.iter_errors({**base, "kind": "ramp", "rpm": 600.0}))
