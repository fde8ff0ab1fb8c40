"""ROSS in and out: a ``Machine`` from a ROSS rotor (the object or its saved file) and a ROSS rotor from a
``Machine`` (docs/model.md, "ROSS in and out"). ROSS is ross-rotordynamics 2.3.0 (Python 3.11), 3.0 (3.12) or 3.1
(3.13), the ``ross`` extra (``pip install -e ".[ross]"``); it is imported inside the functions, so this module
imports without it.

``machine_from_ross(rotor)``:

- ROSS's ShaftElements become ``ShaftSegment``s: the first at each node the shaft's, the others at that node layers
  (``ShaftSegment.node``; their matrices add, as in ROSS); consecutive identical elements (length, diameters,
  material) merged into one segment of ``n_elements``; the material's E, rho and G_s give E, rho, G.
  ROSS's ``shear_effects`` and ``rotary_inertia`` become the machine's ``shear`` and ``rotary_inertia`` (they must
  be the same for every element). Refused with a message: rotors of several shafts (CoAxialRotor, MultiRotor),
  tapered elements (idl != idr or odl != odr), a layer of another length than the shaft's element, mixed shear,
  rotary-inertia or gyroscopic settings, axial force, torque, a shear coefficient other than Cowper's. The elements'
  proportional damping (alpha, beta) is the segments' (the effect ``shaft_damping``).
- DiskElements become ``Disk``s at ROSS's node (m, Ip, Id; the tag as name unless ROSS made it up).
- BearingElements (and seals) become ``Bearing``s named after their tags (non-identifier characters as ``_``):
  constant isotropic coefficients (kxx = kyy, cxx = cyy, no cross terms) as ``k``, ``c``; anything else as a
  ``BearingTable`` of the eight coefficients, at the table's speeds [rad/s] converted to RPM (14 significant
  digits), by ROSS's own rule, so both codes evaluate the same coefficients at any speed (``bearing_table``):
  ROSS 2's ``frequency`` (the speed) with ``interpolation: ross`` (its spline); ROSS 3's ``speed`` with ``pchip``
  or ``linear_extrapolated`` (its ``interpolation``); a ROSS 3 table over the whirl ``frequency`` alone read
  synchronously (whirl = speed, ROSS's default in every analysis); one over both axes refused. Fluid-film bearings
  and seals whose coefficients ROSS computed when they were made are such tables. Mass coefficients (mxx, mxy, myx, myy; ROSS's added mass) go into the table too. Refused: a
  bearing linked to another node (``n_link``), elements whose K or C are not ROSS's table (magnetic bearings, ...),
  point masses (ROSS's are a support's, DOFs of their own where a bearing links), a motor element, modal damping,
  ROSS 3's rotor-wide mass-proportional damping on a rotor with disks (it damps their mass; a rotor's alpha, beta
  that act on the shaft alone become the segments'). Axial coefficients (kzz,
  czz) are dropped: the model has no axial DOFs.
- ROSS has no unbalance planes or probes: give them (``unbalance_planes``, ``sensors``) to have them.

``machine_to_ross(machine)`` is the inverse (segments of explicit ``I`` or ``m`` refused: ROSS computes them from
the diameters; a bearing with neither k nor a table refused: ROSS needs coefficients). ROSS's gyroscopic terms are
on (``gyroscopic=True``); in our model they are the effect ``gyroscopic``, listed or not by a variant. A table whose
rule is not the ROSS release's own is given to ROSS with its coefficients' interpolants replaced by ours
(``_OurRule``), so the rotor in memory evaluates what our model does; ROSS's file form keeps only the table (and
ROSS 3 its own rule), and ``Rotor.load`` gives it ROSS's rule again.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .bearing_table import COEFFICIENTS, COLUMNS, MASSES, BearingTable
from .machine import Machine
from .machine_parts import (Bearing, Disk, MachineSpecError, Sensor, ShaftSegment, UnbalancePlane, build_part,
                            check_known_keys, spec_mapping)

INSTALL = 'pip install -e ".[ross]"'
#: the attribute a ROSS bearing made by ``machine_to_ross`` carries when it evaluates its table as ours
MARK = "hybridtwin_interpolation"


def _ross():
    """The ross package, or an ImportError that says how to install it."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import ross  # here: ROSS is optional (the ross extra) and slow to import
    except Exception as err:  # ImportError, or a dependency of ROSS failing at import
        raise ImportError(f"ROSS (ross-rotordynamics) cannot be imported ({type(err).__name__}: {err}); "
                          f"install it with {INSTALL}") from err
    return ross


def _scalar(values) -> float | None:
    """The one value of a ROSS coefficient list (constant), else None."""
    values = np.atleast_1d(np.asarray(values, dtype=float))
    return float(values[0]) if np.all(values == values[0]) else None


def _shaft(rotor) -> tuple[list[ShaftSegment], bool, bool]:
    elements = sorted(rotor.shaft_elements, key=lambda el: el.n)  # stable: ROSS's order within a node
    nodes = sorted({el.n for el in elements})
    if nodes != list(range(len(nodes))):
        raise ValueError(f"ROSS rotor {rotor.tag!r}: shaft elements at nodes {nodes}; the nodes must be 0, 1, 2, ... "
                         "(one shaft, no gaps)")
    for setting in ("shear_effects", "rotary_inertia", "gyroscopic"):
        found = {bool(getattr(el, setting)) for el in elements}
        if len(found) > 1:
            raise ValueError(f"ROSS rotor {rotor.tag!r}: mixed {setting} (elements with and without it); our machine "
                             f"has one setting for the whole shaft")
    chain: list[list] = []  # [key, count] of consecutive identical elements along the shaft (the first at each node)
    layers: list[list] = []  # [key, first node, count] of the others at a node (layers), runs over consecutive nodes
    base: dict[int, float] = {}
    for el in elements:
        key = _key(el)
        if el.n not in base:
            base[el.n] = float(el.L)
            if chain and chain[-1][0] == key:
                chain[-1][1] += 1
            else:
                chain.append([key, 1])
            continue
        if not np.isclose(float(el.L), base[el.n], rtol=1e-9, atol=0.0):
            raise ValueError(f"ROSS shaft element {el.tag!r} (node {el.n}): a layer {float(el.L):g} m long on an "
                             f"element {base[el.n]:g} m long; layered elements at one node must have the same length")
        run = next((r for r in layers if r[0] == key and r[1] + r[2] == el.n), None)
        if run is not None:
            run[2] += 1
        else:
            layers.append([key, int(el.n), 1])
    out = [_segment(key, n) for key, n in chain] + [_segment(key, n, node) for key, node, n in layers]
    return out, bool(elements[0].shear_effects), bool(elements[0].rotary_inertia)


def _key(el) -> tuple:
    """(element length, d_in, d_out, E, rho, G) of a uniform ROSS shaft element, or ValueError naming what we lack."""
    where = f"ROSS shaft element {el.tag!r} (node {el.n})"
    if el.idl != el.idr or el.odl != el.odr:
        raise ValueError(f"{where}: tapered (idl {el.idl:g}, idr {el.idr:g}, odl {el.odl:g}, odr {el.odr:g} m); "
                         "our segments are uniform: split it into uniform elements")
    for name in ("axial_force", "torque"):
        if float(getattr(el, name, 0) or 0) != 0:
            raise ValueError(f"{where}: {name} = {getattr(el, name)!r} is not modelled here (must be 0)")
    if getattr(el, "shear_method_calc", "cowper") != "cowper":
        raise ValueError(f"{where}: shear_method_calc {el.shear_method_calc!r}; ours is Cowper's coefficient")
    material = el.material
    G = None if material.G_s == material.E / 2.6 else float(material.G_s)  # E / 2.6: our default
    return (float(el.L), float(el.idl), float(el.odl), float(material.E), float(material.rho), G,
            float(el.alpha or 0.0), float(el.beta or 0.0))


def _segment(key: tuple, n: int, node: int | None = None) -> ShaftSegment:
    h, d_in, d_out, E, rho, G, alpha, beta = key
    return ShaftSegment(length=h * n, d_out=d_out, E=E, rho=rho, d_in=d_in, n_elements=n, G=G, node=node,
                        alpha=alpha, beta=beta)


def _name(tag, fallback: str) -> str:
    name = re.sub(r"\W+", "_", str(tag or fallback)).strip("_") or fallback
    return name if name.isidentifier() else f"_{name}"


def _major(ross) -> int:
    """ROSS's major version (2 or 3: their bearing tables differ, module docstring)."""
    return int(str(getattr(ross, "__version__", "2")).split(".")[0])


def _axis(el, ross) -> tuple[np.ndarray | None, str]:
    """The speeds [rad/s] of a ROSS bearing's table (None: constant) and the rule that interpolates them, or
    ValueError: ROSS 2's ``frequency`` (the speed, its spline); ROSS 3's ``speed`` or ``frequency`` (whirl) axis."""
    where = f"ROSS bearing {el.tag!r} (node {el.n})"
    if _major(ross) < 3:
        return el.frequency, getattr(el, MARK, "ross")
    speed, whirl = getattr(el, "speed", None), getattr(el, "frequency", None)
    rule = getattr(el, MARK, None) or {"pchip": "pchip", "linear": "linear_extrapolated"}.get(
        getattr(el, "interpolation", "pchip"))
    if rule is None:
        raise ValueError(f"{where}: interpolation {el.interpolation!r}; only ROSS's pchip and linear are known here")
    if speed is not None and whirl is not None and np.size(speed) > 1 and np.size(whirl) > 1:
        raise ValueError(f"{where}: a table over speed and whirl frequency ({np.size(speed)} x {np.size(whirl)}); "
                         "our bearings' coefficients depend on the speed only (a whirl-frequency table alone is read "
                         "synchronously, whirl = speed)")
    axes = [a for a in (speed, whirl) if a is not None and np.size(a) > 1]
    return (axes[0] if axes else None), rule


def _bearing(ross, el, index: int) -> Bearing:
    where = f"ROSS bearing {el.tag!r} (node {el.n})"
    if getattr(el, "n_link", None) is not None:
        raise ValueError(f"{where}: linked to node {el.n_link} (a support of its own); only bearings to ground "
                         "can be read")
    magnetic = getattr(ross, "MagneticBearingElement", None)
    if magnetic is not None and isinstance(el, magnetic):
        raise ValueError(f"{where}: a MagneticBearingElement (an active magnetic bearing: its coefficients stand for "
                         "its controller); only tables of coefficients (BearingElement, SealElement) can be read")
    if type(el).K is not ross.BearingElement.K or type(el).C is not ross.BearingElement.C:
        raise ValueError(f"{where}: a {type(el).__name__} computes its K or C itself; only tables of coefficients "
                         "(BearingElement, SealElement) can be read")
    name = _name(el.tag, f"bearing_{index}")
    speeds, rule = _axis(el, ross)
    columns = {k: np.atleast_1d(np.asarray(getattr(el, k, 0.0), dtype=float)).ravel() for k in COLUMNS}
    if speeds is None or np.size(speeds) == 1:
        values = {k: _scalar(v) for k, v in columns.items()}
        if values["kxx"] == values["kyy"] and values["cxx"] == values["cyy"] and not any(
                values[k] for k in ("kxy", "kyx", "cxy", "cyx") + MASSES):
            return Bearing(name, int(el.n), k=values["kxx"], c=values["cxx"])
        return Bearing(name, int(el.n), table=BearingTable.constant(**values))
    n = np.size(speeds)
    columns = {k: np.broadcast_to(v, (n,)) if v.size == 1 else v for k, v in columns.items()}  # ROSS's zeros
    # ROSS's speeds are rad/s; to 14 significant digits, so that a table written from RPM comes back as it was
    rpm = [float(f"{w * 60.0 / (2.0 * np.pi):.14g}") for w in np.asarray(speeds, dtype=float)]
    try:
        table = BearingTable(tuple(rpm), **{k: tuple(v) for k, v in columns.items()}, interpolation=rule)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    return Bearing(name, int(el.n), table=table)


def _rotor_damping(rotor, elemental: bool) -> tuple[float, float]:
    """ROSS's rotor-wide proportional damping (``Rotor(alpha=, beta=)``: alpha M0 + beta K0 of the shaft and the
    disks) as the segments' (alpha, beta), or ValueError where ours cannot be it: modal damping, alpha with disks
    (ours damps the shaft's mass only), or beside the elements' own (ROSS then drops theirs)."""
    parameters = getattr(rotor, "parameters", None) or {}
    where = f"ROSS rotor {rotor.tag!r}"
    if parameters.get("modal_damping_ratio") is not None:
        raise ValueError(f"{where}: modal damping (modal_damping_ratio); only proportional damping of the shaft "
                         "(alpha, beta) can be read")
    alpha, beta = float(parameters.get("alpha") or 0.0), float(parameters.get("beta") or 0.0)
    if not (alpha or beta):
        return 0.0, 0.0
    if elemental:
        raise ValueError(f"{where}: rotor-wide damping (alpha {alpha:g}, beta {beta:g}) beside the shaft elements' "
                         "own; ROSS keeps the rotor's only: give one of them")
    if alpha and rotor.disk_elements:
        raise ValueError(f"{where}: rotor-wide mass-proportional damping (alpha {alpha:g} 1/s) acts on the disks' "
                         "mass too; ours damps the shaft's (give alpha to the shaft elements instead)")
    return alpha, beta


def machine_from_ross(rotor, name: str | None = None, unbalance_planes: Sequence[UnbalancePlane] = (),
                      sensors: Sequence[Sensor] = ()) -> Machine:
    """Our ``Machine`` of a ROSS rotor (a ``ross.Rotor``, or the path of a file ``rotor.save`` wrote): module
    docstring. ``name`` default the rotor's tag (ROSS's file does not keep it: "Rotor 0" once loaded);
    ``unbalance_planes``, ``sensors``: ours to add (ROSS has none). A ROSS rotor this cannot represent raises
    ValueError naming the element and the problem."""
    ross = _ross()
    if isinstance(rotor, (str, Path)):
        if not Path(rotor).is_file():
            raise FileNotFoundError(f"{rotor}: no such ROSS rotor file (.toml or .json, from rotor.save)")
        rotor = ross.Rotor.load(rotor)
    kind = type(rotor).__name__
    if kind != "Rotor" and any(c.__name__ in ("CoAxialRotor", "MultiRotor") for c in type(rotor).__mro__):
        raise ValueError(f"ROSS rotor {rotor.tag!r}: a {kind} (several shafts, coaxial or geared); our machine is "
                         "one shaft")
    if getattr(rotor, "motor_element", None) is not None:
        raise ValueError(f"ROSS rotor {rotor.tag!r}: a motor element (its electromagnetic forces) is not modelled "
                         "here")
    segments, shear, rotary_inertia = _shaft(rotor)
    alpha, beta = _rotor_damping(rotor, any(s.alpha or s.beta for s in segments))
    if alpha or beta:
        segments = [dataclasses.replace(s, alpha=alpha, beta=beta) for s in segments]
    disks = [Disk(int(d.n), float(d.m), I_p=float(d.Ip), I_d=float(d.Id),
                  name="" if re.fullmatch(r"Disk \d+", str(d.tag or "Disk 0")) else _name(d.tag, ""))
             for d in rotor.disk_elements]
    for p in getattr(rotor, "point_mass_elements", None) or []:
        raise ValueError(f"ROSS point mass {p.tag!r} (node {p.n}): a support's mass (ROSS gives a point mass DOFs of "
                         "its own, where bearings link the shaft to a support, n_link); supports are not modelled here")
    bearings = [_bearing(ross, el, i) for i, el in enumerate(rotor.bearing_elements)]
    return Machine(name or str(rotor.tag), segments, disks, bearings, unbalance_planes, sensors,
                   rotary_inertia=rotary_inertia, shear=shear)


def machine_from_section(spec: Mapping, config_dir: str | Path = ".") -> Machine:
    """The config's ``machine:`` section naming a ROSS rotor file, ``{ross: rotor.toml, name: compressor,
    unbalance_planes: {...}, sensors: {...}}``: ``machine_from_ross`` of the file (its path relative to
    ``config_dir``, the config's folder) with our name (default the file's stem), unbalance planes and probes beside
    it, in the forms of ``Machine.from_mapping``. A problem raises ``MachineSpecError`` (the file's, at ``ross``)."""
    check_known_keys(spec, (), {"ross", "name", "unbalance_planes", "sensors"})
    if not isinstance(spec["ross"], str):
        raise MachineSpecError(("ross",), f"must be the path of a ROSS rotor file, got {spec['ross']!r}")
    path = Path(config_dir) / spec["ross"]
    if not path.is_file():
        raise MachineSpecError(("ross",), f"{path}: no such file (a ROSS rotor saved with rotor.save, .toml or "
                                          f".json; the path is relative to {config_dir}/)")
    try:
        rotor = _read(str(path.resolve()), path.stat().st_mtime_ns)
    except (ImportError, ValueError) as err:
        raise MachineSpecError(("ross",), f"{path}: {err}") from None
    sensors = [build_part(Sensor, {"name": name, **spec_mapping(item, ("sensors", name))}, ("sensors", name),
                      {"name", "node", "direction"}, {"angle_deg"})
               for name, item in spec_mapping(spec.get("sensors"), ("sensors",)).items()]
    planes = [build_part(UnbalancePlane, {"name": name, "node": node}, ("unbalance_planes", name), {"name", "node"},
                         set())
              for name, node in spec_mapping(spec.get("unbalance_planes"), ("unbalance_planes",)).items()]
    try:
        return Machine(str(spec.get("name", path.stem)), rotor.segments, rotor.disks, rotor.bearings, planes, sensors,
                       rotor.rotary_inertia, rotor.shear)
    except ValueError as err:
        raise MachineSpecError((), str(err)) from None


@functools.cache
def _read(path: str, mtime_ns: int) -> Machine:
    """``machine_from_ross`` of a file, once per version of it (ROSS takes seconds to build a large rotor, and the
    config's machine is asked for often)."""
    return machine_from_ross(path)


class _OurRule:
    """One coefficient of ``table`` as a ROSS bearing's ``<coefficient>_interpolated``: called by ROSS 2 with the
    speed (``frequency``), by ROSS 3 with the whirl frequency and the speed (default the whirl frequency); the speed
    is what ours depends on."""

    def __init__(self, table: BearingTable, key: str):
        self.table, self.key = table, key

    def __call__(self, frequency=None, speed=None):
        at = np.asarray(speed if speed is not None else frequency, dtype=float)
        return self.table.at(at)[self.key]


def _ours(el, table: BearingTable) -> None:
    """Make the ROSS bearing ``el`` evaluate ``table`` by our rule (where ROSS's own differs)."""
    for key in COLUMNS:
        setattr(el, f"{key}_interpolated", _OurRule(table, key))
    setattr(el, MARK, table.interpolation)


def machine_to_ross(machine: Machine, file: str | Path | None = None):
    """A ``ross.Rotor`` of our ``machine`` (module docstring); with ``file`` also saved there (ROSS's
    ``rotor.save``: .toml or .json). A machine ROSS cannot represent raises ValueError naming what."""
    ross = _ross()
    three = _major(ross) >= 3
    shaft, layers, node = [], [], 0
    for i, s in enumerate(machine.segments):
        if s.I is not None or s.m is not None:
            raise ValueError(f"machine {machine.name!r}, segment {i}: gives I or m directly; ROSS computes them "
                             "from the diameters and rho")
        material = ross.Material(name=f"{_name(machine.name, 'machine')}_segment_{i}", rho=s.rho, E=s.E,
                                 G_s=s.shear_modulus)
        first = node if s.node is None else s.node  # a layer: ROSS's elements at the nodes it lies on
        (shaft if s.node is None else layers).extend(
            ross.ShaftElement(L=s.h, idl=s.d_in, odl=s.d_out, material=material, n=first + j,
                              shear_effects=machine.shear, rotary_inertia=machine.rotary_inertia, gyroscopic=True,
                              alpha=s.alpha, beta=s.beta)
            for j in range(s.n_elements))
        node += s.n_elements if s.node is None else 0
    shaft += layers  # after the shaft's: ROSS sorts by node, keeping the order within one (the shaft's element first)
    disks = [ross.DiskElement(n=d.node, m=d.mass, Id=d.I_d, Ip=d.I_p, tag=d.name or None) for d in machine.disks]
    bearings = []
    for b in machine.bearings:
        if b.table is not None:
            t = b.table
            frequency = np.asarray(t.rpm) * (2.0 * np.pi / 60.0)
            columns = {k: np.asarray(getattr(t, k)) for k in COLUMNS}
            if len(t.rpm) == 1:
                el = ross.BearingElement(n=b.node, **{k: float(v[0]) for k, v in columns.items()}, tag=b.name)
            elif three:
                native = {"pchip": "pchip", "linear_extrapolated": "linear"}.get(t.interpolation)
                el = ross.BearingElement(n=b.node, **columns, speed=frequency, interpolation=native or "pchip",
                                         tag=b.name)
                if native is None:
                    _ours(el, t)
            else:
                el = ross.BearingElement(n=b.node, **columns, frequency=frequency, tag=b.name)
                if t.interpolation != "ross":
                    _ours(el, t)
        elif b.k is not None:
            el = ross.BearingElement(n=b.node, kxx=b.k, cxx=b.c, tag=b.name)
        else:
            raise ValueError(f"machine {machine.name!r}: bearing {b.name!r} has no coefficients (k or table); "
                             "a ROSS bearing needs them")
        bearings.append(el)
    rotor = ross.Rotor(shaft, disks, bearings, tag=machine.name)
    if file is not None:
        rotor.save(file)
    return rotor
