"""Exact sensitivities and warm starts of the full-solver forward model, against the former method.

    python benchmarks/sensitivity_benchmark.py [--variant geometric] [--sets 8] [--repeats 3]

On the bundled plan's 19 fit runs (data/default/runs.tsv), for ``--sets`` parameter sets drawn in the
variant's box (seeded), one thread:

- solve: the steady states of every set at every run by a run-up from 300 RPM (``forward.run_up``,
  what every evaluation cost before);
- sensitivity: ``solver.sensitivity`` of all the variant's unknowns at those states; its cost per
  parameter against the solve (target: <= 0.2);
- warm solve: the same sets moved by a small step (0.02 in normalised units), solved at the run's
  speed from the previous states moved along their sensitivities (``SolverModel``'s warm start);
- one Jacobian evaluation of the former ``SolverModel`` (forward differences: 1 + d run-ups per set)
  against the new one (one warm solve + the sensitivities).
Best of ``--repeats`` for each figure (the machine is shared: the minimum is the least disturbed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from hybridtwin.identify.forward import SolverModel, run_up
from hybridtwin.solvers.solver import sensitivity
from hybridtwin.model.variants import builtin_variant

ROOT = Path(__file__).resolve().parents[1]


def best(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="geometric")
    parser.add_argument("--sets", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--harmonics", type=int, default=5)
    args = parser.parse_args()
    variant = builtin_variant(args.variant)
    runs = pd.read_csv(ROOT / "data/default/runs.tsv", sep="\t", dtype={"run": str})
    runs = runs[runs["role"] == "fit"]
    names = list(variant.unknown)
    lower, upper = variant.bounds(names)
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.6, 0.6, (args.sets, len(names)))
    H = args.harmonics
    rows = []
    with threadpool_limits(1):
        for run in runs.itertuples():
            values = {"m_e": np.full(args.sets, run.eccentric_mass_g * 1e-3)}
            values |= {p: lower[j] + 0.5 * (x[:, j] + 1) * (upper[j] - lower[j]) for j, p in enumerate(names)}
            full = {k: np.broadcast_to(np.asarray(v, float), (args.sets,)).copy()
                    for k, v in variant.values(values).items()}
            state = run_up(variant, [run.rpm], full, H)[0]

            def build(v, rpm=run.rpm):
                return variant.model.system(v, rpm)

            steps = 1e-4 * (upper - lower)
            t_solve = best(lambda: run_up(variant, [run.rpm], full, H), args.repeats)
            t_sens = best(lambda: sensitivity(build, full, names, state, steps), args.repeats)
            new = _model(variant, run, names, lower, upper, H)
            old = _model(variant, run, names, lower, upper, H, analytic=False, warm=False)
            new.evaluate(x)  # the cache: the previous LM iterate
            step = x + 0.02 * rng.standard_normal(x.shape)
            t_old = best(lambda: old.evaluate(step), 1)
            copies = []

            def warm_evaluation(model=new, point=step, out=copies):
                out.append(_fresh_copy(model))
                out[-1].evaluate(point)

            t_new = best(warm_evaluation, args.repeats)
            rows.append({"run": run.run, "rpm": run.rpm, "solve_s": t_solve, "sensitivity_s": t_sens,
                         "per_parameter_ratio": t_sens / len(names) / t_solve,
                         "jacobian_old_s": t_old, "jacobian_new_s": t_new, "speed_up": t_old / t_new,
                         "warm": f"{copies[-1].n_warm}/{args.sets}"})
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 200)
    print(f"variant {args.variant}: {len(names)} unknowns, {args.sets} parameter sets, {len(runs)} fit runs, H = {H}")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    total = table[["solve_s", "sensitivity_s", "jacobian_old_s", "jacobian_new_s"]].sum()
    print(f"\nall runs: solve {total.solve_s:.3f} s, sensitivities of {len(names)} parameters {total.sensitivity_s:.3f} s"
          f" -> per parameter {total.sensitivity_s / len(names) / total.solve_s:.3f} x a solve (target <= 0.2)")
    print(f"one Jacobian evaluation of {args.sets} sets at every run: former (forward differences, run-ups) "
          f"{total.jacobian_old_s:.2f} s, now (warm start + exact sensitivities) {total.jacobian_new_s:.2f} s: "
          f"{total.jacobian_old_s / total.jacobian_new_s:.1f}x")
    return 0


def _model(variant, run, names, lower, upper, H, **options) -> SolverModel:
    return SolverModel(variant, run.run, run.rpm, run.eccentric_mass_g, names, lower, upper, H, **options)


def _fresh_copy(model: SolverModel) -> SolverModel:
    """The model with its warm-start cache as it is now (each repeat starts from the same previous iterate)."""
    import copy

    return copy.deepcopy(model)


if __name__ == "__main__":
    sys.exit(main())
