"""Parameter intervals from a run-up against those from steady runs, for equal rig time and equal noise.

    python benchmarks/interval_transient_vs_steady.py [--seed 38] [--runup up15] [--data DIR] [--out TSV]

Issue 38 asks what a transient record is worth against the paper's steady runs. Both data sets come from the same
truth, the bundled one (the Geometric model, the slope force k_w u' + k_z u'^3, a shared bow), fitted with the
variant the diagnosis recommends for it (geometric + expansion_k4, the bow shared), so that both fits reach the
noise and only the data's information differs; the same noise density (0.05 mm of white noise at 2 kHz, the
bundled steady rig's):

- steady: the bundled plan's 19 fit runs (``data/default/runs.tsv``), 4 s each at 2 kHz: 76 s of recording, made
  by the virtual rig's harmonic-balance truth (the noise is what sets an interval; the integrator does not) with
  the bundled nuisances, preprocessed as the workflow does;
- transient: one run-up of the run-up example (default up15: 14.8 g, 100 -> 900 RPM at about 10 RPM/s, 80 s),
  made by time integration with the example's nuisances but the steady rig's noise and sampling, tracked into
  20-RPM bands as the workflow does (bands where the sweep is too fast for a quasi-steady model kept out).

Each is fitted with that variant on the full solver (``diagnosis_benchmark.base_fit``: random starts, the
polish's rule). k4 is compared with the hidden k_w (the cubic term is below the noise at these slopes). Printed:
each parameter's 95 % half-width from either data set, their ratio, the half-widths scaled to 76 s of recording
each (x sqrt(T / 76 s)), and whether the truth is inside.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnosis_benchmark as steady  # noqa: E402
import transient_diagnosis_benchmark as transient  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=38)
    parser.add_argument("--runup", default="up15", help="the example's record to compare (default up15)")
    parser.add_argument("--trials", type=int, default=4)
    parser.add_argument("--data", default=None, help="keep the records in DATA/{steady,transient} and reuse them")
    parser.add_argument("--out", default=str(ROOT / "results/benchmarks/interval_transient_vs_steady.tsv"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    config = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    config["identification"]["per_run"] = []
    geometric = config["variants"]["geometric"]
    config["variants"]["geometric"] = {  # base_fit fits config's "geometric": here the recommended variant
        "description": "geometric + expansion_k4", "effects": geometric["effects"] + ["expansion_k4"],
        "unknown": geometric["unknown"] | {"k4": [-1000, 1000]}}
    H = 3
    with tempfile.TemporaryDirectory() as tmp, threadpool_limits(1):
        base = Path(args.data) if args.data else Path(tmp)
        (base / "steady").mkdir(parents=True, exist_ok=True)
        (base / "transient").mkdir(parents=True, exist_ok=True)
        steady_data, _ = steady.make_data("slope_spring", base / "steady", "hb", args.seed, H)
        noise = yaml.safe_load((ROOT / "data/default/truth.yaml").read_text())["imperfections"]
        same_noise = {"noise_mm": noise["noise_mm"], "sweep_sample_rate_hz": 2000.0}
        transient_data, _, kept_out, _ = transient.make_data("slope_spring", base / "transient", args.seed, H,
                                                             [args.runup], same_noise)
        fits = {}
        for name, data in (("steady", steady_data), ("transient", transient_data)):
            _, fit = steady.base_fit(data, config, args.trials, args.seed, H)
            fits[name] = fit
    plan = pd.read_csv(ROOT / "data/default/runs.tsv", sep="\t")
    durations = {}
    durations["steady"] = float(noise["duration_s"]) * int((plan["role"] == "fit").sum())  # 4 s per run
    runup = pd.read_csv(transient.EXAMPLE / "runs.tsv", sep="\t").set_index("run").loc[args.runup]
    durations["transient"] = abs(float(runup["rpm_end"]) - float(runup["rpm_start"])) / float(
        yaml.safe_load((transient.EXAMPLE / "config/config.yaml").read_text())["rig"]["runup"]["imperfections"][
            "sweep_rate_rpm_s"])
    rows = []
    truth = steady.TRUTH | {"k4": steady.CASES["slope_spring"][1]["k_w"]}
    tables = {k: f.table().set_index(["parameter", "run"]) for k, f in fits.items()}
    for p in truth:
        row = {"parameter": p, "truth": truth[p]}
        for k, t in tables.items():
            r = t.loc[(p, "all")]
            half = 0.5 * (r.ci_high - r.ci_low)
            row |= {f"{k}_value": r.value, f"{k}_half_width": half,
                    f"{k}_half_width_76s": half * np.sqrt(durations[k] / 76.0),
                    f"{k}_inside": bool(r.ci_low <= truth[p] <= r.ci_high), f"{k}_chi2_dof": fits[k].chi2_dof}
        row["ratio_transient_over_steady"] = row["transient_half_width"] / row["steady_half_width"]
        row["ratio_at_equal_time"] = row["transient_half_width_76s"] / row["steady_half_width_76s"]
        rows.append(row)
    table = pd.DataFrame(rows)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, sep="\t", index=False, float_format="%.6g")
    pd.set_option("display.width", 250)
    print(f"steady: {len(steady_data)} runs, {durations['steady']:.0f} s, chi^2/dof {fits['steady'].chi2_dof:.3g}; "
          f"transient: {args.runup}, {len(transient_data)} usable bands ({kept_out} kept out), "
          f"{durations['transient']:.0f} s, chi^2/dof {fits['transient'].chi2_dof:.3g}")
    print(table[["parameter", "truth", "steady_value", "steady_half_width", "transient_value", "transient_half_width",
                 "ratio_transient_over_steady", "ratio_at_equal_time", "steady_inside", "transient_inside"]]
          .to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
