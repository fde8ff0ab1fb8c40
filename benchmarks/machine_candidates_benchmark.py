"""The diagnosis of a machine of your own with its whole catalogue of candidates (issue 54): the stepped rotor of
tests/example_machines.py (bearings a, b with nominal k, c; unbalance plane d1; probes x1, y1 at d1), records made by
the full solver with one effect hidden, the variant ``linear`` (k_a, c_a, c_b fitted; k_b held at its nominal 1e7
N/m) fitted and diagnosed with every candidate ``Machine.sized_candidates`` offers plus speed_damping (19), the
default diagnosis options.

    python benchmarks/machine_candidates_benchmark.py [--cases compliance x2 none]

Cases: ``compliance`` (bearing b 15 % softer than its nominal k: k_b = 8.5e6), ``x2`` (a 2X force (60, -30) N at
d1), ``none`` (nothing hidden). Seven runs 3000-4800 RPM through the critical speeds (3793, 4064 RPM), 20 g,
H = 3, noise 2e-8 m per real/imaginary part. Prints per case the conclusion and the first rows of the verdicts,
with the CPU seconds; 3-4 minutes a case on the loaded development machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from diagnosis_helpers import fit_and_diagnose  # noqa: E402
from example_machines import stepped_machine  # noqa: E402

from hybridtwin.identify import forward as fwd  # noqa: E402
from hybridtwin.identify import identification as idn  # noqa: E402
from hybridtwin.model.candidates import Candidate, builtin_candidates  # noqa: E402
from hybridtwin.model.variants import Variant  # noqa: E402

H, SIGMA = 3, 2e-8
EFFECTS = ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"]
RUNS = [(f"r{int(r)}", r, 20.0) for r in (3000.0, 3500.0, 3800.0, 3950.0, 4100.0, 4400.0, 4800.0)]
BASE = {"k_a": 2.2e7, "c_a": 900.0, "c_b": 450.0}
CASES = {"compliance": ([], BASE | {"k_b": 8.5e6}, 1), "x2": (["excitation_2x@d1"], BASE | {"f2_c_d1": 60.0,
                                                                                          "f2_s_d1": -30.0}, 2),
         "none": ([], BASE, 3)}


def records(machine, extra: list[str], values: dict, seed: int) -> list[idn.RunData]:
    """The truth's harmonics at the runs (full solver) plus Gaussian noise."""
    truth = Variant.from_spec("truth", {"effects": EFFECTS + extra, "unknown": {k: (-1e12, 1e12) for k in values}},
                              shaft=machine)
    rng, names, out = np.random.default_rng(seed), list(values), []
    for run, rpm, mass in RUNS:
        v = np.array([values[n] for n in names])
        X = fwd.SolverModel(truth, run, rpm, mass, names, v - 1.0, v + 1.0, H).evaluate(
            np.zeros((1, len(names))), jacobian=False)[0][0]
        out.append(idn.RunData(run, rpm, mass, "fit", X + SIGMA * (rng.standard_normal(X.shape)
                                                                   + 1j * rng.standard_normal(X.shape)),
                               np.full(X.shape, SIGMA)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    args = parser.parse_args()
    machine = stepped_machine()
    candidates = [Candidate.of(e) for e in machine.sized_candidates().values()] + [builtin_candidates()["speed_damping"]]
    for case in args.cases:
        start = time.process_time()
        data = records(machine, *CASES[case])
        variant = Variant.from_spec("linear", {"effects": EFFECTS, "unknown": {
            "k_a": [1e7, 4e7], "c_a": [400, 1600], "c_b": [250, 1000]}}, shaft=machine)
        result, fit = fit_and_diagnose(variant, data, candidates, H)  # the default diagnosis options
        print(f"## {case}: {len(candidates)} candidates, base chi^2/dof {fit.chi2_dof:.4g}, "
              f"{time.process_time() - start:.0f} s CPU\n{result.conclusion}")
        print(result.table[["effect", "verdict", "delta_bic"]].head(5).to_string(index=False), "\n", flush=True)


if __name__ == "__main__":
    main()
