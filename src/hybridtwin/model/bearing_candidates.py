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

- ``bearing_compliance@NAME``: K[u, u] = K[v, v] += dkiso_NAME (the bearing's stiffness, or its support's, is not
  its nominal k: a softer pedestal, a worn or looser bearing). Range +-20 % of k, limits -99 % .. +900 % of k
  (the stiffness stays positive and below ten times its value).
- ``moment_stiffness@NAME``: K[du, du] = K[dv, dv] += krot_NAME, a moment against the shaft's tilt at the bearing
  (a wide or preloaded bearing clamping part of the slope). Range 0 .. 7 % of the shaft element's 4 E I / h there,
  limits 0 .. 4 E I / h (beyond, the slope is clamped and more changes nothing); not negative: a support does not
  push the tilt further. For a bearing of a machine (``Machine.candidates``), whose element it reads.
- ``bearing_speed_damping@NAME`` (for a bearing with c > 0): C[u, u] = C[v, v] += cv_NAME c Omega / omega_1, the
  bearing's damping growing (or falling) in proportion to the speed (omega_1: the lowest natural frequency of
  the x plane at rest). Range +-0.4 (the damping +-40 % of c at the first critical speed), limits -1 .. 4.
- ``excitation_2x@PLACE``, ``excitation_3x@PLACE`` at every bearing and unbalance plane (``Machine.candidates``):
  the forward-rotating 2X, 3X force of ``effects.HarmonicExcitation`` (misalignment, a coupling, a rub, a
  cracked shaft's breathing) at that node, parameters f2_c_PLACE, f2_s_PLACE [N]. Range +-(1e-5 m x the sum of
  the bearings' k): the force that would move the rotor by 10 um on its supports, a proximity probe's scale;
  limits ten times that.

Each is absent at 0 (its ``switches``), so the diagnosis tests it like any candidate; list them under
``diagnosis: candidates`` (one line each), or leave that null to test all of them at every bearing. The node is
read from the machine the model is built on (``ctx.shaft.node(NAME)``), so the effect follows the machine.
"""

from __future__ import annotations

import numpy as np

from .effect_base import Array, Context, Parameter
from .effects import (ANISOTROPIC, SKEW, BearingTerm, CrossCoupledDamping, CrossCoupledStiffness, HarmonicExcitation,
                      UpperBearingAnisotropy, dof_entries)

#: range and limits of each candidate as fractions of the bearing's k (stiffness terms) or c (damping)
ANISOTROPY_RANGE, ANISOTROPY_LIMIT = 0.2, 0.5
CROSS_STIFFNESS_RANGE, CROSS_STIFFNESS_LIMIT = 0.01, 0.1
CROSS_DAMPING_RANGE, CROSS_DAMPING_LIMIT = 0.4, 4.0
COMPLIANCE_RANGE, COMPLIANCE_LIMITS = 0.2, (-0.99, 9.0)
#: of the shaft element's 4 E I / h at the bearing (the VARM's moment_stiffness: 300 of 4140 N m/rad)
MOMENT_RANGE, MOMENT_LIMIT = 0.07, 1.0
SPEED_DAMPING_RANGE, SPEED_DAMPING_LIMITS = 0.4, (-1.0, 4.0)
#: the displacement [m] the 2X, 3X forces' range would give the rotor on its supports (sum of the bearings' k)
EXCITATION_DISPLACEMENT_M, EXCITATION_LIMIT = 1e-5, 10.0


class AtBearing(BearingTerm):
    """An effect at one named bearing of the machine with one parameter that switches it on (absent at 0): the
    VARM's upper-bearing term of the same kind (``effects.BearingTerm``) at the bearing's node."""

    kind, symbol, unit, what = "", "", "", ""

    def __init__(self, bearing: str, half_range: float, limit: float,
                 bounds: tuple[float, float] | None = None, limits: tuple[float, float] | None = None):
        """A parameter in +-half_range, limits +-limit; or in ``bounds`` with ``limits`` (each holding 0)."""
        bounds = (-half_range, half_range) if bounds is None else bounds
        limits = (-limit, limit) if limits is None else limits
        if not (bounds[0] <= 0.0 <= bounds[1] and bounds[0] < bounds[1] and limits[0] <= bounds[0]
                and bounds[1] <= limits[1]):
            raise ValueError(f"{self.kind}@{bearing}: need a range {bounds} holding 0 inside its limits {limits}")
        self.bearing = bearing
        self.name = f"{self.kind}@{bearing}"
        self.meaning = f"{self.what} at bearing {bearing}"
        self.parameters = (Parameter(f"{self.symbol}_{bearing}", self.unit, tuple(map(float, bounds)), 0.0,
                                     f"{self.what} at bearing {bearing}", tuple(map(float, limits))),)
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


class BearingCompliance(AtBearing):
    """K[u, u] = K[v, v] += dkiso at the bearing: its stiffness differs from the nominal k in both directions."""

    kind, symbol, unit, what = "bearing_compliance", "dkiso", "N/m", "stiffness change (both directions)"

    def stiffness(self, ctx: Context) -> Array:
        node, value = self.bearing_node(ctx), ctx.p[self.parameters[0].name]
        return dof_entries(ctx, {(f"u{node}", f"u{node}"): value, (f"v{node}", f"v{node}"): value})


class BearingMomentStiffness(AtBearing):
    """K[du, du] = K[dv, dv] += krot at the bearing: a moment -krot theta against the shaft's tilt there."""

    kind, symbol, unit, what = "moment_stiffness", "krot", "N m/rad", "moment (tilt) stiffness"

    def stiffness(self, ctx: Context) -> Array:
        node, value = self.bearing_node(ctx), ctx.p[self.parameters[0].name]
        return dof_entries(ctx, {(f"du{node}", f"du{node}"): value, (f"dv{node}", f"dv{node}"): value})


class BearingSpeedDamping(AtBearing):
    """C[u, u] = C[v, v] += cv c Omega / omega_1 at the bearing: its damping c changing in proportion to the speed."""

    kind, symbol, unit, what = "bearing_speed_damping", "cv", "1", "damping change per unit Omega / omega_1, of c,"

    def __init__(self, bearing: str, c: float):
        self.c = float(c)
        super().__init__(bearing, SPEED_DAMPING_RANGE, 0.0, limits=SPEED_DAMPING_LIMITS)

    def damping(self, ctx: Context) -> Array:
        node, share = self.bearing_node(ctx), ctx.p[self.parameters[0].name]
        with np.errstate(invalid="ignore", divide="ignore"):  # at 0 exactly nothing, also where omega_1 is NaN
            value = np.where(share == 0, 0.0, share * self.c * ctx.Omega / ctx.omega_1)
        return dof_entries(ctx, {(f"u{node}", f"u{node}"): value, (f"v{node}", f"v{node}"): value})


def excitations_at(place: str, node: int, force_n: float, kind: str = "bearing") -> list[HarmonicExcitation]:
    """The 2X and 3X forward-rotating forces at ``place`` (a ``kind``, "bearing" or "unbalance plane", at
    ``node``), range +-``force_n`` [N], limits ten times that (module docstring)."""
    if not force_n > 0:
        return []
    return [HarmonicExcitation(name=f"excitation_{h}x@{place}", harmonic=h, node=node, place=place,
                               bounds=(-force_n, force_n), limits=(-EXCITATION_LIMIT * force_n,
                                                                   EXCITATION_LIMIT * force_n),
                               meaning=f"{h}X rotating force at {kind} {place} (node {node}; misalignment, coupling, "
                                       "rub, crack), in-phase and quadrature to the unbalance")
            for h in (2, 3)]


def at_bearing(name: str, k: float | None, c: float = 0.0, tilt_stiffness: float | None = None) -> list[AtBearing]:
    """The candidates of a bearing ``name`` with nominal stiffness ``k`` [N/m] and damping ``c`` [N s/m], their
    ranges sized to them (module docstring); none without k, no cross-coupled damping without c.
    ``tilt_stiffness``: the shaft element's 4 E I / h at the bearing [N m/rad], for the moment stiffness and the
    compliance (``Machine.candidates``; None: the three of the first release only, anisotropy and
    cross-coupling)."""
    if k is None or not k > 0:
        return []
    out: list[AtBearing] = [BearingAnisotropy(name, ANISOTROPY_RANGE * k, ANISOTROPY_LIMIT * k),
                            BearingCrossCoupledStiffness(name, CROSS_STIFFNESS_RANGE * k, CROSS_STIFFNESS_LIMIT * k)]
    if c > 0:
        out.append(BearingCrossCoupledDamping(name, CROSS_DAMPING_RANGE * c, CROSS_DAMPING_LIMIT * c))
    if tilt_stiffness is None:
        return out
    out.append(BearingCompliance(name, COMPLIANCE_RANGE * k, 0.0,
                                 limits=(COMPLIANCE_LIMITS[0] * k, COMPLIANCE_LIMITS[1] * k)))
    if tilt_stiffness > 0:
        out.append(BearingMomentStiffness(name, 0.0, 0.0, bounds=(0.0, MOMENT_RANGE * tilt_stiffness),
                                          limits=(0.0, MOMENT_LIMIT * tilt_stiffness)))
    if c > 0:
        out.append(BearingSpeedDamping(name, c))
    return out
