"""Honest alarms of the twin online (issue 40): the false-alarm rate on records of the unchanged machine, the
detection of a changed machine, the smallest change detected at 95 % power, and the assessment's time.

    OMP_NUM_THREADS=1 python benchmarks/assess_benchmark.py --twin results/geometric_slope --data DIR --out DIR

The twin: a built twin's folder (the README's: the bundled data's geometric_slope). The records: the virtual rig's
(``hybridtwin rig``) from the bundled data's truth (the Geometric model with the slope force, bow 2 / 1.5 mm; its
``DEFAULT_TRUTH``), every nuisance on (0.1 % speed error, random phase and offsets up to 0.5 mm, 0.05 mm noise), a
keyphasor unless ``--no-keyphasor``, at the twin's own fit runs' speeds and masses in turn (records outside the
twin's speeds are refused by design). Cases:

- ``unchanged``: the truth itself, fresh noise per record: the false-alarm rate (any verdict but consistent);
- ``k_b``: the upper bearing 10 % softer; ``bow``: the bow (the VARM's residual unbalance) doubled;
  ``k_xy``: a cross-coupled stiffness of 100 N/m appearing (no parameter of the twin): each scored by whether the
  verdict names it (changed naming k_b; changed naming q_x, q_y; a new discrepancy with cross_coupled_stiffness
  ranked first);
- ``power``: per parameter of the twin, the detection rate (an alarm) at several sizes of change (``--power``
  records each, harmonic balance: the power scan needs many records); the smallest size detected at >= 95 %.

``--routes`` (a twin built with an sPGD library, ``offline.scope`` run or global): every record judged three ways,
side by side: as ``hybridtwin assess`` does (``route="auto"``: the library's verdict, the full solver confirming where
the library's error bound cannot decide), the library's own verdict (``route="library"``) and the full solver's
(``route="solver"``), with their times; prints the verdict counts of each, how many agree with the solver's, how many
the solver confirmed, and the median times (benchmarks/README.md, "The library answers online").

``--integrator time`` (default) makes the records by time integration (no harmonic balance: independent of the solver
the twin uses); the power scan uses harmonic balance (``hb``) for speed. The rig's records are kept in ``--data``
(made once, reused). Prints the tables for benchmarks/README.md and writes ``records.tsv`` (every record's
assessment), ``alarms.png`` (p-values under "unchanged", power curves) to ``--out``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from hybridtwin.rig.rig import DEFAULT_TRUTH, Imperfections, RigSpec, Truth, generate
from hybridtwin.online.assess import ALPHA, RecordVerdict, assess
from hybridtwin.online.intake import RecordError, intake, read_sheet
from hybridtwin.online.twin import load_twin

TRUTH = DEFAULT_TRUTH["values"]
CASES = {  # case: (values changed, effects added, what a right verdict names)
    "unchanged": ({}, [], "consistent"),
    "k_b": ({"k_b": 0.9 * TRUTH["k_b"]}, [], "k_b"),
    "bow": ({"q_x": 2 * TRUTH["q_x"], "q_y": 2 * TRUTH["q_y"]}, [], "q_x,q_y"),
    "k_xy": ({"k_xy": 100.0}, ["cross_coupled_stiffness"], "cross_coupled_stiffness"),
}
#: the power scan: relative changes of each parameter of the truth (k_xy: absolute, N/m)
POWER = {"k_b": [-0.005, -0.01, -0.02, -0.05], "zeta_s": [0.2, 0.5, 1.0, 2.0], "zeta_bup": [0.2, 0.5, 1.0, 2.0],
         "k_w": [0.01, 0.02, 0.05, 0.1], "k_z": [0.5, 1.0, 3.0], "bow": [0.02, 0.05, 0.1, 0.2],
         "k_xy": [10.0, 20.0, 50.0, 100.0]}


ARGS = argparse.Namespace(records_only=False, routes=False)
#: the ways a record is judged side by side (``--routes``)
ROUTES = ("auto", "library", "solver")


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def records(folder: Path, twin, n: int, values: dict, effects: list, integrator: str, keyphasor: bool,
            prefix: str) -> list[dict]:
    """n rig records (made once into ``folder``) at the twin's fit runs' speeds and masses in turn."""
    if not (folder / "runs.tsv").is_file():
        plan = twin.runs.iloc[np.arange(n) % len(twin.runs)].reset_index(drop=True)
        plan = pd.DataFrame({"run": [f"{prefix}_{i:04d}" for i in range(n)], "rpm": plan["rpm"].round(0),
                             "eccentric_mass_g": plan["eccentric_mass_g"], "role": "fit"})
        truth = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"] + effects, "values": TRUTH | values})
        start = time.perf_counter()
        generate(plan, RigSpec(truth, Imperfections(keyphasor=keyphasor), seed=40, integrator=integrator), folder)
        print(f"# {folder}: {n} records by {integrator} in {time.perf_counter() - start:.0f} s", file=sys.stderr)
    return read_sheet(folder / "runs.tsv")


def judge(twin, rows: list[dict], case: str, size: float, alpha: float) -> list[dict]:
    if ARGS.records_only:
        return []
    if ARGS.routes:
        return judge_routes(twin, rows, case, alpha)
    out = []
    for row in rows:
        w, c = time.perf_counter(), cpu()
        try:
            result = assess(twin, intake(twin, row), alpha)
        except RecordError as err:  # refused by the data checks (a clipped record next to the resonance): counted
            print(f"# {row['run']}: {err}", file=sys.stderr)
            out.append({"case": case, "size": size, "record": row["run"], "rpm": row["rpm"],
                        "eccentric_mass_g": row["eccentric_mass_g"], "verdict": "refused", "changed": "",
                        "alternatives": "", "top_candidate": "", "p_value": np.nan, "chi2_dof": np.nan,
                        "truth_inside": np.nan, "wall_s": np.nan, "cpu_s": np.nan})
            continue
        s = result.summary
        top = result.candidates["candidate"].iloc[0] if len(result.candidates) else ""
        truth = CASES.get(case, ({}, [], ""))[0]
        rows_ = result.parameters[result.parameters["parameter"].isin(truth) & result.parameters["moved"]]
        inside = (bool(((rows_["ci_low"] <= rows_["parameter"].map(truth))
                        & (rows_["parameter"].map(truth) <= rows_["ci_high"])).all()) if len(rows_) else np.nan)
        out.append({"case": case, "size": size, "record": s["record"], "rpm": s["rpm_low"],
                    "eccentric_mass_g": s["eccentric_mass_g"], "verdict": s["verdict"], "changed": s["changed"],
                    "alternatives": s["alternatives"], "top_candidate": top, "p_value": s["p_value"],
                    "chi2_dof": s["chi2_dof"], "truth_inside": inside, "wall_s": time.perf_counter() - w,
                    "cpu_s": cpu() - c})
    return out


def judge_routes(twin, rows: list[dict], case: str, alpha: float) -> list[dict]:
    """Each record judged on every route of ``ROUTES`` (``--routes``): one row per record with each route's verdict,
    named change, p-value and times (wall, CPU), and where the first verdict came from."""
    out = []
    for row in rows:
        try:
            record = intake(twin, row)
        except RecordError as err:
            print(f"# {row['run']}: {err}", file=sys.stderr)
            continue
        entry = {"case": case, "record": row["run"], "rpm": record.data[0].rpm,
                 "eccentric_mass_g": record.eccentric_mass_g}
        for route in ROUTES:
            w, c = time.perf_counter(), cpu()
            s = assess(twin, record, alpha, candidates=False, route=route).summary
            entry |= {f"{route}_verdict": s["verdict"], f"{route}_changed": s["changed"],
                      f"{route}_p_value": s["p_value"], f"{route}_wall_s": time.perf_counter() - w,
                      f"{route}_cpu_s": cpu() - c}
            if route == "auto":
                entry |= {"auto_route": s["route"], "library": s["library"], "library_p_low": s["library_p_low"],
                          "library_p_high": s["library_p_high"], "first_verdict_s": s["library_seconds"],
                          "route_note": s["route_note"]}
        out.append(entry)
    return out


def report_routes(table: pd.DataFrame) -> None:
    """The side-by-side table of ``--routes``."""
    def counts(rows, route):
        return ", ".join(f"{v} {n}" for v, n in rows[f"{route}_verdict"].value_counts().items())

    def named(rows, route):
        return rows[f"{route}_verdict"] + ":" + rows[f"{route}_changed"].fillna("")

    print("\n| case | records | on the library (its own verdict) | as `assess` answers (library, solver confirming) "
          "| on the solver | library = solver | assess = solver | confirmed on the solver |\n|---|---|---|---|---|---|---|---|")
    for case, rows in table.groupby("case", sort=False):
        agree_lib = int((named(rows, "library") == named(rows, "solver")).sum())
        agree = int((named(rows, "auto") == named(rows, "solver")).sum())
        print(f"| {case} | {len(rows)} | {counts(rows, 'library')} | {counts(rows, 'auto')} | {counts(rows, 'solver')} "
              f"| {agree_lib} | {agree} | {int((rows['auto_route'] == 'solver').sum())} |")
    on_library = table[table["auto_route"] == "library"]
    confirmed = table[table["auto_route"] == "solver"]
    print("\ntimes per record (assess(): fits, verdict, tables; no import, no figure, no candidates), median wall / CPU "
          "[s]:")
    print("| | records | wall | CPU |\n|---|---|---|---|")
    for label, rows, route in (("the library's verdict (route library)", table, "library"),
                               ("the solver's verdict (route solver)", table, "solver"),
                               ("assess, answered by the library", on_library, "auto"),
                               ("assess, confirmed on the solver", confirmed, "auto")):
        if len(rows):
            print(f"| {label} | {len(rows)} | {rows[f'{route}_wall_s'].median():.3f} | "
                  f"{rows[f'{route}_cpu_s'].median():.3f} |")
    if len(on_library):
        print(f"\nthe library's first verdict: median {on_library['first_verdict_s'].median():.3f} s, max "
              f"{on_library['first_verdict_s'].max():.3f} s (wall, in assess())")
    for note, n in table.loc[table["auto_route"] == "solver", "route_note"].str.split(" \\(").str[0].value_counts().items():
        print(f"# confirmed on the solver, {n} record(s): {note}")


def right(row: pd.Series) -> bool:
    """Whether the verdict names the case's change."""
    want = CASES[row["case"]][2]
    if want == "consistent":
        return row["verdict"] == RecordVerdict.CONSISTENT.value
    if want == "cross_coupled_stiffness":
        return row["verdict"] == RecordVerdict.NEW_DISCREPANCY.value and row["top_candidate"] == want
    return row["verdict"] == RecordVerdict.CHANGED.value and row["changed"] == want


def listed(row: pd.Series) -> bool:
    """Whether the case's change is named first or listed among what the record cannot tell from it."""
    want = CASES[row["case"]][2]
    if want in ("consistent", "cross_coupled_stiffness"):
        return right(row)
    alternatives = [a.replace(" ", "") for a in str(row["alternatives"]).split(";")]
    return row["verdict"] == RecordVerdict.CHANGED.value and (row["changed"] == want or want in alternatives)


def binomial_interval(k: int, n: int) -> tuple[float, float]:
    """Wilson's 95 % interval of a rate k / n."""
    if n == 0:
        return np.nan, np.nan
    z, p = 1.96, k / n
    centre, half = (p + z * z / (2 * n)) / (1 + z * z / n), z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (
        1 + z * z / n)
    return centre - half, centre + half


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--twin", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True, help="the rig's records (made once, reused)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--unchanged", type=int, default=152, help="records of the unchanged machine")
    parser.add_argument("--changed", type=int, default=38, help="records per changed case (0: none)")
    parser.add_argument("--power", type=int, default=38, help="records per size of change in the power scan (0: none)")
    parser.add_argument("--integrator", choices=("time", "hb"), default="time")
    parser.add_argument("--keyphasor", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--alpha", type=float, default=ALPHA)
    parser.add_argument("--cases", default=",".join(CASES), help="the cases to judge (comma-separated)")
    parser.add_argument("--records-only", action="store_true", help="make the rig's records, judge nothing")
    parser.add_argument("--routes", action="store_true",
                        help="judge each record on the library, as assess does, and on the solver, side by side")
    args = parser.parse_args(argv)
    ARGS.records_only, ARGS.routes = args.records_only, args.routes
    twin = load_twin(args.twin)
    args.out.mkdir(parents=True, exist_ok=True)
    tag = f"{args.integrator}_{'kp' if args.keyphasor else 'nokp'}"
    rows = []
    for case, (values, effects, _) in CASES.items():
        if case not in args.cases.split(","):
            continue
        n = args.unchanged if case == "unchanged" else args.changed
        if n == 0:
            continue
        found = records(args.data / f"{case}_{tag}", twin, n, values, effects, args.integrator, args.keyphasor, case)
        rows += judge(twin, found, case, 0.0, args.alpha)
    for parameter, sizes in POWER.items() if args.power else ():
        for size in sizes:
            if parameter == "bow":
                values = {"q_x": (1 + size) * TRUTH["q_x"], "q_y": (1 + size) * TRUTH["q_y"]}
            elif parameter == "k_xy":
                values = {"k_xy": size}
            else:
                values = {parameter: (1 + size) * TRUTH[parameter]}
            effects = ["cross_coupled_stiffness"] if parameter == "k_xy" else []
            found = records(args.data / f"power_{parameter}_{size:g}_hb_{'kp' if args.keyphasor else 'nokp'}", twin,
                            args.power, values, effects, "hb", args.keyphasor, f"p_{parameter}")
            rows += [r | {"case": f"power_{parameter}"} for r in judge(twin, found, parameter, size, args.alpha)]
    if args.records_only:
        return 0
    table = pd.DataFrame(rows)
    table.to_csv(args.out / f"records_{tag}{'_routes' if args.routes else ''}.tsv", sep="\t", index=False,
                 float_format="%.6g")
    if args.routes:
        report_routes(table)
        return 0
    report(table, args)
    return 0


def report(table: pd.DataFrame, args) -> None:
    main_cases = table[table["case"].isin(CASES)].copy()
    main_cases["right"] = main_cases.apply(right, axis=1)
    main_cases["listed"] = main_cases.apply(listed, axis=1)
    print("\n| case | records | verdicts | named first | named or listed | rate [95 % interval] |\n"
          "|---|---|---|---|---|---|")
    for case, rows in main_cases.groupby("case", sort=False):
        counts = ", ".join(f"{v} {n}" for v, n in rows["verdict"].value_counts().items())
        k = int(rows["right"].sum())
        lo, hi = binomial_interval(len(rows) - k if case == "unchanged" else k, len(rows))
        what = "false alarms" if case == "unchanged" else "right"
        rate = (len(rows) - k if case == "unchanged" else k) / len(rows)
        inside = rows["truth_inside"].dropna().astype(bool)
        held = f"; the truth inside the named interval {int(inside.sum())} of {len(inside)}" if len(inside) else ""
        print(f"| {case} | {len(rows)} | {counts} | {k} | {int(rows['listed'].sum())} | {what} {100 * rate:.1f} % "
              f"[{100 * lo:.1f}, {100 * hi:.1f}]{held} |")
    power = table[table["case"].str.startswith("power_") & (table["verdict"] != "refused")]  # rates of the judged
    if len(power):
        print("\n| parameter | size of change: detection rate (alarm) | smallest detected at >= 95 % |\n|---|---|---|")
        for case, rows in power.groupby("case", sort=False):
            rates = rows.groupby("size")["verdict"].apply(lambda v: float((v != RecordVerdict.CONSISTENT.value).mean()))
            unit = " N/m" if case == "power_k_xy" else " %"
            scale = 1.0 if case == "power_k_xy" else 100.0
            smallest = [s for s, r in rates.items() if r >= 0.95]
            best = min(smallest, key=abs) if smallest else None
            print(f"| {case[6:]} | " + ", ".join(f"{scale * s:+g}{unit}: {100 * r:.0f} %" for s, r in rates.items())
                  + f" | {'none of these' if best is None else f'{scale * best:+g}{unit}'} |")
    times = table[["wall_s", "cpu_s"]].median()
    print(f"\nassessment (assess(): fits, verdict, tables; no import, no figure), median per record: "
          f"{times['wall_s']:.2f} s wall, {times['cpu_s']:.2f} s CPU")
    plot(table, main_cases, args.out / f"alarms_{'time' if args.integrator == 'time' else 'hb'}.png", args.alpha)


def plot(table: pd.DataFrame, main_cases: pd.DataFrame, path: Path, alpha: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    p = np.sort(main_cases.loc[main_cases["case"] == "unchanged", "p_value"].to_numpy())
    axes[0].plot(np.arange(1, len(p) + 1) / len(p), p, ".", ms=3, label="records of the unchanged machine")
    axes[0].plot([0, 1], [0, 1], "k--", lw=0.8, label="uniform (calibrated)")
    axes[0].axhline(alpha, color="tab:red", lw=0.8, label=f"alarm level {alpha:g}")
    axes[0].set_xlabel("quantile")
    axes[0].set_ylabel("the record's p-value")
    axes[0].set_title(f"false alarms: {int((p < alpha).sum())} of {len(p)}", fontsize=9)
    axes[0].legend(fontsize=7)
    power = table[table["case"].str.startswith("power_") & (table["verdict"] != "refused")]
    for case, rows in power.groupby("case", sort=False):
        rates = rows.groupby("size")["verdict"].apply(lambda v: float((v != RecordVerdict.CONSISTENT.value).mean()))
        x = np.abs(rates.index.to_numpy(float)) * (1 if case == "power_k_xy" else 100)
        axes[1].plot(x, rates.to_numpy(), "o-", label=case[6:] + (" [N/m]" if case == "power_k_xy" else " [%]"))
    axes[1].axhline(0.95, color="0.5", ls="--", lw=0.8)
    axes[1].set_xscale("log")
    axes[1].set_xlabel("size of the change (% of the truth's value; k_xy in N/m)")
    axes[1].set_ylabel("detection rate (an alarm)")
    axes[1].set_title("power per parameter", fontsize=9)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
