"""The slow-roll runout's error as one offset per record (issue 38; arrow_problem's "runout offsets") on the
transient benchmark's stored records: the fit of ``transient_zeta_v_study.py`` (Geometric + the case's effect, full
solver, 4 starts, the bow shared, H = 3, every usable band) with the offsets and without them (each band's
runout sigma in quadrature, the fit before), the hidden value's estimate and 95 % interval against the truth.

    python benchmarks/transient_runout_offsets.py [--data results/benchmarks/transient_diagnosis_data] [--seed 38]
                                                  [--cases speed_damping,cross_coupled_damping,...]

Reads the records only (``transient_diagnosis_benchmark.py --data DATA`` makes them); writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
import transient_zeta_v_study as study  # noqa: E402
from diagnosis_benchmark import CASES  # noqa: E402

#: the hidden parameters' fit ranges beyond the study's (wide enough for the truth)
study.RANGES.setdefault("upper_bearing_anisotropy", {"dk_up": [-500.0, 500.0]})
DEFAULT_CASES = "speed_damping,cross_coupled_damping,upper_bearing_anisotropy"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(study.ROOT / "results/benchmarks/transient_diagnosis_data"))
    parser.add_argument("--seed", type=int, default=38)
    parser.add_argument("--cases", default=DEFAULT_CASES)
    args = parser.parse_args()
    for case in args.cases.split(","):
        where = Path(args.data) / f"seed{args.seed}" / case
        if not (where / "runs.tsv").is_file() or case not in study.RANGES:
            print(f"{case}: no records under {where} (or no range for its hidden value): skipped")
            continue
        names, truth = list(study.RANGES[case]), CASES[case][1]
        with threadpool_limits(1):
            table, _ = study.tracked(where)
            data = study.usable(table)
            records = sorted({d.record for d in data if d.record})
            print(f"{case}: {len(data)} usable bands, records {records}, truth {truth}")
            for label, part in (("without offsets (quadrature)", [replace(d, record=None, runout_sigma=None)
                                                                   for d in data]),
                                ("with runout offsets", data)):
                start = time.process_time()
                result = study.fit(part, case)
                seconds = time.process_time() - start
                held = study.fit(part, case, {n: truth[n] for n in names})
                values = result.table().set_index("parameter")
                inside = all(values.loc[n, "ci_low"] <= truth[n] <= values.loc[n, "ci_high"] for n in names)
                width = "; ".join(f"width {values.loc[n, 'ci_high'] - values.loc[n, 'ci_low']:.4g}" for n in names)
                print(f"  {study.line(label, result, names)}; {width}; truth inside: {inside}; "
                      f"{result.layout.n_offsets} offset entries; chi^2 rise at the truth "
                      f"{2 * (held.cost - result.cost):.1f}; {seconds:.0f} s CPU", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
