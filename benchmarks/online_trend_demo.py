"""The README's trend figure: twelve days of a machine against its twin (docs/img/online_trend.png).

    python benchmarks/online_trend_demo.py --twin results/geometric_slope --out online_demo

One steady record a day, made by the virtual rig from the bundled data's truth with every nuisance and a
keyphasor, at the speeds and masses of the twin's fit runs with an added mass in turn (the last day at 900 RPM
without one, next to the resonance): days 1-5 the machine the twin was built from, days 6-9 its upper bearing
softening by 1 % a day, days 10-12 the bearing as new again and a cross-coupled stiffness of 100 N/m appearing.
The records go into a runs sheet with a timestamp column, and ``hybridtwin assess`` judges the sheet (its
console lines printed); the trend figure is ``OUT/assessments/trend.png`` (copied to ``--figure`` when given).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from hybridtwin.cli import main as hybridtwin
from hybridtwin.rig.rig import DEFAULT_TRUTH, Imperfections, RigSpec, Truth, generate
from hybridtwin.online.twin import load_twin

TRUTH = DEFAULT_TRUTH["values"]
DAYS = 12


def day_truth(day: int) -> tuple[dict, list]:
    """The machine on ``day`` (1-based): values changed and effects added."""
    if day >= 10:
        return {"k_xy": 100.0}, ["cross_coupled_stiffness"]
    return {"k_b": (1 - 0.01 * max(0, day - 5)) * TRUTH["k_b"]}, []


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--twin", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--figure", type=Path, default=None, help="copy the trend figure here")
    args = parser.parse_args(argv)
    twin = load_twin(args.twin)
    points = twin.runs[twin.runs["eccentric_mass_g"] > 0].reset_index(drop=True)  # the runs with an added mass
    near = {"rpm": 900.0, "eccentric_mass_g": 0.0}  # the last day: next to the resonance, no added mass
    rows = []
    for day in range(1, DAYS + 1):
        point = points.iloc[(3 * day) % len(points)] if day < DAYS else near
        run = f"day{day:02d}"
        values, effects = day_truth(day)
        plan = pd.DataFrame({"run": [run], "rpm": [float(np.round(point["rpm"]))],
                             "eccentric_mass_g": [float(point["eccentric_mass_g"])], "role": ["fit"]})
        truth = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"] + effects, "values": TRUTH | values})
        generate(plan, RigSpec(truth, Imperfections(keyphasor=True), seed=12), args.out / "rig" / run)
        shutil.copy(args.out / "rig" / run / "records" / f"{run}.csv", _records(args.out) / f"{run}.csv")
        rows.append({"run": run, "rpm": plan["rpm"][0], "eccentric_mass_g": plan["eccentric_mass_g"][0],
                     "path": f"records/{run}.csv", "role": "fit", "timestamp": f"2026-11-{day:02d}T08:00:00"})
    sheet = args.out / "runs.tsv"
    pd.DataFrame(rows).to_csv(sheet, sep="\t", index=False)
    status = hybridtwin(["assess", str(sheet), "--twin", str(args.twin), "--out", str(args.out / "assessments")])
    if args.figure is not None:
        shutil.copy(args.out / "assessments" / "trend.png", args.figure)
    return status


def _records(out: Path) -> Path:
    folder = out / "records"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


if __name__ == "__main__":
    sys.exit(main())
