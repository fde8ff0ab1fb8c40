"""The single-file report of a finished run (issue 55): its size, what it is made of, and how long a headless
Chromium takes to open it.

    python benchmarks/report_size.py FOLDER [--report report.html] [--repeats 3] [--against OTHER.html] [--page PAGE]

FOLDER is where the workflow ran (the main job: a clone after `snakemake --cores 2`); the report is made there with
`snakemake --report` unless ``--report`` names one already made. Printed: the report's bytes; the embedded files by
kind (their base64 data URIs: the interactive page, PNGs, tables) and the rest (Snakemake's page and scripts); the
time to open it, ``chromium --headless --dump-dom`` on the report minus the same on an empty page (Chromium's own
start), best of ``--repeats``, as wall seconds and as CPU seconds (``open_times``; ``--against`` another report,
opened in turn with it), with the load average: the wall time is the figure of issue 55, to measure on an idle
machine; on a shared one the CPU time, which moves less with the load, compares two reports. And the time to the report's load event by the page's own clock (``load_time``):
what a user waits, without the dump of the page's HTML that the wall time includes. With ``--page``, the
interactive page by itself to its first figure drawn (``drawn_time``).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
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


def open_times(pages: list[Path], repeats: int) -> list[tuple[float, float]]:
    """Per page: best wall seconds of ``chromium --headless --dump-dom page`` less the same on an empty page, and best
    CPU seconds (user + system) of the same in one process (``--single-process``: the page's renderer counted, which
    as a process of its own is not among ours) less the same on the empty page. The pages are opened in turn, each
    repeat once each, so that two reports meet the same load. The wall time is what a user waits on an idle machine;
    the CPU time moves less with the machine's load."""
    def run(target: Path, *extra: str) -> tuple[float, float]:
        with tempfile.TemporaryDirectory() as profile:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            subprocess.run([CHROMIUM, *FLAGS, *extra, f"--user-data-dir={profile}", "--dump-dom", target.as_uri()],
                           capture_output=True, check=True)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime

    with tempfile.TemporaryDirectory() as folder:
        empty = Path(folder) / "empty.html"
        empty.write_text("<!DOCTYPE html><html><body></body></html>")
        targets = [empty, *pages]
        walls: list[list[float]] = [[] for _ in targets]
        cpus: list[list[float]] = [[] for _ in targets]
        for _ in range(repeats):
            for i, target in enumerate(targets):
                walls[i].append(run(target)[0])
                cpus[i].append(run(target, "--single-process")[1])
        return [(min(w) - min(walls[0]), min(c) - min(cpus[0])) for w, c in zip(walls[1:], cpus[1:])]


#: added to a copy of the report: the page's own clock (ms since the navigation started) at its load event, when
#: the report's scripts have run and its first page is built, written into the page for ``--dump-dom`` to carry out
LOADED = ("<script>window.addEventListener('load', function () { var pre = document.createElement('pre'); "
          "pre.id = 'opened'; pre.textContent = String(performance.now()); document.body.appendChild(pre); });"
          "</script>")


def load_time(page: Path, repeats: int) -> float:
    """Best seconds from the navigation's start to the page's load event, as the page's own clock reads them in
    headless Chromium (``LOADED``): what a user waits for the report, without Chromium's start or the dump of the
    page's 15-25 MB of HTML that the wall time of ``open_time`` includes."""
    html = page.read_text(encoding="utf-8")
    end = html.rindex("</body>")
    times = []
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / page.name
        copy.write_text(html[:end] + LOADED + html[end:], encoding="utf-8")
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as profile:
                done = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--dump-dom", copy.as_uri()],
                                      capture_output=True, check=True, text=True)
            times.append(float(re.search(r'<pre id="opened">([0-9.]+)</pre>', done.stdout)[1]) / 1e3)
    return min(times)


def drawn_time(page: Path, repeats: int) -> tuple[float, int]:
    """Best wall seconds of ``chromium --headless --virtual-time-budget=5000 --dump-dom page`` less the same on an
    empty page, and the plotly figures in the dumped page: the interactive page opened by itself to its first figure
    drawn (the virtual time skips the page's idle waits, not its work), as a Chromium user opens it (Chromium shows
    no report entry above 2 MB)."""
    def run(target: Path) -> tuple[float, str]:
        with tempfile.TemporaryDirectory() as profile:
            start = time.perf_counter()
            done = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=5000",
                                   "--dump-dom", target.as_uri()], capture_output=True, check=True, text=True)
            return time.perf_counter() - start, done.stdout

    with tempfile.TemporaryDirectory() as folder:
        empty = Path(folder) / "empty.html"
        empty.write_text("<!DOCTYPE html><html><body></body></html>")
        runs = [run(page) for _ in range(repeats)]
        return (min(wall for wall, _ in runs) - min(run(empty)[0] for _ in range(repeats)),
                runs[-1][1].count('class="main-svg"'))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path)
    parser.add_argument("--report", type=Path, help="a report already made (default: make FOLDER/report.html)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--against", type=Path, help="another report to open in turn with it (each repeat once "
                        "each: the same load for both), its open time printed after")
    parser.add_argument("--page", type=Path, help="also time this interactive page to its first figure drawn "
                        "(FOLDER/results/interactive.html)")
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
        reports = [report.resolve()] + ([args.against.resolve()] if args.against else [])
        for path, (wall, cpu) in zip(reports, open_times(reports, args.repeats)):
            print(f"{path.name} opens in {wall:.2f} s, {cpu:.2f} s of CPU (headless Chromium's --dump-dom, less its "
                  f"own start; best of {args.repeats}; load average {os.getloadavg()[0]:.1f})")
        print(f"loaded in {load_time(report.resolve(), args.repeats):.2f} s (its load event, the page's own clock; "
              f"best of {args.repeats}; load average {os.getloadavg()[0]:.1f})")
        if args.page is not None:
            seconds, svgs = drawn_time(args.page.resolve(), args.repeats)
            print(f"{args.page} ({args.page.stat().st_size / 1e6:.1f} MB) by itself: its first figure drawn in "
                  f"{seconds:.2f} s ({svgs} plotly SVG layers; best of {args.repeats}, less Chromium's start; load "
                  f"average {os.getloadavg()[0]:.1f})")
    else:
        print(f"no {CHROMIUM}: the open time not measured")


if __name__ == "__main__":
    main()
