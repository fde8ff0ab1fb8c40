"""When can the twin's library answer a record? The same records judged on the library and on the full solver, at
several record noise levels (issue 50, item 3).

    OMP_NUM_THREADS=1 python benchmarks/assess_library_study.py --project DIR --data DIR

The project: a built project whose twin has per-run libraries (``offline.scope: run``), e.g. the small one of
tests/test_identification.py (``make_workdir``: a Geometric truth, 5 fit runs near the resonance, 120-scenario
libraries over narrow ranges; ``--make`` builds it in DIR, about 15 minutes of CPU). The records: the virtual rig's
from that truth (tests/test_identification.py ``TRUTH``, keyphasor on), at 850 RPM (0 and 14.8 g), 900, 950 and
1000 RPM (0 g), unchanged and with the bearing 5 % softer, at each ``--levels`` noise (mm) and duration (s). Each
record is judged as ``hybridtwin assess`` does (the library first), on the library alone and on the solver alone;
printed per level: the verdicts side by side, how many the library decided, whether they agree, the interval of the
record's p-value across the library's error bound (B), and the times.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

RUNS = [("a850", 850.0, 0.0), ("b850", 850.0, 14.8), ("c900", 900.0, 0.0), ("d950", 950.0, 0.0),
        ("e1000", 1000.0, 0.0)]
CASES = {"unchanged": {}, "k_b -5 %": {"k_b": 0.95}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--project", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True, help="the rig's records (made once, reused)")
    parser.add_argument("--make", action="store_true", help="build the project first (tests' make_workdir)")
    parser.add_argument("--levels", default="0.05:16,0.05:4,2:1", help="noise_mm:duration_s, comma-separated")
    args = parser.parse_args(argv)
    from test_identification import GEOMETRIC, TARGETS, TRUTH, make_workdir

    from hybridtwin.rig.rig import RigSpec, generate
    from hybridtwin.online.assess import assess
    from hybridtwin.online.intake import RecordError, intake, read_sheet
    from hybridtwin.online.twin import load_twin

    if args.make:
        args.project.mkdir(parents=True)
        make_workdir(args.project)
        subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", *TARGETS, "results/geometric/twin.yaml"],
                       cwd=args.project, check=True)
    twin = load_twin(args.project / "results" / "geometric")
    print(f"# {twin.library_line()}")
    for entry in twin.library["runs"]:
        anchor = entry.get("anchor") or {}
        print(f"# {entry['run']}: test error median {entry['median_error_pct']:.3g} %, max "
              f"{entry['max_error_pct']:.3g} %; at the twin {anchor.get('raw_error_pct', float('nan')):.3g} %, "
              f"anchored, near the twin {anchor.get('error_pct', float('nan')):.3g} %")
    rows = []
    for level in args.levels.split(","):
        noise, duration = (float(v) for v in level.split(":"))
        for case, scale in CASES.items():
            folder = args.data / f"{case.split()[0]}_{noise:g}mm_{duration:g}s"
            if not (folder / "runs.tsv").is_file():
                plan = pd.DataFrame({"run": [r for r, _, _ in RUNS], "rpm": [v for _, v, _ in RUNS],
                                     "eccentric_mass_g": [m for _, _, m in RUNS], "role": "fit"})
                values = TRUTH | {k: f * TRUTH[k] for k, f in scale.items()}
                generate(plan, RigSpec.from_mapping({
                    "seed": 7, "harmonics": 7, "truth": {"effects": GEOMETRIC, "values": values},
                    "imperfections": {"noise_mm": noise, "duration_s": duration, "keyphasor": True}}), folder)
            for row in read_sheet(folder / "runs.tsv"):
                try:
                    record = intake(twin, row)
                except RecordError as err:
                    print(f"# {row['run']} ({level}): {err}", file=sys.stderr)
                    continue
                out = {"noise_mm": noise, "duration_s": duration, "case": case, "record": row["run"]}
                for route in ("auto", "library", "solver"):
                    start = time.perf_counter()
                    s = assess(twin, record, route=route).summary
                    out |= {f"{route}": f"{s['verdict']}{':' + s['changed'] if s['changed'] else ''}",
                            f"{route}_s": time.perf_counter() - start}
                    if route == "auto":
                        out |= {"answered_by": s["route"], "p_low": s["library_p_low"], "p_high": s["library_p_high"],
                                "B": s["library_bound"], "first_verdict_s": s["library_seconds"]}
                    if route == "solver":
                        out["solver_p"] = s["p_value"]
                rows.append(out)
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    print("\n| noise, duration | case | records | answered by the library | assess = solver | library alone = solver "
          "| median B | first verdict [s] | assess [s] | solver [s] |\n|---|---|---|---|---|---|---|---|---|---|")
    for (noise, duration, case), g in table.groupby(["noise_mm", "duration_s", "case"], sort=False):
        print(f"| {noise:g} mm, {duration:g} s | {case} | {len(g)} | {int((g['answered_by'] == 'library').sum())} | "
              f"{int((g['auto'] == g['solver']).sum())} | {int((g['library'] == g['solver']).sum())} | "
              f"{g['B'].median():.3g} | {g['first_verdict_s'].median():.2f} | {g['auto_s'].median():.2f} | "
              f"{g['solver_s'].median():.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
