"""Rebuild the twin tests/test_assess.py judges records against: tests/twin/results/geometric_slope.

    python tests/twin/rebuild.py WORKDIR

runs the workflow (offline.scope: none: the fits on the full solver, a couple of minutes on one core) in WORKDIR on
8 runs of the bundled data set with the configuration below, then copies what `hybridtwin assess` reads of the
twin (hybridtwin.online.twin.FILES) here. Rebuild it when the twin's card format or the joint fit's tables change.
"""

import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from test_workflow import SNAKEMAKE, _copy_workflow  # noqa: E402

from hybridtwin.online.twin import FILES  # noqa: E402

RUNS = ["r400_m25p9", "r550_m25p9", "r650_m25p9", "r650_m14p8", "r750_m14p8", "r850_m14p8", "r850_m0p0",
        "r950_m0p0", "v700_m19p5"]
CONFIG = """
harmonics: 3
runs: data/small/runs.tsv
effects_files: []
offline: {scope: none}
identification: {trials: 4, monte_carlo: 20, joint: {trials: 4, monte_carlo: 10, monte_carlo_starts: 2}}
variants:
  geometric_slope:
    effects: [centrifugal_softening, structural_damping, upper_housing, lower_bearing, unbalance, shaft_bow,
              geometric_spring, slope_spring]
    unknown: {k_b: [2000, 3500], zeta_s: [0.01, 0.05], zeta_bup: [0, 0.05], q_x: [0.001, 0.01], q_y: [0.001, 0.01],
              k_w: [0, 1000], k_z: [0, 1000]}
"""


def main(work: Path) -> None:
    work.mkdir(parents=True)
    _copy_workflow(work, RUNS, CONFIG)
    subprocess.run([*SNAKEMAKE, "results/geometric_slope/twin.yaml", "--cores", "1"], cwd=work, check=True)
    for name in FILES.values():
        target = HERE / "results" / "geometric_slope" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(work / "results" / "geometric_slope" / name, target)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
