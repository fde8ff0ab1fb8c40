"""How long `hybridtwin assess` takes: a steady record and a 60-s run-up, from a built twin (issue 40's targets:
<= 5 s wall for a steady record, <= 30 s for a 60-s run-up, on 2 cores).

    OMP_NUM_THREADS=1 python benchmarks/assess_timing.py --twin results/geometric_slope --data DIR [--repeats 3]

Records (made once into ``--data`` by the virtual rig from the bundled data's truth, a keyphasor on): a steady record
at 720 RPM, 14.8 g, of the unchanged machine and of a bearing 10 % softer; a run-up 380 -> 980 RPM without added
mass, 60 s at 10 RPM/s, 5 kHz (time integration, about a minute to make). Each is judged by the command itself
(`python -m hybridtwin.cli assess ...` in a new process: the import, the record's reading and checks, the fits, the
tables, the figure and the trend), ``--repeats`` times, with and without the figures; the wall and CPU time
(user + system of the process) are printed, with the load average (the machine is shared: CPU time is what an idle
machine's wall time would be, one core being used). Then the phases of one assessment in one process.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from hybridtwin.rig.rig import DEFAULT_TRUTH, Imperfections, RigSpec, Truth, generate

TRUTH = DEFAULT_TRUTH["values"]


def make(folder: Path, plan: pd.DataFrame, values: dict) -> Path:
    if not (folder / "runs.tsv").is_file():
        truth = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"], "values": TRUTH | values})
        generate(plan, RigSpec(truth, Imperfections(keyphasor=True), seed=21), folder)
    return folder / "runs.tsv"


def run(command: list[str]) -> tuple[float, float, float]:
    """Wall and CPU (user + system) seconds of a command in a new process, and the wall seconds until its first
    line on the console (the verdict: the command prints it before it draws the figures)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as process:
        first = process.stdout.readline()
        verdict = time.perf_counter() - start
        rest, err = process.communicate()
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{err[-2000:]}")
    print("   ", first.strip()[:160])
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), verdict


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--twin", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    steady = pd.DataFrame({"run": ["r720"], "rpm": [720.0], "eccentric_mass_g": [14.8], "role": ["fit"]})
    runup = pd.DataFrame({"run": ["u0"], "kind": ["runup"], "rpm": [float("nan")], "rpm_start": [380.0],
                          "rpm_end": [980.0], "eccentric_mass_g": [0.0], "role": ["fit"]})
    cases = {"steady, unchanged": make(args.data / "steady", steady, {}),
             "steady, bearing 10 % softer": make(args.data / "steady_soft", steady, {"k_b": 0.9 * TRUTH["k_b"]}),
             "run-up 60 s, unchanged": make(args.data / "runup", runup, {})}
    out = args.data / "out"
    print(f"| record | figures | verdict on the console [s] | wall [s] (median of {args.repeats}) | CPU [s] | "
          "load average |\n|---|---|---|---|---|---|")
    for name, sheet in cases.items():
        for figures in (True, False):
            times = []
            for _ in range(args.repeats):
                command = [sys.executable, "-m", "hybridtwin.cli", "assess", str(sheet), "--twin", str(args.twin),
                           "--out", str(out)] + ([] if figures else ["--no-figure"])
                times.append(run(command))
            wall, cpu, verdict = (sorted(t[k] for t in times)[len(times) // 2] for k in (0, 1, 2))
            print(f"| {name} | {'yes' if figures else 'no'} | {verdict:.1f} | {wall:.1f} | {cpu:.1f} | "
                  f"{os.getloadavg()[0]:.1f} |")
    phases(args.twin, cases)
    return 0


def phases(twin_path: Path, cases: dict) -> None:
    """Where one assessment's time goes, in one process (CPU seconds)."""
    def cpu() -> float:
        t = os.times()
        return t.user + t.system

    start = cpu()
    from hybridtwin.online.assess import assess
    from hybridtwin.online.intake import intake, read_sheet
    from hybridtwin.online.twin import load_twin
    imported = cpu()
    twin = load_twin(twin_path)
    print(f"\nimport {imported - start:.2f} s CPU; twin {cpu() - imported:.2f} s\n"
          "| record | intake (read, check, harmonics or bands) | assess (fits, verdict, tables) | figure |\n"
          "|---|---|---|---|")
    from hybridtwin.online.assess_plots import plot_assessment
    for name, sheet in cases.items():
        row = read_sheet(sheet)[0]
        a = cpu()
        record = intake(twin, row)
        b = cpu()
        result = assess(twin, record)
        c = cpu()
        plot_assessment(result).savefig(sheet.parent / "figure.png", dpi=110)
        d = cpu()
        print(f"| {name} ({result.summary['verdict']}, {result.summary['n_runs']} run(s)) | {b - a:.2f} | {c - b:.2f} "
              f"| {d - c:.2f} |")


if __name__ == "__main__":
    sys.exit(main())
