"""Offline-stage benchmark: the whole white-box stage of the default configuration, timed, side by side.

    python benchmarks/offline_benchmark.py --workdir DIR [--baseline OTHER/results]
    python benchmarks/offline_benchmark.py --workdir DIR --variants geometric expansion final --fit-runs
    python benchmarks/offline_benchmark.py --results DIR/results [--baseline OTHER/results]

1. With --workdir: a copy of the workflow and the bundled data in DIR (kept, so a second call only
   summarises), then `snakemake --cores 2` on every variant's library_validation.tsv from scratch: scenarios,
   chunk solves, enrichment, gather, POD, sPGD libraries and their validation (the identification and later
   stages are not run). Prints the wall time. --variants: only these variants (default: every declared
   one); --fit-runs: only the runs sheet's fit runs (a copy of the sheet without the validation runs).
   The second line is issue 3's own plan: the paper's three variants at its 19 runs.
2. Job-seconds per rule and variant from Snakemake's own per-rule benchmark files
   (results/benchmarks/{variant}/{rule}[_{wildcards}].tsv, column s), with the job count.
3. Library accuracy per run (results/{variant}/library_validation.tsv: median and 95th percentile of the
   relative sensor error on the held-out test scenarios) and each variant's worst run.

With --baseline (another results folder, e.g. from an older commit) every figure is printed next to the
baseline's, with the ratio. Times are wall-clock on the machine as it is: other jobs inflate them.
"""

from __future__ import annotations

import argparse
import re
import shutil
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
from workflow_run import timed_snakemake

ROOT = Path(__file__).resolve().parents[1]
OFFLINE_RULES = ["sample_scenarios", "solve_chunk", "sample_enrichment", "solve_enrichment", "gather_snapshots",
                 "pod", "spgd_library", "spgd_global", "validate_library"]
_RULE = re.compile(r"^(" + "|".join(sorted(OFFLINE_RULES, key=len, reverse=True)) + r")(_.*)?$")


def run_offline_stage(work: Path, variants: Sequence[str] | None = None, fit_runs: bool = False) -> float | None:
    """Copy the workflow into ``work`` and build the libraries of ``variants`` (default: every declared one)
    from scratch, at every run of the runs sheet or only its fit runs; the wall time [s] (None when ``work``
    already holds a finished run)."""
    declared = _variants(ROOT / "config" / "config.yaml")
    unknown = sorted(set(variants or []) - set(declared))
    if unknown:
        raise SystemExit(f"--variants: {unknown} not declared in config/config.yaml (declared: {declared})")
    variants = list(variants or declared)
    targets = [f"results/{v}/library_validation.tsv" for v in variants]
    if all((work / t).exists() for t in targets):
        return None
    for item in ("Snakefile", "workflow", "scripts", "config", "profiles", "data"):
        source = ROOT / item
        if not (work / item).exists():
            (shutil.copytree if source.is_dir() else shutil.copy)(source, work / item)
    return timed_snakemake(work, targets, ["--config", f"runs={_fit_runs_sheet(work)}"] if fit_runs else [])


def _fit_runs_sheet(work: Path) -> str:
    """A copy of the config's runs sheet with its fit runs only, next to it (record paths stay valid)."""
    import yaml

    sheet = Path(yaml.safe_load((work / "config" / "config.yaml").read_text())["runs"])
    runs = pd.read_csv(work / sheet, sep="\t")
    fit = sheet.with_name(f"{sheet.stem}_fit_only.tsv")
    runs[runs["role"] == "fit"].to_csv(work / fit, sep="\t", index=False)
    return str(fit)


def _variants(config: Path) -> list[str]:
    import yaml

    return list(yaml.safe_load(config.read_text())["variants"])


def job_seconds(results: Path) -> pd.DataFrame:
    """Job-seconds and job count per (variant, rule) of the offline rules."""
    rows = []
    for path in sorted((results / "benchmarks").glob("*/*.tsv")):
        match = _RULE.match(path.stem)
        if path.parent.name == "data" or not match:
            continue
        seconds = pd.read_csv(path, sep="\t")["s"].iloc[-1]
        rows.append({"variant": path.parent.name, "rule": match.group(1), "s": float(seconds)})
    table = pd.DataFrame(rows, columns=["variant", "rule", "s"])
    return table.groupby(["variant", "rule"], sort=False).agg(s=("s", "sum"), jobs=("s", "size")).reset_index()


def accuracy(results: Path) -> pd.DataFrame:
    """Per variant and run: median and 95th percentile of the library's test error [%]."""
    parts = []
    for path in sorted(results.glob("*/library_validation.tsv")):
        table = pd.read_csv(path, sep="\t")
        table = table[table["run"] != "all runs"]
        parts.append(table.assign(variant=path.parent.name)[["variant", "run", "median_error_pct", "p95_error_pct"]])
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
        columns=["variant", "run", "median_error_pct", "p95_error_pct"])


def side_by_side(now: pd.DataFrame, baseline: pd.DataFrame | None, keys: list[str], values: list[str]) -> pd.DataFrame:
    if baseline is None:
        return now
    both = now.merge(baseline, on=keys, how="outer", suffixes=("", "_baseline"))
    for value in values:
        both[f"{value}_ratio"] = both[value] / both[f"{value}_baseline"]
    return both


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--workdir", type=Path, help="run the offline stage from scratch in this folder")
    where.add_argument("--results", type=Path, help="only summarise this results folder")
    parser.add_argument("--baseline", type=Path, help="a results folder to compare with, side by side")
    parser.add_argument("--variants", nargs="+", metavar="NAME", help="only these variants (with --workdir)")
    parser.add_argument("--fit-runs", action="store_true", help="only the runs sheet's fit runs (with --workdir)")
    args = parser.parse_args()
    if args.workdir:
        args.workdir.mkdir(parents=True, exist_ok=True)
        wall = run_offline_stage(args.workdir, args.variants, args.fit_runs)
        print("offline stage from scratch: " + (f"{wall:.0f} s wall" if wall is not None else
                                                "already built (delete the folder to time it again)"))
        results = args.workdir / "results"
    else:
        results = args.results
    pd.set_option("display.width", 200, "display.max_rows", 200, "display.float_format", "{:.4g}".format)
    baseline_jobs = job_seconds(args.baseline) if args.baseline else None
    jobs = job_seconds(results)
    print("\njob-seconds per rule (Snakemake benchmark files)")
    print(side_by_side(jobs, baseline_jobs, ["variant", "rule"], ["s"]).to_string(index=False))
    totals = jobs.groupby("variant")["s"].sum().rename("s").reset_index()
    base_totals = baseline_jobs.groupby("variant")["s"].sum().rename("s").reset_index() if args.baseline else None
    print("\njob-seconds per variant (the wall time on 2 cores is at least half the total)")
    print(side_by_side(totals, base_totals, ["variant"], ["s"]).to_string(index=False))
    print(f"total: {jobs['s'].sum():.0f} job-seconds" +
          (f" (baseline {baseline_jobs['s'].sum():.0f})" if args.baseline else ""))
    errors = side_by_side(accuracy(results), accuracy(args.baseline) if args.baseline else None,
                          ["variant", "run"], ["median_error_pct", "p95_error_pct"])
    print("\nlibrary test error per run [%]")
    print(errors.to_string(index=False))


if __name__ == "__main__":
    main()
