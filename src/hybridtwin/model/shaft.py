"""Euler-Bernoulli finite-element shaft of the VARM (docs/model.md, "Shaft").

Degrees of freedom (44 for n = 10 elements). Per node i, per bending plane, a
deflection and a slope (theta = dw/dz). Global ordering::

    x plane: u_i  -> 2 i,          du_i (= du/dz) -> 2 i + 1
    y plane: v_i  -> 2 (n+1) + 2 i, dv_i (= dv/dz) -> 2 (n+1) + 2 i + 1

so the x plane is the first block of 2 (n+1) DOFs and the y plane the second.
DOF names used across the package: ``u3``, ``v3``, ``du3``, ``dv3`` (node 3).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_DOF_NAME = re.compile(r"^(u|v|du|dv)(\d+)$")


class DofCounts:
    """Node and DOF counts of a beam mesh of ``n`` elements (u, v, their slopes at each node), shared by the
    uniform ``Shaft`` and a ``machine.Machine`` of segments."""

    n: int

    @property
    def n_nodes(self) -> int:
        return self.n + 1

    @property
    def n_plane(self) -> int:
        """DOFs per bending plane, 2 (n + 1)."""
        return 2 * self.n_nodes

    @property
    def n_dof(self) -> int:
        """All DOFs, 4 (n + 1) (44 for n = 10)."""
        return 2 * self.n_plane


@dataclass(frozen=True)
class Shaft(DofCounts):
    """Uniform Euler-Bernoulli shaft, z pointing down from the upper bearing (z = 0).

    Defaults are the paper's Table 1 (SI units). ``I`` uses Table 1's value,
    ten times pi r^4 / 4 (see docs/model.md, the note on I).
    """

    L: float = 0.850  # shaft length [m]
    n: int = 10  # number of beam elements
    E: float = 110.3e9  # Young's modulus [Pa]
    I: float = 79.81e-11  # area moment of inertia [m^4]
    m: float = 0.35  # mass per unit length [kg/m]

    def __post_init__(self) -> None:
        for name in ("L", "E", "I", "m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"shaft: {name} must be positive, got {getattr(self, name)!r}")
        if int(self.n) != self.n or self.n < 1:
            raise ValueError(f"shaft: n must be a positive integer, got {self.n!r}")

    @property
    def h(self) -> float:
        """Element length L / n [m]."""
        return self.L / self.n

    @property
    def z(self) -> np.ndarray:
        """Node positions z_i = i h [m]."""
        return np.arange(self.n_nodes) * self.h

    def node_at(self, z: float) -> int:
        """Index of the node nearest to axial position ``z`` [m]."""
        if not 0.0 <= z <= self.L:
            raise ValueError(f"shaft: position z = {z} m lies outside the shaft [0, {self.L}] m")
        return int(np.rint(z / self.h))

    def dof(self, name: str) -> int:
        """Global index of a named DOF, e.g. ``dof("u0")`` or ``dof("dv10")``."""
        match = _DOF_NAME.match(name)
        if match is None:
            raise ValueError(f"unknown DOF name {name!r}: expected u<i>, v<i>, du<i> or dv<i>")
        kind, node = match.group(1), int(match.group(2))
        if node >= self.n_nodes:
            raise ValueError(f"DOF {name!r}: node {node} does not exist (nodes 0..{self.n})")
        plane = 0 if kind in ("u", "du") else self.n_plane
        return plane + 2 * node + (1 if kind.startswith("d") else 0)

    def translational(self, plane: str = "x") -> np.ndarray:
        """Global indices of the deflection DOFs of one plane, node 0..n."""
        offset = 0 if plane == "x" else self.n_plane
        return offset + 2 * np.arange(self.n_nodes)

    def element_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Element stiffness and consistent mass matrices, DOFs [w1, theta1, w2, theta2].

        K_e = EI/h^3 [...] and M_e = m h / 420 [...] (cubic Hermite shape functions,
        docs/model.md, "Discretisation").
        """
        return beam_element(self.h, self.E * self.I, self.m)

    def plane_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Assembled stiffness and mass of one bending plane (2(n+1) square), free ends."""
        K_e, M_e = self.element_matrices()
        K = np.zeros((self.n_plane, self.n_plane))
        M = np.zeros_like(K)
        for e in range(self.n):
            s = slice(2 * e, 2 * e + 4)
            K[s, s] += K_e
            M[s, s] += M_e
        return K, M

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Stiffness and mass of both planes (uncoupled blocks), n_dof square."""
        K_p, M_p = self.plane_matrices()
        zero = np.zeros_like(K_p)
        return np.block([[K_p, zero], [zero, K_p]]), np.block([[M_p, zero], [zero, M_p]])


def beam_element(h: float, EI: float, m: float, phi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Beam element of length ``h``, bending stiffness ``EI`` [N m^2] and mass per unit length ``m`` [kg/m], DOFs
    [w1, theta1, w2, theta2] of one plane (docs/model.md, "Discretisation").

    ``phi`` = 0: Euler-Bernoulli, K_e = EI/h^3 [...] and the consistent mass M_e = m h / 420 [...] (cubic Hermite
    shape functions). ``phi`` = 12 EI / (kappa G A h^2) > 0: Timoshenko, shear deformation in the shape functions
    (Friswell et al., Dynamics of Rotating Machines, 2010, sec. 5.4; ``shear_phi``): K_e = EI / (h^3 (1 + phi))
    [[12, 6h, -12, 6h], [6h, (4 + phi) h^2, -6h, (2 - phi) h^2], ...] and the translational mass
    m h / (840 (1 + phi)^2) [[312 + 588 phi + 280 phi^2, (44 + 77 phi + 35 phi^2) h, ...], ...]."""
    if phi:
        return _timoshenko(h, EI, m, phi)
    K_e = EI / h**3 * np.array(
        [
            [12, 6 * h, -12, 6 * h],
            [6 * h, 4 * h * h, -6 * h, 2 * h * h],
            [-12, -6 * h, 12, -6 * h],
            [6 * h, 2 * h * h, -6 * h, 4 * h * h],
        ]
    )
    M_e = m * h / 420 * np.array(
        [
            [156, 22 * h, 54, -13 * h],
            [22 * h, 4 * h * h, 13 * h, -3 * h * h],
            [54, 13 * h, 156, -22 * h],
            [-13 * h, -3 * h * h, -22 * h, 4 * h * h],
        ]
    )
    return K_e, M_e


def _timoshenko(h: float, EI: float, m: float, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """``beam_element`` with shear (phi > 0)."""
    p2 = phi * phi
    K_e = EI / (h**3 * (1 + phi)) * np.array(
        [
            [12, 6 * h, -12, 6 * h],
            [6 * h, (4 + phi) * h * h, -6 * h, (2 - phi) * h * h],
            [-12, -6 * h, 12, -6 * h],
            [6 * h, (2 - phi) * h * h, -6 * h, (4 + phi) * h * h],
        ]
    )
    a, b = 312 + 588 * phi + 280 * p2, (44 + 77 * phi + 35 * p2) * h
    c, d = 108 + 252 * phi + 140 * p2, (26 + 63 * phi + 35 * p2) * h
    e, f = (8 + 14 * phi + 7 * p2) * h * h, (6 + 14 * phi + 7 * p2) * h * h
    M_e = m * h / (840 * (1 + phi) ** 2) * np.array([[a, b, c, -d], [b, e, d, -f], [c, d, a, -b], [-d, -f, -b, e]])
    return K_e, M_e


def slope_element(h: float, inertia: float, phi: float = 0.0) -> np.ndarray:
    """integral of inertia * N'^T N' dz over an element of length ``h`` (N the beam's shape functions),
    DOFs [w1, theta1, w2, theta2]: the consistent rotary-inertia matrix for ``inertia`` = rho I [kg m] (the
    section's diametral inertia per unit length) and the gyroscopic block for rho I_p = 2 rho I.
    ``phi`` = 0 (Euler-Bernoulli): inertia / (30 h) [[36, 3h, -36, 3h], [3h, 4h^2, -3h, -h^2], [-36, -3h, 36, -3h],
    [3h, -h^2, -3h, 4h^2]]; ``phi`` > 0 (Timoshenko, ``beam_element``): inertia / (30 h (1 + phi)^2)
    [[36, (3 - 15 phi) h, ...], [., (4 + 5 phi + 10 phi^2) h^2, ., (-1 - 5 phi + 5 phi^2) h^2], ...]."""
    if phi:
        g = (3 - 15 * phi) * h
        e, f = (4 + 5 * phi + 10 * phi * phi) * h * h, (-1 - 5 * phi + 5 * phi * phi) * h * h
        return inertia / (30 * h * (1 + phi) ** 2) * np.array(
            [[36, g, -36, g], [g, e, -g, f], [-36, -g, 36, -g], [g, f, -g, e]])
    return inertia / (30 * h) * np.array(
        [
            [36, 3 * h, -36, 3 * h],
            [3 * h, 4 * h * h, -3 * h, -h * h],
            [-36, -3 * h, 36, -3 * h],
            [3 * h, -h * h, -3 * h, 4 * h * h],
        ]
    )


def shear_phi(h: float, E: float, G: float, I: float, area: float, d_in: float, d_out: float) -> float:
    """phi = 12 E I / (kappa G A h^2) of a Timoshenko element of length ``h`` (``beam_element``), with Cowper's
    shear coefficient of a hollow circular section (Cowper 1966; the one ROSS uses by default), r = d_in / d_out,
    nu = E / (2 G) - 1: kappa = 6 (1 + nu) (1 + r^2)^2 / ((7 + 6 nu) (1 + r^2)^2 + (20 + 12 nu) r^2)."""
    nu = E / (2 * G) - 1
    r2 = (d_in / d_out) ** 2
    kappa = 6 * (1 + nu) * (1 + r2) ** 2 / ((7 + 6 * nu) * (1 + r2) ** 2 + (20 + 12 * nu) * r2)
    return 12 * E * I / (kappa * G * area * h * h)
