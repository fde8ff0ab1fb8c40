"""Identification benchmark at full scale: the paper's protocol on the paper's 19 runs, Geometric truth.

    python benchmarks/identification_benchmark.py [--workdir DIR] [--scipy-runs 3] [--skip-me] [--no-keyphasor]

1. Data and workflow: the virtual rig writes the paper's run plan (19 fit runs, 3 validation runs; 4 s at
   2 kHz, noise 0.05 mm, random phase, DC offsets, 0.1 % speed error, a keyphasor column unless
   --no-keyphasor) from a Geometric truth (paper Table 2 values, bow q_x = 1.8 mm, q_y = 1.2 mm); the
   workflow (a copy in DIR) builds the libraries and runs the identification: per-run fits by the paper's
   protocol (tau = 50, n_MC = 1000), the joint fit (bow per run, absolute keyphasor phases with their timing
   uncertainty as a prior, polished with the full solver) and the validation predictions.
2. Time per run of the protocol (in-process, one BLAS thread: wall and CPU), and the workflow's own.
3. The batched LM against scipy.optimize.least_squares run trial by trial on the same problems (same
   residuals, Jacobian, bounds, starts, tolerances): best optimum and time, per run (tau trials) and joint.
4. Recovery: the joint fit vs the truth, polished with the full solver (value, 95 % interval, error,
   chi^2/dof): the workflow's (bow per run, keyphasor phases); the same with a phase fitted per run, as a
   record without a keyphasor allows; a bow shared by all runs (the truth's structure).
5. The eccentric mass as a sixth unknown (paper sec. 4.1): libraries over (k_b, zeta_s, zeta_bup, q_x, q_y,
   m_e) built here (one run-up through the 19 speeds), per-run protocol fits, m_e per mass vs truth.
Everything is cached in DIR, so a second call only re-runs the measurements.
"""

from __future__ import annotations

import argparse
import multiprocessing
import shutil
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits
from workflow_run import timed_snakemake

from hybridtwin.identify import forward as fwd
from hybridtwin.identify.arrow_problem import ArrowProblem
from hybridtwin.identify import identification as idn
from hybridtwin.identify import lm
from hybridtwin.identify import polish as pol
from hybridtwin.offline.library import Library, build_library, relative_sensor_error
from hybridtwin.offline.pod import pod, to_features
from hybridtwin.identify.protocol import ProtocolOptions, random_starts
from hybridtwin.rig.rig import RigSpec, generate, read_plan
from hybridtwin.offline.scenarios import default_n_scenarios, sample_scenarios
from hybridtwin.model.sensor import observable, sensor_dofs
from hybridtwin.model.variants import Variant

ROOT = Path(__file__).resolve().parents[1]
GEOMETRIC = ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "unbalance",
             "shaft_bow", "geometric_spring"]
TRUTH = {"k_b": 2331.5, "zeta_s": 0.0271, "zeta_bup": 0.0215, "q_x": 0.0018, "q_y": 0.0012}
RANGES = {"k_b": [2000, 3500], "zeta_s": [0.01, 0.05], "zeta_bup": [0.0, 0.05], "q_x": [0.001, 0.01],
          "q_y": [0.001, 0.01]}
TARGETS = ["results/geometric/parameters.tsv", "results/geometric/validation.tsv"]


def prepare(work: Path, keyphasor: bool = True) -> None:
    """The workflow copy, the Geometric-truth data set and the config (once)."""
    if (work / "config" / "config.yaml").exists():
        return
    for item in ("Snakefile", "workflow", "scripts", "config", "profiles"):
        source = ROOT / item
        (shutil.copytree if source.is_dir() else shutil.copy)(source, work / item)
    spec = RigSpec.from_mapping({"seed": 1, "harmonics": 7, "truth": {"effects": GEOMETRIC, "values": TRUTH},
                                 "imperfections": {"noise_mm": 0.05, "keyphasor": keyphasor}})
    generate(read_plan(ROOT / "data" / "default" / "runs.tsv"), spec, work / "data" / "geometric")
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["runs"] = "data/geometric/runs.tsv"
    config["variants"] = {"geometric": {"effects": GEOMETRIC, "unknown": RANGES}}
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))


def load(work: Path, runs: list[str], keyphasor: bool = True) -> tuple[list[idn.RunData], list[Library], dict]:
    table = idn.read_harmonics(work / "results" / "data" / "harmonics.tsv")
    data = [idn.run_data(table, r, keyphasor=keyphasor) for r in runs]
    libraries = [Library.load(work / "results" / "geometric" / "library" / f"{r}.zarr") for r in runs]
    errors = idn.model_errors(pd.read_csv(work / "results" / "geometric" / "library_validation.tsv", sep="\t"), runs)
    return data, libraries, errors


def fit_runs(work: Path) -> list[str]:
    sheet = pd.read_csv(work / "data" / "geometric" / "runs.tsv", sep="\t")
    return sheet.loc[sheet["role"] == "fit", "run"].tolist()


# --- 2. time per run ------------------------------------------------------------------------------------


def protocol_timing(work: Path, runs: list[str]) -> pd.DataFrame:
    data, libraries, errors = load(work, runs)
    rows = []
    for d, library in zip(data, libraries):
        wall, cpu = time.perf_counter(), time.process_time()
        fit = idn.identify([fwd.SensorSurrogate(library)], [d], options=ProtocolOptions(seed=1),
                           model_error=errors)
        rows.append({"run": d.run, "lm_problems": fit.protocol.n_lm, "wall_s": time.perf_counter() - wall,
                     "cpu_s": time.process_time() - cpu, "mean_iterations": fit.protocol.trials.nit.mean(),
                     "chi2_dof": fit.chi2_dof})
    return pd.DataFrame(rows)


# --- 3. scipy -------------------------------------------------------------------------------------------


def scipy_comparison(problem: ArrowProblem, X: np.ndarray, starts: np.ndarray) -> dict:
    """Batched LM vs least_squares (trf, bounds, exact Jacobian) from the same starts, same tolerances."""
    lower, upper = problem.layout.bounds()
    options = lm.LMOptions(stall_chi2=0.0, ftol=1e-8, xtol=1e-8, gtol=1e-8, max_iterations=200)
    Xt = np.repeat(X[None], len(starts), axis=0)
    t0 = time.perf_counter()
    batched = lm.levenberg_marquardt(problem, starts, Xt, options)
    t_batched = time.perf_counter() - t0

    def fun(theta):
        ev = problem.evaluate(theta[None], X[None], jacobian=False)
        return np.concatenate([ev.r[0].ravel(), ev.rho[0]])

    def jac(theta):
        return problem.dense_jacobian(problem.evaluate(theta[None], X[None]), data_only=False)

    t0 = time.perf_counter()
    reference = [least_squares(fun, s, jac=jac, bounds=(lower, upper), method="trf", x_scale="jac", ftol=1e-8,
                               xtol=1e-8, gtol=1e-8, max_nfev=2000) for s in starts]
    t_scipy = time.perf_counter() - t0
    costs = np.array([r.cost for r in reference])
    b_best, s_best = int(np.argmin(batched.cost)), int(np.argmin(costs))
    physical = ~problem.layout.is_phase
    return {"trials": len(starts), "batched_s": t_batched, "scipy_s": t_scipy, "ratio": t_scipy / t_batched,
            "best_cost_batched": batched.cost[b_best], "best_cost_scipy": costs[s_best],
            "best_x_max_difference": float(np.abs(batched.x[b_best, physical]
                                                  - reference[s_best].x[physical]).max()),
            "scipy_nfev_mean": float(np.mean([r.nfev for r in reference])),
            "batched_iterations_mean": float(batched.nit.mean())}


def scipy_benchmark(work: Path, runs: list[str], all_runs: list[str]) -> pd.DataFrame:
    rows = []
    rng = np.random.default_rng(7)
    data, libraries, errors = load(work, runs)
    for d, library in zip(data, libraries):
        fit = idn.identify([fwd.SensorSurrogate(library)], [d], options=ProtocolOptions(trials=1, monte_carlo=0),
                           model_error=errors)
        X = fit.X
        starts = fit.problem.initial_phases(random_starts(fit.layout, 50, rng), np.repeat(X[None], 50, 0))
        rows.append({"problem": d.run, **scipy_comparison(fit.problem, X, starts)})
    data, libraries, errors = load(work, all_runs)
    fit = idn.identify([fwd.SensorSurrogate(lib) for lib in libraries], data, per_run=["q_x", "q_y"],
                       options=ProtocolOptions(trials=1, monte_carlo=0), model_error=errors)
    starts = fit.problem.initial_phases(random_starts(fit.layout, 20, rng), np.repeat(fit.X[None], 20, 0))
    rows.append({"problem": f"joint ({len(all_runs)} runs, {fit.layout.n} unknowns)",
                 **scipy_comparison(fit.problem, fit.X, starts)})
    return pd.DataFrame(rows)


# --- 4. recovery ----------------------------------------------------------------------------------------


def recovery_table(table: pd.DataFrame) -> pd.DataFrame:
    physical = table[table["kind"] != "nuisance"].copy()
    physical["truth"] = physical["parameter"].map(TRUTH)
    physical["error_pct"] = 100 * (physical["value"] / physical["truth"] - 1)
    physical["inside_95"] = (physical["ci_low"] <= physical["truth"]) & (physical["truth"] <= physical["ci_high"])
    return physical[["parameter", "run", "value", "stderr", "ci_low", "ci_high", "truth", "error_pct", "inside_95",
                     "identifiable", "at_bound"]]


def alternative_fit(work: Path, runs: list[str], per_run: list[str], keyphasor: bool
                    ) -> tuple[idn.Identification, float]:
    """A joint fit with other nuisance choices than the workflow's, polished with the full solver."""
    data, libraries, errors = load(work, runs, keyphasor)
    variant = Variant.from_spec("geometric", {"effects": GEOMETRIC, "unknown": RANGES})
    start = time.perf_counter()
    fit = idn.identify([fwd.SensorSurrogate(lib) for lib in libraries], data, per_run=per_run,
                       options=ProtocolOptions(monte_carlo=0), model_error=errors)
    solver = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, lib.parameters, lib.lower, lib.upper, 5)
              for d, lib in zip(data, libraries)]
    return pol.polish(fit, solver), time.perf_counter() - start


# --- 5. m_e as the sixth unknown -------------------------------------------------------------------------


def _solve_chunk(args) -> tuple[np.ndarray, np.ndarray]:
    spec, rpm, values = args
    with threadpool_limits(1):
        variant = Variant.from_spec("geometric_me", spec)
        results = fwd.run_up(variant, rpm, values, 5)
    return np.stack([r.harmonics for r in results]), np.stack([r.success for r in results])


def me_libraries(work: Path, runs: list[str]) -> dict[str, Library]:
    """Libraries over the five unknowns and m_e in [0, 40] g, at each run's refined speed (cached)."""
    folder = work / "me_libraries"
    if all((folder / f"{r}.zarr").exists() for r in runs):
        return {r: Library.load(folder / f"{r}.zarr") for r in runs}
    spec = {"effects": GEOMETRIC, "unknown": {**RANGES, "m_e": [0.0, 0.040]}}
    variant = Variant.from_spec("geometric_me", spec)
    n = default_n_scenarios(6)
    scenarios = sample_scenarios(variant, n, seed=1, validation_fraction=0.2, n_test=200)
    table = idn.read_harmonics(work / "results" / "data" / "harmonics.tsv").set_index("run")
    rpm = table.loc[runs, "rpm_true"].to_numpy(float)
    names = variant.unknown_names
    chunks = np.array_split(np.arange(len(scenarios)), 2)
    jobs = [(spec, rpm, {k: scenarios[k].to_numpy()[c] for k in names}) for c in chunks]
    start = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        parts = pool.map(_solve_chunk, jobs)
    harmonics = np.concatenate([p[0] for p in parts], axis=1)  # (R, S, H+1, n)
    success = np.concatenate([p[1] for p in parts], axis=1)
    print(f"  m_e scenarios: {len(scenarios)} x {len(runs)} runs solved in {time.perf_counter() - start:.0f} s")
    config = yaml.safe_load((work / "config" / "config.yaml").read_text())
    spgd = config["offline"]["spgd"]
    lower, upper = variant.bounds(names)
    folder.mkdir(exist_ok=True)
    out = {}
    split = scenarios["split"].to_numpy()
    values = scenarios[names].to_numpy()
    for r, run in enumerate(runs):
        usable = success[r] & observable(harmonics[r], variant.model.shaft, 0.014)
        basis = pod(to_features(harmonics[r][usable & (split == "train")]), 1e-10)
        library = build_library(run, basis, np.nan_to_num(harmonics[r]), values, split, usable, names, lower,
                                upper, sensor_dofs(variant.model.shaft), **spgd)
        test = usable & (split == "test")
        error = relative_sensor_error(library.sensor(values[test]), harmonics[r][test][:, :, library.sensor_dofs])
        library.info["test_median_error"] = float(np.median(error))
        library.save(folder / f"{run}.zarr")
        out[run] = library
    return out


def me_joint(work: Path, runs: list[str]) -> tuple[idn.Identification, float]:
    """m_e per run with the other unknowns shared (bow included), polished with the full solver."""
    libraries = me_libraries(work, runs)
    table = idn.read_harmonics(work / "results" / "data" / "harmonics.tsv")
    data = [idn.run_data(table, r) for r in runs]
    models = [fwd.SensorSurrogate(libraries[r]) for r in runs]
    errors = {r: libraries[r].info.get("test_median_error", 0.0) for r in runs}
    start = time.perf_counter()
    fit = idn.identify(models, data, per_run=["m_e"], options=ProtocolOptions(monte_carlo=0), model_error=errors)
    variant = Variant.from_spec("geometric_me", {"effects": GEOMETRIC, "unknown": {**RANGES, "m_e": [0.0, 0.040]}})
    first = libraries[runs[0]]
    solver = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, first.parameters, first.lower, first.upper, 5)
              for d in data]
    return pol.polish(fit, solver), time.perf_counter() - start


def me_fits(work: Path, runs: list[str]) -> pd.DataFrame:
    libraries = me_libraries(work, runs)
    table = idn.read_harmonics(work / "results" / "data" / "harmonics.tsv")
    rows = []
    for run in runs:
        d = idn.run_data(table, run)
        library = libraries[run]
        error = {run: library.info.get("test_median_error", 0.0)}
        wall = time.perf_counter()
        fit = idn.identify([fwd.SensorSurrogate(library)], [d], options=ProtocolOptions(seed=1),
                           model_error=error)
        values = fit.table().set_index("parameter")
        rows.append({"run": run, "rpm": d.rpm, "m_e_true_g": d.eccentric_mass_g,
                     "m_e_g": 1e3 * values.loc["m_e", "value"], "m_e_mc_mean_g": 1e3 * values.loc["m_e", "mc_mean"],
                     "m_e_stderr_g": 1e3 * values.loc["m_e", "stderr"], "k_b": values.loc["k_b", "value"],
                     "k_b_mc_mean": values.loc["k_b", "mc_mean"], "library_error_pct": 100 * error[run],
                     "chi2_dof": fit.chi2_dof, "wall_s": time.perf_counter() - wall})
    return pd.DataFrame(rows)


# --- main -----------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/hybridtwin-identification-benchmark"))
    parser.add_argument("--scipy-runs", type=int, default=3, help="per-run problems compared with scipy")
    parser.add_argument("--timing-runs", type=int, default=3, help="runs timed in-process")
    parser.add_argument("--skip-me", action="store_true", help="skip the m_e-as-sixth-unknown case")
    parser.add_argument("--reuse", action="store_true", help="use the workflow results already in DIR")
    parser.add_argument("--no-keyphasor", action="store_true",
                        help="records without a keyphasor column (a new DIR: the data are made once per DIR)")
    args = parser.parse_args()
    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 30)
    work = args.workdir
    work.mkdir(parents=True, exist_ok=True)
    prepare(work, keyphasor=not args.no_keyphasor)
    print(f"1. workflow in {work} (Geometric truth, 19 fit + 3 validation runs)")
    if not args.reuse:
        print(f"   done in {timed_snakemake(work, TARGETS):.0f} s")
    runs = fit_runs(work)
    bench = pd.read_csv(work / "results" / "benchmarks" / "geometric" / "identify_run.tsv", sep="\t")
    print(f"   workflow rule identify_run (tau = 50, n_MC = 1000, every fit run in one job): {bench['s'].iloc[0]:.1f} s, "
          f"{bench['s'].iloc[0] / len(runs):.2f} s per run (incl. start-up and outputs)")
    with threadpool_limits(1):
        picked = [runs[i] for i in np.linspace(0, len(runs) - 1, args.timing_runs).round().astype(int)]
        print("\n2. protocol per run, in-process, one BLAS thread (50 trials x (1 + 1000) repeats)")
        timing = protocol_timing(work, picked)
        print(timing.round(3).to_string(index=False))
        print(f"   mean {timing['wall_s'].mean():.2f} s wall, {timing['cpu_s'].mean():.2f} s CPU per run")
        print("\n3. batched LM vs scipy.optimize.least_squares trial by trial (same problem, starts, tolerances)")
        picked = [runs[i] for i in np.linspace(0, len(runs) - 1, args.scipy_runs).round().astype(int)]
        comparison = scipy_benchmark(work, picked, runs)
        print(comparison.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
        per_trial_scipy = comparison["scipy_s"].iloc[:-1].sum() / comparison["trials"].iloc[:-1].sum()
        print(f"   the full protocol with scipy would take ~{per_trial_scipy * 50050:.0f} s per run "
              f"({per_trial_scipy * 1e3:.1f} ms per trial x 50050 trials), vs {timing['wall_s'].mean():.1f} s")
    references = idn.read_harmonics(work / "results" / "data" / "harmonics.tsv")["phase_reference"]
    keyed = bool((references == "keyphasor").all())
    print(f"\n4. recovery, joint fit polished with the full solver; records {'with' if keyed else 'without'} "
          "a keyphasor")
    joint = pd.read_csv(work / "results" / "geometric" / "parameters.tsv", sep="\t")
    summary = yaml.safe_load((work / "results" / "geometric" / "identification" / "summary.yaml").read_text())
    print(f"   bow per run, keyphasor phases where there is one (workflow default): chi^2/dof "
          f"{summary['final']['chi2_dof']:.3f} (library fit {summary['library']['chi2_dof']:.3f}), collinearity "
          f"index {summary['final']['collinearity_index']:.0f}")
    recovered = recovery_table(joint)
    print(recovered[recovered["run"] == "all"].to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    bows = recovered[recovered["run"] != "all"]
    print(f"   per-run bows: |error| median {bows['error_pct'].abs().median():.2f} %, max "
          f"{bows['error_pct'].abs().max():.2f} %, {bows['inside_95'].mean() * 100:.0f} % of truths inside their "
          f"95 % intervals")
    for note in summary["final"]["notes"]:
        print(f"   note: {note}")
    cases = [("bow per run, a phase fitted per run (as without a keyphasor)", ["q_x", "q_y"], False),
             ("bow shared (the truth's structure), keyphasor phases", [], True)]
    for title, per_run, keyphasor in cases if keyed else cases[1:]:
        with threadpool_limits(1):
            other, seconds = alternative_fit(work, runs, per_run, keyphasor)
        print(f"   {title}: chi^2/dof {other.chi2_dof:.3f}, {seconds:.0f} s")
        table = recovery_table(other.table())
        print(table[table["run"] == "all"].to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    validation = pd.read_csv(work / "results" / "geometric" / "validation.tsv", sep="\t")
    print("   validation runs (never fitted):")
    print(validation[["run", "model", "error_rel", "chi2_per_residual"]].to_string(index=False))
    if not args.skip_me:
        print("\n5. m_e as the sixth unknown (per-run protocol fits, libraries over 6 unknowns)")
        with threadpool_limits(1):
            me = me_fits(work, runs)
        print(me.round(4).to_string(index=False))
        groups = me.groupby("m_e_true_g").agg(m_e_g=("m_e_g", "mean"), m_e_mc_mean_g=("m_e_mc_mean_g", "mean"),
                                              k_b=("k_b", "mean"), runs=("run", "count"))
        groups["error_pct"] = 100 * (groups["m_e_g"] / groups.index - 1)
        print(groups.round(3).to_string())
        with threadpool_limits(1):
            joint, seconds = me_joint(work, runs)
        result = joint.table()
        print(f"   joint, m_e per run, the rest shared, polished with the full solver ({seconds:.0f} s): "
              f"chi^2/dof {joint.chi2_dof:.3f}")
        shared = recovery_table(result[result["run"] == "all"])
        print(shared.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
        masses = result[result["parameter"] == "m_e"].merge(me[["run", "m_e_true_g"]], on="run")
        masses["m_e_g"], masses["stderr_g"] = 1e3 * masses["value"], 1e3 * masses["stderr"]
        masses["inside_95"] = (1e3 * masses["ci_low"] <= masses["m_e_true_g"]) & (
            masses["m_e_true_g"] <= 1e3 * masses["ci_high"])
        print(masses.groupby("m_e_true_g").agg(m_e_g=("m_e_g", "mean"), stderr_g=("stderr_g", "mean"),
                                               inside_95=("inside_95", "mean"), runs=("run", "count"))
              .round(3).to_string())


if __name__ == "__main__":
    main()
