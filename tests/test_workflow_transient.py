"""The workflow end to end on a transient project: run-up and coast-down records through every rule that reads a
joint fit's parameter table (twin card, diagnosis, validation), in a temporary copy.

The run-up example's records (examples/runup: keyphasor, probes at 45/135 degrees, micrometres, slow-roll runout)
with one fit run-up, the fit coast-down and the validation run-up, the Geometric variant on the full solver
(``offline.scope: none``) and two diagnosis candidates: the same rules as the example, in a few minutes. The
example's workflow once stopped in twin_card and diagnose because they took the fit runs from the parameter
table's nuisance rows, whose run is a record's name for a runout offset: nothing but a run of the rules sees that.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from hybridtwin.identify import identification as idn

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "runup"
RECORDS = ["up15", "down26", "up8"]


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    work = tmp_path_factory.mktemp("transient")
    for item in ("Snakefile", "workflow", "scripts", "profiles"):
        source = ROOT / item
        (shutil.copytree if source.is_dir() else shutil.copy)(source, work / item)
    (work / "data" / "records").mkdir(parents=True)
    sheet = pd.read_csv(EXAMPLE / "runs.tsv", sep="\t", dtype=str, keep_default_na=False)
    sheet = sheet[sheet["run"].isin(RECORDS)]
    for path in sheet["path"]:
        shutil.copy(EXAMPLE / path, work / path)
    sheet.to_csv(work / "runs.tsv", sep="\t", index=False)
    example = yaml.safe_load((EXAMPLE / "config" / "config.yaml").read_text())
    config = {"machine": example["machine"], "runs": "runs.tsv", "harmonics": 3, "effects_files": [],
              "variants": {"geometric": example["variants"]["geometric"]},
              "offline": {"scope": "none"},
              "identification": {"per_run": [], "trials": 2, "monte_carlo": 0, "keyphasor": True,
                                 "joint": {"trials": 3, "monte_carlo": 0}},
              "diagnosis": {"candidates": ["expansion_k4", "cross_coupled_stiffness"], "sparse_variant": None}}
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    targets = [f"results/geometric/{name}" for name in ("twin.yaml", "diagnosis.md", "validation.tsv",
                                                        "parameters.tsv")]
    run = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", *targets], cwd=work,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return work


def test_the_rules_after_the_joint_fit_take_its_bands_as_fit_runs(project):
    table = idn.read_parameters(project / "results/geometric/parameters.tsv")
    runs = idn.fit_runs(table)
    assert runs and all(run.startswith(("up15_b", "down26_b")) for run in runs)
    card = yaml.safe_load((project / "results/geometric/twin.yaml").read_text())
    assert card  # written (the rule failed before on the runout offsets' record rows)
    validation = pd.read_csv(project / "results/geometric/validation.tsv", sep="\t")
    assert validation["run"].astype(str).str.startswith("up8_b").all() and len(validation)
    text = (project / "results/geometric/diagnosis.md").read_text()
    assert "expansion_k4" in text
