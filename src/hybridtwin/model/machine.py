"""Your own machine: the rotor (shaft segments, rigid disks) and where its bearings, unbalance planes and
sensors are (docs/model.md, "Describing your machine").

A ``Machine`` is both the description and its finite-element discretisation: it has the interface of
``Shaft`` (``n``, ``dof``, ``translational``, ``node_at``, ``matrices``, ...), so a ``Model`` built on it
assembles its shaft, disks and (optionally) the sections' rotary inertia as the structure's M and K, and the
effects act on its DOFs. Nodes are numbered along the shaft from 0 at z = 0, each segment contributing
``n_elements`` equal elements; DOF names and ordering are those of ``Shaft`` (``u3``, ``dv7``, x plane
first).

Bearings, unbalance planes and sensors are named nodes. The effects that act there are placed by name:
``machine.place(effect, "drive_end")`` or, by name in a variant's effect list, ``"linear_bearing@drive_end"``,
``"lower_bearing@drive_end"``, ``"unbalance@disk"``, ... (``Machine.effects``). Gyroscopic coupling is the
effect ``gyroscopic`` (Omega G in the damping, from the disks' polar inertia and the shaft's distributed one);
the VARM's variants leave it out, as the paper does.

``Machine.varm()`` is the bundled default, the paper's rig: one uniform segment with Table 1's I and m,
bearings ``upper`` (node 0) and ``lower`` (node 10), the unbalance plane ``eccentric_mass`` (node 5),
sensors ``x`` and ``y`` at node 1. A model built on it is bit for bit the one built on ``Shaft()``.

Sensors: any number of probes, each at a node in direction x or y; a record holds one channel per sensor,
named after it (docs/measurement-format.md). At least one node needs both an x and a y probe
(``sensor_node``, the orbit the plots and checks show).

The parts (``ShaftSegment``, ``Disk``, ``Bearing``, ``UnbalancePlane``, ``Sensor``) and the reading of their config
form (``MachineSpecError``) are ``hybridtwin.model.machine_parts``'; the parts are importable from here too.
"""

from __future__ import annotations

import copy
import re
import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .bearing_candidates import EXCITATION_DISPLACEMENT_M, at_bearing, excitations_at
from .faults import fault_candidates
from .bearing_table import TableBearing
from .effect_base import Context, Effect, LocalMatrix, Parameter
from .effects import ANGLE_ME, Unbalance, builtin_effects, trial_force
# re-exported: Bearing, Disk, Sensor, ShaftSegment, UnbalancePlane (docs/model.md imports them from here with Machine)
from .machine_parts import (Bearing, Disk, MachineSpecError, Sensor, ShaftSegment, UnbalancePlane, bearing_from_spec,
                            build_part, check_known_keys, spec_mapping, spec_sequence)
from .probes import check_pair
from .sensor import machine_order, sensor_pairs
from .shaft import DofCounts, Shaft, beam_element, slope_element

Array = np.ndarray


def _tuple(items: Iterable, kind: type) -> tuple:
    out = tuple(items)
    for item in out:
        if not isinstance(item, kind):
            raise TypeError(f"expected {kind.__name__} objects, got {type(item).__name__}")
    return out


#: the VARM's words for where a built-in effect acts, and what they become where it is placed at a bearing
_VARM_PLACES = ((r"at node 0\b", "at node {node}"), (r"at the lowest node", "at node {node}"),
                (r"\b(the )?upper bearing\b", "bearing {at}"), (r"\b(the )?lower bearing\b", "bearing {at}"),
                (r" \(rubber bushing\)", ""))
#: what a placed effect's parameter with a nonzero nominal value says of it: the value is the VARM's bearing's
VARM_NOMINAL = " [nominal: the VARM's value; give this machine's under fixed: or unknown:]"


def placed_meaning(meaning: str, at: str, node: int) -> str:
    """A built-in effect's meaning with the VARM's place (its upper or lower bearing, node 0, the lowest node)
    replaced by the bearing ``at`` and its ``node`` ("2X rotating force at bearing nde")."""
    for pattern, place in _VARM_PLACES:
        meaning = re.sub(pattern, place.format(at=at, node=node), meaning)
    return meaning


@dataclass(frozen=True, eq=False)
class Machine(DofCounts):
    """A rotor described by segments and disks, with named bearings, unbalance planes and sensors.

    ``rotary_inertia``: add the sections' rotary inertia rho I (a Rayleigh beam); off for the VARM, whose
    model leaves it out (docs/model.md, "Shaft"). ``shear``: Timoshenko elements, the shear deformation in the
    stiffness, mass, rotary and gyroscopic matrices (``shaft.beam_element``, Cowper's shear coefficient); off
    for the VARM, whose slender shaft the paper models as Euler-Bernoulli. ``sensors`` are kept plane by plane,
    each plane's x probe then
    its y probe (planes in order of first appearance), probes without a partner after them: the records'
    channel order.
    """

    name: str
    segments: Sequence[ShaftSegment]
    disks: Sequence[Disk] = ()
    bearings: Sequence[Bearing] = ()
    unbalance_planes: Sequence[UnbalancePlane] = ()
    sensors: Sequence[Sensor] = ()
    rotary_inertia: bool = False
    shear: bool = False
    _names: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        where = f"machine {self.name!r}"
        for attr, kind in (("segments", ShaftSegment), ("disks", Disk), ("bearings", Bearing),
                           ("unbalance_planes", UnbalancePlane), ("sensors", Sensor)):
            try:
                object.__setattr__(self, attr, _tuple(getattr(self, attr), kind))
            except TypeError as err:
                raise ValueError(f"{where}: {attr}: {err}") from None
        if not self.chain:
            raise ValueError(f"{where}: the shaft needs at least one segment (not a layer: without node)")
        # the channel order (sensor.machine_order, also the records' as read with the config's sensors): plane
        # by plane (in order of first appearance) its x probe, then its y probe; probes without a partner after them,
        # as declared. The whirl checks read channels 0 and 1 as the first plane's x and y; a config written with
        # sorted keys (x1, x2, y1, y2) would otherwise have them read x1 and x2.
        object.__setattr__(self, "sensors", tuple(self.sensors[i] for i in machine_order(self.sensors)))
        n_nodes = sum(s.n_elements for s in self.chain) + 1
        h = np.repeat([s.h for s in self.chain], [s.n_elements for s in self.chain])  # each element's length
        for i, layer in enumerate(self.segments):
            if layer.node is None:
                continue
            if layer.node + layer.n_elements > n_nodes - 1:
                raise ValueError(f"{where}: segment {i} (a layer from node {layer.node}, {layer.n_elements} "
                                 f"elements) reaches beyond the shaft's last node {n_nodes - 1}")
            under = h[layer.node:layer.node + layer.n_elements]
            if not np.allclose(under, layer.h, rtol=1e-9, atol=0.0):
                raise ValueError(f"{where}: segment {i} (a layer from node {layer.node}): its elements are "
                                 f"{layer.h:g} m long, the shaft's there {', '.join(f'{x:g}' for x in under)} m; a "
                                 "layer's elements must span the shaft's")
        names: dict[str, int] = {}
        for kind, items in (("disk", self.disks), ("bearing", self.bearings),
                            ("unbalance plane", self.unbalance_planes), ("sensor", self.sensors)):
            for item in items:
                label = f"{kind} {item.name!r}" if item.name else kind
                if isinstance(item.node, bool) or not isinstance(item.node, (int, np.integer)) \
                        or not 0 <= item.node < n_nodes:
                    raise ValueError(f"{where}: {label} at node {item.node!r}: nodes are the integers 0..{n_nodes - 1}")
                if kind == "disk":
                    continue
                if not item.name or not str(item.name).isidentifier():
                    raise ValueError(f"{where}: {kind} name {item.name!r} must be a non-empty identifier")
                if item.name in names:
                    raise ValueError(f"{where}: the name {item.name!r} is used twice")
                names[item.name] = int(item.node)
        for ix, iy in sensor_pairs(self.sensors):  # the two probes of a plane must give its x and y
            check_pair(self.sensors[ix].angle_deg, self.sensors[iy].angle_deg,
                       (self.sensors[ix].name, self.sensors[iy].name))
        lowered = [str(s.name).lower() for s in self.sensors]
        clash = sorted({s.name for s in self.sensors if lowered.count(str(s.name).lower()) > 1})
        if clash:  # a record's header is read in any case: X1_mm and x1_mm are one column
            raise ValueError(f"{where}: sensors {', '.join(map(repr, clash))} differ only in case; records cannot "
                             "tell their columns apart")
        for disk in self.disks:
            if not (disk.mass >= 0 and disk.I_p >= 0 and disk.I_d >= 0):
                raise ValueError(f"{where}: disk at node {disk.node}: mass, I_p and I_d must be >= 0")
        for bearing in self.bearings:
            if bearing.k is not None and not (bearing.k >= 0 and bearing.c >= 0):
                raise ValueError(f"{where}: bearing {bearing.name!r}: k and c must be >= 0")
        object.__setattr__(self, "_names", names)

    # --- the bundled default -------------------------------------------------------------------------

    @classmethod
    def varm(cls) -> "Machine":
        """The paper's Vertical Axis Rotating Machine (Table 1, docs/model.md).

        One bronze segment of 0.85 m in 10 elements, d = 2 r = 6.35 mm, with Table 1's I = 79.81e-11 m^4 and
        m = 0.35 kg/m given directly (see the note on I); rho = m / A makes the sections' rotary and polar
        inertia consistent with that m (neither is used by the paper's model). No disk: the bearing housings
        and the eccentric mass are the effects' point masses.
        """
        shaft = Shaft()
        d = 2 * 0.003175
        rho = shaft.m / (np.pi * d**2 / 4)
        return cls(
            name="varm",
            segments=(ShaftSegment(length=shaft.L, d_out=d, E=shaft.E, rho=rho, n_elements=shaft.n, I=shaft.I,
                                   m=shaft.m),),
            bearings=(Bearing("upper", 0), Bearing("lower", shaft.n)),
            unbalance_planes=(UnbalancePlane("eccentric_mass", shaft.node_at(0.425)),),
            sensors=(Sensor("x", 1, "x"), Sensor("y", 1, "y")),
        )

    @classmethod
    def from_mapping(cls, spec: Mapping | None) -> "Machine":
        """A machine from its config form (``machine:`` in config/config.yaml; None: the VARM)::

            name: test_rig
            segments:                       # along z, from node 0
              - {length: 0.2, d_out: 0.04, E: 2.11e+11, rho: 7810, n_elements: 4}   # d_in, I, m optional
              - {length: 0.1, d_out: 0.06, d_in: 0.04, E: 2.11e+11, rho: 7810, n_elements: 2, node: 1}  # a layer
            disks: [{node: 8, mass: 15.3, I_p: 0.12, I_d: 0.062, name: impeller}]
            bearings: {drive_end: {node: 2, k: 2.0e+7, c: 800}, free_end: {node: 16}}
            # or a bearing's eight coefficients against speed: {node: 16, table: {rpm: [...], kxx: [...], ...}}
            unbalance_planes: {impeller: 8}
            sensors: {x1: {node: 8, direction: x}, y1: {node: 8, direction: y}}   # angle_deg optional
            rotary_inertia: false           # the sections' rotary inertia (Rayleigh beams)
            shear: false                    # Timoshenko beams (a segment's shear modulus G optional)

        A section naming a ROSS rotor file (``{ross: rotor.toml, ...}``) is ``ross_io.machine_from_section``'s
        (``hybridtwin.config.machine`` reads either).

        A section that gives only ``sensors`` (and optionally ``name``) is the VARM's shaft, bearings and
        unbalance plane with those sensors (probes at other angles or nodes of the VARM, e.g.
        ``{x: {node: 1, direction: x, angle_deg: 45}, y: {node: 1, direction: y, angle_deg: 135}}``).
        A problem raises ``MachineSpecError`` (one line; ``path``: where in the section).
        """
        if spec is None:
            return cls.varm()
        if not isinstance(spec, Mapping):
            raise MachineSpecError((), f"must be a mapping, got {spec!r}")
        check_known_keys(spec, (), {"name", "segments", "disks", "bearings", "unbalance_planes", "sensors",
                                    "rotary_inertia", "shear"})
        sensors = [build_part(Sensor, {"name": name, **spec_mapping(item, ("sensors", name))}, ("sensors", name),
                          {"name", "node", "direction"}, {"angle_deg"})
                   for name, item in spec_mapping(spec.get("sensors"), ("sensors",)).items()]
        if "sensors" in spec and set(map(str, spec)) <= {"name", "sensors"}:  # the VARM with these sensors
            varm = cls.varm()
            spec = {**varm.to_mapping(), "name": spec.get("name", varm.name)}
        segments = [build_part(ShaftSegment, item, ("segments", i), {"length", "d_out", "E", "rho"},
                           {"d_in", "n_elements", "I", "m", "G", "node", "alpha", "beta"})
                    for i, item in enumerate(spec_sequence(spec, "segments"))]
        disks = [build_part(Disk, item, ("disks", i), {"node", "mass"}, {"I_p", "I_d", "name"})
                 for i, item in enumerate(spec_sequence(spec, "disks"))]
        bearings = [bearing_from_spec(name, item)
                    for name, item in spec_mapping(spec.get("bearings"), ("bearings",)).items()]
        planes = [build_part(UnbalancePlane, {"name": name, "node": node}, ("unbalance_planes", name), {"name", "node"},
                             set())
                  for name, node in spec_mapping(spec.get("unbalance_planes"), ("unbalance_planes",)).items()]
        try:
            return cls(str(spec.get("name", "machine")), segments, disks, bearings, planes, sensors,
                       bool(spec.get("rotary_inertia", False)), bool(spec.get("shear", False)))
        except ValueError as err:
            raise MachineSpecError((), str(err)) from None

    # --- discretisation: the interface of Shaft ------------------------------------------------------

    @property
    def chain(self) -> tuple[ShaftSegment, ...]:
        """The segments that make up the shaft one after another (``node`` None); the others are layers on it."""
        return tuple(s for s in self.segments if s.node is None)

    @cached_property
    def _elements(self) -> list[tuple[int, ShaftSegment]]:
        """(element index, its segment) of every beam element: the shaft's, then each layer's (several at one
        element where layers lie: their matrices add)."""
        out, e = [], 0
        for segment in self.chain:
            out += [(e + i, segment) for i in range(segment.n_elements)]
            e += segment.n_elements
        for segment in self.segments:
            if segment.node is not None:
                out += [(segment.node + i, segment) for i in range(segment.n_elements)]
        return out

    @property
    def n(self) -> int:
        """Number of beam elements along the shaft (layers lie on them)."""
        return int(sum(s.n_elements for s in self.chain))

    @property
    def L(self) -> float:
        """Shaft length [m], the sum of the segments' lengths (layers not counted)."""
        return float(sum(s.length for s in self.chain))

    @cached_property
    def z(self) -> np.ndarray:
        """Node positions [m]: each segment's nodes at its start + i h."""
        parts, start = [np.zeros(1)], 0.0
        for segment in self.chain:
            local = np.arange(1, segment.n_elements + 1) * segment.h
            parts.append(start + local)
            start = start + segment.length
        return np.concatenate(parts)

    def node_at(self, z: float) -> int:
        """Index of the node nearest to axial position ``z`` [m]."""
        if not 0.0 <= z <= self.L * (1 + 1e-12):
            raise ValueError(f"machine {self.name!r}: position z = {z} m lies outside the shaft [0, {self.L}] m")
        return int(np.argmin(np.abs(self.z - z)))

    dof = Shaft.dof
    translational = Shaft.translational

    @cached_property
    def _plane(self) -> tuple[np.ndarray, np.ndarray]:
        K = np.zeros((self.n_plane, self.n_plane))
        M = np.zeros_like(K)
        for e, segment in self._elements:
            phi = segment.phi(self.shear)
            K_e, M_e = beam_element(segment.h, segment.E * segment.bending_I, segment.mass_per_length, phi)
            sl = slice(2 * e, 2 * e + 4)
            K[sl, sl] += K_e
            M[sl, sl] += M_e
            if self.rotary_inertia:
                M[sl, sl] += slope_element(segment.h, segment.rho * segment.section_I, phi)
        for disk in self.disks:
            M[2 * disk.node, 2 * disk.node] += disk.mass
            M[2 * disk.node + 1, 2 * disk.node + 1] += disk.I_d
        K.flags.writeable = M.flags.writeable = False
        return K, M

    def plane_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Stiffness and mass of one bending plane (2(n+1) square), free ends: shaft elements, the sections'
        rotary inertia (with ``rotary_inertia``), the disks' mass and transverse inertia."""
        K, M = self._plane
        return K.copy(), M.copy()

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Stiffness and mass of both planes (uncoupled blocks), n_dof square."""
        K_p, M_p = self.plane_matrices()
        zero = np.zeros_like(K_p)
        return np.block([[K_p, zero], [zero, K_p]]), np.block([[M_p, zero], [zero, M_p]])

    @cached_property
    def _damping(self) -> np.ndarray:
        C = np.zeros((self.n_plane, self.n_plane))
        for e, segment in self._elements:
            if not (segment.alpha or segment.beta):
                continue
            phi = segment.phi(self.shear)
            K_e, M_e = beam_element(segment.h, segment.E * segment.bending_I, segment.mass_per_length, phi)
            if self.rotary_inertia:
                M_e = M_e + slope_element(segment.h, segment.rho * segment.section_I, phi)
            sl = slice(2 * e, 2 * e + 4)
            C[sl, sl] += segment.alpha * M_e + segment.beta * K_e
        zero = np.zeros_like(C)
        C = np.block([[C, zero], [zero, C]])
        C.flags.writeable = False
        return C

    def shaft_damping_matrix(self) -> np.ndarray:
        """The shaft's proportional damping (n_dof square, both planes): sum over the elements of every segment and
        layer of alpha M_e + beta K_e, M_e with the sections' rotary inertia when the machine has it (ROSS's
        ShaftElement.C). Zero unless a segment gives alpha or beta."""
        return self._damping.copy()

    @cached_property
    def _gyroscopic(self) -> np.ndarray:
        R = np.zeros((self.n_plane, self.n_plane))
        for e, segment in self._elements:
            sl = slice(2 * e, 2 * e + 4)
            R[sl, sl] += slope_element(segment.h, 2.0 * segment.rho * segment.section_I,  # rho I_p = 2 rho I
                                       segment.phi(self.shear))
        for disk in self.disks:
            R[2 * disk.node + 1, 2 * disk.node + 1] += disk.I_p
        zero = np.zeros_like(R)
        G = np.block([[zero, R], [-R, zero]])
        G.flags.writeable = False
        return G

    def gyroscopic_matrix(self) -> np.ndarray:
        """G of the gyroscopic force -Omega G q' (n_dof square, skew-symmetric), Omega about +z (the shaft
        turning from +x towards +y): G[du_i, dv_j] = +R_ij, G[dv_i, du_j] = -R_ij, R the polar inertia
        distributed over the slopes (shaft: rho I_p N'^T N' per element; disk: I_p on its node's slope).
        Derivation: docs/model.md, "Describing your machine"."""
        return self._gyroscopic.copy()

    # --- names ---------------------------------------------------------------------------------------

    def node(self, name: str) -> int:
        """The node of a named bearing, unbalance plane or sensor."""
        try:
            return self._names[name]
        except KeyError:
            raise ValueError(f"machine {self.name!r} has no bearing, unbalance plane or sensor named {name!r} "
                             f"(names: {sorted(self._names)})") from None

    def sensor_dofs(self) -> list[int]:
        """Global DOF index of each sensor, in the order of ``sensors``."""
        return [self.dof(f"{'u' if s.direction == 'x' else 'v'}{s.node}") for s in self.sensors]

    @property
    def sensor_planes(self) -> list[int]:
        """The nodes that carry sensors, in order of first appearance."""
        return list(dict.fromkeys(s.node for s in self.sensors))

    @property
    def sensor_node(self) -> int:
        """The node of the first x, y probe pair (the first node, in the machine's order, with both an x and a y
        probe): the plane whose orbit the plots, the whirl checks and ``hybridtwin simulate`` show. A one-line
        error when no node has both. Records carry every sensor (``sensor_dofs``); this is only the orbit."""
        for node in self.sensor_planes:
            if {s.direction for s in self.sensors if s.node == node} == {"x", "y"}:
                return node
        raise ValueError(f"machine {self.name!r}: sensors {[(s.name, s.node, s.direction) for s in self.sensors]}"
                         " have no node with both an x and a y probe; at least one x, y pair is needed (its orbit)")

    @property
    def sensor_pairs(self) -> list[tuple[int, int]]:
        """(index of the x probe, index of the y probe) in ``sensors`` for each node with exactly one of each,
        in order of the nodes' first appearance: the orbits the records show (``sensor.sensor_pairs``);
        (0, 1), (2, 3), ... since the machine orders its sensors so."""
        return sensor_pairs(self.sensors)

    # --- effects at named places ---------------------------------------------------------------------

    def place(self, effect: Effect, at: str, name: str | None = None) -> Effect:
        """A copy of ``effect`` acting at the node named ``at``, named ``name`` (default ``effect@at``).

        Works for effects that act at one node they declare (``node``): the polynomial bearings
        (geometric, radial and slope springs, expansion terms), the harmonic excitations, upper_housing,
        lower_bearing, and this module's linear_bearing and plane unbalance.
        """
        node = self.node(at)
        name = name or f"{effect.name}@{at}"
        if not hasattr(effect, "node"):
            raise ValueError(f"effect {effect.name!r} acts at a fixed place and cannot be placed at {at!r}")
        if isinstance(effect, LinearBearing):
            return dataclasses.replace(effect, node=node, name=name, bearing=at)
        if dataclasses.is_dataclass(effect):
            named = {"place": at} if "place" in {f.name for f in dataclasses.fields(effect)} else {}
            placed = dataclasses.replace(effect, node=node, name=name, **named)  # parameters named after `at`
        else:
            placed = copy.copy(effect)
            placed.node, placed.name = node, name
        if isinstance(getattr(effect, "meaning", None), str):  # its words for the place, the place's (frozen too)
            object.__setattr__(placed, "meaning", placed_meaning(effect.meaning, at, node))
        if not self.varm_structure:  # its parameters' words too, and a nominal value that is the VARM's says so
            object.__setattr__(placed, "parameters", tuple(
                dataclasses.replace(p, meaning=placed_meaning(p.meaning, at, node) + (VARM_NOMINAL if p.nominal else ""))
                for p in placed.parameters))
        return placed

    def effects(self) -> dict[str, Effect]:
        """The effects this machine adds to the built-in ones, by name (for a variant's effect list):
        ``gyroscopic``; ``shaft_damping`` when a segment gives alpha or beta; ``linear_bearing@<bearing>`` for each
        bearing with nominal coefficients (and ``bearing_table@<bearing>`` for one with a table of coefficients against
        speed); every placeable built-in effect at every bearing, ``<effect>@<bearing>``; ``unbalance@<plane>`` for
        each unbalance plane (the run's eccentric mass m_e at that plane); and the candidates sized to the machine
        (``sized_candidates``, over a placed built-in of the same name)."""
        out: dict[str, Effect] = {"gyroscopic": Gyroscopic()}
        if any(s.alpha or s.beta for s in self.segments):
            out["shaft_damping"] = ShaftDamping()
        placeable = [e for e in builtin_effects().values() if hasattr(e, "node")]
        for bearing in self.bearings:
            if bearing.k is not None:
                out[f"linear_bearing@{bearing.name}"] = LinearBearing(
                    name=f"linear_bearing@{bearing.name}", bearing=bearing.name, node=bearing.node,
                    k=bearing.k, c=bearing.c)
            if bearing.table is not None:
                out[f"bearing_table@{bearing.name}"] = TableBearing(
                    name=f"bearing_table@{bearing.name}", bearing=bearing.name, node=bearing.node, table=bearing.table)
            for effect in placeable:
                placed = self.place(effect, bearing.name)
                out[placed.name] = placed
        for plane in self.unbalance_planes:
            out[f"unbalance@{plane.name}"] = PlaneUnbalance(name=f"unbalance@{plane.name}", node=plane.node)
        out |= self.sized_candidates()  # sized to the bearings' k, c and the shaft (over a placed VARM one's name)
        if not self.varm_structure:  # the plain `unbalance` along this shaft, not at the VARM's 0.425 m
            first = self.unbalance_planes[0] if self.unbalance_planes else None
            out["unbalance"] = MachineUnbalance(self.name, self.L, None if first is None else
                                                float(self.z[first.node]))
        return out

    def tilt_stiffness(self, node: int) -> float:
        """4 E I / h of the stiffest shaft element at ``node`` [N m/rad]: the moment that turns the element's end by
        one radian with the other end clamped, the scale of a bearing's moment stiffness there (the layers lying on an
        element add theirs: their matrices add, ``_elements``)."""
        elements = [e for e in (node - 1, node) if 0 <= e < self.n]
        return max(sum(4 * s.E * s.bending_I / s.h for element, s in self._elements if element == e) for e in elements)

    def sized_candidates(self) -> dict[str, Effect]:
        """The candidates sized to this machine (``bearing_candidates``), by name: at each bearing with nominal k its
        anisotropy, cross-coupled stiffness and damping, compliance, moment stiffness and speed-dependent damping;
        at each such bearing and each unbalance plane the 2X and 3X forces, their range the force that moves the
        rotor 10 um on its supports (sum of the bearings' k); the faults (``faults.fault_candidates``): looseness and
        a coupling's misalignment at each such bearing, a breathing crack and a rub at each unbalance plane. None on
        the VARM (no nominal k)."""
        out: dict[str, Effect] = {}
        for bearing in self.bearings:
            for candidate in at_bearing(bearing.name, bearing.k, bearing.c, self.tilt_stiffness(bearing.node)):
                out[candidate.name] = candidate
        force = EXCITATION_DISPLACEMENT_M * sum(b.k for b in self.bearings if b.k)
        places = ([(b.name, b.node, "bearing") for b in self.bearings if b.k]
                  + [(p.name, p.node, "unbalance plane") for p in self.unbalance_planes])
        for place, node, kind in places if force > 0 else ():
            for excitation in excitations_at(place, node, force, kind):
                out[excitation.name] = excitation
        for fault in fault_candidates(self, force):  # looseness, misalignment at the bearings; crack, rub at the planes
            out[fault.name] = fault
        return out

    def candidates(self) -> dict[str, Effect]:
        """The effects of ``effects()`` the diagnosis can test (those declaring ``switches``): the candidates sized
        to each bearing with nominal k, and the placeable built-in candidates at every bearing, by name."""
        return {name: e for name, e in self.effects().items() if e.switches}

    def to_mapping(self) -> dict:
        """The config form of this machine (``from_mapping``'s input, plain numbers and strings, ready for
        YAML): ``Machine.from_mapping(m.to_mapping())`` builds the same machine. Optional keys at their
        defaults are left out."""
        segments = []
        for s in self.segments:
            item = {"length": float(s.length), "d_out": float(s.d_out), "E": float(s.E), "rho": float(s.rho)}
            item |= {"d_in": float(s.d_in)} if s.d_in else {}
            item["n_elements"] = int(s.n_elements)
            item |= {k: float(getattr(s, k)) for k in ("I", "m", "G") if getattr(s, k) is not None}
            item |= {"node": int(s.node)} if s.node is not None else {}
            item |= {k: float(getattr(s, k)) for k in ("alpha", "beta") if getattr(s, k)}
            segments.append(item)
        out = {"name": self.name, "segments": segments}
        if self.disks:
            out["disks"] = [{"node": int(d.node), "mass": float(d.mass), "I_p": float(d.I_p), "I_d": float(d.I_d)}
                            | ({"name": d.name} if d.name else {}) for d in self.disks]
        if self.bearings:
            out["bearings"] = {b.name: {"node": int(b.node)} | ({"k": float(b.k)} if b.k is not None else {})
                               | ({"c": float(b.c)} if b.k is not None or b.c else {})
                               | ({"table": b.table.to_mapping()} if b.table is not None else {})
                               for b in self.bearings}
        if self.unbalance_planes:
            out["unbalance_planes"] = {p.name: int(p.node) for p in self.unbalance_planes}
        if self.sensors:
            out["sensors"] = {s.name: {"node": int(s.node), "direction": s.direction}
                              | ({"angle_deg": float(s.angle_deg)} if s.rotated else {}) for s in self.sensors}
        if self.rotary_inertia:
            out["rotary_inertia"] = True
        if self.shear:
            out["shear"] = True
        return out

    @cached_property
    def varm_structure(self) -> bool:
        """Whether this is the VARM's rotor (shaft, disks, bearings, unbalance plane), whatever its probes (e.g. the
        run-up example's rotated ones)."""
        def structure(machine: Machine) -> dict:
            return {k: v for k, v in machine.to_mapping().items() if k not in ("name", "sensors")}
        return self is _VARM or structure(self) == structure(_VARM)

    @property
    def is_varm(self) -> bool:
        """Whether this is the bundled default machine, the VARM (the same description as ``Machine.varm()``)."""
        return self is _VARM or self.to_mapping() == _VARM.to_mapping()

    def describe(self) -> str:
        """Multi-line summary: segments, disks, named nodes."""
        lines = [f"machine {self.name}: {self.n} elements, {self.n_nodes} nodes, L = {self.L:g} m"]
        node = 0
        for i, s in enumerate(self.segments):
            first = node if s.node is None else s.node
            lines.append(f"  {'segment' if s.node is None else 'layer'} {i}: nodes {first}..{first + s.n_elements}, "
                         f"length {s.length:g} m, "
                         f"d_out {s.d_out:g} m, d_in {s.d_in:g} m, E {s.E:g} Pa, rho {s.rho:g} kg/m^3"
                         + (f", I {s.I:g} m^4" if s.I is not None else "")
                         + (f", m {s.m:g} kg/m" if s.m is not None else "")
                         + (f", damping alpha {s.alpha:g} 1/s, beta {s.beta:g} s" if s.alpha or s.beta else ""))
            node += s.n_elements if s.node is None else 0
        for d in self.disks:
            lines.append(f"  disk {d.name or ''} at node {d.node}: mass {d.mass:g} kg, I_p {d.I_p:g}, "
                         f"I_d {d.I_d:g} kg m^2")
        for b in self.bearings:
            lines.append(f"  bearing {b.name} at node {b.node}"
                         + (f": k {b.k:g} N/m, c {b.c:g} N s/m" if b.k is not None else "")
                         + (f": {b.table.describe()}" if b.table is not None else ""))
        for p in self.unbalance_planes:
            lines.append(f"  unbalance plane {p.name} at node {p.node}")
        for s in self.sensors:
            lines.append(f"  sensor {s.name} at node {s.node}, direction {s.direction}"
                         + (f", angle {s.angle_deg:g} deg" if s.rotated else ""))
        return "\n".join(lines)


# --- effects of a described machine ---------------------------------------------------------------------


def _structure(ctx: Context, what: str):
    if not isinstance(ctx.shaft, Machine):
        raise ValueError(f"effect {what!r} needs a Machine (its polar inertia or named places), "
                         f"the model is built on a {type(ctx.shaft).__name__}")
    return ctx.shaft


class Gyroscopic(Effect):
    """Gyroscopic coupling Omega G q' (G from ``Machine.gyroscopic_matrix``): disks and shaft sections."""

    name = "gyroscopic"
    meaning = ("gyroscopic coupling of the spinning disks and shaft sections, Omega G in the damping "
               "(off in the paper's VARM model)")

    def damping(self, ctx: Context) -> Array:
        G = _structure(ctx, self.name).gyroscopic_matrix()
        return ctx.Omega[:, None, None] * G[None]


class ShaftDamping(Effect):
    """The shaft's proportional damping C = sum alpha M_e + beta K_e of its segments
    (``Machine.shaft_damping_matrix``), offered when a segment gives alpha or beta."""

    name = "shaft_damping"
    meaning = "the shaft's proportional (Rayleigh) damping alpha M_e + beta K_e of its segments' elements"

    def damping(self, ctx: Context) -> Array:
        C = _structure(ctx, self.name).shaft_damping_matrix()
        return np.broadcast_to(C, (ctx.n_scenarios,) + C.shape)


@dataclass(eq=False)
class LinearBearing(Effect):
    """An isotropic linear bearing at a node: spring k and damper c on both translational DOFs.

    Parameters ``k_<bearing>`` [N/m] and ``c_<bearing>`` [N s/m], nominal the machine's values, default
    range a factor 2 either side (k, c never negative).
    """

    name: str = "linear_bearing"
    bearing: str = ""
    node: int = 0
    k: float = 0.0
    c: float = 0.0
    meaning: str = field(init=False)
    parameters: tuple[Parameter, ...] = field(init=False)

    def __post_init__(self) -> None:
        self.meaning = f"linear isotropic bearing {self.bearing or self.node}: spring k and damper c at node {self.node}"
        suffix = self.bearing or str(self.node)
        self._k, self._c = f"k_{suffix}", f"c_{suffix}"
        self.parameters = (
            Parameter(self._k, "N/m", (0.5 * self.k, 2.0 * self.k), self.k, f"stiffness of bearing {suffix}",
                      (0.0, np.inf)),
            Parameter(self._c, "N s/m", (0.5 * self.c, 2.0 * self.c), self.c, f"damping of bearing {suffix}",
                      (0.0, np.inf)),
        )

    def _point(self, ctx: Context, value: Array) -> LocalMatrix:
        return LocalMatrix.diagonal((ctx.dof(f"u{self.node}"), ctx.dof(f"v{self.node}")), value, ctx.n_scenarios)

    def stiffness(self, ctx: Context) -> LocalMatrix:
        return self._point(ctx, ctx.p[self._k])

    def damping(self, ctx: Context) -> LocalMatrix:
        return self._point(ctx, ctx.p[self._c])


_M_E, _R_ME = Unbalance.parameters[0], Unbalance.parameters[1]


@dataclass(eq=False)
class PlaneUnbalance(Effect):
    """The eccentric mass m_e at radius r_me fixed at a node (an unbalance plane): its point mass and the
    rotating force m_e r_me Omega^2 at angle_me, F_1 = m_e r_me Omega^2 exp(i angle_me) in x and -i times that in
    y (as ``Unbalance``, whose parameters m_e, r_me and angle_me it shares, with the node instead of z_me)."""

    name: str = "unbalance_plane"
    node: int = 0
    meaning: str = field(init=False)
    parameters: tuple[Parameter, ...] = (_M_E, _R_ME, ANGLE_ME)

    def __post_init__(self) -> None:
        self.meaning = (f"eccentric mass at node {self.node}: its point mass and the rotating force "
                        "m_e r_me Omega^2 (eq. 14-15)")

    def mass(self, ctx: Context) -> LocalMatrix:
        return LocalMatrix.diagonal((ctx.dof(f"u{self.node}"), ctx.dof(f"v{self.node}")), ctx.p.m_e, ctx.n_scenarios)

    def forcing(self, ctx: Context) -> dict[int, Array]:
        f = ctx.zero_vector()
        f[:, ctx.dof(f"u{self.node}")], f[:, ctx.dof(f"v{self.node}")] = trial_force(
            ctx, ctx.p.m_e * ctx.p.r_me * ctx.Omega**2)
        return {1: f}


class MachineUnbalance(Unbalance):
    """The built-in ``unbalance`` (the eccentric mass at the node nearest z_me) on a machine of one's own: z_me
    ranges over the machine's length [0, L] (the VARM's is 0-0.85 m), nominal at its first unbalance plane, or
    none without one (NaN: the variant gives z_me under ``fixed:`` or ``unknown:``, ``Variant.from_spec`` says
    so), never the VARM's 0.425 m by default."""

    def __init__(self, machine: str, length: float, z: float | None):
        where = f"the first unbalance plane's, z = {z:g} m" if z is not None else "none: give it"
        self.parameters = (_M_E, _R_ME, Parameter(
            "z_me", "m", (0.0, float(length)), np.nan if z is None else float(z),
            f"axial position of the eccentric mass along machine {machine!r} (0-{length:g} m; nominal {where})",
            (0.0, float(length))), ANGLE_ME)


def default_machine() -> Machine:
    """The bundled default machine, the VARM."""
    return _VARM


_VARM = Machine.varm()
