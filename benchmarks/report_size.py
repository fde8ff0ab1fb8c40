"""The single-file report of a finished run (issue 55): its size, what it is made of, and how long a headless
Chromium takes to open it.

    python benchmarks/report_size.py FOLDER [--report report.html] [--repeats 3]

FOLDER is where the workflow ran (the main job: a clone after `snakemake --cores 2`); the report is made there with
`snakemake --report` unless ``--report`` names one already made. Printed: the report's bytes; the embedded files by
kind (their base64 data URIs: the interactive page, PNGs, tables) and the rest (Snakemake's page and scripts); and the
time to open it, ``chromium --headless --dump-dom`` on the report minus the same on an empty page (Chromium's own
start), best of ``--repeats``. The open time is a wall time: measure on an idle machine.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def parts(html: str) -> Counter:
    """Bytes of the report by kind: each embedded file's data URI (by its file name's kind) and the rest."""
    sizes: Counter = Counter()
    embedded = 0
    for match in re.finditer(r"data:[^;\"]+;charset=utf8;filename=([^;]+);base64,([A-Za-z0-9+/=]*)", html):
        name, size = match[1], len(match[2])
        kind = "interactive page" if name.endswith(".html") else Path(name).suffix.lstrip(".") or "other"
        sizes[kind] += size
        embedded += size
    sizes["Snakemake's page, scripts and metadata"] = len(html) - embedded
    return sizes


def open_time(page: Path, repeats: int) -> float:
    """Best wall seconds of ``chromium --headless --dump-dom page`` less the same on an empty page."""
    def best(target: Path) -> float:
        times = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as profile:
                start = time.perf_counter()
                subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--dump-dom", target.as_uri()],
                               capture_output=True, check=True)
                times.append(time.perf_counter() - start)
        return min(times)

    with tempfile.TemporaryDirectory() as folder:
        empty = Path(folder) / "empty.html"
        empty.write_text("<!DOCTYPE html><html><body></body></html>")
        return best(page) - best(empty)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path)
    parser.add_argument("--report", type=Path, help="a report already made (default: make FOLDER/report.html)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    report = args.report
    if report is None:
        report = args.folder / "report.html"
        subprocess.run([sys.executable, "-m", "snakemake", "--report", str(report.name)], cwd=args.folder,
                       check=True, capture_output=True)
    html = report.read_text(encoding="utf-8")
    print(f"{report}: {len(html) / 1e6:.1f} MB")
    for kind, size in parts(html).most_common():
        print(f"  {kind}: {size / 1e6:.2f} MB")
    if shutil.which(CHROMIUM) or Path(CHROMIUM).exists():
        print(f"opens in {open_time(report.resolve(), args.repeats):.2f} s (headless Chromium, less its own start; "
              f"best of {args.repeats})")
    else:
        print(f"no {CHROMIUM}: the open time not measured")


if __name__ == "__main__":
    main()
