"""A full disk at the user's desk (issue 55, item 4): a job that cannot write for want of space (errno ENOSPC, 28)
ends with one message naming the file it was writing, the space left and what to free, instead of the writer's
traceback; the same command, once space is freed, resumes: the finished jobs kept, the failed one run again.

The full disk is simulated: a ``sitecustomize`` module on the jobs' PYTHONPATH makes pandas' ``to_csv`` write a
few bytes of one chosen file and then raise OSError(ENOSPC), as a write to a full file system does (no file name in
the error: the job's outputs name it).
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd

from hybridtwin.config import disk_full, disk_full_message
from hybridtwin.data.measured import read_harmonics, write_harmonics
from workflow_helpers import RUNS, copy_workflow, snakemake

FAULT = textwrap.dedent("""\
    import errno, os
    import pandas as pd

    _to_csv = pd.DataFrame.to_csv
    _target = os.environ.get("HYBRIDTWIN_TEST_DISK_FULL", "")

    def to_csv(self, path_or_buf=None, *args, **kwargs):
        if _target and isinstance(path_or_buf, (str, os.PathLike)) and str(path_or_buf).endswith(_target):
            with open(path_or_buf, "w") as stream:
                stream.write("run\\t")  # a partial file, as a write cut short leaves it
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return _to_csv(self, path_or_buf, *args, **kwargs)

    pd.DataFrame.to_csv = to_csv
    """)
TARGET = "results/data/harmonics.tsv"
SMALL_TARGETS = [TARGET]


def test_the_message_names_the_file_the_space_and_what_to_free(tmp_path):
    (tmp_path / "results" / "geometric" / "snapshots").mkdir(parents=True)
    (tmp_path / "results" / "geometric" / "snapshots" / "chunk").write_bytes(b"0" * 3_000_000)
    (tmp_path / "results" / "data").mkdir()
    wrapped = ValueError("could not write the store")
    wrapped.__cause__ = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    full = disk_full(wrapped)
    assert full is wrapped.__cause__ and disk_full(ValueError("other")) is None
    assert disk_full(OSError(errno.EACCES, "denied")) is None
    message = disk_full_message(full, [str(tmp_path / "results" / "data" / "harmonics.tsv")], tmp_path)
    assert f"while writing {tmp_path / 'results' / 'data' / 'harmonics.tsv'}" in message
    assert "No space left on device" in message and "MB free on the file system of" in message
    assert f"{tmp_path / 'results' / 'geometric' / 'snapshots'} (3 MB)" in message
    assert "run the same snakemake command again" in message
    named = disk_full_message(OSError(errno.ENOSPC, "No space left on device", "results/x.zarr/0.0"), [], tmp_path)
    assert "while writing results/x.zarr/0.0" in named


def test_a_job_on_a_full_disk_says_so_in_one_message(tmp_path):
    """A script as Snakemake runs it (``snakemake`` in its globals, ``rule_logger`` called): exit status 1, the
    message on standard error and in the job's log (which Snakemake shows), with where it was raised, no
    traceback."""
    (tmp_path / "fault").mkdir()
    (tmp_path / "fault" / "sitecustomize.py").write_text(FAULT)
    script = tmp_path / "job.py"
    script.write_text(textwrap.dedent(f"""\
        from types import SimpleNamespace
        import pandas as pd
        from hybridtwin import config as cfg
        snakemake = SimpleNamespace(output=["out/table.tsv"], log=["job.log"])
        log = cfg.rule_logger(snakemake.log[0], "demo")
        pd.DataFrame({{"a": [1.0]}}).to_csv("out/table.tsv", sep="\\t")
        """))
    (tmp_path / "out").mkdir()
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(tmp_path / "fault"), os.environ.get("PYTHONPATH", "")]),
                        "HYBRIDTWIN_TEST_DISK_FULL": "table.tsv"}
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 1
    assert "demo: error: disk full (errno 28, No space left on device) while writing out/table.tsv" in done.stderr
    assert "Traceback" not in done.stderr
    log = (tmp_path / "job.log").read_text()
    assert "disk full" in log and "OSError" in log and "raised at" in log and "Traceback" not in log


def test_the_workflow_on_a_full_disk_names_the_file_and_resumes(tmp_path):
    """The small workflow's data stage with the full disk at its harmonics table: the job says so and fails, the
    partial file goes; the same command again runs only that job, whose table is then whole: every run of the
    sheet, the bytes of its per-run tables joined by the table's own writer."""
    (tmp_path / "work").mkdir()
    work = copy_workflow(tmp_path / "work")
    (tmp_path / "fault").mkdir()
    (tmp_path / "fault" / "sitecustomize.py").write_text(FAULT)
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(tmp_path / "fault"), os.environ.get("PYTHONPATH", "")]),
                        "HYBRIDTWIN_TEST_DISK_FULL": TARGET}
    failed = subprocess.run([sys.executable, "-m", "snakemake", *SMALL_TARGETS, "--cores", "2"], cwd=work, env=env,
                            capture_output=True, text=True, timeout=900)
    assert failed.returncode != 0
    said = failed.stdout + failed.stderr
    assert f"measured_harmonics: error: disk full (errno 28, No space left on device) while writing {TARGET}" in said
    assert "run the same snakemake command again" in said and "Traceback" not in said
    assert not (work / TARGET).exists()  # the partial file: removed by Snakemake
    finished = {p: p.stat().st_mtime_ns for p in (work / "results" / "data").rglob("*") if p.is_file()}
    assert any(p.name == "check.tsv" for p in finished)
    again = snakemake(work, *SMALL_TARGETS)  # space freed: the same command
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "measured_harmonics" in again.stdout + again.stderr
    assert all(p.stat().st_mtime_ns == t for p, t in finished.items())  # the finished jobs kept, not redone
    order = pd.read_csv(work / "data" / "small" / "runs.tsv", sep="\t")["run"]  # the job joins in the sheet's order
    runs = [work / "results" / "data" / "runs" / run / "harmonics.tsv" for run in order]
    assert sorted(order) == sorted(RUNS)
    expected = tmp_path / "expected.tsv"
    write_harmonics(pd.concat([read_harmonics(p) for p in runs], ignore_index=True), expected)
    table = read_harmonics(work / TARGET)
    assert sorted(table["run"]) == sorted(RUNS)
    assert (work / TARGET).read_bytes() == expected.read_bytes()
