"""Our fault effects against ROSS's own time integration of the same faults (issue 54; hybridtwin.peers.ross_faults).

ROSS 2.3.0's ``rotor_example_with_damping()`` (two disks on a 19 mm shaft, anisotropic bearings) at 1200 RPM, an
unbalance at the first disk; ROSS integrates each fault from rest (Newmark, direct, dt = 1e-4 s); its steady 1X, 2X,
3X at both disks (x and y) over the last 20 turns (``order_harmonics``) against our harmonic balance (5 harmonics)
of the same rotor with our effect for the same fault (``ross_fault_cases.CASES``, ``run_case``). One row per case: the
largest amplitude of each harmonic, the largest difference relative to ROSS's largest amplitude there, and for the
crack the share of the term our crack leaves out (``parametric_share``), and our periodic orbit's Floquet radius
(> 1: unstable, the motion then wanders around it).

    python benchmarks/ross_faults_benchmark.py [--cases crack_mayes_0.1,...] [--cache DIR]

ROSS's runs take 1-3 minutes each on a loaded machine (one process at a time, nice 19); ``--cache`` keeps each run's
probe signals (npz) to rerun the comparison without them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybridtwin.peers.ross_fault_cases import (CASE_PROBE_NODES, CASE_RPM, CASE_TURNS, CASES,
                                                 ross_example_rotor, run_case)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--cache", type=Path, default=None)
    args = parser.parse_args()
    rotor = ross_example_rotor()
    print(f"rotor_example_with_damping at {CASE_RPM:g} RPM, last {CASE_TURNS} turns; probes x, y at nodes "
          f"{CASE_PROBE_NODES}")
    print("| case | ROSS 1X, 2X, 3X max [um] | ours 1X, 2X, 3X max [um] | difference 1X, 2X, 3X (of ROSS's max) | "
          "crack's left-out share | our orbit's Floquet radius | ROSS s |")
    print("|---|---|---|---|---|---|---|")
    for case in args.cases.split(","):
        r = run_case(rotor, case, args.cache)
        amp = lambda X: ", ".join(f"{np.abs(X[h]).max() * 1e6:.3g}" for h in (1, 2, 3))  # noqa: E731
        print(f"| {case} | {amp(r.theirs)} | {amp(r.ours)}{'' if r.converged else ' (not converged)'} | "
              f"{', '.join(f'{r.difference(h):.3f}' for h in (1, 2, 3))} | "
              f"{'' if r.share is None else f'{r.share:.3f}'} | {r.floquet_radius:.3f} | {r.seconds:.0f} |", flush=True)


if __name__ == "__main__":
    main()
