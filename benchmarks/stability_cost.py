"""Extra cost of the stability check (Floquet multipliers, ``hybridtwin.solvers.floquet``) in the chunk jobs' solver call.

    python benchmarks/stability_cost.py [--variant geometric] [--scenarios 64] [--repeats 2]

``scenarios.solve_runs`` of ``--scenarios`` parameter sets drawn in the variant's box (seeded) at the bundled
plan's runs (data/default/runs.tsv, via config/config.yaml), H = 5, one thread, CPU time: as it is (the
converged points at the runs' speeds assessed in one batch) and with ``floquet_radius`` replaced by a no-op
(everything else the same). Best of ``--repeats`` each (the machine is shared). Also prints how many converged
points are unstable. About 10 s per repeat and variant for 64 scenarios.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

from hybridtwin import config as cfg
from hybridtwin.offline import scenarios

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variant", default="geometric")
    parser.add_argument("--scenarios", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["runs"] = str(ROOT / config["runs"])
    runs = cfg.run_plan(config)
    variant = cfg.variant(config, args.variant)
    lo, hi = variant.bounds(variant.unknown_names)
    draw = lo + np.random.default_rng(0).random((args.scenarios, lo.size)) * (hi - lo)
    values = dict(zip(variant.unknown_names, draw.T))
    check = scenarios.floquet_radius
    cpu = {"with": [], "without": []}
    for _ in range(args.repeats):
        for label, times in cpu.items():
            scenarios.floquet_radius = check if label == "with" else lambda system, harmonics: np.zeros(len(harmonics))
            start = time.process_time()
            scenarios.solve_runs(variant, runs, values, 5)
            times.append(time.process_time() - start)
    scenarios.floquet_radius = check
    with_, without = min(cpu["with"]), min(cpu["without"])
    points = args.scenarios * len(runs)
    print(f"{args.variant}: {args.scenarios} scenarios x {len(runs)} runs, CPU {without:.2f} s without the check, "
          f"{with_:.2f} s with it: +{100 * (with_ / without - 1):.0f} %, {1e3 * (with_ - without) / points:.2f} ms per "
          f"(run, scenario) against {1e3 * without / points:.2f} ms for its solve")
    solved = scenarios.solve_runs(variant, runs, values, 5)
    converged = int(solved.success.sum())
    print(f"{converged} converged points, {int((solved.success & ~solved.stable).sum())} of them unstable")


if __name__ == "__main__":
    with threadpool_limits(1):
        main()
