"""Helpers shared by the resilience tests and the Slurm test (tests/slurm/run_slurm_test.sh).

The small configuration and the workflow copy are test_workflow's own (imported, not repeated).
"Same results" here means byte-identical files: the same code, seeds and binaries, with BLAS
pinned to one thread in every job (hybridtwin.config.rule_logger), do the same floating-point
operations in the same order, so any difference is a real change, never rounding. Only wall
times are left out: results/benchmarks/ (Snakemake's per-job timings) and the `seconds` and `*_seconds`
entries of YAML summaries. (Across different machines, e.g. CPUs with other SIMD paths in
BLAS, bit-identity is not promised; a tolerance would be needed there.)

Command line, for the shell script::

    python tests/workflow_helpers.py copy DIR       # the small workflow in DIR (test_workflow._copy_workflow)
    python tests/workflow_helpers.py compare A B    # A/results vs B/results; exit 1 listing the differences
"""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_workflow import RUNS, SMALL, SNAKEMAKE, _copy_workflow, _snakemake  # noqa: E402

__all__ = ["RUNS", "SMALL", "SNAKEMAKE", "copy_workflow", "snakemake", "result_files", "compare_results"]

copy_workflow = _copy_workflow
snakemake = _snakemake

WALL_TIME_KEYS = {"seconds"}  # and every key ending in "_seconds" (the diagnosis's score_seconds)
NOT_COMPARED_DIRS = {"benchmarks"}
NOT_COMPARED_FILES = {".snakemake_timestamp"}


def result_files(work: Path) -> dict[str, Path]:
    """Every result file of a workflow directory (relative path -> path), wall-time records left out."""
    root = Path(work) / "results"
    return {path.relative_to(root).as_posix(): path for path in sorted(root.rglob("*"))
            if path.is_file() and path.name not in NOT_COMPARED_FILES
            and path.relative_to(root).parts[0] not in NOT_COMPARED_DIRS}


def _without_wall_times(data):
    if isinstance(data, dict):
        return {k: _without_wall_times(v) for k, v in data.items()
                if k not in WALL_TIME_KEYS and not str(k).endswith("_seconds")}
    if isinstance(data, list):
        return [_without_wall_times(v) for v in data]
    return data


def _content(path: Path) -> bytes:
    if path.suffix in (".yaml", ".yml"):
        return yaml.safe_dump(_without_wall_times(yaml.safe_load(path.read_text())), sort_keys=True).encode()
    return path.read_bytes()


def compare_results(a: Path, b: Path) -> list[str]:
    """Differences between two workflow directories' results (empty: the same files, byte for byte)."""
    files_a, files_b = result_files(a), result_files(b)
    differences = [f"only in {a}: {name}" for name in sorted(files_a.keys() - files_b.keys())]
    differences += [f"only in {b}: {name}" for name in sorted(files_b.keys() - files_a.keys())]
    differences += [f"differs: {name}" for name in sorted(files_a.keys() & files_b.keys())
                    if _content(files_a[name]) != _content(files_b[name])]
    return differences


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "copy":
        Path(argv[1]).mkdir(parents=True)
        copy_workflow(Path(argv[1]))
        return 0
    if len(argv) == 3 and argv[0] == "compare":
        differences = compare_results(Path(argv[1]), Path(argv[2]))
        n_files = len(result_files(Path(argv[1])))
        if differences:
            print(f"{len(differences)} difference(s) between {argv[1]} and {argv[2]}:", *differences[:50], sep="\n  ")
            return 1
        if n_files == 0:
            print(f"no result files in {argv[1]}")
            return 1
        print(f"{n_files} result files identical (byte for byte; wall times left out)")
        return 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
