"""Where the library pays (issue 50, item 4): the library against the full solver as the machine grows.

    OMP_NUM_THREADS=1 python benchmarks/library_crossover.py [--refine 1,2,4,8] [--scenarios 300] [--points 64]

The stepped rotor of examples/stepped_rotor (variant ``linear``: four unknowns, the bearings' stiffness and damping;
H = 1) with every shaft element split in ``refine`` (17 elements, 72 DOFs at 1; 144 at 2, 288 at 4, 576 at 8: the
"refined shaft of a few hundred DOF"), and the VARM (variant ``geometric``, five unknowns, H = 5, nonlinear), each at
one run (the stepped rotor at 3800 RPM with 20 g, near its critical speeds; the VARM at 600 RPM with 25.9 g). Per
machine, CPU time (one thread, ``time.process_time``):

- the offline stage of one run's library: ``--scenarios`` Latin-hypercube scenarios solved by run-up with their
  stability check (``scenarios.solve_runs``, as a chunk does), the POD and the sPGD fit (``library.build_library``
  with the workflow's default sPGD options), per scenario and in total;
- one online evaluation, the response and its Jacobian at ``--points`` points (what each LM iteration asks), on
  the full solver (``forward.SolverModel``: harmonic balance with its analytic sensitivities, warm-started) and on
  the library (``forward.SensorSurrogate``), per point;
- the crossover: the offline cost over the saving per evaluation, the number of evaluations from which the library
  is cheaper; the main job's fits ask about 1e5 per run (50 trials and 8 Monte Carlo starts of LM, about 20
  iterations each, 1000 repeats); and the library's test error (relative, median over 100 held-out scenarios).
"""

from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from threadpoolctl import threadpool_limits

from hybridtwin import config as cfg
from hybridtwin.identify.forward import SensorSurrogate, SolverModel
from hybridtwin.model.variants import builtin_variant
from hybridtwin.offline.library import build_library, relative_sensor_error, sensor_dofs
from hybridtwin.offline.pod import pod, to_features
from hybridtwin.offline.scenarios import sample_scenarios, solve_runs

ROOT = Path(__file__).resolve().parents[1]
SPGD = {"degree": 8, "max_terms": 60, "ridge": 1e-8, "patience": 8, "backfit_iterations": 3}


def stepped(refine: int):
    """The stepped rotor's variant ``linear`` with every element split in ``refine``, its nodes renumbered."""
    folder = ROOT / "examples" / "stepped_rotor" / "config"
    config = yaml.safe_load((folder / "config.yaml").read_text())
    machine = copy.deepcopy(config["machine"])
    for segment in machine["segments"]:
        segment["n_elements"] *= refine
    for disk in machine["disks"]:
        disk["node"] *= refine
    for bearing in machine["bearings"].values():
        bearing["node"] *= refine
    machine["unbalance_planes"] = {k: v * refine for k, v in machine["unbalance_planes"].items()}
    for sensor in machine["sensors"].values():
        sensor["node"] *= refine
    config["machine"] = machine
    variant = cfg.variant(config, "linear", folder)
    return f"stepped rotor x{refine}", variant, 3800.0, 20.0, int(config["harmonics"])


def varm():
    return "VARM (geometric)", builtin_variant("geometric"), 600.0, 25.9, 5


def measure(name, variant, rpm, mass_g, H, n_scenarios, n_points) -> dict:
    table = sample_scenarios(variant, n_scenarios, seed=1, n_test=100)
    values = {k: table[k].to_numpy(float) for k in variant.unknown_names}
    runs = pd.DataFrame({"run": ["r"], "rpm": [rpm], "eccentric_mass_g": [mass_g]})
    start = time.process_time()
    solved = solve_runs(variant, runs, values, H)
    t_solve = time.process_time() - start
    harmonics, ok = solved.harmonics[0], solved.success[0] & solved.stable[0]
    start = time.process_time()
    split = table["split"].to_numpy()
    features = to_features(np.nan_to_num(harmonics))
    basis = pod(features[ok & (split == "train")])
    lower, upper = variant.bounds(variant.unknown_names)
    library = build_library("r", basis, harmonics, table[variant.unknown_names].to_numpy(float), split, ok,
                            variant.unknown_names, lower, upper, sensor_dofs(variant.model.shaft), None, **SPGD)
    t_fit = time.process_time() - start
    test = ok & (split == "test")
    shaft = variant.model.shaft
    predicted = library.field(table.loc[test, variant.unknown_names].to_numpy(float))
    error = float(np.median(relative_sensor_error(predicted, harmonics[test])))
    x = np.random.default_rng(2).uniform(-0.5, 0.5, (n_points, len(lower)))
    solver = SolverModel(variant, "r", rpm, mass_g, variant.unknown_names, lower, upper, H)
    solver.evaluate(x[:1], True)  # the warm start the fits have from their previous iteration
    start = time.process_time()
    solver.evaluate(x, True)
    t_solver = (time.process_time() - start) / n_points
    surrogate = SensorSurrogate(library, H)
    surrogate.evaluate(x[:1], True)
    start = time.process_time()
    for _ in range(20):
        surrogate.evaluate(x, True)
    t_library = (time.process_time() - start) / (20 * n_points)
    offline = t_solve + t_fit
    return {"machine": name, "n_dof": shaft.n_dof, "unknowns": len(lower), "H": H, "scenarios": n_scenarios + 100,
            "offline_s": offline, "solve_ms_per_scenario": 1e3 * t_solve / (n_scenarios + 100), "fit_s": t_fit,
            "solver_ms_per_eval": 1e3 * t_solver, "library_ms_per_eval": 1e3 * t_library,
            "crossover_evaluations": offline / max(t_solver - t_library, 1e-12), "test_error_pct": 100 * error}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--refine", default="1,2,4,8")
    parser.add_argument("--scenarios", type=int, default=300)
    parser.add_argument("--points", type=int, default=64)
    args = parser.parse_args()
    rows = []
    with threadpool_limits(1):
        for case in [varm] + [lambda r=int(r): stepped(r) for r in args.refine.split(",")]:
            name, variant, rpm, mass, H = case()
            row = measure(name, variant, rpm, mass, H, args.scenarios, args.points)
            rows.append(row)
            print(f"{name}: {row['n_dof']} DOFs, offline {row['offline_s']:.1f} s, solver {row['solver_ms_per_eval']:.3g}"
                  f" ms, library {row['library_ms_per_eval']:.3g} ms per evaluation", flush=True)
    print("\n| machine | DOFs | unknowns, H | offline: solves per scenario / sPGD fit / total | one evaluation with its "
          "Jacobian: solver / library | library pays after (evaluations) | library test error |\n"
          "|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['machine']} | {r['n_dof']} | {r['unknowns']}, {r['H']} | {r['solve_ms_per_scenario']:.3g} ms / "
              f"{r['fit_s']:.2g} s / {r['offline_s']:.3g} s | {r['solver_ms_per_eval']:.3g} / "
              f"{r['library_ms_per_eval']:.3g} ms | {r['crossover_evaluations']:.3g} | {r['test_error_pct']:.2g} % |")


if __name__ == "__main__":
    main()
