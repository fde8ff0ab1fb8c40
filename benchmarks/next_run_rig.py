"""The next runs checked on the rig (issue 41, item 5): take the runs the design recommends, on the project's virtual
rig, and see whether the intervals shrink as it expected.

From a finished main job (``--results``, a folder with results/ and config/): the variant's recommended runs
(results/{variant}/design/next_runs.tsv) are recorded by the virtual rig of the config's ``rig: default`` entry (the
bundled truth and every nuisance: random phase, speed error, offsets, noise, clipping), but integrated in time
(``integrator: time``: no harmonic balance), with a keyphasor where the design asked for one and with another seed
than the bundled records. Each record is preprocessed as the workflow does (``preprocess_run``), added to the bundled
fit runs, and the variant refitted jointly on the full solver (``fit_joint`` without libraries: the workflow's
``offline.scope: none`` path). Per shared parameter: the interval now (parameters.tsv), the half-width the design
expected (design/intervals.tsv), the one achieved, their ratio, and whether the truth lies inside.

    OMP_NUM_THREADS=1 python benchmarks/next_run_rig.py --results CLONE [--variant geometric_expansion_k4]
        [--seed 2] [--out CLONE/results/benchmarks/next_run_rig] [--truth-model]

``--truth-model`` also refits, on the same runs, the truth's own model (its effects; the variant's unknowns but
those of the effects it lacks, and the truth's other values unknown over [0, 1000] N: the slope force's k_w, k_z),
the bow shared: what is left of the misses when the model's form is the truth's.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from hybridtwin import config as cfg
from hybridtwin.data.measurements import read_runs
from hybridtwin.data.preprocessing import preprocess_run
from hybridtwin.rig.rig import RigSpec, generate
from hybridtwin.identify import identification as idn
from hybridtwin.identify.run_fits import fit_joint
from hybridtwin.settings import IdentificationSettings


def record_runs(chosen: pd.DataFrame, rig: dict, seed: int, out: Path) -> pd.DataFrame:
    """The chosen runs recorded by the rig (time integration), one data set per keyphasor setting; their runs
    sheet rows (with the resolved record paths)."""
    rows = []
    for keyphasor, group in chosen.groupby("keyphasor"):
        plan = pd.DataFrame({"run": [f"n{r.step}_r{r.rpm:g}_m{r.eccentric_mass_g:g}".replace(".", "p")
                                     for r in group.itertuples()],
                             "rpm": group["rpm"].to_numpy(float), "eccentric_mass_g": group["eccentric_mass_g"],
                             "role": "fit"})
        spec = dict(rig) | {"integrator": "time", "seed": seed}
        spec["imperfections"] = dict(rig.get("imperfections") or {}) | {"keyphasor": bool(keyphasor)}
        folder = out / ("keyphasor" if keyphasor else "no_keyphasor")
        folder.mkdir(parents=True, exist_ok=True)
        start = time.process_time()
        truth = generate(plan, RigSpec.from_mapping(spec), folder)
        print(f"rig ({'keyphasor' if keyphasor else 'no keyphasor'}, time integration): {len(plan)} runs in "
              f"{time.process_time() - start:.0f} s CPU; inside the sensor range: {truth['inside_range'].tolist()}, "
              f"stable: {truth['stable'].tolist()}", flush=True)
        rows.append(read_runs(folder / "runs.tsv"))
    return pd.concat(rows, ignore_index=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, required=True, help="a finished main job's folder")
    parser.add_argument("--variant", default="geometric_expansion_k4")
    parser.add_argument("--seed", type=int, default=2, help="the rig's seed for the new records (bundled: 1)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--truth-model", action="store_true", help="also refit the truth's own model")
    args = parser.parse_args()
    root = args.results
    out = args.out or root / "results" / "benchmarks" / "next_run_rig"
    config = yaml.safe_load((root / "config" / "config.yaml").read_text())
    variant = cfg.variant(config, args.variant, root / "config")
    base = root / "results" / args.variant
    chosen = pd.read_csv(base / "design" / "next_runs.tsv", sep="\t")
    expected = pd.read_csv(base / "design" / "intervals.tsv", sep="\t").set_index("parameter")
    now = idn.read_parameters(base / "parameters.tsv")
    harmonics = idn.read_harmonics(root / "results" / "data" / "harmonics.tsv")
    truth = config["rig"]["default"]["truth"]["values"]
    print(f"{args.variant}: the design's runs\n{chosen.to_string(index=False)}", flush=True)
    sheet = record_runs(chosen, config["rig"]["default"], args.seed, out)
    new = pd.concat([preprocess_run(row.to_dict(), int(config["harmonics"]),
                                    float(config["offline"]["sensor_range_mm"]) * 1e-3)[0]
                     for _, row in sheet.iterrows()], ignore_index=True)
    for r in new.itertuples():
        print(f"{r.run}: usable {r.usable} ({r.note}), phase {r.phase_reference}", flush=True)
    table = pd.concat([harmonics, new], ignore_index=True)
    fit_runs = list(dict.fromkeys(now.loc[now["parameter"] == "phase", "run"]))
    options = IdentificationSettings.from_config(config).rule(args.variant, "joint")
    start = time.process_time()
    result = fit_joint(variant, options, [], table, {}, None, int(config["harmonics"]),
                       runs=fit_runs + new["run"].tolist())
    print(f"refit with the {len(new)} new runs ({len(fit_runs) + len(new)} runs, full solver): chi^2/dof "
          f"{result.fit.chi2_dof:.4g}, {time.process_time() - start:.0f} s CPU", flush=True)
    after = result.fit.table()
    rows = []
    for p in expected.index:
        a = now.set_index(["parameter", "run"]).loc[(p, "all")]
        b = after.set_index(["parameter", "run"]).loc[(p, "all")]
        achieved = 0.5 * (b["ci_high"] - b["ci_low"])
        rows.append({"parameter": p, "truth": truth.get(p, truth.get("k_w") if p == "k4" else np.nan),
                     "value_now": a["value"], "half_width_now": 0.5 * (a["ci_high"] - a["ci_low"]),
                     "expected_half_width": expected.loc[p, "expected_half_width"], "value_after": b["value"],
                     "half_width_after": achieved, "interval_after": b["interval"],
                     "achieved_over_expected": achieved / expected.loc[p, "expected_half_width"],
                     "truth_inside_after": bool(b["ci_low"] <= truth.get(p, truth.get("k_w") if p == "k4" else np.nan)
                                                <= b["ci_high"]),
                     "interest": bool(expected.loc[p, "interest"])})
    report = pd.DataFrame(rows)
    out.mkdir(parents=True, exist_ok=True)
    report.to_csv(out / "intervals.tsv", sep="\t", index=False, float_format="%.6g")
    pd.set_option("display.width", 200)
    print(report.to_string(index=False, float_format=lambda v: f"{v:.5g}"))
    if args.truth_model:
        truth_model(config, root, args.variant, options, table, fit_runs + new["run"].tolist(), truth)
    return 0


def truth_model(config: dict, root: Path, name: str, options: dict, table: pd.DataFrame, runs: list[str],
                truth: dict) -> None:
    """The truth's own model refitted on ``runs`` (module docstring): each shared parameter against its truth."""
    spec = config["variants"][name]
    effects = config["rig"]["default"]["truth"]["effects"]
    unknown = {p: r for p, r in spec["unknown"].items() if p in truth}
    unknown |= {p: [0.0, 1000.0] for p in truth if p not in unknown}
    model = {**config, "variants": {"truth_model": {"effects": effects, "unknown": unknown, "per_run": []}}}
    variant = cfg.variant(model, "truth_model", root / "config")
    start = time.process_time()
    fit = fit_joint(variant, options, [], table, {}, None, int(config["harmonics"]), runs=runs).fit
    print(f"the truth's model ({', '.join(unknown)}) on the same {len(runs)} runs: chi^2/dof {fit.chi2_dof:.4g}, "
          f"{time.process_time() - start:.0f} s CPU")
    for r in fit.table().itertuples():
        if r.run == "all":
            print(f"  {r.parameter}: {r.value:.6g} [{r.ci_low:.6g}, {r.ci_high:.6g}] ({r.interval}) truth "
                  f"{truth[r.parameter]}: {'inside' if r.ci_low <= truth[r.parameter] <= r.ci_high else 'OUTSIDE'}")


if __name__ == "__main__":
    raise SystemExit(main())
