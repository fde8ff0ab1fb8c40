"""Settings read once (issue 37, part 3): the workflow reads its runs sheet once per plan (it read it 65 times while
planning the default project: every input function and param opened it again), and the readers that take a sheet
give the same from the sheet already read as from its path."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd

from hybridtwin.config import run_plan
from hybridtwin.data.measurements import read_runs, runs_with_role, sheet_entry, sheet_of

ROOT = Path(__file__).resolve().parents[1]
SHEET = ROOT / "data" / "default" / "runs.tsv"

# counts every call of the one reader of runs sheets in the process that imports it (snakemake, planning)
COUNTER = textwrap.dedent("""
    import atexit
    import hybridtwin.data.measurements as measurements
    calls = []
    reader = measurements.read_runs
    def read_runs(*args, **kwargs):
        calls.append(str(args[0] if args else kwargs.get("path")))
        return reader(*args, **kwargs)
    measurements.read_runs = read_runs
    atexit.register(lambda: print(f"READ_RUNS {len(calls)} {sorted(set(calls))}"))
""")


def test_the_workflow_reads_its_runs_sheet_once_per_plan(tmp_path):
    (tmp_path / "sitecustomize.py").write_text(COUNTER)
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT / "src"),
                                                       os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1", "-q", "--directory", str(ROOT)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    line = [ln for ln in done.stdout.splitlines() if ln.startswith("READ_RUNS")]
    assert line, f"the counter did not run:\n{done.stdout[-1000:]}\n{done.stderr[-1000:]}"
    assert line[-1].split()[1] == "1", line[-1]


def test_a_sheet_already_read_gives_what_its_path_gives():
    sheet = read_runs(SHEET, require_mass=True)
    assert sheet_of(sheet) is sheet  # passed on, not read again
    pd.testing.assert_frame_equal(run_plan(sheet), run_plan(str(SHEET)))
    pd.testing.assert_frame_equal(run_plan(sheet), run_plan({"runs": str(SHEET)}))
    for role in ("fit", "validate"):
        assert runs_with_role(sheet, role) == runs_with_role(SHEET, role)
    run = sheet["run"].iloc[3]
    assert sheet_entry(sheet, run) == sheet_entry(SHEET, run)


def test_the_shared_sheet_is_never_written_by_its_readers():
    sheet = read_runs(SHEET, require_mass=True)
    before = sheet.copy()
    plan = run_plan(sheet)
    plan["rpm"] = 0.0  # what run_plan does with measured speeds: on its own copy
    entry = sheet_entry(sheet, sheet["run"].iloc[0])
    entry["rpm"] = -1.0
    pd.testing.assert_frame_equal(sheet, before)


def test_a_run_missing_from_a_sheet_already_read_names_the_file():
    sheet = read_runs(SHEET, require_mass=True)
    try:
        sheet_entry(sheet, "no_such_run")
    except Exception as err:  # DataError
        assert str(SHEET) in str(err) and "no_such_run" in str(err)
    else:
        raise AssertionError("no error for a run the sheet does not have")
