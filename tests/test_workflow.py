"""The Snakemake workflow end to end on a small configuration, in a temporary copy."""

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    work = tmp_path_factory.mktemp("workflow")
    for item in ("Snakefile", "workflow", "scripts", "config", "profiles"):
        source = ROOT / item
        (shutil.copytree if source.is_dir() else shutil.copy)(source, work / item)
    (work / "config" / "operating_points.tsv").write_text(
        "run\trpm\teccentric_mass_g\trole\nslow\t400\t25.9\tfit\nfast\t650\t25.9\tfit\nheld\t700\t19.5\tvalidate\n"
    )
    (work / "small.yaml").write_text("harmonics: 3\n")
    return work


def _snakemake(work, *args):
    return subprocess.run([*SNAKEMAKE, "--cores", "2", "--configfile", "small.yaml", *args], cwd=work,
                          capture_output=True, text=True)


def test_workflow_runs_and_rerun_is_a_no_op(workdir):
    run = _snakemake(workdir)
    assert run.returncode == 0, run.stderr[-3000:]
    for variant in ("geometric", "expansion", "final"):
        table = pd.read_csv(workdir / "results" / variant / "whitebox" / "sweep.tsv", sep="\t")
        assert table["run"].tolist() == ["slow", "fast", "held"]  # every run kept, in order
        assert table["success"].all()
        assert "U3_re_m" in table and "U4_re_m" not in table  # H from the overlay
        assert (workdir / "results" / variant / "whitebox" / "sweep.png").stat().st_size > 0
        assert (workdir / "logs" / variant / "whitebox_sweep.log").read_text().count("converged") == 3
    again = _snakemake(workdir, "--dry-run")
    assert again.returncode == 0
    assert "Nothing to be done" in again.stdout + again.stderr


def test_invalid_config_is_rejected_with_the_reason(workdir):
    (workdir / "bad.yaml").write_text("harmonics: 0\n")
    run = subprocess.run([*SNAKEMAKE, "--cores", "1", "--configfile", "bad.yaml", "--dry-run"], cwd=workdir,
                         capture_output=True, text=True)
    assert run.returncode != 0
    output = run.stdout + run.stderr
    assert "harmonics" in output and "minimum" in output
