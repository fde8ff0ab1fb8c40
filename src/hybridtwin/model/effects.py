"""The physical effects the package ships (docs/model.md): the VARM machine's base effects, its
upper-bearing forces (Geometric, Final and Expansion models) and the candidate effects a model may lack.

How an effect is written (its hooks into eq. 29, ``PolynomialBearing``) is ``hybridtwin.model.effect_base``;
``builtin_effects()`` is every effect here by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .effect_base import Array, Context, Effect, Parameter, PolynomialBearing, Term


def _node_pair(ctx: Context, node: int) -> tuple[int, int]:
    return ctx.dof(f"u{node}"), ctx.dof(f"v{node}")


def _isotropic_point(ctx: Context, node: int, value: Array) -> Array:
    """(S, n, n) matrix with ``value`` (S,) on both translational DOFs of ``node``."""
    out = ctx.zeros()
    for i in _node_pair(ctx, node):
        out[:, i, i] = value
    return out


# --- the machine's base effects ---------------------------------------------------------


class CentrifugalSoftening(Effect):
    """-Omega^2 M (eq. 29): the paper's centrifugal term, full mass matrix."""

    name = "centrifugal_softening"
    meaning = "centrifugal softening -Omega^2 M of the rotating shaft and attached masses (eq. 29)"

    def speed_stiffness(self, ctx: Context) -> Array:
        return -(ctx.Omega**2)[:, None, None] * ctx.M


class StructuralDamping(Effect):
    """Mass-proportional Rayleigh damping C_s = alpha_d M, alpha_d = 2 zeta_s omega_1 (eq. 31-32)."""

    name = "structural_damping"
    meaning = "material and air damping of the shaft, mass-proportional (eq. 31-32)"
    parameters = (Parameter("zeta_s", "1", (0.01, 0.05), 0.0271, "structural damping ratio of the first mode"),)

    def damping(self, ctx: Context) -> Array:
        alpha_d = 2.0 * ctx.p.zeta_s * ctx.omega_1
        return alpha_d[:, None, None] * ctx.M


class UpperHousing(Effect):
    """Upper bearing housing at node 0: point mass m_bup and viscous damping (eq. 25-26).

    c_bup = 2 zeta_bup sqrt(k_up m_bup), with k_up the linear support stiffness
    that the bearing effects put on node 0 (per plane: 2 k_b for the Geometric
    and Final models, k3 for the Expansion model).
    """

    name = "upper_housing"
    meaning = "upper bearing housing: lumped mass and viscous damping at node 0 (eq. 25-26)"
    parameters = (
        Parameter("m_bup", "kg", (0.03, 0.09), 0.056, "upper bearing and housing mass"),
        Parameter("zeta_bup", "1", (0.0, 0.05), 0.0215, "upper bearing damping ratio"),
    )
    node = 0  # where it acts (Machine.place puts a copy at another named node)

    def mass(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, self.node, ctx.p.m_bup)

    def damping(self, ctx: Context) -> Array:
        out = ctx.zeros()
        for i in _node_pair(ctx, self.node):
            k_up = np.maximum(ctx.K_support[:, i, i], 0.0)
            out[:, i, i] = 2.0 * ctx.p.zeta_bup * np.sqrt(k_up * ctx.p.m_bup)
        return out


class LowerBearing(Effect):
    """Stiff lower bearing at the last node: mass, spring and damper (eq. 18-19)."""

    name = "lower_bearing"
    meaning = "stiff lower bearing (rubber bushing): lumped mass, spring k and damper at the lowest node (eq. 18-19)"
    parameters = (
        Parameter("m_blo", "kg", (0.1, 0.3), 0.176, "lower bearing mass"),
        Parameter("k", "N/m", (1e3, 1e5), 1e4, "lower bearing stiffness"),
        Parameter("zeta_blo", "1", (0.0, 0.2), 0.05, "lower bearing damping ratio, c_blo = 2 zeta_blo sqrt(k m_blo)"),
    )

    node: int | None = None  # where it acts, None: the last node (Machine.place puts a copy at a named node)

    def mass(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, ctx.shaft.n if self.node is None else self.node, ctx.p.m_blo)

    def stiffness(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, ctx.shaft.n if self.node is None else self.node, ctx.p.k)

    def damping(self, ctx: Context) -> Array:
        c_blo = 2.0 * ctx.p.zeta_blo * np.sqrt(ctx.p.k * ctx.p.m_blo)
        return _isotropic_point(ctx, ctx.shaft.n if self.node is None else self.node, c_blo)


def _unbalance_nodes(ctx: Context) -> Array:
    """The node nearest z_me, per scenario (each distinct z_me looked up once: a sweep asks at every step)."""
    z, which = np.unique(np.broadcast_to(ctx.p.z_me, ctx.Omega.shape), return_inverse=True)
    return np.array([ctx.shaft.node_at(value) for value in z], dtype=int)[which.reshape(-1)]


#: the angle of a run's trial (eccentric) mass at t = 0 (the keyphasor mark), from +x towards +y, the sense of
#: rotation: its force turns by it, F_1 x exp(i angle_me); the runs sheet's eccentric_mass_angle_deg
ANGLE_ME = Parameter("angle_me", "rad", (0.0, 2 * np.pi), 0.0,
                     "angle of the eccentric (trial) mass at t = 0 from +x towards +y, the sense of rotation")


def trial_mass_values(mass_g: float, angle_deg: float = 0.0) -> dict[str, float]:
    """The model values of a run's trial (eccentric) mass: m_e [kg] from ``mass_g`` [g] and, at a non-zero
    ``angle_deg`` [deg, from +x towards +y; any finite value, taken modulo 360], angle_me [rad]. An angle of 0
    adds no value: the model's nominal angle_me is 0, so such a run is computed exactly as before angles were."""
    values = {"m_e": float(mass_g) * 1e-3}
    angle = trial_angle_rad(angle_deg)
    if angle != 0.0:
        values["angle_me"] = angle
    return values


def trial_angle_rad(angle_deg: float) -> float:
    """angle_me [rad, in [0, 2 pi)] of a trial mass at ``angle_deg`` [deg, any finite value: -90 is 270]."""
    return float(np.deg2rad(np.mod(float(angle_deg), 360.0)))


def trial_force(ctx: Context, amplitude: Array) -> tuple[Array, Array]:
    """The 1X force (x, y) of a trial mass of force ``amplitude`` (S,) = m_e r_me Omega^2 placed at angle_me:
    (F_x, F_y) = amplitude exp(i angle_me) (1, -i), i.e. f = amplitude (cos(Omega t + angle_me),
    sin(Omega t + angle_me)); at angle_me = 0 exactly amplitude (1, -i)."""
    F = amplitude * np.exp(1j * ctx.p.angle_me)
    return F, -1j * F


class Unbalance(Effect):
    """Eccentric mass m_e at z_me: point mass and rotating force (eq. 14-15, 30).

    f = m_e r_me Omega^2 (cos(Omega t + angle_me), sin(Omega t + angle_me)) at the node nearest z_me, so
    F_1 = m_e r_me Omega^2 exp(i angle_me) in x and -i times that in y (angle_me = 0: the mass on +x at t = 0).
    """

    name = "unbalance"
    meaning = "eccentric (unbalance) mass: its point mass and the rotating force m_e r_me Omega^2 (eq. 14-15)"
    parameters = (
        Parameter("m_e", "kg", (0.0, 0.040), 0.0, "eccentric mass"),
        Parameter("r_me", "m", (0.0, 0.1), 0.040, "eccentricity of the eccentric mass"),
        Parameter("z_me", "m", (0.0, 0.85), 0.425, "axial position of the eccentric mass"),
        ANGLE_ME,
    )
    inertial = True  # the force is the mass's inertia: at variable speed also m_e r_me Omega' (hybridtwin.solvers.sweep)

    def mass(self, ctx: Context) -> Array:
        out = ctx.zeros()
        rows = np.arange(ctx.n_scenarios)
        nodes = _unbalance_nodes(ctx)
        for plane in ("x", "y"):
            i = ctx.shaft.translational(plane)[nodes]
            out[rows, i, i] = ctx.p.m_e
        return out

    def forcing(self, ctx: Context) -> dict[int, Array]:
        f = ctx.zero_vector()
        rows = np.arange(ctx.n_scenarios)
        nodes = _unbalance_nodes(ctx)
        f[rows, ctx.shaft.translational("x")[nodes]], f[rows, ctx.shaft.translational("y")[nodes]] = trial_force(
            ctx, ctx.p.m_e * ctx.p.r_me * ctx.Omega**2)
        return {1: f}


class ShaftBow(Effect):
    """Distributed unbalance of the bent shaft, m_el q Phi_1 Omega^2 (eq. 16-17, 30)."""

    name = "shaft_bow"
    meaning = "initial bow / distributed unbalance of the shaft along its first mode, m_el q Phi_1 Omega^2 (eq. 30)"
    parameters = (
        Parameter("q_x", "m", (0.001, 0.01), 0.005, "bow amplitude along the first mode, x"),
        Parameter("q_y", "m", (0.001, 0.01), 0.005, "bow amplitude along the first mode, y"),
        Parameter("m_el", "kg", (0.01, 0.05), 0.0281, "mass of one shaft element used in the bow force"),
    )
    inertial = True  # the bent shaft's mass turning with it: at variable speed also the Omega' term

    def forcing(self, ctx: Context) -> dict[int, Array]:
        f = ctx.zero_vector()
        scale = (ctx.p.m_el * ctx.Omega**2)[:, None] * ctx.Phi_1
        f[:, ctx.shaft.translational("x")] = ctx.p.q_x[:, None] * scale
        f[:, ctx.shaft.translational("y")] = -1j * ctx.p.q_y[:, None] * scale
        return {1: f}



# --- polynomial bearing forces of the VARM upper bearing (eq. 22-24, 38-39) -----------------


K_B = Parameter("k_b", "N/m", (2000.0, 3500.0), 2331.5, "stiffness of each of the four upper bearing springs")
L_I = Parameter("l_i", "m", (0.03, 0.08), 0.0508, "unstretched length of the upper bearing springs")


def geometric_spring() -> PolynomialBearing:
    """Four springs at 0, 90, 180, 270 degrees, third-order expansion (eq. 22)."""
    return PolynomialBearing(
        name="geometric_spring",
        meaning="four-spring compliant upper bearing, exact third-order expansion (eq. 22)",
        parameters=(K_B, L_I),
        terms=(
            Term(lambda p: p.k_b / p.l_i**2, (3, 0, 0, 0), "k_b/l_i^2 u^3"),
            Term(lambda p: -4.0 * p.k_b / p.l_i**2, (1, 2, 0, 0), "-4 k_b/l_i^2 u v^2"),
            Term(lambda p: 2.0 * p.k_b, (1, 0, 0, 0), "2 k_b u"),
        ),
    )


def radial_spring() -> PolynomialBearing:
    """The Final model's upper bearing spring without the cross term (eq. 38-39)."""
    return PolynomialBearing(
        name="radial_spring",
        meaning="upper bearing spring, cubic in its own deflection, no cross term (Final model, eq. 38-39)",
        parameters=(K_B, L_I),
        terms=(
            Term(lambda p: p.k_b / p.l_i**2, (3, 0, 0, 0), "k_b/l_i^2 u^3"),
            Term(lambda p: 2.0 * p.k_b, (1, 0, 0, 0), "2 k_b u"),
        ),
    )


def slope_spring() -> PolynomialBearing:
    """Bearing force on the shaft slope, k_w u' + k_z (u')^3 (eq. 38-39)."""
    return PolynomialBearing(
        name="slope_spring",
        meaning="upper bearing force proportional to the shaft slope (tilt) at the bearing, linear and cubic (eq. 38-39)",
        parameters=(
            Parameter("k_w", "N", (0.0, 1000.0), 324.2, "linear slope stiffness"),
            Parameter("k_z", "N", (0.0, 1000.0), 301.1, "cubic slope stiffness"),
        ),
        terms=(
            Term(lambda p: p.k_w, (0, 0, 1, 0), "k_w u'"),
            Term(lambda p: p.k_z, (0, 0, 3, 0), "k_z u'^3"),
        ),
        switches=("k_w", "k_z"),  # a candidate: the Final model's slope force, absent at k_w = k_z = 0
    )


def _expansion_term(index: int, powers: tuple[int, int, int, int], scale: str, meaning: str,
                    unit: str, bounds: tuple[float, float], nominal: float,
                    candidate: bool = False) -> PolynomialBearing:
    """Term k{index} of the Expansion model; ``candidate``: the diagnosis may test it, switched on by k{index}
    (l_i keeps its value)."""
    name = f"k{index}"
    exponent = {"": 0, "/l_i": 1, "/l_i^2": 2}[scale]
    parameters = (Parameter(name, unit, bounds, nominal, f"Expansion model coefficient k{index} (eq. 23)"),)
    if exponent:
        parameters += (L_I,)
    monomial = " ".join(f"{v}^{e}" if e > 1 else v for v, e in zip(("u", "v", "u'", "v'"), powers) if e)
    return PolynomialBearing(
        name=f"expansion_{name}",
        meaning=meaning,
        parameters=parameters,
        terms=(Term(lambda p: p[name] / p.l_i**exponent if exponent else p[name], powers,
                    f"{name}{scale} {monomial}"),),
        switches=(name,) if candidate else (),
    )


def expansion_terms() -> list[PolynomialBearing]:
    """The seven terms of the Expansion model of the upper bearing force (eq. 23-24).

    The extra terms k2, k4-k7 (u^2, u', u v, (u')^3, u v^2) are candidates; k1 and k3 (the cubic and
    linear stiffness every upper bearing model has) are not."""
    return [
        _expansion_term(1, (3, 0, 0, 0), "/l_i^2", "cubic stiffness of the upper bearing", "N/m", (0, 3500), 2562.7),
        _expansion_term(2, (2, 0, 0, 0), "/l_i", "quadratic (asymmetric) stiffness of the upper bearing", "N/m",
                        (-1000, 1000), -70.9, candidate=True),
        _expansion_term(3, (1, 0, 0, 0), "", "linear stiffness of the upper bearing", "N/m", (0, 7000), 5428.5),
        _expansion_term(4, (0, 0, 1, 0), "", "linear force on the shaft slope at the upper bearing", "N",
                        (-1000, 1000), 341.1, candidate=True),
        _expansion_term(5, (1, 1, 0, 0), "/l_i", "quadratic cross-coupling u v of the upper bearing", "N/m",
                        (-1000, 1000), 60.9, candidate=True),
        _expansion_term(6, (0, 0, 3, 0), "", "cubic force on the shaft slope at the upper bearing", "N",
                        (-1000, 1000), 293.0, candidate=True),
        _expansion_term(7, (1, 2, 0, 0), "/l_i^2", "cubic cross-coupling u v^2 of the upper bearing", "N/m",
                        (-14000, 14000), -627.7, candidate=True),
    ]


# --- candidate effects (issue 6): physics a model may lack, absent at zero -----------------
#
# Each parameter below has nominal 0, and at 0 its effect adds exactly nothing (0.0 to the
# matrices, no forcing harmonic), so a model extended by any of them at zero *is* the model
# without it. Each effect declares them as its ``switches`` (the parameters the diagnosis tests).
#
# Ranges. The top of each range changes the sensor response clearly (sensor noise 0.05 mm), about as much as
# the bundled data's hidden slope force, but not absurdly, and every run of the paper's plan still solves (how each
# was estimated, with its figures: benchmarks/README.md, "The candidate effects' ranges"). Per parameter:
# - dk_up +-500 N/m: +-10 % of 2 k_b per axis.
# - k_xy +-200 N/m: a destabilising term; the linearised machine stays stable up to |k_xy| ~ 350 N/m at the
#   bundled dampings, only up to ~ 110 N/m at the lowest damping of the base ranges (zeta_s 0.01, zeta_bup 0).
# - c_xy +-5 N s/m: at 1X forward an equivalent stiffness Omega c_xy of 180-520 N/m, like dk_up's size.
# - k_rot 0-300 N m/rad: 7 % of an element's 4 EI/h = 4140 N m/rad (partial clamping of the tilt). Not negative:
#   a support does not push the tilt further.
# - dk_lo +-2000 N/m: +-20 % of k = 1e4 N/m.
# - f2 +-0.5 N: largest near the 2X critical speed Omega = omega_1/sqrt(5); only the 2X line changes.
# - f3 +-0.3 N: largest near the 3X critical speed omega_1/sqrt(10); 3X line only.
# - zeta_v 0-0.05: adds up to 0.05 Omega/omega_1 = 0.04 to zeta_s at 1000 RPM (zeta_s's own range is
#   0.01-0.05). Not negative: damping does not fall with speed here.
RANGE_DK_UP = (-500.0, 500.0)
RANGE_K_XY = (-200.0, 200.0)
RANGE_C_XY = (-5.0, 5.0)
RANGE_K_ROT = (0.0, 300.0)
RANGE_DK_LO = (-2000.0, 2000.0)
RANGE_F2 = (-0.5, 0.5)
RANGE_F3 = (-0.3, 0.3)
RANGE_ZETA_V = (0.0, 0.05)
# e2 +-4.5e-5 kg m (a 2X unbalance of 45 g mm): the 2X force e Omega^2 reaches f2's range, 0.5 N, at
# 1000 RPM (Omega^2 = 1.1e4) and is 4 times weaker at 500 RPM.
RANGE_E2 = (-4.5e-5, 4.5e-5)
# Physical limits (Parameter.limits), how far the diagnosis may widen a range when an estimate sits at its
# edge: the upper bearing's x or y stiffness 2 k_b +- dk_up stays positive at the lowest k_b of the base
# ranges (2000 N/m); the lower bearing's k + dk_lo stays above 1 % of k = 1e4 N/m and below 10 k; k_rot up
# to ~ 4 EI/h = 4140 N m/rad of an element, beyond which the tilt is clamped and more changes nothing;
# a damping ratio below 1; the others ten times their range, where the response would be far off the
# sensors' scale.
LIMIT_DK_UP = (-4000.0, 4000.0)
LIMIT_K_XY = (-2000.0, 2000.0)
LIMIT_C_XY = (-50.0, 50.0)
LIMIT_K_ROT = (0.0, 4140.0)
LIMIT_DK_LO = (-9900.0, 90000.0)
LIMIT_F = (-10.0, 10.0)
LIMIT_E = (-4.5e-4, 4.5e-4)
LIMIT_ZETA_V = (0.0, 1.0)


def dof_entries(ctx: Context, values: Mapping[tuple[str, str], Array]) -> Array:
    """(S, n, n) matrix with ``values`` (S,) at the (row DOF, column DOF) entries named by its keys."""
    out = ctx.zeros()
    for (row, col), value in values.items():
        out[:, ctx.dof(row), ctx.dof(col)] += value
    return out


#: (row, column, sign) of a bearing's node that a bearing term's parameter enters (u, v: the node's displacements):
#: stiffer along x than along y (mean unchanged), and the skew-symmetric (cross-coupled) pair
ANISOTROPIC = (("u", "u", 1.0), ("v", "v", -1.0))
SKEW = (("u", "v", 1.0), ("v", "u", -1.0))


class BearingTerm(Effect):
    """An effect of one parameter at one bearing's node: the parameter times each (row, column, sign) of ``pairs``
    (``ANISOTROPIC``, ``SKEW``), in K or C as the subclass says. The VARM's candidates below sit at its upper bearing
    (node 0); ``bearing_candidates.AtBearing`` at a named bearing of a machine (``bearing_node``; not ``node``,
    which marks an effect ``Machine.place`` can move)."""

    pairs: tuple[tuple[str, str, float], ...] = ()

    def bearing_node(self, ctx: Context) -> int:
        return 0

    def entries(self, ctx: Context) -> Array:
        """(S, n, n): the parameter's value times each of ``pairs`` at the bearing's node."""
        node = self.bearing_node(ctx)
        value = ctx.p[self.parameters[0].name]
        return dof_entries(ctx, {(f"{row}{node}", f"{col}{node}"): sign * value for row, col, sign in self.pairs})


class UpperBearingAnisotropy(BearingTerm):
    """Upper bearing stiffer in x than in y: K[u0, u0] += dk_up, K[v0, v0] -= dk_up (mean unchanged).

    Four springs that are not identical, or a housing stiffer along one axis. The term is part
    of the support stiffness at rest, so it also reaches what is derived from it: UpperHousing's
    c_bup = 2 zeta_bup sqrt(k_up m_bup) reads K_support's node-0 diagonal per plane (becomes
    2 zeta_bup sqrt((2 k_b +- dk_up) m_bup): zeta_bup stays a damping ratio per plane), and
    omega_1, Phi_1 are those of the x plane (stiffer by dk_up), so alpha_d (eq. 31-32) and the
    bow force (eq. 30) follow the x plane. At dk_up = 0 none of this changes.
    """

    name = "upper_bearing_anisotropy"
    meaning = "upper bearing stiffer along x than along y by 2 dk_up (unequal springs), mean stiffness unchanged"
    parameters = (Parameter("dk_up", "N/m", RANGE_DK_UP, 0.0,
                            "added to the node-0 stiffness in x, removed in y", LIMIT_DK_UP),)
    switches = ("dk_up",)
    pairs = ANISOTROPIC

    def stiffness(self, ctx: Context) -> Array:
        return self.entries(ctx)


class CrossCoupledStiffness(BearingTerm):
    """Cross-coupled stiffness at the upper bearing: K[u0, v0] = +k_xy, K[v0, u0] = -k_xy.

    The force on the shaft, -K q, is k_xy (-v, u): perpendicular to the deflection, along the
    direction of rotation (+x -> +y) for k_xy > 0 (the destabilising sense of fluid films,
    seals and rubbing). For a forward whirl (y = -i x) it acts as a damping -k_xy / (h Omega),
    for a backward one as +k_xy / (h Omega). Only the off-diagonal of node 0 changes, so the
    x-plane omega_1, Phi_1 and c_bup (which read the x plane and the diagonal) do not.
    """

    name = "cross_coupled_stiffness"
    meaning = "cross-coupled (circulatory) stiffness at the upper bearing, force k_xy (-v, u) along the rotation"
    parameters = (Parameter("k_xy", "N/m", RANGE_K_XY, 0.0, "K[u0, v0] = +k_xy, K[v0, u0] = -k_xy",
                            LIMIT_K_XY),)
    switches = ("k_xy",)
    pairs = SKEW

    def stiffness(self, ctx: Context) -> Array:
        return self.entries(ctx)


class CrossCoupledDamping(BearingTerm):
    """Cross-coupled damping at the upper bearing: C[u0, v0] = +c_xy, C[v0, u0] = -c_xy.

    A skew-symmetric (gyroscopic-like) damping: the force -C q' = c_xy (-v', u') does no work.
    For a forward whirl at h Omega it acts as a stiffness +h Omega c_xy, for a backward one as
    -h Omega c_xy: on 1X forward data it looks like a speed-proportional stiffness.
    """

    name = "cross_coupled_damping"
    meaning = "cross-coupled (skew-symmetric) damping at the upper bearing, force c_xy (-v', u')"
    parameters = (Parameter("c_xy", "N s/m", RANGE_C_XY, 0.0, "C[u0, v0] = +c_xy, C[v0, u0] = -c_xy",
                            LIMIT_C_XY),)
    switches = ("c_xy",)
    pairs = SKEW

    def damping(self, ctx: Context) -> Array:
        return self.entries(ctx)


class MomentStiffness(Effect):
    """Rotational (moment) stiffness of the upper bearing: K[du0, du0] = K[dv0, dv0] += k_rot.

    A moment -k_rot theta against the shaft's tilt at node 0 (a bearing that clamps part of the
    slope, e.g. a wide or preloaded ball bearing). Symmetric, unlike the slope force k_w u' of
    eq. 38-39 (a force on the deflection DOF driven by the slope). It stiffens the shaft at
    rest, so it raises omega_1 (and changes Phi_1, hence alpha_d and the bow force); c_bup reads
    the deflection diagonal only and does not change.
    """

    name = "moment_stiffness"
    meaning = "rotational (moment) stiffness of the upper bearing against the shaft's tilt at node 0"
    parameters = (Parameter("k_rot", "N m/rad", RANGE_K_ROT, 0.0, "moment per unit slope at node 0, both planes",
                            LIMIT_K_ROT),)
    switches = ("k_rot",)

    def stiffness(self, ctx: Context) -> Array:
        return dof_entries(ctx, {("du0", "du0"): ctx.p.k_rot, ("dv0", "dv0"): ctx.p.k_rot})


class LowerBearingCompliance(Effect):
    """The "known" lower bearing stiffness k is wrong by dk_lo: K[u_n, u_n] = K[v_n, v_n] += dk_lo.

    Negative dk_lo: a softer rubber bushing or a compliant frame under the lower bearing.
    Only the stiffness changes: LowerBearing's damper c_blo = 2 zeta_blo sqrt(k m_blo) is
    computed from the parameter k and keeps its value (a wrong k is a stiffness question; a
    wrong damper would be another candidate). It changes omega_1 and Phi_1 like any support.
    """

    name = "lower_bearing_compliance"
    meaning = "lower bearing stiffness differs from its known value k by dk_lo (both planes, last node)"
    parameters = (Parameter("dk_lo", "N/m", RANGE_DK_LO, 0.0, "error of the known lower bearing stiffness k",
                            LIMIT_DK_LO),)
    switches = ("dk_lo",)

    def stiffness(self, ctx: Context) -> Array:
        n = ctx.shaft.n
        return dof_entries(ctx, {(f"u{n}", f"u{n}"): ctx.p.dk_lo, (f"v{n}", f"v{n}"): ctx.p.dk_lo})


@dataclass(eq=False)
class HarmonicExcitation(Effect):
    """A forward-rotating force at h Omega on one node, given relative to the unbalance.

    f_x = f_c cos(h Omega t) - f_s sin(h Omega t), f_y = f_c sin(h Omega t) + f_s cos(h Omega t):
    F_h = f_c + i f_s in x and -i (f_c + i f_s) in y (forward whirl, as Unbalance), i.e. at
    t = 0, when the unbalance points to +x, the force is (f_c, f_s): f_c along the unbalance,
    f_s 90 degrees ahead in the sense of rotation. The response is linear in (f_c, f_s) and the
    amplitude sqrt(f_c^2 + f_s^2) [N] does not depend on speed (a constraint force of the
    misfit, not an inertial one).

    Where: the built-ins act on node 0. A misaligned shaft line (the motor under the lower
    bearing, the 3D-printed upper housing off the line through both bearings) forces the shaft
    through its bearings, and the compliant upper bearing is where the misfit turns into motion:
    the stiff lower bearing (k = 1e4 N/m) next to the coupling takes much of a force applied
    there (the same 2X force at node 10 moves the sensor at node 1 3-9 times less below
    550 RPM, comparably above 650 RPM). A user who wants the coupling itself builds
    ``HarmonicExcitation(name=..., meaning=..., harmonic=2, node=10, bounds=...)``; off node 0
    the parameters are named f{h}_c_{node}, f{h}_s_{node} so that both can be in one model; placed at a named
    bearing of a machine (``place``, set by ``Machine.place``: ``excitation_2x@nde``) f{h}_c_{bearing},
    f{h}_s_{bearing}.

    Law: ``law="constant"`` (above), or ``law="omega2"``: the force grows like an unbalance,
    F_h = (e_c + i e_s) Omega^2 with e_c, e_s [kg m] (parameters e{h}_c, e{h}_s): an inertial
    source turning at h Omega, e.g. a coupling or a part mounted off-axis twice per turn. On data
    over a range of speeds the two laws differ by Omega^2, so the diagnosis can say which one the
    data prefer (or that they are confounded, on a narrow speed range).

    Both parameters vanish at 0 (no harmonic at all), so every harmonic excitation declares them as
    its ``switches``: built with the names of its law and node, a copy at another node included.
    """

    name: str = ""
    meaning: str = ""
    harmonic: int = 2
    node: int = 0
    bounds: tuple[float, float] = (-1.0, 1.0)
    law: str = "constant"
    limits: tuple[float, float] | None = None
    place: str = ""
    parameters: tuple[Parameter, ...] = field(init=False)
    switches: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        if int(self.harmonic) != self.harmonic or self.harmonic < 1:
            raise ValueError(f"effect {self.name}: harmonic must be a positive integer, got {self.harmonic!r}")
        if self.law not in ("constant", "omega2"):
            raise ValueError(f"effect {self.name}: law must be 'constant' or 'omega2', got {self.law!r}")
        h, node = self.harmonic, self.node
        suffix = f"_{self.place}" if self.place else "" if node == 0 else f"_{node}"
        letter, unit, what = ("f", "N", "force") if self.law == "constant" else ("e", "kg m", "force / Omega^2")
        self._names = (f"{letter}{h}_c{suffix}", f"{letter}{h}_s{suffix}")
        self.parameters = (
            Parameter(self._names[0], unit, self.bounds, 0.0, f"{h}X {what} at t = 0 along the unbalance "
                      f"(node {node})", self.limits),
            Parameter(self._names[1], unit, self.bounds, 0.0,
                      f"{h}X {what} at t = 0, 90 degrees ahead of the unbalance (node {node})", self.limits),
        )
        self.switches = self._names

    def forcing(self, ctx: Context) -> dict[int, Array]:
        h = self.harmonic
        F = ctx.p[self._names[0]] + 1j * ctx.p[self._names[1]]
        if self.law == "omega2":
            F = F * ctx.Omega**2
        if not np.any(F):
            return {}  # absent: not even a zero harmonic (a solver with H < h must still run)
        f = ctx.zero_vector()
        f[:, ctx.dof(f"u{self.node}")] = F
        f[:, ctx.dof(f"v{self.node}")] = -1j * F
        return {h: f}


def misalignment_2x() -> HarmonicExcitation:
    """2X excitation (misalignment) at the upper bearing."""
    return HarmonicExcitation(name="excitation_2x", harmonic=2, node=0, bounds=RANGE_F2, limits=LIMIT_F,
                              meaning="2X rotating force at the upper bearing (shaft-line misalignment), "
                                      "in-phase and quadrature to the unbalance")


def excitation_2x_inertial() -> HarmonicExcitation:
    """2X excitation at the upper bearing growing like an unbalance, (e_c + i e_s) Omega^2."""
    return HarmonicExcitation(name="excitation_2x_inertial", harmonic=2, node=0, bounds=RANGE_E2, law="omega2",
                              limits=LIMIT_E, meaning="2X rotating force at the upper bearing growing like "
                              "Omega^2 (an inertial source turning twice per revolution), in-phase and "
                              "quadrature to the unbalance")


def excitation_3x() -> HarmonicExcitation:
    """3X excitation at the upper bearing."""
    return HarmonicExcitation(name="excitation_3x", harmonic=3, node=0, bounds=RANGE_F3, limits=LIMIT_F,
                              meaning="3X rotating force at the upper bearing (misalignment, coupling, bearing "
                                      "defect), in-phase and quadrature to the unbalance")


class SpeedDependentDamping(Effect):
    """Mass-proportional damping growing with speed: C += 2 zeta_v Omega M.

    Extends eq. 31-32 (C_s = 2 zeta_s omega_1 M): together alpha_d = 2 (zeta_s omega_1 +
    zeta_v Omega), i.e. the structural damping ratio of the first mode becomes
    zeta_s + zeta_v Omega / omega_1 (windage, damping of the rotating parts growing with speed).
    M is the full mass (point masses included), as in eq. 31-32.
    """

    name = "speed_damping"
    meaning = "mass-proportional damping growing with speed, C += 2 zeta_v Omega M (extends eq. 31-32)"
    parameters = (Parameter("zeta_v", "1", RANGE_ZETA_V, 0.0,
                            "added first-mode damping ratio per unit Omega / omega_1", LIMIT_ZETA_V),)
    switches = ("zeta_v",)

    def damping(self, ctx: Context) -> Array:
        return (2.0 * ctx.p.zeta_v * ctx.Omega)[:, None, None] * ctx.M


def candidate_effects() -> list[Effect]:
    """The candidate effects (issue 6) with parameters absent at zero, each declaring them as its ``switches``
    (hybridtwin.model.candidates)."""
    return [UpperBearingAnisotropy(), CrossCoupledStiffness(), CrossCoupledDamping(), MomentStiffness(),
            LowerBearingCompliance(), misalignment_2x(), excitation_2x_inertial(), excitation_3x(),
            SpeedDependentDamping()]


def base_effects() -> list[Effect]:
    """Effects every VARM variant shares: the machine without its upper bearing spring."""
    return [CentrifugalSoftening(), StructuralDamping(), UpperHousing(), LowerBearing(), Unbalance(), ShaftBow()]


def builtin_effects() -> dict[str, Effect]:
    """All effects the package ships, by name."""
    effects: list[Effect] = base_effects() + [geometric_spring(), radial_spring(), slope_spring()]
    effects += expansion_terms()
    effects += candidate_effects()
    return {e.name: e for e in effects}
