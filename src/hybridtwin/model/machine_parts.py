"""The parts a ``Machine`` is described by and their config form (docs/model.md, "Describing your machine").

The parts: shaft segments (``ShaftSegment``), rigid disks (``Disk``), named bearings (``Bearing``), unbalance planes
(``UnbalancePlane``) and displacement probes (``Sensor``), each checking its own values. Their config form: the
``machine:`` section's items read into parts (``build_part``, ``bearing_from_spec``; ``Machine.from_mapping`` reads the
section with them), every problem a ``MachineSpecError`` that says where in the section it is. The machine they make up,
its discretisation and the effects placed at its named nodes are ``hybridtwin.model.machine``'s.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .bearing_table import BearingTable
from .probes import DEFAULT_ANGLE_DEG
from .shaft import shear_phi


@dataclass(frozen=True)
class ShaftSegment:
    """A uniform piece of the shaft: ``n_elements`` equal beam elements.

    length, d_out, d_in [m], E [Pa], rho [kg/m^3]. The bending stiffness uses I = pi (d_out^4 - d_in^4) / 64
    and the mass per unit length rho A, unless ``I`` [m^4] or ``m`` [kg/m] give them directly (the VARM's
    Table 1 values). The sections' rotary and polar inertia always come from the diameters and rho. ``G``: the
    shear modulus [Pa], read only by a machine with ``shear`` (Timoshenko beams); default E / (2 (1 + 0.3)),
    steel's Poisson ratio 0.3.

    ``node``: None (the default), the segment continues the shaft after the previous one. An integer: the segment is
    a *layer* lying over the shaft from that node on (a sleeve shrunk on it, an impeller's hub; ROSS's several shaft
    elements at one node): its ``n_elements`` elements each span the shaft's element there (the same length) and
    their matrices add to the shaft's (``Machine``).

    ``alpha`` [1/s], ``beta`` [s]: proportional (Rayleigh) damping of the segment's elements, C_e = alpha M_e + beta K_e
    (ROSS's ShaftElement alpha, beta), the effect ``shaft_damping`` (``Machine.effects``); default 0.
    """

    length: float
    d_out: float
    E: float
    rho: float
    d_in: float = 0.0
    n_elements: int = 1
    I: float | None = None
    m: float | None = None
    G: float | None = None
    node: int | None = None
    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self) -> None:
        for name in ("length", "d_out", "E", "rho"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"shaft segment: {name} must be a positive number, got {value!r}")
        if not 0.0 <= self.d_in < self.d_out:
            raise ValueError(f"shaft segment: d_in must be in [0, d_out = {self.d_out}), got {self.d_in!r}")
        if isinstance(self.n_elements, bool) or not isinstance(self.n_elements, (int, np.integer)) \
                or self.n_elements < 1:
            raise ValueError(f"shaft segment: n_elements must be a positive integer, got {self.n_elements!r}")
        for name in ("I", "m", "G"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"shaft segment: {name} must be positive when given, got {value!r}")
        if self.node is not None and (isinstance(self.node, bool) or not isinstance(self.node, (int, np.integer))
                                      or self.node < 0):
            raise ValueError(f"shaft segment: node (a layer's first node) must be an integer >= 0, got {self.node!r}")
        for name in ("alpha", "beta"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                raise ValueError(f"shaft segment: {name} (proportional damping) must be a number >= 0, got {value!r}")

    @property
    def area(self) -> float:
        """Cross-section area pi (d_out^2 - d_in^2) / 4 [m^2]."""
        return np.pi * (self.d_out**2 - self.d_in**2) / 4

    @property
    def section_I(self) -> float:
        """Second moment of area of the annulus, pi (d_out^4 - d_in^4) / 64 [m^4]."""
        return np.pi * (self.d_out**4 - self.d_in**4) / 64

    @property
    def bending_I(self) -> float:
        """The I of the bending stiffness: ``I`` when given, else ``section_I`` [m^4]."""
        return self.section_I if self.I is None else self.I

    @property
    def mass_per_length(self) -> float:
        """``m`` when given, else rho A [kg/m]."""
        return self.rho * self.area if self.m is None else self.m

    @property
    def h(self) -> float:
        """Element length [m]."""
        return self.length / self.n_elements

    @property
    def shear_modulus(self) -> float:
        """``G`` when given, else E / (2 (1 + 0.3)) [Pa]."""
        return self.E / 2.6 if self.G is None else self.G

    def phi(self, shear: bool) -> float:
        """The element's shear parameter 12 E I / (kappa G A h^2) with ``shear`` (``shaft.shear_phi``), else 0."""
        return shear_phi(self.h, self.E, self.shear_modulus, self.bending_I, self.area, self.d_in, self.d_out) \
            if shear else 0.0


@dataclass(frozen=True)
class Disk:
    """A rigid disk at a node: mass [kg], polar I_p and transverse (diametral) I_d inertia [kg m^2]."""

    node: int
    mass: float
    I_p: float = 0.0
    I_d: float = 0.0
    name: str = ""


@dataclass(frozen=True)
class Bearing:
    """A named bearing position. ``k`` [N/m], ``c`` [N s/m]: nominal isotropic coefficients of the effect
    ``linear_bearing@<name>`` (offered only when ``k`` is given). Or ``table``: its eight coefficients against
    speed (``bearing_table.BearingTable``), the effect ``bearing_table@<name>``; not both."""

    name: str
    node: int
    k: float | None = None
    c: float = 0.0
    table: BearingTable | None = None

    def __post_init__(self) -> None:
        if self.table is not None and not isinstance(self.table, BearingTable):
            raise ValueError(f"bearing {self.name!r}: table must be a BearingTable, got {type(self.table).__name__}")
        if self.table is not None and (self.k is not None or self.c):
            raise ValueError(f"bearing {self.name!r}: give either k (and c) or a table, not both")


@dataclass(frozen=True)
class UnbalancePlane:
    """A named plane (node) where an eccentric mass can be fixed."""

    name: str
    node: int


@dataclass(frozen=True)
class Sensor:
    """A displacement probe: ``name`` (its channel), ``node``, ``direction`` "x" or "y" (its place in its plane's
    pair: the x probe, the y probe), ``angle_deg`` its mounting angle in the cross-section from +x towards +y
    (the direction of rotation; default 0 for direction x, 90 for y: along the model's x, y). A probe reads
    x cos(a) + y sin(a) (``hybridtwin.model.probes``)."""

    name: str
    node: int
    direction: str
    angle_deg: float | None = None

    def __post_init__(self) -> None:
        if self.direction not in ("x", "y"):
            raise ValueError(f"sensor {self.name!r}: direction must be 'x' or 'y', got {self.direction!r}")
        if self.angle_deg is None:
            object.__setattr__(self, "angle_deg", DEFAULT_ANGLE_DEG[self.direction])
        elif isinstance(self.angle_deg, bool) or not np.isfinite(self.angle_deg):
            raise ValueError(f"sensor {self.name!r}: angle_deg must be a finite number of degrees, got "
                             f"{self.angle_deg!r}")
        else:
            object.__setattr__(self, "angle_deg", float(self.angle_deg))

    @property
    def rotated(self) -> bool:
        """Whether the probe stands at another angle than its direction's default (0 for x, 90 for y)."""
        return self.angle_deg != DEFAULT_ANGLE_DEG[self.direction]


class MachineSpecError(ValueError):
    """A bad ``machine:`` section: ``path`` (keys inside the section) and a one-line message."""

    def __init__(self, path: tuple, message: str):
        self.path, self.message = tuple(path), message
        where = "machine" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in self.path)
        super().__init__(f"{where}: {message}")


def spec_mapping(value, path: tuple) -> Mapping:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise MachineSpecError(path, f"must be a mapping, got {value!r}")
    return value


def spec_sequence(spec: Mapping, key: str) -> list:
    value = spec.get(key)
    if value is None:
        return []
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Sequence):
        raise MachineSpecError((key,), f"must be a list, got {value!r}")
    return list(value)


def check_known_keys(spec: Mapping, path: tuple, allowed: set[str]) -> None:
    stray = sorted(set(map(str, spec)) - allowed)
    if stray:
        raise MachineSpecError(path, f"unknown key(s) {stray} (allowed: {', '.join(sorted(allowed))})")


def bearing_from_spec(name, item) -> Bearing:
    """A bearing from its config form: node, and k (and c) or a table (``BearingTable.from_mapping``)."""
    path = ("bearings", name)
    item = dict(spec_mapping(item, path))
    spec = item.pop("table", None)
    bearing = build_part(Bearing, {"name": name, **item}, path, {"name", "node"}, {"k", "c", "table"})
    if spec is None:
        return bearing
    try:
        table = BearingTable.from_mapping(spec)
    except ValueError as err:
        raise MachineSpecError(path + ("table",), str(err)) from None
    try:
        return dataclasses.replace(bearing, table=table)
    except ValueError as err:
        raise MachineSpecError(path, str(err)) from None


def build_part(kind: type, item, path: tuple, required: set[str], optional: set[str]):
    item = spec_mapping(item, path)
    check_known_keys(item, path, required | optional)
    missing = sorted(required - set(item))
    if missing:
        raise MachineSpecError(path, f"missing key(s) {missing}")
    for key, value in item.items():
        if key not in ("name", "direction") and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise MachineSpecError(path + (key,), f"must be a number, got {value!r}")
    try:
        return kind(**item)
    except ValueError as err:
        raise MachineSpecError(path, str(err)) from None
