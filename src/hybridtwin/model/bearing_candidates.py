"""Candidate effects at a named bearing of a machine, their ranges sized to that bearing (docs/model.md,
"Describing your machine"; docs/diagnosis.md).

The VARM's built-in candidates act at its upper bearing (node 0) with ranges sized for its 2400 N/m springs.
On a machine of your own, every bearing given nominal coefficients (``machine: bearings: NAME: {node, k, c}``)
also offers, by name:

- ``bearing_anisotropy@NAME``: K[u, u] += dk_NAME, K[v, v] -= dk_NAME at the bearing's node (stiffer along x than
  along y, mean unchanged). Range +-20 % of k, where a split of the critical speeds moves the probes' 1X
  visibly; limits +-50 % of k, which keep both directions' stiffness positive for a variant that lets k itself
  fall to three quarters of its nominal value.
- ``cross_coupled_stiffness@NAME``: K[u, v] = +kxy_NAME, K[v, u] = -kxy_NAME (a force kxy (-v, u) along the rotation
  for kxy > 0: oil film, seal, rub). Range +-1 % of k, limits +-10 % of k: a circulatory stiffness of a few
  per cent of the bearing's drives lightly damped forward modes unstable (the stability check of a refit then
  rejects such an optimum: no steady unbalance response exists there).
- ``cross_coupled_damping@NAME`` (for a bearing with c > 0): C[u, v] = +cxy_NAME, C[v, u] = -cxy_NAME (on a forward
  whirl at Omega, a stiffness +Omega cxy). Range +-40 % of c, limits +-4 c.

Each is absent at 0 (its ``switches``), so the diagnosis tests it like any candidate; list them under
``diagnosis: candidates`` (one line each), or leave that null to test all of them at every bearing. The node is
read from the machine the model is built on (``ctx.shaft.node(NAME)``), so the effect follows the machine.
"""

from __future__ import annotations

from .effect_base import Context, Parameter
from .effects import ANISOTROPIC, SKEW, BearingTerm, CrossCoupledDamping, CrossCoupledStiffness, UpperBearingAnisotropy

#: range and limits of each candidate as fractions of the bearing's k (stiffness terms) or c (damping)
ANISOTROPY_RANGE, ANISOTROPY_LIMIT = 0.2, 0.5
CROSS_STIFFNESS_RANGE, CROSS_STIFFNESS_LIMIT = 0.01, 0.1
CROSS_DAMPING_RANGE, CROSS_DAMPING_LIMIT = 0.4, 4.0


class AtBearing(BearingTerm):
    """An effect at one named bearing of the machine with one parameter that switches it on (absent at 0): the
    VARM's upper-bearing term of the same kind (``effects.BearingTerm``) at the bearing's node."""

    kind, symbol, unit, what = "", "", "", ""

    def __init__(self, bearing: str, half_range: float, limit: float):
        if not (half_range > 0 and limit >= half_range):
            raise ValueError(f"{self.kind}@{bearing}: need 0 < range {half_range:g} <= limit {limit:g}")
        self.bearing = bearing
        self.name = f"{self.kind}@{bearing}"
        self.meaning = f"{self.what} at bearing {bearing}"
        self.parameters = (Parameter(f"{self.symbol}_{bearing}", self.unit, (-half_range, half_range), 0.0,
                                     f"{self.what} at bearing {bearing}", (-limit, limit)),)
        self.switches = (self.parameters[0].name,)

    def bearing_node(self, ctx: Context) -> int:
        return ctx.shaft.node(self.bearing)


class BearingAnisotropy(AtBearing):
    """K[u, u] += dk, K[v, v] -= dk at the bearing: stiffer along x than along y by 2 dk, mean unchanged."""

    kind, symbol, unit, what = "bearing_anisotropy", "dk", "N/m", "stiffness along x minus the mean"
    pairs = ANISOTROPIC
    stiffness = UpperBearingAnisotropy.stiffness


class BearingCrossCoupledStiffness(AtBearing):
    """K[u, v] = +kxy, K[v, u] = -kxy at the bearing: a force kxy (-v, u) perpendicular to the deflection."""

    kind, symbol, unit, what = "cross_coupled_stiffness", "kxy", "N/m", "cross-coupled stiffness"
    pairs = SKEW
    stiffness = CrossCoupledStiffness.stiffness


class BearingCrossCoupledDamping(AtBearing):
    """C[u, v] = +cxy, C[v, u] = -cxy at the bearing: a skew-symmetric damping, force cxy (-v', u')."""

    kind, symbol, unit, what = "cross_coupled_damping", "cxy", "N s/m", "cross-coupled damping"
    pairs = SKEW
    damping = CrossCoupledDamping.damping


def at_bearing(name: str, k: float | None, c: float = 0.0) -> list[AtBearing]:
    """The candidates of a bearing ``name`` with nominal stiffness ``k`` [N/m] and damping ``c`` [N s/m], their
    ranges sized to them (module docstring); none without k, no cross-coupled damping without c."""
    if k is None or not k > 0:
        return []
    out: list[AtBearing] = [BearingAnisotropy(name, ANISOTROPY_RANGE * k, ANISOTROPY_LIMIT * k),
                            BearingCrossCoupledStiffness(name, CROSS_STIFFNESS_RANGE * k, CROSS_STIFFNESS_LIMIT * k)]
    if c > 0:
        out.append(BearingCrossCoupledDamping(name, CROSS_DAMPING_RANGE * c, CROSS_DAMPING_LIMIT * c))
    return out
