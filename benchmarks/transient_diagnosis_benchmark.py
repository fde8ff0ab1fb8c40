"""Diagnosis benchmark on transient records: run-ups and coast-downs made by time integration, every nuisance on.

    python benchmarks/transient_diagnosis_benchmark.py [--cases none,slope_spring,...] [--seed 38] [--trials 4]
                                                       [--out results/benchmarks/transient_diagnosis_benchmark.tsv]
                                                       [--data results/benchmarks/transient_diagnosis_data]
                                                       [--sweep-model first_order,quasi_steady] [--form-only]

The transient counterpart of ``benchmarks/diagnosis_benchmark.py`` (same cases, same judging, same base fit with
the full solver from random starts, same ``diagnosis.diagnose``); what differs is the data:

- the plan is the run-up example's fit records (``examples/runup/runs.tsv``, role fit: a run-up at 14.8 g to 900
  RPM, a run-up without added mass to 1000 RPM, a coast-down at 25.9 g from 650 RPM);
- the virtual rig (``hybridtwin.rig.rig.generate``) integrates the equations of motion in time along each
  record's speed profile with the example's nuisances (``examples/runup/config/config.yaml``, rig: runup): a
  keyphasor, probes at 45 and 135 degrees, micrometres, slow-roll runout at 1X and 2X, offsets, noise, a drive
  whose rate wobbles around 10 RPM/s; the truth is the Geometric model plus the case's hidden effect(s);
- the records are read and tracked as the workflow's ``track_record`` rule does (``transient.track_record``: the
  speed from the keyphasor, probes turned into x and y, runout subtracted, 20-RPM speed bands, the bands where
  the sweep is too fast for a quasi-steady model kept out with their note); the usable bands are the fit's runs;
- the bow is shared by every band and record (the example's ``identification: per_run: []``).

Printed per case as the steady benchmark prints: top-1, verdict, chi^2/dof before and after, each hidden value
against its 95 % interval, the times. The noise floor is the "none" case's base chi^2/dof; each case's own floor is
the truth's chi^2/dof on its usable bands (``truth_floor``: column ``truth_chi2_dof``, and ``after_over_truth``);
``--truth-floor-only`` prints only that.

The harder cases of issue 51 (``HARDER``: not tuned on; each a case of the table above, or its own hidden effect,
with the rig's nuisances changed): a strong 2X source (three times the 2X force), two effects with the weak one at
half the benchmark's cross-coupled stiffness, the slope force's expansion term swept two and three times faster
(20 and 30 RPM/s), an anisotropic upper bearing read by probes at +-45 degrees in mils. ``--sweep-model`` fits the
bands with the swept forward model (``first_order``, the default: the steady state corrected for the sweep rate,
a band kept out only where even that misses by more than the noise), today's quasi-steady one, or both in turn on
the same records; each case reports the share of its reached bands used and the damping ratios' 95 % intervals
at the final fit with whether they hold the truth (``zeta_s``, ``zeta_bup``). ``--form-only``: instead of the base
fit and the diagnosis, one fit of the truth's own form (the Geometric model plus the case's hidden effects, every
value free), the cheapest run that says what the forward model does to the bands and the dampings.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnosis_benchmark import CASES, MIDSPAN_CUBIC, TRUTH, base_fit, coverage, estimates, judge  # noqa: E402

from hybridtwin.data.measured import run_data  # noqa: E402
from hybridtwin.data.measurements import read_runs  # noqa: E402
from hybridtwin.data.records import read_record  # noqa: E402
from hybridtwin.rig.rig import RigSpec, generate, read_plan  # noqa: E402
from hybridtwin.data.transient import track_record  # noqa: E402
from hybridtwin.diagnose import diagnosis as dg  # noqa: E402
from hybridtwin.identify import forward as fwd, identification as idn, lm  # noqa: E402
from hybridtwin.identify.protocol import ProtocolOptions  # noqa: E402
from hybridtwin.model.variants import Variant  # noqa: E402
from hybridtwin.model.candidates import candidates_for  # noqa: E402
from hybridtwin.settings import diagnosis_settings  # noqa: E402

#: the harder cases of issue 51 (module docstring): name -> (effects, hidden values, expected, the rig's nuisances
#: changed); they join the shared case table so that the steady benchmark's judging reads them
HARDER: dict[str, tuple[list[str], dict, list[str] | str, dict]] = {
    "excitation_2x_strong": (["excitation_2x"], {"f2_c": 0.3, "f2_s": -0.15}, ["excitation_2x"], {}),
    "two_effects_weak": (["slope_spring", "cross_coupled_stiffness"], {"k_w": 324.2, "k_z": 301.1, "k_xy": 50.0},
                         [["slope_spring", "expansion_k4"], ["cross_coupled_stiffness"]], {}),
    "expansion_k4_rate20": (["expansion_k4"], {"k4": 300.0}, ["expansion_k4", "slope_spring"],
                            {"sweep_rate_rpm_s": 20.0}),
    "expansion_k4_rate30": (["expansion_k4"], {"k4": 300.0}, ["expansion_k4", "slope_spring"],
                            {"sweep_rate_rpm_s": 30.0}),
    "anisotropy_probes_45_mils": (["upper_bearing_anisotropy"], {"dk_up": 72.0}, ["upper_bearing_anisotropy"],
                                  {"probe_angles_deg": {"x": 45.0, "y": -45.0}, "unit": "mils"}),
}
CASES.update({name: spec[:3] for name, spec in HARDER.items()})
#: the damping ratios reported per case (their truth in TRUTH)
DAMPINGS = ("zeta_s", "zeta_bup")

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples/runup"
log = logging.getLogger("transient_diagnosis_benchmark")


def make_data(case: str, out: Path, seed: int, harmonics: int, runs: list[str] | None = None,
              imperfections: dict | None = None, sweep_model: str = "first_order") -> tuple[list, float, int, int]:
    """The case's transient fit records (rig, time integration) tracked into usable speed bands (RunData) for the
    forward model ``sweep_model`` (``run_kinds.SWEEP_MODELS``), the rig's seconds, the number of bands kept out and
    of the bands the records reach. ``runs``: which of the example's records (default: its fit records);
    ``imperfections``: overrides of the example rig's nuisances (a harder case's own first)."""
    effects, values, _ = CASES[case]
    imperfections = dict(HARDER[case][3] if case in HARDER else {}) | dict(imperfections or {})
    example = yaml.safe_load((EXAMPLE / "config/config.yaml").read_text())
    rig = example["rig"]["runup"]
    base_effects = [e for e in rig["truth"]["effects"] if e != "slope_spring"]
    spec = {"seed": seed, "harmonics": rig["harmonics"],
            "truth": {"description": case, "effects": base_effects + effects, "values": TRUTH | values},
            "imperfections": rig["imperfections"] | dict(imperfections or {})}
    plan = read_plan(EXAMPLE / "runs.tsv")
    plan = plan[plan["run"].isin(runs) if runs else plan["role"] == "fit"].reset_index(drop=True)
    start = time.perf_counter()
    if not (out / "runs.tsv").is_file():  # records kept from an earlier run (--data) are reused
        generate(plan, RigSpec.from_mapping(spec, {"midspan_cubic": MIDSPAN_CUBIC}), out)
    seconds = time.perf_counter() - start
    table = band_table(out, harmonics, sweep_model, imperfections.get("probe_angles_deg"),
                       slowroll_default="sweep_rate_rpm_s" in imperfections)
    data = [run_data(table, run, harmonics) for run in table["run"]]
    usable = [d for d in data if d.usable]
    reached = int((~table["note"].astype(str).str.startswith("not reached")).sum())
    return usable, seconds, len(data) - len(usable), reached


def band_table(where: Path, harmonics: int, sweep_model: str = "first_order", angles: dict | None = None,
               slowroll_default: bool = False) -> pd.DataFrame:
    """Every band of the records in ``where`` (its runs.tsv), tracked as the workflow's ``track_record`` rule
    does for the forward model ``sweep_model``, one table (usable or not); ``angles``: the probes' angles [deg]
    where the rig's differ from the example's (the config's sensors say where they stand); ``slowroll_default``:
    the sheet's slow-roll bands left to the default (a faster sweep: the coast-down's 200 RPM holds one window of 6
    revolutions at 30 RPM/s, and the record is refused with that remedy)."""
    sensors = yaml.safe_load((EXAMPLE / "config/config.yaml").read_text())["machine"]["sensors"]
    for name, angle in dict(angles or {}).items():
        sensors[name] = dict(sensors[name]) | {"angle_deg": float(angle)}
    bands = []
    for _, row in read_runs(where / "runs.tsv").iterrows():
        sheet_row = row.to_dict() | {"sweep_model": sweep_model}
        if slowroll_default:
            sheet_row["slowroll_rpm"] = float("nan")
        table = track_record(read_record(row["record"], sensors), sheet_row, harmonics).bands
        table.attrs = {}  # the runout table rides along in attrs; pandas cannot concatenate frames holding frames
        bands.append(table)
    return pd.concat(bands, ignore_index=True)


def fit_case_form(case: str, data: list, config: dict, harmonics: int, unknown: dict, fixed: dict | None = None,
                  trials: int = 2):
    """The Geometric variant plus the case's hidden effect(s) (the mid-span cubic spring too, which no candidate
    models), ``unknown`` {name: [low, high]} and ``fixed`` {name: value}, fitted to ``data`` on the full solver
    (``trials`` random starts, no Monte Carlo)."""
    effects, _, _ = CASES[case]
    spec = {"effects": config["variants"]["geometric"]["effects"] + list(effects), "unknown": unknown}
    variant = Variant.from_spec(case, spec | ({"fixed": fixed} if fixed else {}), {"midspan_cubic": MIDSPAN_CUBIC})
    names = list(variant.unknown)
    lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
    models = [fwd.SolverModel.for_data(variant, d, names, lower, upper, harmonics) for d in data]
    return idn.identify(models, data, [], ProtocolOptions(trials=trials, monte_carlo=0, seed=1,
                                                         lm=lm.LMOptions(max_iterations=60)))


def truth_floor(data: list, case: str, config: dict, harmonics: int) -> float:
    """The truth's own chi^2/dof on these bands: the Geometric model plus the case's hidden effect(s), every physical
    parameter at its hidden value (the bow q_x held to a 1e-9 range around it), only the phases and runout offsets
    fitted. The floor these bands allow (their sigmas, the tracking, the quasi-steady model), case by case: a case
    whose bands hold a sweep lag below the check's threshold sits above the clean case's floor, whatever is fitted."""
    truth = dict(TRUTH) | dict(CASES[case][1])
    q_x = truth["q_x"]
    fit = fit_case_form(case, data, config, harmonics, {"q_x": [q_x * (1 - 1e-9), q_x * (1 + 1e-9)]},
                        {k: v for k, v in truth.items() if k != "q_x"})
    return float(fit.chi2_dof)


def form_fit(case: str, data: list, config: dict, harmonics: int, trials: int):
    """The truth's own form fitted to ``data`` (``--form-only``): the Geometric variant's unknowns and the case's
    hidden values free over their effects' ranges (widened to hold the truth), ``trials`` random starts."""
    effects, values, _ = CASES[case]
    unknown = {k: list(v) for k, v in config["variants"]["geometric"]["unknown"].items()}
    variant = Variant.from_spec(case, {"effects": config["variants"]["geometric"]["effects"] + list(effects)},
                                {"midspan_cubic": MIDSPAN_CUBIC})
    for name, truth in values.items():
        low, high = variant.model.parameters[name].bounds
        unknown[name] = [min(low, truth - 0.5 * abs(truth)), max(high, truth + 0.5 * abs(truth))]
    return fit_case_form(case, data, config, harmonics, unknown, trials=trials)


def damping_intervals(fit) -> dict:
    """Each damping ratio's estimate, 95 % interval and whether it holds the truth, at a fit (``DAMPINGS``)."""
    table = fit.table()
    table = table[table["run"] == "all"].set_index("parameter")
    out = {}
    for name in DAMPINGS:
        if name in table.index:
            r = table.loc[name]
            out[name] = f"{r.value:.4g} [{r.ci_low:.4g}, {r.ci_high:.4g}]"
            out[f"{name}_inside"] = bool(r.ci_low <= TRUTH[name] <= r.ci_high)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated subset of: " + ", ".join(CASES))
    parser.add_argument("--seed", type=int, default=38)
    parser.add_argument("--trials", type=int, default=4, help="random starts of the base fit")
    parser.add_argument("--harmonics", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "results/benchmarks/transient_diagnosis_benchmark.tsv"))
    parser.add_argument("--data", default=None,
                        help="keep each case's rig records in DATA/seed{seed}/{case} and reuse them when present "
                             "(default: a temporary directory, made anew)")
    parser.add_argument("--runs", default=None,
                        help="comma-separated records of the example's sheet (default: its fit records: up15, up0, "
                             "down26); with --data, give each selection its own folder")
    parser.add_argument("--sweep-model", default="first_order",
                        help="comma-separated forward models of the bands, each in turn on the same records: "
                             "first_order (the swept model), quasi_steady (today's)")
    parser.add_argument("--form-only", action="store_true",
                        help="one fit of the truth's form per case instead of the base fit and the diagnosis: the "
                             "bands used and the damping intervals (``form_fit``)")
    parser.add_argument("--truth-floor-only", action="store_true",
                        help="print each case's truth chi^2/dof on its bands (``truth_floor``) and stop: no base fit, "
                             "no diagnosis (with --data, the stored records)")
    args = parser.parse_args()
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    config = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    config["identification"]["per_run"] = []  # the bow is the shaft's: shared by every band and record
    options = diagnosis_settings(config).options()
    models = [m.strip() for m in args.sweep_model.split(",") if m.strip()]
    rows = []
    for case, sweep_model in ((c, m) for c in cases for m in models):
        with tempfile.TemporaryDirectory() as tmp, threadpool_limits(1):
            # with --data the records are kept, so that every forward model reads the same ones
            where = Path(args.data) / f"seed{args.seed}" / case if args.data else Path(tmp)
            where.mkdir(parents=True, exist_ok=True)
            data, rig_s, kept_out, reached = make_data(case, where, args.seed, args.harmonics,
                                                       args.runs.split(",") if args.runs else None,
                                                       sweep_model=sweep_model)
            used = {"case": case, "sweep_model": sweep_model, "bands": len(data), "bands_kept_out": kept_out,
                    "bands_reached": reached, "bands_used_share": len(data) / max(reached, 1)}
            if args.form_only:
                start = time.perf_counter()
                fit = form_fit(case, data, config, args.harmonics, args.trials)
                rows.append(used | {"chi2_dof": fit.chi2_dof, **damping_intervals(fit),
                                    "fit_s": time.perf_counter() - start, "rig_s": rig_s})
                print(f"[{case}, {sweep_model}] {rows[-1]}", flush=True)
                Path(args.out).parent.mkdir(parents=True, exist_ok=True)
                pd.DataFrame(rows).to_csv(args.out, sep="\t", index=False, float_format="%.6g")
                continue
            floor_truth = truth_floor(data, case, config, args.harmonics)
            if args.truth_floor_only:
                print(f"[{case}] {len(data)} usable bands: the truth's chi^2/dof {floor_truth:.4g}", flush=True)
                continue
            start = time.perf_counter()
            base, fit = base_fit(data, config, args.trials, args.seed, args.harmonics)
            fit_s = time.perf_counter() - start
            log.info("[%s] %d usable bands (%d kept out); base fit %.0f s: chi^2/dof %.4g; polish starts:\n%s",
                     case, len(data), kept_out, fit_s, fit.chi2_dof, fit.starts.to_string(index=False))
            candidates = candidates_for([e.name for e in base.variant.model.effects])
            start, cpu = time.perf_counter(), time.process_time()
            result = dg.diagnose(base, candidates, options, log)
            diagnose_s, diagnose_cpu_s = time.perf_counter() - start, time.process_time() - cpu
        top, correct = judge(case, result)
        after = result.path[-1].chi2_dof_after if result.path else result.summary["base_chi2_dof"]
        final = result.path[-1].confirmation.fit if result.path else fit
        rows.append(used | {"top1": top, "correct": correct,
                            "visible": bool(result.summary["misfit"]), "verdict": result.conclusion.split(":")[0],
                            "status": result.status.value, "chi2_dof_before": result.summary["base_chi2_dof"],
                            "chi2_dof_after": after, "truth_chi2_dof": floor_truth,
                            "path": " + ".join(s.effect for s in result.path),
                            "estimate_vs_truth": estimates(case, result), **damping_intervals(final),
                            **dict(zip(("inside", "estimated", "inside_over_candidates"), coverage(case, result))),
                            "rig_s": rig_s, "fit_s": fit_s,
                            "diagnose_s": diagnose_s, "diagnose_cpu_s": diagnose_cpu_s,
                            "refits": len(result.summary["refitted"]),
                            "fingerprint": result.summary.get("fingerprint", ""),  # the residual at the path's end
                            "conclusion": result.conclusion})
        row = rows[-1]
        print(f"[{case}, {sweep_model}] top-1 {top} ({'correct' if correct else 'WRONG'}), {row['verdict']}; "
              f"chi^2/dof {row['chi2_dof_before']:.3g} -> {after:.3g}; {row['estimate_vs_truth']}; {len(data)} of "
              f"{reached} bands; zeta_s {row.get('zeta_s')}, zeta_bup {row.get('zeta_bup')}; rig {rig_s:.0f} s, "
              f"base fit {fit_s:.0f} s, diagnosis {diagnose_s:.0f} s wall, {diagnose_cpu_s:.0f} s CPU", flush=True)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        pd.DataFrame(rows).to_csv(args.out, sep="\t", index=False, float_format="%.6g")  # after every case
    table = pd.DataFrame(rows)
    if table.empty or args.form_only:
        if not table.empty:
            print(table.drop(columns=["rig_s"]).to_string(index=False, float_format=lambda v: f"{v:.3g}"))
        return 0
    table["after_over_truth"] = table["chi2_dof_after"] / table["truth_chi2_dof"]
    for model in models:  # each forward model's own floor: its "none" case
        floor = table.loc[(table["case"] == "none") & (table["sweep_model"] == model), "chi2_dof_before"]
        if len(floor):
            mine = table["sweep_model"] == model
            table.loc[mine, "after_over_floor"] = table.loc[mine, "chi2_dof_after"] / float(floor.iloc[0])
    table.to_csv(args.out, sep="\t", index=False, float_format="%.6g")
    pd.set_option("display.width", 250)
    pd.set_option("display.max_colwidth", 70)
    shown = [c for c in ["case", "sweep_model", "bands", "bands_used_share", "top1", "correct", "verdict",
                         "chi2_dof_before", "chi2_dof_after", "after_over_floor", "truth_chi2_dof", "after_over_truth", "estimate_vs_truth", "zeta_s",
                         "zeta_s_inside", "zeta_bup", "zeta_bup_inside", "inside", "estimated", "rig_s", "fit_s",
                         "diagnose_s"] if c in table]
    print(table[shown].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    inside, estimated = int(table["inside"].sum()), int(table["estimated"].sum())
    over = int(table["inside_over_candidates"].sum())
    print(f"\ncorrect: {int(table['correct'].sum())} of {len(table)}; hidden values inside their 95 % interval: "
          f"{inside} of {estimated}, inside the interval over the candidates: {over}; table written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
