"""Shared by the benchmark scripts: the workflow run in a folder, timed."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path


def timed_snakemake(work: Path, targets: Sequence[str], options: Sequence[str] = ()) -> float:
    """`snakemake --cores 2 TARGETS [OPTIONS]` in ``work``; its wall time [s]. Exits with Snakemake's output
    on failure."""
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", *targets, *options], cwd=work,
                         capture_output=True, text=True)
    if run.returncode:
        raise SystemExit(run.stdout[-3000:] + run.stderr[-3000:])
    return time.perf_counter() - start
