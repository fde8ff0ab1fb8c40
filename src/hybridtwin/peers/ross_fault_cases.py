"""The cases on which our fault effects are compared with ROSS's own time integration of them (issue 54): ROSS's
``rotor_example_with_damping()`` at 1200 RPM with each fault (``CASES``), ROSS's run order-tracked and our harmonic
balance of the same rotor and fault (``run_case``); the conventions and helpers are ``hybridtwin.peers.ross_faults``'.
Used by benchmarks/ross_faults_benchmark.py, benchmarks/ross_faults_diagnosis.py and tests/test_ross_faults.py.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

from ..model.machine_parts import UnbalancePlane
from ..model.model import Model
from ..model.ross_io import machine_from_ross
from ..solvers.solver import solve
from .ross_faults import (base_effects, compare, model_values, order_harmonics, our_fault, parametric_share, ross_dof,
                          ross_fault_run, with_sag)

#: ROSS's ``rotor_example_with_damping()`` at one speed, the unbalance at its first disk (node 12); each case: (fault,
#: ROSS's parameters, unbalance m e [kg m], seconds integrated). The crack's unbalance is small beside its weight's
#: sag (the premise of our crack); the rub's takes the first disk's free orbit (15 um per 1e-4 kg m) to 1.3 times
#: the clearance, the contact holding it at 1.03 times. There our periodic orbit is unstable (Floquet radius 1.03)
#: and ROSS's motion wanders around it (a component near 39.5 Hz comes and goes, 2-10 um, beside the steady 1X):
#: the 1X is compared. The rub needs 8 s for its transient to die out (the first modes decay at about 1.1 1/s).
CASES = {
    "crack_mayes_0.1": ("crack", {"n": 18, "depth_ratio": 0.1, "crack_model": "Mayes"}, 1e-5, 3.0),
    "crack_mayes_0.2": ("crack", {"n": 18, "depth_ratio": 0.2, "crack_model": "Mayes"}, 1e-5, 3.0),
    "crack_gasch_0.1": ("crack", {"n": 18, "depth_ratio": 0.1, "crack_model": "Gasch"}, 1e-5, 3.0),
    "misalignment_parallel": ("misalignment", {"n": 0, "mis_type": "parallel", "mis_distance_x": 2e-4,
                                               "mis_distance_y": 2e-4, "mis_angle": 0.0, "radial_stiffness": 40e3,
                                               "bending_stiffness": 38e3}, 1e-5, 3.0),
    "rub": ("rub", {"n": 12, "distance": 7.95e-5, "contact_stiffness": 1.1e6, "contact_damping": 0.0,
                    "friction_coeff": 0.0}, 7e-4, 8.0),
}
CASE_RPM, CASE_DT, CASE_TURNS, CASE_PLANE_NODE, CASE_PROBE_NODES = 1200.0, 1e-4, 20, 12, (12, 24)


@dataclasses.dataclass
class CaseResult:
    """One case: ROSS's and our harmonics 0..5 at the probes (x, y per node), the crack's left-out share, whether
    our harmonic balance converged, ROSS's seconds, our periodic orbit's Floquet radius (> 1: unstable)."""

    theirs: np.ndarray
    ours: np.ndarray
    share: float | None
    converged: bool
    seconds: float
    floquet_radius: float = float("nan")

    def difference(self, h: int) -> float:
        return compare(self.ours, self.theirs, (h,))[h]


def ross_example_rotor():
    """ROSS's ``rotor_example_with_damping()`` (its import's warnings silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import ross  # here: ROSS is optional (the ross extra) and slow to import

        return ross.rotor_example_with_damping()


def cached_fault_run(rotor, fault: str, rpm: float, seconds: float, unbalance: float, parameters: dict,
                     probes: list, path: Path | None) -> np.ndarray:
    """ROSS's time response of ``rotor`` with ``fault`` at ``rpm`` over ``seconds`` (step ``CASE_DT``) at the
    ``probes``' DOFs, (T, len(probes)); kept in the npz file ``path`` and read from it when there (ROSS's runs take
    minutes)."""
    if path is not None and path.exists():
        return np.load(path)["y"]
    t = np.arange(0.0, seconds, CASE_DT)
    y = ross_fault_run(rotor, fault, rpm, t, CASE_PLANE_NODE, unbalance, **parameters)[:, probes]
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, y=y)
    return y


def run_case(rotor, case: str, cache: Path | None = None) -> CaseResult:
    """ROSS's run of ``case`` (``CASES``; its probe signals kept in ``cache`` as npz) and our harmonic balance of
    the same rotor and fault (5 harmonics), both at the probes."""
    fault, parameters, unbalance, seconds = CASES[case]
    probes = [ross_dof(n, d) for n in CASE_PROBE_NODES for d in "xy"]
    start = time.time()
    y = cached_fault_run(rotor, fault, CASE_RPM, seconds, unbalance, parameters, probes,
                         None if cache is None else Path(cache) / f"{case}_{seconds:g}s.npz")
    elapsed = time.time() - start
    theirs = order_harmonics(y, CASE_DT, CASE_RPM, CASE_TURNS, harmonics=5)

    machine = machine_from_ross(rotor, unbalance_planes=[UnbalancePlane("d1", CASE_PLANE_NODE)])
    effect, fault_values = our_fault(machine, fault, rotor, rpm=CASE_RPM, **parameters)
    base = base_effects(machine, "d1")
    # m_e r_me = ROSS's m e with r_me = 1 m: the eccentric mass's own point mass (at most 7e-4 kg beside the disk's
    # 2.6 kg) is the only difference, 3e-4 of the disk
    model = Model(base + [effect], machine)
    values = model_values(model, m_e=unbalance, r_me=1.0, angle_me=0.0, **fault_values)
    if fault == "crack":
        effect = with_sag(model, effect, values, CASE_RPM)
        model = Model(base + [effect], machine)
    steady = solve(model.system(values, CASE_RPM), 5)
    X = steady.harmonics[0]
    dofs = [machine.dof(f"{'u' if d == 'x' else 'v'}{n}") for n in CASE_PROBE_NODES for d in "xy"]
    share = parametric_share(machine, effect, X) if fault == "crack" else None
    return CaseResult(theirs, X[:, dofs], share, bool(steady.success[0]), elapsed, float(steady.floquet_radius[0]))
