"""Benchmark of the offline sPGD libraries (issue 3, "What it must show").

Reads the workflow's results of one variant (default results/geometric: scenarios, snapshots.zarr,
pod.zarr, library/*.zarr) and, on the SAME training / validation / test scenarios as the workflow
(the splits stored in snapshots.zarr; observable scenarios only: converged and inside the sensor range),
measures:

1. Surrogates, per run: the sPGD library exactly as the workflow builds it
   (hybridtwin.offline.library.build_library on the run's POD, the config's offline.spgd options) against two
   peers a user would pick, both fitted to the SAME targets, the run's POD coefficients
   alpha = Phi^T q (the sensor response is then Phi_sensor alpha for all three):
   - scikit-learn GaussianProcessRegressor, C * Matern(ARD, nu=2.5) + WhiteKernel, normalize_y=True,
     inputs scaled to [-1, 1]; one multi-output GP (every POD coefficient shares the kernel
     hyper-parameters, each is normalised separately), hyper-parameters by maximum likelihood on the
     training set;
   - scipy.interpolate.RBFInterpolator, thin-plate spline, degree 1, inputs scaled to [-1, 1], the
     smoothing chosen on the validation set (the sPGD chooses its size on the same set).
   Metric: hybridtwin.offline.library.relative_sensor_error on the test scenarios (median, p95); fit time;
   evaluation time per parameter set in batches of 1000 (sPGD with its exact Jacobian; the peers have
   none, so they are also timed with a forward-difference Jacobian, d + 1 evaluations); the full solver
   (variant.solve at the run's rpm and eccentric mass, batched over the run's test scenarios) per scenario.
   Targets: sPGD error <= 2x the GP's, sPGD evaluation with Jacobian <= 10 us per set, >= 100x faster
   than the full solver.
2. Library scope: "per run" (the workflow's libraries, one per run) vs "global" (offline.scope: global,
   hybridtwin.offline.library.build_global_library: ONE sPGD over the unknown parameters plus rpm and eccentric
   mass, fitted on the stacked snapshots of the fit runs of the runs sheet, POD over all of them, each run
   served by its slice at its operating point), scored on the test scenarios of every run; the validation
   runs (role "validate") are operating points the global library never saw. For those, the per-run scope is also
   shown as a user without new snapshots would use it: the library of the nearest fit run.

Usage (from the repository root, in the project's environment):

    pip install -e '.[bench]'        # scikit-learn, for the GP peer
    python benchmarks/library_benchmark.py                  # 5 representative runs + the scope comparison
    python benchmarks/library_benchmark.py --all            # every run
    python benchmarks/library_benchmark.py --runs r700_m14p8 v700_m19p5 --no-scope

Timings are wall-clock on the machine as it is (load average printed at the start; fit times also as CPU
time), evaluation times the best of --repeats batches; BLAS threads = --threads (default 1, as the
workflow's rules pin it: on a shared 2-core machine multi-threaded BLAS was up to 30x slower).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from hybridtwin import config as cfg
from hybridtwin.offline import snapshots
from hybridtwin.offline.library import Library, build_global_library, build_library, mode_scaling_kinks, relative_sensor_error
from hybridtwin.offline.pod import load_pod, to_features
from hybridtwin.model.sensor import observable, sensor_dofs
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant, builtin_variant
from hybridtwin.solvers.solver import solve_variant

DEFAULT_RPMS = (350, 700, 850, 900, 950)  # the default subset: a representative spread of speeds
BATCH = 1000  # parameter sets per evaluation batch
TARGET_ERROR_RATIO = 2.0
TARGET_EVAL_US = 10.0
TARGET_SPEEDUP = 100.0


def require_sklearn():
    try:
        import sklearn  # noqa: F401
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
    except ImportError:
        sys.exit("library_benchmark: scikit-learn is needed for the Gaussian-process peer and is not installed.\n"
                 "Install the benchmark extra from the repository root:  pip install -e '.[bench]'\n"
                 "(or: pip install 'scikit-learn>=1.4'), or skip the peers with --no-peers.")
    return GaussianProcessRegressor, ConstantKernel, Matern, WhiteKernel


# ----------------------------------------------------------------------------------------------- inputs

def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Install the GP peer with: pip install -e '.[bench]'")
    parser.add_argument("--results", default="results/geometric",
                        help="the variant's results folder (snapshots.zarr, pod.zarr, library/) [%(default)s]")
    parser.add_argument("--config", default="config/config.yaml", help="workflow config [%(default)s]")
    parser.add_argument("--runs", nargs="+", metavar="RUN",
                        help="runs to benchmark (default: one run at each of %s RPM)" % ", ".join(map(str, DEFAULT_RPMS)))
    parser.add_argument("--all", action="store_true", help="benchmark every run")
    parser.add_argument("--speed", choices=("auto", "nominal", "measured"), default="auto",
                        help="the rpm each run's snapshots were solved at: the runs sheet's nominal rpm or the "
                             "speed refined from the records (results/data/harmonics.tsv); auto: the one with "
                             "which the full solver reproduces the stored snapshots [%(default)s]")
    parser.add_argument("--speeds-table", default=None,
                        help="preprocessed table with rpm_true [<results>/../data/harmonics.tsv]")
    parser.add_argument("--solver-scenarios", type=int, default=200,
                        help="test scenarios per run solved by the full solver for its timing [%(default)s]")
    parser.add_argument("--gp-restarts", type=int, default=0, help="GP optimizer restarts [%(default)s]")
    # 50, not 7: a batch takes ~2 ms, and on a shared machine the best of 7 still carried the load (lowest
    # speed-up over the solver 71-101x in repeated runs of the same libraries; 101x with 200 repeats; 113x
    # since the evaluation reuses its intermediates)
    parser.add_argument("--repeats", type=int, default=50, help="timing repeats per batch (the best counts) [%(default)s]")
    parser.add_argument("--threads", type=int, default=1,
                        help="BLAS threads (1, as the workflow's rules pin it) [%(default)s]")
    parser.add_argument("--no-peers", action="store_true", help="skip the GP and RBF peers")
    parser.add_argument("--no-scope", action="store_true", help="skip the per-run vs global scope comparison")
    parser.add_argument("--spgd", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config offline.spgd option, e.g. --spgd degree_search=parameter (repeatable)")
    parser.add_argument("--global-max-terms", type=int, default=None,
                        help="max sPGD terms of the global library [config offline.spgd.max_terms]")
    return parser.parse_args(argv)


class Setup:
    """The variant, its runs and options as the workflow saw them."""

    def __init__(self, args: argparse.Namespace):
        self.results = Path(args.results)
        self.store = self.results / "snapshots.zarr"
        self.pod_store = self.results / "pod.zarr"
        for path in (self.store, self.pod_store):
            if not path.exists():
                sys.exit(f"library_benchmark: {path} does not exist; build it first "
                         f"(snakemake --cores 2 {self.results}/library_validation.tsv)")
        self.config = yaml.safe_load(Path(args.config).read_text())
        import zarr

        group = zarr.open_group(str(self.store), mode="r")
        self.variant_name = group.attrs["variant"]
        self.offline = cfg.offline(self.config)
        self.offline["spgd"] = cfg.spgd_for(self.config, self.variant_name)
        for item in args.spgd:  # values parsed as YAML scalars (numbers, words)
            key, _, value = item.partition("=")
            self.offline["spgd"][key] = yaml.safe_load(value)
        self.runs = list(group.attrs["runs"])
        self.parameters = list(group.attrs["parameters"])
        if self.variant_name in self.config.get("variants", {}):
            self.variant: Variant = cfg.variant(self.config, self.variant_name, Path(args.config).parent)
        elif self.variant_name in BUILTIN_VARIANTS:
            self.variant = builtin_variant(self.variant_name)
        else:
            sys.exit(f"library_benchmark: variant {self.variant_name!r} is neither in {args.config} nor built in")
        self.shaft = self.variant.model.shaft
        self.sensor_dofs = sensor_dofs(self.shaft)
        self.sensor_range_m = self.offline["sensor_range_mm"] * 1e-3
        self.lower, self.upper = self.variant.bounds(self.parameters)
        self.plan = cfg.run_plan(self.config).set_index("run")
        missing = sorted(set(self.runs) - set(self.plan.index))
        if missing:
            sys.exit(f"library_benchmark: runs {missing} of {self.store} are not in the runs sheet {self.config['runs']}")
        self.plan = self.plan.loc[self.runs]
        if "role" not in self.plan:
            self.plan["role"] = "fit"
        self.nominal_rpm = self.plan["rpm"].astype(float)
        table = Path(args.speeds_table) if args.speeds_table else self.results.parent / "data" / "harmonics.tsv"
        self.measured_rpm = None
        if table.exists():
            self.measured_rpm = cfg.run_plan(self.config, table).set_index("run").loc[self.runs, "rpm"].astype(float)
        self.speeds_table = table
        self.rpm = self.nominal_rpm  # set by choose_speed

    def kinks(self):
        """The sPGD pieces as the workflow's (config offline.pieces)."""
        if self.offline.get("pieces", "mode_scaling") == "none":
            return None
        return mode_scaling_kinks(self.variant, self.parameters, self.lower, self.upper)
        self.speed_source = "nominal"


def choose_speed(setup: Setup, mode: str, n: int = 4) -> str:
    """Which rpm the stored snapshots were solved at: re-solve a few test scenarios at each candidate.

    The store does not record its runs' speeds, and offline.speed may have changed since it was built.
    The check uses the slowest run (far from resonance, so a direct solve lands on the run-up's branch).
    """
    run = setup.nominal_rpm.idxmin()
    candidates = {"nominal": setup.nominal_rpm}
    if setup.measured_rpm is not None:
        candidates["measured"] = setup.measured_rpm
    if mode != "auto":
        if mode not in candidates:
            sys.exit(f"library_benchmark: --speed measured needs {setup.speeds_table}")
        setup.rpm, setup.speed_source = candidates[mode], mode
        return f"speeds: {mode} (--speed {mode})"
    snaps = snapshots.load(setup.store, run)
    pick = np.flatnonzero((snaps.split == "test") & snaps.success[0])[:n]
    mass = float(setup.plan.loc[run, "eccentric_mass_g"])
    deviations = {}
    for name, rpm in candidates.items():
        result = solve_full(setup, float(rpm[run]), mass, snaps.values[pick])
        deviations[name] = float(np.nanmax(relative_sensor_error(result.harmonics[:, :, setup.sensor_dofs],
                                                                 snaps.harmonics[0][pick][:, :, setup.sensor_dofs])))
    best = min(deviations, key=deviations.get)
    text = ", ".join(f"{k} rpm {float(candidates[k][run]):.3f}: max deviation {v:.1e}" for k, v in deviations.items())
    if deviations[best] > 1e-6:
        setup.rpm, setup.speed_source = candidates["nominal"], "nominal"
        return f"speeds: nominal (WARNING: no candidate speed reproduces {run}'s stored snapshots; {text})"
    setup.rpm, setup.speed_source = candidates[best], best
    return (f"speeds: {best} (the full solver reproduces {run}'s stored snapshots at it; {text}; "
            f"config offline.speed is {setup.offline['speed']!r})")


def select_runs(setup: Setup, args: argparse.Namespace) -> list[str]:
    if args.all:
        return list(setup.runs)
    if args.runs:
        stray = [r for r in args.runs if r not in setup.runs]
        if stray:
            sys.exit(f"library_benchmark: unknown run(s) {stray} (runs: {setup.runs})")
        return list(args.runs)
    chosen = []
    fit = setup.plan[setup.plan["role"] == "fit"]
    for rpm in DEFAULT_RPMS:  # per speed, the fit run with the highest eccentric mass (the most common one)
        rows = fit[np.isclose(fit["rpm"].astype(float), rpm)]
        if len(rows):
            chosen.append(rows.sort_values("eccentric_mass_g").index[-1])
    return chosen or list(setup.runs[:5])


# ----------------------------------------------------------------------------------------------- helpers

def solve_full(setup: Setup, rpm: float, mass_g: float, values: np.ndarray):
    overrides = {k: values[:, i] for i, k in enumerate(setup.parameters)}
    overrides["m_e"] = np.full(values.shape[0], mass_g * 1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return solve_variant(setup.variant, rpm, overrides, harmonics=setup.n_harmonics - 1)


def best_time(function, repeats: int) -> float:
    """Shortest of ``repeats`` wall-clock times after a warm-up (timeit's rule: the others measure the load)."""
    function()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.min(times))


class Clock:
    """Wall-clock and CPU time (all threads of this process) of a block."""

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu


def stats(error: np.ndarray) -> tuple[float, float]:
    if error.size == 0:
        return np.nan, np.nan
    return 100 * float(np.median(error)), 100 * float(np.percentile(error, 95))


def fd_points(x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """x and x + step e_j (j = 1..d), stacked: the d + 1 evaluations of a forward-difference Jacobian."""
    d = x.shape[1]
    shifted = x[None] + step * np.eye(d)[:, None, :]
    return np.concatenate([x, shifted.reshape(-1, d)])


def sensor_from_alpha(library: Library, alpha: np.ndarray) -> np.ndarray:
    """Sensor harmonics (N, H+1, 2) from POD coefficients, as the library maps them."""
    return library._to_sensor(alpha @ library._sensor_modes.T)


def fmt(value: float, digits: int = 3) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    if value == 0:
        return "0"
    magnitude = abs(value)
    if magnitude >= 1000 or magnitude < 1e-3:
        return f"{value:.2e}"
    return f"{value:.{digits}g}"


def verdict(ok: bool) -> str:
    return "OK" if ok else "MISSED"


def print_table(frame: pd.DataFrame, title: str) -> None:
    print(f"\n{title}")
    text = frame.map(lambda v: fmt(v) if isinstance(v, (float, np.floating)) else str(v)).to_string(index=False)
    print(text)


# ----------------------------------------------------------------------------------------------- part 1

def benchmark_run(setup: Setup, run: str, args, peers) -> tuple[dict, dict]:
    """sPGD vs GP vs RBF on one run; returns the table row and the pooled errors."""
    snaps = snapshots.load(setup.store, run)
    basis, usable = load_pod(setup.pod_store, run)
    harmonics, values, split = snaps.harmonics[0], snaps.values, snaps.split
    train, val, test = (usable & (split == s) for s in ("train", "validation", "test"))
    reference = harmonics[test][:, :, setup.sensor_dofs]

    with Clock() as clock:
        library = build_library(run, basis, harmonics, values, split, usable, setup.parameters, setup.lower,
                                setup.upper, setup.sensor_dofs, setup.kinks(), **setup.offline["spgd"])
    fit, cpu = {"sPGD": clock.wall}, {"sPGD": clock.cpu}
    errors = {"sPGD": relative_sensor_error(library.sensor(values[test]), reference)}

    rng = np.random.default_rng(0)
    batch = setup.lower + (setup.upper - setup.lower) * rng.random((BATCH, len(setup.parameters)))
    xb = library.normalise(batch)
    eval_us = {"sPGD": 1e6 * best_time(lambda: library.sensor(batch), args.repeats) / BATCH,
               "sPGD+J": 1e6 * best_time(lambda: library.sensor(batch, jacobian=True), args.repeats) / BATCH}

    x = library.normalise(values)
    alpha = basis.project(to_features(np.nan_to_num(harmonics)))
    if peers is not None:
        GaussianProcessRegressor, ConstantKernel, Matern, WhiteKernel = peers
        d = x.shape[1]
        kernel = (ConstantKernel(1.0, (1e-4, 1e12)) * Matern(np.ones(d), (1e-2, 1e5), nu=2.5)
                  + WhiteKernel(1e-6, (1e-14, 1e-1)))
        with Clock() as clock, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # bound warnings of the optimizer
            gp = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=args.gp_restarts,
                                          random_state=0).fit(x[train], alpha[train])
        fit["GP"], cpu["GP"] = clock.wall, clock.cpu
        errors["GP"] = relative_sensor_error(sensor_from_alpha(library, gp.predict(x[test])), reference)
        eval_us["GP"] = 1e6 * best_time(lambda: sensor_from_alpha(library, gp.predict(xb)), args.repeats) / BATCH
        xfd = fd_points(xb)
        eval_us["GP+FD-J"] = 1e6 * best_time(lambda: sensor_from_alpha(library, gp.predict(xfd)), args.repeats) / BATCH

        from scipy.interpolate import RBFInterpolator

        with Clock() as clock:
            best = (np.inf, None, None)
            for smoothing in (0.0, 1e-8, 1e-6, 1e-4, 1e-2):
                rbf = RBFInterpolator(x[train], alpha[train], kernel="thin_plate_spline", degree=1,
                                      smoothing=smoothing)
                residual = (rbf(x[val]) - alpha[val]) @ basis.modes.T  # relative error on validation, all DOFs
                score = np.median(np.linalg.norm(residual, axis=1) /
                                  np.linalg.norm(alpha[val] @ basis.modes.T, axis=1))
                if score < best[0]:
                    best = (score, rbf, smoothing)
        fit["RBF"], cpu["RBF"] = clock.wall, clock.cpu
        rbf = best[1]
        errors["RBF"] = relative_sensor_error(sensor_from_alpha(library, rbf(x[test])), reference)
        eval_us["RBF"] = 1e6 * best_time(lambda: sensor_from_alpha(library, rbf(xb)), args.repeats) / BATCH
        eval_us["RBF+FD-J"] = 1e6 * best_time(lambda: sensor_from_alpha(library, rbf(xfd)), 3) / BATCH
        gp_kernel, rbf_smoothing = str(gp.kernel_), best[2]
    else:
        gp_kernel, rbf_smoothing = "", np.nan

    # the full solver on the run's test scenarios, batched, at the run's rpm and mass
    pick = np.flatnonzero(split == "test")[: args.solver_scenarios]
    rpm, mass = float(setup.rpm[run]), float(setup.plan.loc[run, "eccentric_mass_g"])
    solve_full(setup, rpm, mass, values[pick[:2]])  # warm-up (first-call costs)
    times = []
    for _ in range(2):  # best of two
        start = time.perf_counter()
        result = solve_full(setup, rpm, mass, values[pick])
        times.append(time.perf_counter() - start)
    solver_ms = 1e3 * min(times) / pick.size
    check = relative_sensor_error(result.harmonics[:, :, setup.sensor_dofs],
                                  harmonics[pick][:, :, setup.sensor_dofs])
    agree = float(np.mean(check[np.isfinite(check)] < 1e-6)) if np.isfinite(check).any() else np.nan

    row = {"run": run, "rpm": rpm, "m_e_g": mass, "n_train": int(train.sum()), "n_test": int(test.sum()),
           "terms": library.model.n_terms, "modes": library.n_modes, "n_parameters": len(setup.parameters)}
    for name, e in errors.items():
        row[f"{name}_med"], row[f"{name}_p95"] = stats(e)
    row.update({f"fit_{k}_s": v for k, v in fit.items()})
    row.update({f"cpu_{k}_s": v for k, v in cpu.items()})
    row.update({f"eval_{k}_us": v for k, v in eval_us.items()})
    row.update({"solver_ms": solver_ms, "solver_ok": float(result.success.mean()), "solver_agrees": agree,
                "gp_kernel": gp_kernel, "rbf_smoothing": rbf_smoothing})
    return row, errors


def report_surrogates(rows: list[dict], pooled: dict, peers: bool) -> dict:
    table = pd.DataFrame(rows)
    names = ["sPGD", "GP", "RBF"] if peers else ["sPGD"]
    overall = {"run": "overall", "rpm": np.nan, "m_e_g": np.nan, "n_train": table["n_train"].sum(),
               "n_test": table["n_test"].sum(), "terms": np.nan, "modes": np.nan}
    for name in names:
        overall[f"{name}_med"], overall[f"{name}_p95"] = stats(np.concatenate(pooled[name]))
    for column in table.columns:
        if column.startswith(("fit_", "cpu_")):
            overall[column] = table[column].sum()
        elif column.startswith("eval_") or column.startswith("solver"):
            overall[column] = table[column].median()
    table = pd.concat([table, pd.DataFrame([overall])], ignore_index=True)

    accuracy = table[["run", "rpm", "m_e_g", "n_train", "n_test", "modes", "terms"]].copy()
    for name in names:
        accuracy[f"{name} med%"] = table[f"{name}_med"]
        accuracy[f"{name} p95%"] = table[f"{name}_p95"]
    if peers:
        accuracy["sPGD/GP med"] = table["sPGD_med"] / table["GP_med"]
        accuracy["sPGD/GP p95"] = table["sPGD_p95"] / table["GP_p95"]
    print_table(accuracy, "1a. Relative sensor error on the test scenarios [%] (observable ones; same splits as the "
                          "workflow; overall = pooled scenarios)")

    timing = table[["run"]].copy()
    for name in names:
        timing[f"fit {name} s"] = table[f"fit_{name}_s"]
    for name in names:
        timing[f"(cpu {name})"] = table[f"cpu_{name}_s"]
    timing["sPGD us"] = table["eval_sPGD_us"]
    timing["sPGD+J us"] = table["eval_sPGD+J_us"]
    if peers:
        for name in ("GP", "GP+FD-J", "RBF", "RBF+FD-J"):
            timing[f"{name} us"] = table[f"eval_{name}_us"]
    timing["solver ms"] = table["solver_ms"]
    timing["solver/sPGD+J"] = 1e3 * table["solver_ms"] / table["eval_sPGD+J_us"]
    timing["solver conv."] = table["solver_ok"]
    timing["= store"] = table["solver_agrees"]
    print_table(timing, f"1b. Fit time [s] (wall; in brackets CPU time, all threads) and evaluation time per parameter set [us] (batches of {BATCH}; FD-J: with "
                        "a forward-difference Jacobian, d+1 evaluations; best of repeats); full solver per scenario [ms] on the run's "
                        "test scenarios, batched; '= store': fraction of its solutions equal to the stored "
                        "snapshots (< 1e-6); overall = sum of fit times, median of the rest")
    if peers:
        print("\n    GP kernels (fitted):")
        for row in rows:
            print(f"      {row['run']}: {row['gp_kernel']}")
        print("    RBF smoothing chosen on validation: " +
              ", ".join(f"{r['run']} {r['rbf_smoothing']:g}" for r in rows))
    return overall


def report_targets(overall: dict, rows: list[dict], peers: bool) -> list[tuple[str, bool]]:
    print("\nTargets (issue 3), overall row:")
    results = []
    if peers:
        for stat in ("med", "p95"):
            ratio = overall[f"sPGD_{stat}"] / overall[f"GP_{stat}"]
            ok = ratio <= TARGET_ERROR_RATIO
            results.append((f"sPGD/GP error ratio ({'median' if stat == 'med' else 'p95'})", ok))
            print(f"  sPGD/GP error ratio, {'median' if stat == 'med' else 'p95   '} {ratio:6.2f} "
                  f"(target <= {TARGET_ERROR_RATIO:g}) {verdict(ok)}")
        worst = max(rows, key=lambda r: r["sPGD_med"] / r["GP_med"])
        print(f"     (per run, median ratio from {min(r['sPGD_med'] / r['GP_med'] for r in rows):.2f} to "
              f"{worst['sPGD_med'] / worst['GP_med']:.2f} at {worst['run']}; "
              f"runs within 2x: {sum(r['sPGD_med'] / r['GP_med'] <= 2 for r in rows)}/{len(rows)} on the median, "
              f"{sum(r['sPGD_p95'] / r['GP_p95'] <= 2 for r in rows)}/{len(rows)} on p95)")
    us = overall["eval_sPGD+J_us"]
    worst_us = max(r["eval_sPGD+J_us"] for r in rows)
    ok = worst_us <= TARGET_EVAL_US
    results.append(("sPGD evaluation with Jacobian", ok))
    print(f"  sPGD evaluation with Jacobian {us:6.2f} us per set, median; worst run {worst_us:.2f} us "
          f"(target <= {TARGET_EVAL_US:g} us) {verdict(ok)}")
    speedups = [1e3 * r["solver_ms"] / r["eval_sPGD+J_us"] for r in rows]
    ok = min(speedups) >= TARGET_SPEEDUP
    results.append(("speed-up over the full solver", ok))
    print(f"  speed-up over the full solver (solver per scenario / sPGD with Jacobian per set): median "
          f"{np.median(speedups):.0f}x, lowest {min(speedups):.0f}x (target >= {TARGET_SPEEDUP:g}x) {verdict(ok)}")
    d = rows[0]["n_parameters"]
    print(f"     (the solver gives no Jacobian: with a forward-difference one, d+1 = {d + 1} solves per LM step, "
          f"the speed-up is {(d + 1) * np.median(speedups):.0f}x median, {(d + 1) * min(speedups):.0f}x lowest)")
    median_ok = overall["sPGD_med"] <= 1.0 and overall["sPGD_p95"] <= 3.0
    print(f"  (accuracy, for reference: sPGD median {overall['sPGD_med']:.3g} % (target <= 1 %), "
          f"p95 {overall['sPGD_p95']:.3g} % (target <= 3 %) {verdict(median_ok)})")
    return results


# ----------------------------------------------------------------------------------------------- part 2

def better(row: dict) -> None:
    """Which library wins on the median: per run vs global, and (unseen runs) global vs the nearest fit run's."""
    row["better: per-run|global"] = "per-run" if row["per-run med%"] <= row["global med%"] else "global"
    row["global|nearest"] = ("" if not np.isfinite(row["nearest med%"]) else
                             "global" if row["global med%"] < row["nearest med%"] else "nearest")


def scope_comparison(setup: Setup, args) -> dict:
    roles = setup.plan["role"]
    fit_runs = [r for r in setup.runs if roles[r] == "fit"]
    options = dict(setup.offline["spgd"])
    if args.global_max_terms:
        options["max_terms"] = args.global_max_terms
    snaps = snapshots.load(setup.store)
    print("  global library: fitting (hybridtwin.offline.library.build_global_library, as offline.scope: global) ...",
          flush=True)
    with Clock() as fit_clock:
        glib = build_global_library(snaps, fit_runs, setup.lower, setup.upper, setup.shaft, setup.sensor_range_m,
                                    setup.offline["pod_energy_tolerance"], setup.kinks(), **options)
    model, names = glib.model, glib.parameters
    op_lower, op_upper = glib.lower[-2:], glib.upper[-2:]
    rng = np.random.default_rng(0)
    batch = glib.lower + (glib.upper - glib.lower) * rng.random((BATCH, len(names)))
    eval_us = 1e6 * best_time(lambda: glib.sensor(batch, jacobian=True), args.repeats) / BATCH

    # the per-run libraries (the workflow's, from <results>/library, else built here)
    libraries, built = {}, []
    for run in setup.runs:
        path = setup.results / "library" / f"{run}.zarr"
        b, usable = load_pod(setup.pod_store, run)
        if path.exists():
            library = Library.load(path)
            if library.modes.shape == b.modes.shape and np.allclose(library.modes, b.modes):
                libraries[run] = library
                continue
        # missing, or stale (not built on the current POD basis): build it as the workflow does
        one = snapshots.load(setup.store, run)
        libraries[run] = build_library(run, b, one.harmonics[0], one.values, one.split, usable,
                                       setup.parameters, setup.lower, setup.upper, setup.sensor_dofs,
                                       setup.kinks(), **setup.offline["spgd"])
        built.append(run)
    source = (f"loaded from {setup.results / 'library'}" if not built else
              f"loaded from {setup.results / 'library'}, except {built} (missing or not on the current POD: "
              "built here with build_library)")
    point = dict(zip(snaps.runs, zip(snaps.rpm, snaps.eccentric_mass_g)))  # each run's, as solved
    op = {r: 2.0 * (np.array(point[r]) - op_lower) / (op_upper - op_lower) - 1.0 for r in setup.runs}
    unseen = [r for r in setup.runs if r not in fit_runs]

    rows, pooled = [], {"fit": {"per-run": [], "global": [], "nearest": []},
                        "unseen": {"per-run": [], "global": [], "nearest": []}}
    for r, run in enumerate(snaps.runs):
        here = (snaps.split == "test") & snaps.success[r] & observable(snaps.harmonics[r], setup.shaft,
                                                                       setup.sensor_range_m)
        values, reference = snaps.values[here], snaps.harmonics[r][here][:, :, setup.sensor_dofs]
        own = relative_sensor_error(libraries[run].sensor(values), reference)
        glob = relative_sensor_error(glib.at_operating_point(run, *point[run]).sensor(values), reference)
        kind = "fit" if run in fit_runs else "unseen"
        row = {"run": run, "role": roles[run], "rpm": float(point[run][0]), "m_e_g": float(point[run][1]),
               "n_test": int(here.sum())}
        row["per-run med%"], row["per-run p95%"] = stats(own)
        row["global med%"], row["global p95%"] = stats(glob)
        if kind == "unseen":
            nearest = min(fit_runs, key=lambda f: np.linalg.norm(op[f] - op[run]))
            near = relative_sensor_error(libraries[nearest].sensor(values), reference)
            row["nearest fit run"] = nearest
            row["nearest med%"], row["nearest p95%"] = stats(near)
            pooled[kind]["nearest"].append(near)
        else:
            row["nearest fit run"], row["nearest med%"], row["nearest p95%"] = "", np.nan, np.nan
        better(row)
        pooled[kind]["per-run"].append(own)
        pooled[kind]["global"].append(glob)
        rows.append(row)
    for kind, label in (("fit", "fit runs (pooled)"), ("unseen", "unseen runs (pooled)")):
        if not pooled[kind]["per-run"]:
            continue
        row = {"run": label, "role": "", "rpm": np.nan, "m_e_g": np.nan,
               "n_test": int(sum(e.size for e in pooled[kind]["per-run"]))}
        for name in ("per-run", "global", "nearest"):
            row[f"{name} med%"], row[f"{name} p95%"] = (stats(np.concatenate(pooled[kind][name]))
                                                        if pooled[kind][name] else (np.nan, np.nan))
        row["nearest fit run"] = ""
        better(row)
        rows.append(row)
    table = pd.DataFrame(rows)
    print_table(table, "2. Library scope: per run (the workflow's libraries, one per run, each fitted on its own "
                       "run's snapshots) vs global (ONE sPGD over the unknowns + rpm + eccentric mass, fitted on the "
                       "fit runs only); relative sensor error on every run's test scenarios [%]; for the unseen "
                       "runs also the library of the nearest fit run (what per-run scope offers without new solves)")
    ratio = glib.singular_values[1] / glib.singular_values[0]
    print(f"\n    global library: {glib.info['n_train']} training / {glib.info['n_validation']} validation scenarios "
          f"from {len(fit_runs)} fit runs; POD {glib.n_modes} modes (sigma2/sigma1 = {ratio:.3g}); sPGD "
          f"{model.n_terms} terms (max {options['max_terms']}), degree "
          f"{options['degree']}, fit {fit_clock.wall:.0f} s (CPU {fit_clock.cpu:.0f} s); evaluation with Jacobian {eval_us:.2f} us per set "
          f"({len(names)} parameters); operating range rpm {op_lower[0]:.0f}-{op_upper[0]:.0f}, "
          f"m_e {op_lower[1]:g}-{op_upper[1]:g} g (trained at masses "
          f"{sorted(set(setup.plan.loc[fit_runs, 'eccentric_mass_g'].astype(float)))} g only)")
    print(f"    per-run libraries {source}")
    masses = sorted(set(setup.plan.loc[fit_runs, "eccentric_mass_g"].astype(float)))
    high = int((model.degrees.min(axis=1) >= len(masses)).sum())
    print(f"    global sPGD term degrees {model.degrees.max(axis=1)}: {high} of {model.n_terms} terms have degree >= "
          f"{len(masses)} in every factor, mass included, which {len(masses)} training masses cannot determine")
    return {"table": table, "unseen": unseen, "fit_s": fit_clock.wall, "eval_us": eval_us, "terms": model.n_terms,
            "modes": glib.n_modes}


def report_scope(result: dict) -> str:
    table = result["table"].set_index("run")
    fit = table.loc["fit runs (pooled)"]
    winner = "per-run" if fit["per-run med%"] <= fit["global med%"] else "global"
    factor = max(fit["global med%"], fit["per-run med%"]) / min(fit["global med%"], fit["per-run med%"])
    wins = int((table.loc[[r for r in table.index if "pooled" not in r], "better: per-run|global"] == "per-run").sum())
    lines = ["\nScope verdict:",
             f"  fit runs (seen by both): per-run median {fit['per-run med%']:.3g} % / p95 {fit['per-run p95%']:.3g} % vs "
             f"global {fit['global med%']:.3g} % / {fit['global p95%']:.3g} % -> {winner} is better ({factor:.0f}x on "
             f"the median; per-run better on {wins} of {len(table) - 2 if 'unseen runs (pooled)' in table.index else len(table) - 1} runs)"]
    if "unseen runs (pooled)" in table.index:
        unseen = table.loc["unseen runs (pooled)"]
        lines.append(f"  unseen operating points ({', '.join(result['unseen'])}): global {unseen['global med%']:.3g} % / "
                     f"{unseen['global p95%']:.3g} % vs the nearest fit run's library {unseen['nearest med%']:.3g} % / "
                     f"{unseen['nearest p95%']:.3g} % (no new solves either) vs a per-run library built there from "
                     f"new snapshots {unseen['per-run med%']:.3g} % / {unseen['per-run p95%']:.3g} %")
        for run in result["unseen"]:
            row = table.loc[run]
            ok = row["global med%"] <= 1.0 and row["global p95%"] <= 3.0
            lines.append(f"    {run}: global median {row['global med%']:.3g} %, p95 {row['global p95%']:.3g} % "
                         f"(library target <= 1 % / <= 3 %) {verdict(ok)}")
    lines.append(f"  better scope: {winner}")
    print("\n".join(lines))
    return winner


# ----------------------------------------------------------------------------------------------- main

def main(argv=None) -> int:
    args = parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(args.threads)
    peers = None if args.no_peers else require_sklearn()
    wall = time.perf_counter()
    setup = Setup(args)
    runs = select_runs(setup, args)
    snaps_shape = snapshots.load(setup.store, runs[0]).harmonics.shape
    setup.n_harmonics = snaps_shape[2]

    import scipy

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"library benchmark: variant {setup.variant_name}, {setup.results} ({len(setup.runs)} runs, "
          f"{snaps_shape[1]} scenarios, H = {setup.n_harmonics - 1}); runs benchmarked: {', '.join(runs)}")
    print(f"sPGD options (config offline.spgd): {setup.offline['spgd']}; sensor range "
          f"{setup.offline['sensor_range_mm']} mm; BLAS threads {args.threads}; load average {load:.1f} on "
          f"{os.cpu_count()} CPUs; numpy {np.__version__}, scipy {scipy.__version__}"
          + ("" if peers is None else f", scikit-learn {__import__('sklearn').__version__}"))
    if peers is not None:
        print("peers, fitted like the sPGD on the run's POD coefficients (same training set, inputs in [-1, 1]): "
              "GP = GaussianProcessRegressor(C * Matern(ARD, nu=2.5) + WhiteKernel, normalize_y=True), one multi-output "
              "GP with shared hyper-parameters; RBF = RBFInterpolator(thin_plate_spline, degree=1), smoothing chosen on "
              "the validation set")
    print(choose_speed(setup, args.speed))

    rows, pooled = [], {"sPGD": [], "GP": [], "RBF": []}
    for run in runs:
        start = time.perf_counter()
        row, errors = benchmark_run(setup, run, args, peers)
        rows.append(row)
        for name, e in errors.items():
            pooled[name].append(e)
        print(f"  {run}: done in {time.perf_counter() - start:.0f} s", flush=True)
    overall = report_surrogates(rows, pooled, peers is not None)
    report_targets(overall, rows, peers is not None)

    if not args.no_scope:
        result = scope_comparison(setup, args)
        report_scope(result)
    print(f"\ntotal benchmark time {time.perf_counter() - wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
