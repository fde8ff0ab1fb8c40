"""Rebuild the twin tests/test_assess.py judges records against: tests/twin/results/geometric_slope.

    python tests/twin/rebuild.py WORKDIR

runs the workflow in WORKDIR on the bundled data set (its 19 fit runs) with the project's configuration reduced to
the variant geometric_slope, fitted on the full solver (offline.scope: none: no library; the same joint fit as
the libraries' polish, benchmarks/README.md "The main job without libraries"; about 10 minutes of CPU), then copies
what `hybridtwin assess` reads of the twin (hybridtwin.online.twin.FILES) here. Rebuild it when the twin's card
format or the joint fit's tables change.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE.parent))

from test_workflow import SNAKEMAKE, _copy_workflow  # noqa: E402

from hybridtwin.online.twin import FILES  # noqa: E402


#: the twin's variant, the bundled config's improved variant when the fixture was built (geometric + the paper's slope
#: force, the bow per run); the config now carries the diagnosis's own recommendation instead, so it is kept here
GEOMETRIC_SLOPE = {
    "description": "geometric + slope_spring: upper bearing force on the shaft slope (eq. 38-39)",
    "effects": ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "unbalance",
                "shaft_bow", "geometric_spring", "slope_spring"],
    "unknown": {"k_b": [2000, 3500], "zeta_s": [0.01, 0.05], "zeta_bup": [0, 0.05], "q_x": [0.001, 0.01],
                "q_y": [0.001, 0.01], "k_w": [0, 1000], "k_z": [0, 1000]}}


def config() -> str:
    """The project's configuration with geometric_slope alone, on the full solver, no side-by-side sparse route."""
    data = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    data["runs"] = "data/small/runs.tsv"
    data["variants"] = {"geometric_slope": GEOMETRIC_SLOPE}
    data["offline"] = {"scope": "none"}
    data["identification"]["sparsity"] = {}
    data["diagnosis"] = {"sparse_variant": None}
    data.pop("rig", None)
    return yaml.safe_dump(data, sort_keys=False)


def main(work: Path) -> None:
    work.mkdir(parents=True)
    runs = pd.read_csv(ROOT / "data" / "default" / "runs.tsv", sep="\t")["run"].tolist()
    _copy_workflow(work, runs, config())
    subprocess.run([*SNAKEMAKE, "results/geometric_slope/twin.yaml", "--cores", "2"], cwd=work, check=True)
    for name in FILES.values():
        target = HERE / "results" / "geometric_slope" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(work / "results" / "geometric_slope" / name, target)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
