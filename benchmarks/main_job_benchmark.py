"""The main job's stage breakdown (issue 23): job-seconds per stage from Snakemake's per-job benchmark files,
an earlier commit and this one side by side.

Every rule writes results/benchmarks/{variant}/<rule>[_<run or chunk>].tsv (and results/benchmarks/data/... for
the measured data): wall seconds ``s`` and a ``cpu_time`` that Snakemake samples (every 0.5 s for the first
15 s of a job, then every 30 s: the CPU of a longer job's last stretch is missed, so it is shown as sampled).
The stages:

    sPGD library fits        spgd_library, spgd_global
    per-run protocol         identify_run
    joint fit + polish       identify_joint
    harmonic-balance solves  solve_chunk, solve_enrichment
    the rest                 everything else (sampling, POD, validation, the measured data, ...)

Usage (from the repository root, in the project's environment):

    # two folders where the workflow has run (e.g. git worktrees of the two commits)
    python benchmarks/main_job_benchmark.py --old /tmp/base --new . --variant geometric

    # the whole measurement: a worktree of each commit under WORKDIR, the workflow run in each (old first, then
    # new, `nice`, `--cores 2`) on the Geometric variant's targets, then the table
    python benchmarks/main_job_benchmark.py --run --old-commit COMMIT --workdir /tmp/mjb --variant geometric

    # the per-run protocol in-process, the paper's literal repeats (monte_carlo_starts 0) against the workflow's
    # (repeats from the trials' optima), on the libraries of a workflow run: CPU time, LM problems, the estimate
    # and the Monte Carlo spread
    python benchmarks/main_job_benchmark.py --protocol . --protocol-runs r350_m25p9 r700_m14p8 r950_m0p0

    # the joint fit's library protocol in-process (identify_joint without the polish), its repeats from fresh random
    # starts (the literal protocol) against the workflow's (joint.monte_carlo_starts), per variant
    python benchmarks/main_job_benchmark.py --joint . --joint-variants geometric expansion

    # the scenario solves of one chunk in-process (as solve_chunk: the first N scenarios of the variant at every run),
    # an older source tree (e.g. a worktree of the previous commit) against this one, each in its own process, one
    # thread, twice in turn: CPU seconds and how far the steady states differ
    python benchmarks/main_job_benchmark.py --solves FOLDER --old-src OLD/src --variant expansion --scenarios 200

    # the per-rule table of one finished run of the main job (every variant): job-seconds, jobs and sampled CPU per
    # rule, largest first, and the wall and CPU of the whole run from `/usr/bin/time -v` output if given
    python benchmarks/main_job_benchmark.py --rules FOLDER [--time-log FILE]

    # did the results move? two finished runs of the main job: the ledger's columns, every estimate (in standard
    # errors of the old one), each diagnosis's verdict, the libraries' test errors and the per-run protocol's estimates
    python benchmarks/main_job_benchmark.py --results OLD_FOLDER NEW_FOLDER

Timings on a shared machine are noisy: the load average before and after each run is printed; compare the
two columns of one invocation, not figures taken at different times.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
STAGES = [
    ("sPGD library fits", ("spgd_library", "spgd_global")),
    ("per-run protocol", ("identify_run",)),
    ("joint fit + polish", ("identify_joint",)),
    ("harmonic-balance solves", ("solve_chunk", "solve_enrichment")),
]
REST = "the rest"


def stage_of(path: Path) -> str:
    """The stage of a benchmark file (its rule is the file name up to the run or chunk suffix)."""
    name = path.stem
    for stage, rules in STAGES:
        if any(name == rule or name.startswith(rule + "_") for rule in rules):
            return stage
    return REST


def jobs(results: Path, variant: str) -> pd.DataFrame:
    """One row per job of ``variant`` (``all``: of every variant) and of the measured data: file, stage, s,
    cpu_time."""
    folders = ([p for p in (results / "benchmarks").iterdir() if p.is_dir()] if variant == "all"
               else [results / "benchmarks" / variant, results / "benchmarks" / "data"])
    files = sorted(p for folder in folders if folder.is_dir() for p in folder.rglob("*.tsv"))
    if not files:
        raise SystemExit(f"main_job_benchmark: no benchmark files under {results / 'benchmarks'} for {variant} "
                         "(has the workflow run there?)")
    rows = []
    for path in files:
        table = pd.read_csv(path, sep="\t")
        rows.append({"file": str(path.relative_to(results)), "stage": stage_of(path),
                     "s": float(table["s"].iloc[-1]),
                     "cpu_time": pd.to_numeric(table.get("cpu_time", pd.Series([float("nan")])), errors="coerce")
                     .iloc[-1]})
    return pd.DataFrame(rows)


def rule_of(path: Path, rules: list[str]) -> str:
    """The rule a benchmark file belongs to: the longest rule name its stem is or starts with (then ``_``), or its
    folder's name where the rule writes one file per run into a folder of its own (data/preprocess/{run}.tsv)."""
    name = path.stem
    matches = [rule for rule in rules if name == rule or name.startswith(rule + "_")]
    if matches:
        return max(matches, key=len)
    return path.parent.name if path.parent.name in rules else name


def workflow_rules(folder: Path) -> list[str]:
    """The rule names declared in ``folder``'s workflow (Snakefile and workflow/rules/*.smk)."""
    import re

    sources = [folder / "Snakefile", *sorted((folder / "workflow" / "rules").glob("*.smk"))]
    return sorted({m for path in sources if path.exists() for m in re.findall(r"^rule (\w+):", path.read_text(), re.M)})


def per_rule(folder: Path) -> pd.DataFrame:
    """job-s, jobs and sampled CPU per rule over every variant of a finished run in ``folder``, largest first,
    with the total."""
    table = jobs(folder / "results", "all")
    rules = workflow_rules(folder)
    table["rule"] = [rule_of(Path(file), rules) for file in table["file"]]
    grouped = table.groupby("rule").agg(job_s=("s", "sum"), jobs=("s", "size"), cpu_s=("cpu_time", "sum"))
    grouped = grouped.sort_values("job_s", ascending=False)
    grouped.loc["total"] = grouped.sum()
    return grouped


def time_log(path: Path) -> dict:
    """Wall [s], CPU (user + system) [s] and peak resident memory [GB] from a `/usr/bin/time -v` output."""
    import re

    text = path.read_text()
    def field(label: str) -> str:
        return re.search(re.escape(label) + r":\s*(\S+)", text).group(1)
    parts = [float(p) for p in field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":")]
    wall = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
    return {"wall_s": wall, "cpu_s": float(field("User time (seconds)")) + float(field("System time (seconds)")),
            "max_rss_gb": float(field("Maximum resident set size (kbytes)")) / 1e6}


def breakdown(results: Path, variant: str) -> pd.DataFrame:
    """job-s, jobs and sampled CPU per stage, in the order of ``STAGES``, then the rest and the total."""
    table = jobs(results, variant)
    order = [stage for stage, _ in STAGES] + [REST]
    grouped = table.groupby("stage").agg(job_s=("s", "sum"), jobs=("s", "size"), cpu_s=("cpu_time", "sum"))
    grouped = grouped.reindex(order).fillna({"job_s": 0.0, "jobs": 0, "cpu_s": 0.0})
    grouped.loc["total"] = grouped.sum()
    return grouped


def side_by_side(old: pd.DataFrame, new: pd.DataFrame) -> str:
    """The markdown table: per stage, job-s (jobs) and sampled CPU of both, and new / old."""
    lines = ["| stage | old job-s (jobs) | new job-s (jobs) | new / old | old CPU s* | new CPU s* |",
             "|---|---|---|---|---|---|"]
    for stage in old.index:
        o, n = old.loc[stage], new.loc[stage]
        ratio = n.job_s / o.job_s if o.job_s > 0 else float("nan")
        lines.append(f"| {stage} | {o.job_s:.0f} ({o.jobs:.0f}) | {n.job_s:.0f} ({n.jobs:.0f}) | {ratio:.2f} | "
                     f"{o.cpu_s:.0f} | {n.cpu_s:.0f} |")
    lines.append("\n*CPU as Snakemake samples it (a job's CPU after its first 15 s is sampled every 30 s: a lower "
                 "bound for long jobs).")
    return "\n".join(lines)


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def run_workflow(work: Path, variant: str) -> float:
    """The variant's targets (libraries, their validation, the per-run and joint fits) from clean in ``work``
    (its results/ and logs/ removed first), `nice -n 10 snakemake --cores 2`; the wall time [s]."""
    for folder in ("results", "logs"):
        subprocess.run(["rm", "-rf", str(work / folder)], check=True)
    targets = [f"results/{variant}/library_validation.tsv", f"results/{variant}/parameters.tsv"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(work / "src")}
    print(f"{work}: load average before {load()}", flush=True)
    start = time.perf_counter()
    run = subprocess.run(["nice", "-n", "10", sys.executable, "-m", "snakemake", "--cores", "2", *targets], cwd=work,
                         env=env, capture_output=True, text=True, check=False)
    if run.returncode:
        raise SystemExit(run.stdout[-3000:] + run.stderr[-3000:])
    wall = time.perf_counter() - start
    print(f"{work}: {wall:.0f} s wall, load average after {load()}", flush=True)
    return wall


def worktree(workdir: Path, name: str, commit: str) -> Path:
    path = workdir / name
    if not path.exists():
        subprocess.run(["git", "worktree", "add", "--detach", str(path), commit], cwd=ROOT, check=True,
                       capture_output=True)
    return path


def _literal_and_optima(fit, k: int) -> tuple[dict, dict]:
    """``fit(monte_carlo_starts)`` with the literal repeats (0) and with ``k`` starts, on one BLAS thread: the fits
    and their CPU seconds, keyed "literal" and "optima"."""
    from threadpoolctl import threadpool_limits

    fits, cpu = {}, {}
    for name, starts in (("literal", 0), ("optima", k)):
        start = time.process_time()
        with threadpool_limits(1):
            fits[name] = fit(starts)
        cpu[name] = time.process_time() - start
    return fits, cpu


def _side_by_side(fits: dict, cpu: dict, spread: pd.Series) -> dict:
    """The figures both protocol comparisons print: CPU seconds and LM problems of each, the largest change of the
    estimate (normalised units; the same trials on the measured data, batched with other repeats: round-off
    apart), the Monte Carlo std ratio optima / literal (median and range over the parameters)."""
    import numpy as np

    return {"cpu_literal_s": cpu["literal"], "cpu_optima_s": cpu["optima"],
            "lm_literal": fits["literal"].protocol.n_lm, "lm_optima": fits["optima"].protocol.n_lm,
            "estimate_change": float(np.abs(fits["optima"].theta - fits["literal"].theta).max()),
            "mc_std_ratio_median": float(spread.median()), "mc_std_ratio_min": float(spread.min()),
            "mc_std_ratio_max": float(spread.max())}


def protocol_comparison(folder: Path, variant_name: str, runs: list[str]) -> pd.DataFrame:
    """Per run: the per-run protocol with the paper's literal repeats and with the workflow's setting, CPU
    seconds, LM problems, the largest change of the estimate (normalised units), the Monte Carlo std of each physical
    parameter
    (optima / literal, median and range over the parameters) and the repeats' mean loss."""
    from dataclasses import replace

    import yaml
    from hybridtwin.identify import forward as fwd
    from hybridtwin.identify import identification as idn
    from hybridtwin.offline.library import Library
    from hybridtwin.settings import IdentificationSettings

    config = yaml.safe_load((folder / "config" / "config.yaml").read_text())
    options = IdentificationSettings.from_config(config).for_variant(variant_name)
    harmonics = idn.read_harmonics(folder / "results" / "data" / "harmonics.tsv")
    validation = pd.read_csv(folder / "results" / variant_name / "library_validation.tsv", sep="\t")
    rows = []
    for run in runs:
        data = idn.run_data(harmonics, run, keyphasor=options["keyphasor"])
        library = Library.load(folder / "results" / variant_name / "library" / f"{run}.zarr")
        errors = idn.model_errors(validation, [run], options["model_error"])
        fits, cpu = _literal_and_optima(lambda k: idn.identify(
            [fwd.SensorSurrogate(library)], [data], (), replace(idn.protocol_options(options), monte_carlo_starts=k),
            errors), int(options["monte_carlo_starts"]))
        tables = {name: fit.table().set_index("parameter") for name, fit in fits.items()}
        physical = [p for p in tables["literal"].index if p != "phase"]
        spread = tables["optima"].loc[physical, "mc_std"] / tables["literal"].loc[physical, "mc_std"]
        rows.append({"run": run, **_side_by_side(fits, cpu, spread),
                     "mc_loss_literal": float(fits["literal"].protocol.monte_carlo_loss.mean()),
                     "mc_loss_optima": float(fits["optima"].protocol.monte_carlo_loss.mean())})
    return pd.DataFrame(rows)


def joint_comparison(folder: Path, variant_name: str) -> dict:
    """The joint fit's library protocol (``run_fits.fit_joint`` with the polish off) with the literal repeats and with
    the workflow's ``joint.monte_carlo_starts``: CPU seconds, LM problems, the largest change of the estimate
    (normalised units), the Monte Carlo std of the shared physical parameters (optima / literal)."""
    import yaml

    from hybridtwin import config as cfg
    from hybridtwin.identify import identification as idn
    from hybridtwin.offline.library import Library
    from hybridtwin.identify.run_fits import fit_joint
    from hybridtwin.settings import IdentificationSettings

    config = yaml.safe_load((folder / "config" / "config.yaml").read_text())
    variant = cfg.variant(config, variant_name, folder / "config")
    options = {**IdentificationSettings.from_config(config).rule(variant_name, "joint"), "polish": False}
    results = folder / "results" / variant_name
    runs = idn.runs_with_role(folder / config["runs"], "fit")
    libraries = [Library.load(results / "library" / f"{run}.zarr") for run in runs]
    per_run = {run: idn.read_parameters(results / "runs" / run / "parameters.tsv") for run in runs}
    harmonics = idn.read_harmonics(folder / "results" / "data" / "harmonics.tsv")
    validation = pd.read_csv(results / "library_validation.tsv", sep="\t")
    fits, cpu = _literal_and_optima(lambda k: fit_joint(
        variant, {**options, "joint": {**options["joint"], "monte_carlo_starts": k}}, libraries, harmonics, per_run,
        validation, int(config["harmonics"])).library_fit, int(options["joint"]["monte_carlo_starts"]))
    tables = {name: fit.table() for name, fit in fits.items()}
    shared = tables["literal"]["run"].eq("all") & tables["literal"]["parameter"].ne("phase")
    spread = tables["optima"].loc[shared, "mc_std"] / tables["literal"].loc[shared, "mc_std"]
    loss = {name: fit.protocol.monte_carlo_loss for name, fit in fits.items()}
    return {"variant": variant_name, **_side_by_side(fits, cpu, spread),
            # the Monte Carlo std over the linearised standard error, median over the shared physical parameters
            **{f"mc_over_se_{name}": float((tables[name].loc[shared, "mc_std"] / tables[name].loc[shared, "stderr"])
                                           .median()) for name in fits},
            # repeats (same noise draws in both) whose kept loss is no higher than the literal repeat's
            "optima_not_worse": float((loss["optima"] <= loss["literal"] * (1 + 1e-6) + 1e-12).mean()),
            "mc_loss_literal": float(loss["literal"].mean()), "mc_loss_optima": float(loss["optima"].mean())}


_SOLVE = """
import pickle, sys, time
import pandas as pd, yaml
from hybridtwin import config as cfg
from hybridtwin.offline.scenarios import solve_runs
folder, variant_name, n, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
config = yaml.safe_load(open(f"{folder}/config/config.yaml"))
variant = cfg.variant(config, variant_name, __import__("pathlib").Path(folder) / "config")
scenarios = pd.read_csv(f"{folder}/results/{variant_name}/scenarios.tsv", sep="\\t").iloc[:n]
runs = cfg.run_plan(f"{folder}/{config['runs']}", f"{folder}/results/data/harmonics.tsv")
start = time.process_time()
solutions = solve_runs(variant, runs, {k: scenarios[k].to_numpy() for k in variant.unknown_names}, config["harmonics"])
print(time.process_time() - start)
pickle.dump(solutions, open(out, "wb"))
"""


def solve_comparison(folder: Path, old_src: Path, variant: str, n: int, repeats: int = 2) -> None:
    """``_SOLVE`` with each source tree (old, new, old, new, ...): CPU seconds, then the states' differences."""
    import pickle
    import tempfile

    import numpy as np

    cpu: dict[str, list[float]] = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            for name, src in (("old", old_src), ("new", ROOT / "src")):
                env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(src)}
                run = subprocess.run([sys.executable, "-c", _SOLVE, str(folder), variant, str(n), f"{tmp}/{name}.pkl"],
                                     env=env, capture_output=True, text=True, check=False)
                if run.returncode:
                    raise SystemExit(f"the solves with {src} failed:\n{run.stderr[-3000:]}")
                cpu[name].append(float(run.stdout.split()[-1]))
        old, new = (pickle.load(open(f"{tmp}/{name}.pkl", "rb")) for name in ("old", "new"))
    both = old.success & new.success
    scale = np.abs(old.harmonics[both]).max(axis=(1, 2))
    change = np.abs(new.harmonics[both] - old.harmonics[both]).max(axis=(1, 2)) / scale
    listed = {name: ", ".join(f"{c:.1f}" for c in values) for name, values in cpu.items()}
    print(f"{variant}, {n} scenarios at {len(old.runs)} runs, one thread: CPU old {listed['old']}"
          f" s, new {listed['new']} s (new / old {min(cpu['new']) / min(cpu['old']):.2f}, "
          f"best of each)")
    print(f"steady states: success flags the same {bool((old.success == new.success).all())}, stability the same "
          f"{bool((old.stable == new.stable).all())}, branches the same {bool((old.branch == new.branch).all())}; "
          f"largest relative change of a converged state {change.max():.1e} (median {np.median(change):.1e})")


def results_comparison(old: Path, new: Path) -> None:
    """How far a run's results moved against another's: per ledger column group the largest relative change,
    per variant the largest change of an estimate over its old standard error, and whether each diagnosis's
    diagnosis recommends the same effects (diagnosis.yaml) and says so in the same words."""
    import yaml

    from hybridtwin.identify.identification import read_parameters

    ledgers = [pd.read_csv(folder / "results" / "ledger.tsv", sep="\t") for folder in (old, new)]
    numeric = [c for c in ledgers[0].columns if pd.api.types.is_numeric_dtype(ledgers[0][c])]
    change = ((ledgers[1][numeric] - ledgers[0][numeric]).abs() / ledgers[0][numeric].abs()).max()
    validation = [c for c in numeric if c.startswith(("validation", "chi2_dof_v"))]
    groups = {"fit (chi2, chi2_dof, bic, per fit run)": [c for c in numeric if c not in validation],
              "validation runs": validation}
    for name, columns in groups.items():
        print(f"ledger, {name}: largest relative change {change[columns].max():.1e} ({change[columns].idxmax()})")
    text = [c for c in ledgers[0].columns if c not in numeric]
    same_text = all((ledgers[0][c].astype(str) == ledgers[1][c].astype(str)).all() for c in text)
    print(f"ledger, text columns the same: {same_text}")
    for variant in ledgers[0]["variant"]:
        tables = [read_parameters(folder / "results" / variant / "parameters.tsv") for folder in (old, new)]
        moved = float(((tables[1]["value"] - tables[0]["value"]).abs() / tables[0]["stderr"]).max())
        diagnoses = [yaml.safe_load((folder / "results" / variant / "diagnosis.yaml").read_text())
                     for folder in (old, new)]
        recommended = [(d.get("recommended_variant") or {}).get("spec", {}).get("effects") for d in diagnoses]
        confounded = [d.get("confounded") for d in diagnoses]
        same = recommended[0] == recommended[1] and confounded[0] == confounded[1]
        text = "word for word" if diagnoses[0]["conclusion"] == diagnoses[1]["conclusion"] else "not word for word"
        print(f"{variant}: estimates moved at most {moved:.1e} standard errors; diagnosis: the recommended effects "
              f"and the confounded ones {'the same' if same else 'DIFFER'}, the conclusion {text}")
        if text != "word for word":
            print(f"  old: {diagnoses[0]['conclusion']}\n  new: {diagnoses[1]['conclusion']}")
        print(f"  {library_and_protocol_change(old, new, variant)}")


def library_and_protocol_change(old: Path, new: Path, variant: str) -> str:
    """What the libraries' density changes: their test errors (library_validation.tsv, the medians over the runs
    of each run's median and 95th percentile, and the largest per-run ratio new/old), and how far the paper's
    per-run protocol moved (runs/*/parameters.tsv: every per-run estimate's change over its old Monte Carlo
    spread; median, 90th percentile, largest)."""
    from hybridtwin.identify.identification import read_parameters

    errors = [pd.read_csv(folder / "results" / variant / "library_validation.tsv", sep="\t").set_index("run")
              for folder in (old, new)]
    ratio = errors[1]["median_error_pct"] / errors[0]["median_error_pct"]
    moves = []
    for path in sorted((old / "results" / variant / "runs").glob("*/parameters.tsv")):
        before, after = read_parameters(path), read_parameters(new / path.relative_to(old))
        moves.append((after["value"] - before["value"]).abs() / before["mc_std"].where(before["mc_std"] > 0))
    moved = pd.concat(moves).dropna() if moves else pd.Series(dtype=float)
    median, p95 = ([table[f"{q}_error_pct"].median() for table in errors] for q in ("median", "p95"))
    text = (f"library test error (% of the response, median over the runs) median {median[0]:.3g} -> {median[1]:.3g}, "
            f"p95 {p95[0]:.3g} -> {p95[1]:.3g} (per run new/old: median x{ratio.median():.2f}, "
            f"largest x{ratio.max():.2f})")
    if moved.size:
        text += (f"; per-run protocol estimates moved median {moved.median():.2f}, 90 % {moved.quantile(0.9):.2f}, "
                 f"largest {moved.max():.3g} Monte Carlo spreads ({moved.size} estimates)")
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--old", type=Path, help="folder of the earlier commit's workflow run")
    parser.add_argument("--new", type=Path, default=ROOT, help="folder of this commit's workflow run")
    parser.add_argument("--variant", default="geometric", help="a variant, or all (the whole main job)")
    parser.add_argument("--run", action="store_true", help="run the workflow in worktrees of both commits first")
    parser.add_argument("--old-commit", help="with --run: the earlier commit")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/main_job_benchmark"))
    parser.add_argument("--protocol", type=Path, help="folder of a workflow run: compare the per-run protocols")
    parser.add_argument("--protocol-runs", nargs="+", default=["r350_m25p9", "r700_m14p8", "r950_m0p0"])
    parser.add_argument("--joint", type=Path, help="folder of a workflow run: compare the joint fit's protocols")
    parser.add_argument("--joint-variants", nargs="+", default=["geometric", "expansion", "final", "geometric_expansion_k4"])
    parser.add_argument("--solves", type=Path, help="folder of a workflow run: time one chunk's solves, old vs new")
    parser.add_argument("--old-src", type=Path, help="with --solves: the older source tree (its src folder)")
    parser.add_argument("--scenarios", type=int, default=200, help="with --solves: the first N scenarios")
    parser.add_argument("--rules", type=Path, help="folder of a finished main job: the per-rule table")
    parser.add_argument("--time-log", type=Path, help="with --rules: the run's `/usr/bin/time -v` output")
    parser.add_argument("--results", type=Path, nargs=2, metavar=("OLD", "NEW"),
                        help="two finished runs of the main job: how far the results moved")
    args = parser.parse_args()
    if args.solves and args.old_src is None:
        parser.error("--solves needs --old-src")
    if args.run and not args.old_commit:
        parser.error("--run needs --old-commit")
    stage_table = args.run or args.old is not None
    if not (args.results or args.solves or args.joint or args.protocol or args.rules or stage_table):
        parser.error("give --old FOLDER (or --run --old-commit COMMIT), --rules, --results, --solves, --joint or "
                     "--protocol")
    if args.rules:
        table = per_rule(args.rules)
        print("| rule | job-s | jobs | CPU s* |\n|---|---|---|---|")
        for rule, row in table.iterrows():
            print(f"| {rule} | {row.job_s:.0f} | {row.jobs:.0f} | {row.cpu_s:.0f} |")
        print("\n*CPU as Snakemake samples it (a lower bound for jobs longer than 15 s).")
        if args.time_log:
            whole = time_log(args.time_log)
            print(f"\nthe whole run: {whole['wall_s']:.0f} s wall ({whole['wall_s'] / 60:.1f} min), "
                  f"{whole['cpu_s']:.0f} s CPU (user + system), {whole['max_rss_gb']:.2f} GB peak resident (one process)")
    # each requested comparison in turn (several may be asked at once), the stage table last
    if args.results:
        results_comparison(*args.results)
    if args.solves:
        print(f"load average {load()}")
        solve_comparison(args.solves, args.old_src, args.variant, args.scenarios)
    for folder, compare, names in ((args.joint, joint_comparison_table, args.joint_variants),
                                   (args.protocol, protocol_comparison, args.protocol_runs)):
        if folder:
            print(f"load average {load()}")
            table = compare(folder, args.variant, names)
            table["estimate_change"] = table["estimate_change"].map("{:.1e}".format)
            print(table.round(3).to_string(index=False), flush=True)
    if not stage_table:
        return
    if args.run:
        args.workdir.mkdir(parents=True, exist_ok=True)
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, check=True, capture_output=True,
                              text=True).stdout.strip()
        args.old, args.new = worktree(args.workdir, "old", args.old_commit), worktree(args.workdir, "new", head)
        walls = {name: run_workflow(path, args.variant) for name, path in (("old", args.old), ("new", args.new))}
        print(f"wall: old {walls['old']:.0f} s, new {walls['new']:.0f} s")
    old, new = (breakdown(folder / "results", args.variant) for folder in (args.old, args.new))
    print(f"\n{args.variant}: old {args.old}, new {args.new} (load average now {load()})\n")
    print(side_by_side(old, new))


def joint_comparison_table(folder: Path, variant: str, names: list[str]) -> pd.DataFrame:
    """``joint_comparison`` of each variant of ``names`` (``variant`` unused: the joint comparison is per
    variant), one row each."""
    return pd.DataFrame([joint_comparison(folder, name) for name in names])

if __name__ == "__main__":
    main()
