"""A machine other than the VARM for the tests of the commands, the rig and the plots: a stepped steel shaft with
two disks, two linear bearings inside the span and one x, y probe pair at the first disk; its config section,
the same machine through the Python API, and its linear unbalance response assembled and solved by hand (no
Model, no effect, no harmonic balance: the independent path the commands are compared with)."""

import numpy as np
import yaml

from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import Bearing, Disk, Sensor, ShaftSegment, UnbalancePlane

STEPPED_YAML = """\
machine:
  name: stepped
  segments:
    - {length: 0.2, d_out: 0.04, E: 2.11e+11, rho: 7810, n_elements: 4}
    - {length: 0.5, d_out: 0.05, d_in: 0.02, E: 2.11e+11, rho: 7810, n_elements: 10}
    - {length: 0.3, d_out: 0.035, E: 2.11e+11, rho: 7810, n_elements: 3}
  disks:
    - {node: 8, mass: 15.3, I_p: 0.12, I_d: 0.062, name: d1}
    - {node: 16, mass: 7.4, I_p: 0.037, I_d: 0.019, name: d2}
  bearings: {a: {node: 2, k: 2.0e+7, c: 800}, b: {node: 13, k: 1.0e+7, c: 500}}
  unbalance_planes: {d1: 8}
  sensors: {x1: {node: 8, direction: x}, y1: {node: 8, direction: y}}
variants:
  linear:
    effects: [linear_bearing@a, linear_bearing@b, gyroscopic, unbalance@d1]
    unknown: {k_a: [1.0e+7, 4.0e+7], c_b: [100, 1000]}
"""
LINEAR_EFFECTS = ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"]
#: its critical speeds (1X crossings, tests/test_machine.py's Campbell): 3793 (backward), 4064 (forward) RPM
SENSOR_NODE = 8


def stepped_config() -> dict:
    return yaml.safe_load(STEPPED_YAML)


def stepped_machine() -> Machine:
    """The machine of STEPPED_YAML, written out through the Python API (not read from the YAML)."""
    steel = dict(E=211e9, rho=7810.0)
    return Machine(
        "stepped",
        [ShaftSegment(0.2, 0.04, n_elements=4, **steel), ShaftSegment(0.5, 0.05, d_in=0.02, n_elements=10, **steel),
         ShaftSegment(0.3, 0.035, n_elements=3, **steel)],
        disks=[Disk(8, 15.3, 0.12, 0.062, "d1"), Disk(16, 7.4, 0.037, 0.019, "d2")],
        bearings=[Bearing("a", 2, k=2e7, c=800.0), Bearing("b", 13, k=1e7, c=500.0)],
        unbalance_planes=[UnbalancePlane("d1", 8)],
        sensors=[Sensor("x1", 8, "x"), Sensor("y1", 8, "y")],
    )


def linear_response(machine: Machine, rpm: float, m_e: float, r_me: float = 0.04, k: dict | None = None,
                    c: dict | None = None) -> np.ndarray:
    """All DOFs' 1X amplitude [m] of the linear rotor (bearings k, c by name, default the machine's; gyroscopic
    coupling; the eccentric mass m_e at r_me on the first unbalance plane), from
    (K - Omega^2 M + i Omega C) X = F, F = m_e r_me Omega^2 (1 in x, -i in y): u(t) = Re(X exp(i Omega t))."""
    K, M = machine.matrices()
    C = np.zeros_like(K)
    for bearing in machine.bearings:
        for dof in (f"u{bearing.node}", f"v{bearing.node}"):
            i = machine.dof(dof)
            K[i, i] += (k or {}).get(bearing.name, bearing.k)
            C[i, i] += (c or {}).get(bearing.name, bearing.c)
    Omega = rpm * 2 * np.pi / 60
    C += Omega * machine.gyroscopic_matrix()
    node = machine.unbalance_planes[0].node
    F = np.zeros(machine.n_dof, complex)
    u, v = machine.dof(f"u{node}"), machine.dof(f"v{node}")
    M[u, u] += m_e
    M[v, v] += m_e
    F[u], F[v] = m_e * r_me * Omega**2, -1j * m_e * r_me * Omega**2
    return np.linalg.solve(K - Omega**2 * M + 1j * Omega * C, F)
