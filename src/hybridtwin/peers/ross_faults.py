"""ROSS's fault simulations beside our fault effects (issue 54; docs/model.md, "Faults"; tests/test_ross_faults.py).

ROSS 2.3.0 (the ``ross`` extra) integrates a rotor with a fault in time (Newmark, from rest): ``run_crack``,
``run_misalignment``, ``run_rubbing``. This module runs one case at one constant speed (``ross_fault_run``), takes
the steady harmonics of its time response (``order_harmonics``: after the transients, over whole turns), and builds
our effect for the same fault and parameters (``our_fault``), so that our harmonic balance can be compared with
ROSS's integration harmonic by harmonic. Where the two codes' conventions differ:

- **crack** (``faults.Crack``): ROSS's Mayes and Gasch cracks lower the element's cantilever tip stiffness by
  ko - kc (its ``Ko``, ``Kc`` from Papadopoulos's compliance table at the depth ratio), here dk_xi, dk_eta; ROSS
  keeps the fixed-frame dk_xx, dk_yy and drops dk_xy (``cross_terms=False`` here); its crack angle is Omega t (psi
  = 0). ROSS integrates the full time-varying stiffness with the weight; our effect keeps the weight-dominated part
  (the loss acting on the static sag, and its mean), leaving out the loss acting on the dynamic deflection: the two
  differ by about |t . q_dyn| / |t . q_s| at the crack (``parametric_share``).
- **flexible-coupling misalignment** (``faults.Misalignment``): ROSS's force (Xia et al.'s hexangular coupling) is
  a function of the angle only, +F at the element's left node and -F at its right one; our effect is its 2X part
  (taken from ROSS's own force, ``coupling_force``), the pair at the same nodes. ROSS's rigid coupling (a force
  that depends on the deflection) is not modelled here.
- **rub** (``faults.Rub``): the contact's normal spring k (r - delta) is the same. ROSS's friction is
  f (-|F_x|, +|F_y|) of the contact force (for a positive surface speed), componentwise, not along the surface
  (at a contact on the x axis it pushes along the normal), and its contact damping c acts on the whole velocity;
  ours is Coulomb friction mu N along the surface, no contact damping. Compared at friction 0 and damping 0.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence

import numpy as np

from ..model.faults import Crack, Misalignment, Rub, static_sag, tip_vector
from ..model.machine import Machine
from ..model.model import Model

#: ROSS's DOFs per node
ROSS_DOFS = 6
#: the 4-term Blackman-Harris window's coefficients: its side lobes below -92 dB, so a free mode of the start-up ten
#: frequency bins from a harmonic leaks 1e-5 of its amplitude into it
BLACKMAN_HARRIS = (0.35875, 0.48829, 0.14128, 0.01168)


#: the orders ``order_harmonics`` returns by default: 0 .. 3X, those the faults compared show
TRACKED_HARMONICS = 3


def order_harmonics(y: np.ndarray, dt: float, rpm: float, periods: int,
                    harmonics: int = TRACKED_HARMONICS) -> np.ndarray:
    """The complex harmonics 0..``harmonics`` (h, d) of the last ``periods`` whole turns of the signals y (N, d)
    sampled every ``dt`` from t = 0, y = Re(sum_h X_h exp(i h Omega t)): a DFT at the orders, the Blackman-Harris
    window against the transients' leakage (exact for a steady periodic signal of whole turns)."""
    Omega = rpm * 2 * np.pi / 60
    per_turn = 2 * np.pi / Omega / dt
    if abs(per_turn - round(per_turn)) > 1e-6 * per_turn:
        raise ValueError(f"dt = {dt} s does not divide a turn at {rpm} RPM into whole samples ({per_turn:.6g})")
    n = periods * int(round(per_turn))
    if n > len(y):
        raise ValueError(f"{periods} turns need {n} samples, the signal has {len(y)}")
    start = len(y) - n
    k = 2 * np.pi * np.arange(n) / n
    a0, a1, a2, a3 = BLACKMAN_HARRIS
    w = a0 - a1 * np.cos(k) + a2 * np.cos(2 * k) - a3 * np.cos(3 * k)
    t = (start + np.arange(n)) * dt
    return np.array([(2.0 if h else 1.0) / w.sum() * ((w * np.exp(-1j * h * Omega * t)) @ y[start:])
                     for h in range(harmonics + 1)])


def ross_dof(node: int, direction: str) -> int:
    """ROSS's global index of the deflection of ``node`` along "x" or "y"."""
    return ROSS_DOFS * node + {"x": 0, "y": 1}[direction]


def ross_fault_run(rotor, fault: str, rpm: float, t: np.ndarray, unbalance_node: int, unbalance_kg_m: float,
                   unbalance_phase: float = 0.0, **parameters) -> np.ndarray:
    """ROSS's time response (N, ndof) of ``rotor`` with one fault at constant speed ``rpm`` over times ``t`` (from
    rest), the unbalance m e at ``unbalance_node``; ``parameters``: the fault's, as ROSS names them (crack: n,
    depth_ratio, crack_model; misalignment: n, mis_type, mis_distance_x, mis_distance_y, mis_angle,
    radial_stiffness, bending_stiffness; rub: n, distance, contact_stiffness, contact_damping, friction_coeff);
    fault "none": the unbalance alone. Direct integration (no modal reduction)."""
    from ross.units import Q_  # here: ROSS is optional (the ross extra)

    common = dict(node=[unbalance_node], unbalance_magnitude=[unbalance_kg_m], unbalance_phase=[unbalance_phase],
                  speed=Q_(rpm, "RPM"), t=t)
    runs = {"crack": rotor.run_crack, "misalignment": lambda **kw: rotor.run_misalignment(coupling="flex", **kw),
            "rub": rotor.run_rubbing}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if fault == "none":
            F = rotor.unbalance_force_over_time([unbalance_node], [unbalance_kg_m], [unbalance_phase],
                                                rpm * np.pi / 30, t)
            return rotor.run_time_response(speed=rpm * np.pi / 30, F=F.T, t=t, method="newmark").yout
        if fault not in runs:
            raise ValueError(f"fault must be one of {sorted(runs) + ['none']}, got {fault!r}")
        return runs[fault](**common, **parameters).yout


def crack_losses(rotor, n: int, depth_ratio: float, crack_model: str = "Mayes") -> tuple[float, float, float]:
    """(dk_xi, dk_eta, element length) of ROSS's crack in element ``n`` at ``depth_ratio``: ko - kc along its two
    axes [N/m] (ROSS's ``Crack.Ko``, ``Kc``) and the element's length [m]."""
    from ross.faults.crack import Crack as RossCrack  # here: ROSS is optional (the ross extra)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        crack = RossCrack(rotor, n, depth_ratio, crack_model)
    ko = crack.Ko[0, 0]
    return float(ko - crack.Kc[0, 0]), float(ko - crack.Kc[1, 1]), float(crack.shaft_elem.L)


def coupling_force(rotor, n: int, harmonic: int = 2, **parameters) -> tuple[complex, complex]:
    """The ``harmonic`` part (a_x, a_y) [N] of ROSS's flexible-coupling force at element ``n``'s left node, F(t) =
    Re(a exp(i h Omega t)) (ROSS's own force over one turn, ``MisalignmentFlex.compute_reaction_force``)."""
    from ross.faults.misalignment import MisalignmentFlex  # here: ROSS is optional (the ross extra)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fault = MisalignmentFlex(rotor, n=n, **parameters)
    angle = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    F = fault.compute_reaction_force(angle)
    left = fault.dofs
    ax, ay = (2.0 / angle.size * (F[left[i]] @ np.exp(-1j * harmonic * angle)) for i in (0, 1))
    return complex(ax), complex(ay)


def our_fault(machine: Machine, fault: str, rotor=None, **parameters):
    """Our effect for ROSS's fault (module docstring) and its parameter values: crack (n, depth_ratio,
    crack_model; ``rotor`` for ROSS's losses), misalignment (n, rpm and ROSS's flexible-coupling parameters) or rub
    (n, distance, contact_stiffness; ROSS's friction and contact damping must be 0: their conventions differ)."""
    n = parameters["n"]
    if fault == "crack":
        xi, eta, h = crack_losses(rotor, n, parameters["depth_ratio"], parameters.get("crack_model", "Mayes"))
        effect = Crack(name="crack", node=n, place="ross", element_length_m=h,
                       model=parameters.get("crack_model", "Mayes").lower(), cross_terms=False)
        return effect, {"dk_xi_ross": xi, "dk_eta_ross": eta, "psi_ross": 0.0}
    if fault == "misalignment":
        ross_parameters = {k: v for k, v in parameters.items() if k not in ("n", "rpm")}
        ax, ay = coupling_force(rotor, n, 2, **ross_parameters)
        effect = Misalignment(name="misalignment", node=n, partner=n + 1, place="ross")
        return effect, {"f2x_c_ross": ax.real, "f2x_s_ross": ax.imag, "f2y_c_ross": ay.real, "f2y_s_ross": ay.imag}
    if fault == "rub":
        if parameters.get("friction_coeff", 0.0) or parameters.get("contact_damping", 0.0):
            raise ValueError("ROSS's rub friction and contact damping follow other conventions than ours (module "
                             "docstring): compare at friction_coeff = 0 and contact_damping = 0")
        effect = Rub(name="rub", node=n, place="ross")
        return effect, {"delta_ross": parameters["distance"], "k_rub_ross": parameters["contact_stiffness"],
                        "mu_ross": 0.0}
    raise ValueError(f"fault must be crack, misalignment or rub, got {fault!r}")


def with_sag(model: Model, crack: Crack, values: dict, rpm: float) -> Crack:
    """``crack`` with its ``sag_m`` from ``model``'s stiffness at ``rpm`` (supports that are tables over speed
    included; ``faults.static_sag``)."""
    system = model.system(values, rpm)
    sag = static_sag(model.shaft, system.M[0], system.K[0], crack.gravity_m_s2)
    n, t = crack.node, tip_vector(crack.element_length_m)
    tip = [sag[[model.shaft.dof(f"{d}{node}") for d, node in ((w, n), (f"d{w}", n), (w, n + 1), (f"d{w}", n + 1))]] @ t
           for w in "uv"]
    return dataclasses.replace(crack, sag_m=(float(tip[0]), float(tip[1])))


def parametric_share(machine: Machine, crack: Crack, harmonics: np.ndarray) -> float:
    """max over the harmonics >= 1 of |t . X_h| / |t . q_s| at the crack, both planes: the size of the term our
    crack leaves out (the loss acting on the dynamic deflection) relative to the one it keeps."""
    t = tip_vector(crack.element_length_m)
    n = crack.node
    out = 0.0
    for w, sag in zip("uv", crack.sag_m or (0.0, 0.0)):
        dofs = [machine.dof(f"{d}{node}") for d, node in ((w, n), (f"d{w}", n), (w, n + 1), (f"d{w}", n + 1))]
        if sag:
            out = max(out, float(np.abs(harmonics[1:, dofs] @ t).max() / abs(sag)))
    return out


def model_values(model: Model, **values: float) -> dict:
    """Every parameter of ``model`` at its nominal value, ``values`` over them."""
    return {name: p.nominal for name, p in model.parameters.items()} | values


def base_effect_names(machine: Machine, plane: str) -> list[str]:
    """The linear rotor of a ROSS rotor imported with ``machine_from_ross``, by name: its bearings (tables or k, c),
    the shaft's proportional damping where it has one, the gyroscopic terms and the unbalance at ``plane``."""
    fx = machine.effects()
    names = [k for k in fx if k.startswith(("linear_bearing@", "bearing_table@"))]
    return names + [k for k in ("shaft_damping", "gyroscopic") if k in fx] + [f"unbalance@{plane}"]


def base_effects(machine: Machine, plane: str) -> list:
    """The effects of ``base_effect_names``."""
    fx = machine.effects()
    return [fx[k] for k in base_effect_names(machine, plane)]


def compare(ours: np.ndarray, theirs: np.ndarray, harmonics: Sequence[int]) -> dict[int, float]:
    """max |ours - theirs| / max |theirs| over the probes, per harmonic (arrays (h, probes) complex)."""
    return {h: float(np.abs(ours[h] - theirs[h]).max() / np.abs(theirs[h]).max()) for h in harmonics}
