"""``hybridtwin docs-images``: the README's and the docs' figures (docs/img) regenerated from a finished run of the
main job, so that they cannot go stale (issue 37 part 5, issue 39 item 6).

``FROM_RUN`` maps each figure a page shows to the result of the workflow it is a copy of; ``FROM_BENCHMARKS`` names
the figures a benchmark script makes instead, with the command (benchmarks/README.md lists them; they are not
rerun here). Every docs/img image a page shows is in one of the two (tests/test_docs_images.py)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from .common import UsageError

#: docs/img figure <- the main job's result it shows (paths under the project: results/ of `snakemake --cores 2`)
FROM_RUN = {
    "summary.png": "results/summary.png",  # README, what to look at first, 1
    "geometric_run.png": "results/geometric/report/runs/r1000_m0p0.png",  # README, 2: a run geometric fails
    "design.png": "results/geometric_expansion_k4/design/design.png",  # README, the next run to take
}
#: docs/img figure <- the benchmark command that makes it (not a result of the main job; benchmarks/README.md)
FROM_BENCHMARKS = {
    "online_trend.png": "python benchmarks/online_trend_demo.py --twin results/geometric_slope --out online_demo "
                        "--figure docs/img/online_trend.png",
    "online_alarms.png": "OMP_NUM_THREADS=1 python benchmarks/assess_benchmark.py --twin results/geometric_slope "
                         "--data DIR --out DIR (its alarms_time.png, copied)",
}


def add_docs_images_command(sub) -> None:
    """Register ``hybridtwin docs-images`` on the CLI's subparsers."""
    parser = sub.add_parser(
        "docs-images", help="copy the README's and docs' figures (docs/img) from a finished run of the main job",
        description="Copy each figure the README and docs/ show that a run of the main job makes (results/summary.png,"
                    " geometric's r1000_m0p0 run, geometric_expansion_k4's design) from --results to --out. The "
                    "figures the benchmarks make are listed, with their commands, in benchmarks/README.md.")
    parser.add_argument("--results", type=Path, default=Path("results"),
                        help="the run's results folder (default ./results)")
    parser.add_argument("--out", type=Path, default=Path("docs/img"), help="where the figures go (default docs/img)")
    parser.set_defaults(handler=docs_images_command)


def docs_images_command(args: argparse.Namespace) -> int:
    """Copy ``FROM_RUN``'s figures; a missing one is an error naming it and the rule that makes it, nothing copied."""
    sources = {name: args.results / Path(path).relative_to("results") for name, path in FROM_RUN.items()}
    missing = [str(path) for path in sources.values() if not path.is_file()]
    if missing:
        raise UsageError(f"{', '.join(missing)}: missing; run the main job first (`snakemake --cores 2`) or give "
                         "--results the results folder of a finished run")
    args.out.mkdir(parents=True, exist_ok=True)
    for name, path in sources.items():
        shutil.copyfile(path, args.out / name)
        print(f"{args.out / name} <- {path}")
    for name, command in FROM_BENCHMARKS.items():
        print(f"{args.out / name}: made by a benchmark, not copied: {command}")
    return 0
