"""Does the diagnosis name a fault in records ROSS made with it? (issue 54; docs/diagnosis.md)

ROSS 2.3.0's ``rotor_example_with_damping()`` integrated in time with each fault of ``ross_fault_cases.CASES`` (crack,
flexible-coupling misalignment, rub) and without one, at a few constant speeds; each run's probe signals (x, y at
both disks) order-tracked over their last 20 turns (``order_harmonics``, harmonics 1..3), complex Gaussian noise of
``--noise`` m added to each part with that sigma, a keyphasor's phase (ROSS's t = 0). The base variant is the
linear rotor as imported (``machine_from_ross``: bearings, shaft damping, gyroscopic terms, the unbalance at the
first disk) with the unbalance's size r_me and angle unknown; the candidates are the machine's faults
(``faults.fault_candidates``: a crack and a rub at the unbalance plane, a misaligned coupling and a loose bearing at
each bearing; ROSS's bearings are tables, so their force scale is given here: 1e-5 m times the tables' mean stiffness
at rest) beside the 2X and 3X forces at the plane (``bearing_candidates.excitations_at``). One row per fault: the
verdict (the diagnosis's first effect and conclusion), chi^2/dof of the base fit, the named effect's values.

    python benchmarks/ross_faults_diagnosis.py [--faults crack,misalignment,rub,none] [--cache DIR] [--set-aside 2]

``--set-aside``: harmonics whose parts weigh nothing in the fits (their sigma 1 m): ROSS's rub record is not
periodic (a component near 2X comes and goes), and setting its 2X aside asks whether the periodic rest names the rub.

ROSS's runs take 1-5 minutes each (one process at a time, nice 19); ``--cache`` keeps their probe signals.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from diagnosis_helpers import fit_and_diagnose  # noqa: E402

from hybridtwin.data.measured import RunData  # noqa: E402
from hybridtwin.model.bearing_candidates import EXCITATION_DISPLACEMENT_M, excitations_at  # noqa: E402
from hybridtwin.model.candidates import Candidate  # noqa: E402
from hybridtwin.model.faults import fault_candidates  # noqa: E402
from hybridtwin.model.machine_parts import Sensor, UnbalancePlane  # noqa: E402
from hybridtwin.model.ross_io import machine_from_ross  # noqa: E402
from hybridtwin.model.variants import Variant  # noqa: E402
from hybridtwin.peers.ross_fault_cases import (CASE_DT, CASE_PLANE_NODE, CASE_PROBE_NODES, CASE_TURNS,  # noqa: E402
                                               CASES, cached_fault_run, ross_example_rotor)
from hybridtwin.peers.ross_faults import base_effect_names, order_harmonics, ross_dof  # noqa: E402

#: the speeds of each fault's runs [RPM]: whole samples a turn at dt 1e-4 s, below the first critical speeds (1730
#: and 1790 RPM); 1200 RPM is the comparison's (benchmarks/ross_faults_benchmark.py: its runs serve here too). Two
#: speeds only: ROSS's rub takes 8 s of integration a speed, minutes each on a loaded machine
SPEEDS = (1000.0, 1200.0)
#: the case of ``CASES`` each fault is recorded with
FAULT_CASE = {"crack": "crack_mayes_0.2", "misalignment": "misalignment_parallel", "rub": "rub"}
H = 3


#: the sigma [m] of a harmonic set aside (``--set-aside``): far above any amplitude here, so it weighs nothing
SET_ASIDE_SIGMA = 1.0


def records(rotor, fault: str, cache: Path | None, noise: float, seed: int, speeds=SPEEDS,
            set_aside: tuple[int, ...] = ()) -> list:
    """The runs' RunData (harmonics 1..3 at the probes, noise added) of ``fault`` ("none": the unbalance alone);
    the harmonics ``set_aside`` at sigma ``SET_ASIDE_SIGMA``."""
    case = FAULT_CASE.get(fault)
    kind, parameters, unbalance, seconds = CASES[case] if case else ("none", {}, 1e-5, 3.0)
    probes = [ross_dof(n, d) for n in CASE_PROBE_NODES for d in "xy"]
    rng = np.random.default_rng(seed)
    out = []
    for rpm in speeds:
        y = cached_fault_run(rotor, kind, rpm, seconds, unbalance, parameters, probes,
                             None if cache is None else cache / f"diagnosis_{fault}_{rpm:g}rpm_{seconds:g}s.npz")
        X = order_harmonics(y, CASE_DT, rpm, CASE_TURNS, harmonics=H)[1:]
        X = X + noise * (rng.standard_normal(X.shape) + 1j * rng.standard_normal(X.shape))
        # the trial mass in grams at r_me = 1 m: m e [kg m] * 1e3
        sigma = np.full(X.shape, noise)
        sigma[[h - 1 for h in set_aside]] = SET_ASIDE_SIGMA
        out.append(RunData(f"{fault}_{rpm:g}", rpm, unbalance * 1e3, "fit", X, sigma,
                           phase_sigma=1e-3, channels=("x12", "y12", "x24", "y24")))
    return out


def machine_and_candidates(rotor):
    """The imported machine (probes at both disks, the plane at the first) and the candidates (module docstring)."""
    sensors = [Sensor(f"{d}{n}", n, d) for n in CASE_PROBE_NODES for d in "xy"]
    machine = machine_from_ross(rotor, unbalance_planes=[UnbalancePlane("d1", CASE_PLANE_NODE)], sensors=sensors)
    k = {b.name: 0.5 * float(b.table.kxx[0] + b.table.kyy[0])
         for b in machine.bearings}
    force = EXCITATION_DISPLACEMENT_M * sum(k.values())
    # the faults at bearings that carry a nominal k: the tables' mean stiffness at rest stands in for it
    nominal = dataclasses.replace(machine, bearings=[dataclasses.replace(b, k=k[b.name], table=None)
                                                     for b in machine.bearings])
    effects = fault_candidates(nominal, force) + excitations_at("d1", CASE_PLANE_NODE, force, "unbalance plane")
    return machine, [Candidate.of(e) for e in effects]


def diagnose(machine, candidates, data):
    """The linear rotor as imported (r_me and angle_me unknown) fitted and diagnosed among ``candidates``
    (tests/diagnosis_helpers.py, the set-up tests/test_machine_candidates.py shares); (diagnosis, base chi^2/dof)."""
    names = base_effect_names(machine, "d1")
    variant = Variant.from_spec("ross_linear", {"effects": names, "unknown": {"r_me": [0.5, 2.0],
                                                                               "angle_me": [-0.5, 0.5]}},
                                shaft=machine)
    result, fit = fit_and_diagnose(variant, data, candidates, H, {"thorough": 2, "starts": 0, "widen": 1,
                                                                  "max_effects": 1, "quick_iterations": 8,
                                                                  "max_iterations": 30})
    return result, fit.chi2_dof


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faults", default="crack,misalignment,rub,none")
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--noise", type=float, default=5e-8, help="sigma of each part [m]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--speeds", default=",".join(f"{s:g}" for s in SPEEDS), help="RPM, comma-separated")
    parser.add_argument("--set-aside", default="", help="harmonics weighing nothing, comma-separated (e.g. 2)")
    args = parser.parse_args()
    speeds = [float(s) for s in args.speeds.split(",")]
    set_aside = tuple(int(h) for h in args.set_aside.split(",") if h)
    rotor = ross_example_rotor()
    machine, candidates = machine_and_candidates(rotor)
    print(f"candidates: {', '.join(c.name for c in candidates)}; speeds {speeds} RPM; noise {args.noise:g} m"
          + (f"; harmonics {set_aside} set aside" if set_aside else ""))
    print("| fault (ROSS) | records | base chi^2/dof | verdict | estimates | s |")
    print("|---|---|---|---|---|---|")
    for fault in args.faults.split(","):
        start = time.time()
        data = records(rotor, fault, args.cache, args.noise, args.seed, speeds, set_aside)
        result, chi2 = diagnose(machine, candidates, data)
        path = result.path_table()
        values = ""
        if len(path):  # the first effect's values in its refit
            first = result.confirmations[path["effect"].iloc[0]]
            table = first.fit.table().set_index("parameter")
            values = ", ".join(f"{p.name} = {table.loc[p.name, 'value']:.4g}{'' if p.unit == '1' else ' ' + p.unit}"
                               for p in first.candidate.parameters)
        verdict = result.conclusion.split(";")[0].split(": it ")[0]
        print(f"| {fault} | {len(data)} runs at {', '.join(f'{s:g}' for s in speeds)} RPM | {chi2:.3g} | "
              f"{verdict} | {values} | {time.time() - start:.0f} |", flush=True)


if __name__ == "__main__":
    main()
