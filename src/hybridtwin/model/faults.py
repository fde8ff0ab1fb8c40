"""Faults as effects (issue 54, item 4; docs/model.md, "Faults"): a rub of the rotor on a stator ring.

``Rub``: at a node, a stator ring of radial clearance delta; where the shaft's deflection r = |(u, v)| exceeds it,
the ring pushes back with a normal force N = k_rub (r - delta) and a Coulomb friction mu N against the sliding of
the shaft's surface, which turns from +x towards +y (the surface speed Omega R of a rotor far exceeds its whirl
speed, so the friction's sense is the rotation's, whatever the whirl):

    F_u = -g (u - mu v),   F_v = -g (v + mu u),   g = k_rub max(0, 1 - delta / r)

(the normal part -N (u, v) / r, the friction -mu N (-v, u) / r). Non-smooth at r = delta: the harmonic balance
samples it at 64 instants a period (``solver.default_n_time`` for a force of no polynomial degree) and the time
integrator evaluates it as it is. Absent at k_rub = 0; not a built-in candidate (the score test at k_rub = 0 sees
it only where the fitted orbit already reaches the clearance). Place it with ``Rub(node=..., place=...)`` in a
file under the config's ``effects_files`` (its parameters then named delta_PLACE, k_rub_PLACE, mu_PLACE), or
``Machine.place(Rub(), "bearing")``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effect_base import Array, Effect, Parameter, Params


@dataclass(eq=False)
class Rub(Effect):
    """Rub on a stator ring of clearance delta at ``node`` (module docstring)."""

    name: str = "rub"
    node: int = 0
    place: str = ""
    clearance_m: tuple[float, float] = (1e-4, 1e-2)
    stiffness_n_m: tuple[float, float] = (0.0, 1e5)
    meaning: str = "rub on a stator ring at node 0: normal contact force k_rub (r - delta) beyond the clearance, " \
                   "Coulomb friction mu along the rotation"
    parameters: tuple[Parameter, ...] = field(init=False)
    dofs: tuple[str, ...] = field(init=False)
    degree: int | None = None

    def __post_init__(self) -> None:
        suffix = f"_{self.place}" if self.place else "" if self.node == 0 else f"_{self.node}"
        self._names = (f"delta{suffix}", f"k_rub{suffix}", f"mu{suffix}")
        lo, hi = self.clearance_m
        self.parameters = (
            Parameter(self._names[0], "m", (lo, hi), float(np.sqrt(lo * hi)),
                      f"radial clearance of the stator ring at node {self.node}", (0.0, np.inf)),
            Parameter(self._names[1], "N/m", self.stiffness_n_m, 0.0,
                      f"contact stiffness of the ring at node {self.node} (0: no rub)", (0.0, np.inf)),
            Parameter(self._names[2], "1", (0.0, 0.5), 0.2, "Coulomb friction coefficient of the contact",
                      (0.0, 2.0)),
        )
        self.dofs = (f"u{self.node}", f"v{self.node}")
        self.meaning = self.meaning.replace("at node 0", f"at node {self.node}")

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        """F (S, 2, N) on the shaft at (u, v) and its derivative (S, 2, 2, N) (module docstring); zero inside the
        clearance."""
        delta, k, mu = (p[name][:, None] for name in self._names)
        u, v = q[:, 0], q[:, 1]
        r = np.hypot(u, v)
        contact = r > delta
        safe = np.where(contact, r, 1.0)
        g = np.where(contact, k * (1.0 - delta / safe), 0.0)
        dg = np.where(contact, k * delta / safe**3, 0.0)  # dg/du = dg u, dg/dv = dg v
        a, b = u - mu * v, v + mu * u
        F = np.stack([-g * a, -g * b], axis=1)
        J = np.empty(q.shape[:1] + (2, 2) + q.shape[2:])
        J[:, 0, 0] = -dg * u * a - g
        J[:, 0, 1] = -dg * v * a + g * mu
        J[:, 1, 0] = -dg * u * b - g * mu
        J[:, 1, 1] = -dg * v * b - g
        return F, J
