"""Faults as effects (issue 54, item 4; docs/model.md, "Faults"): a rub of the rotor on a stator ring.

``Rub``: at a node, a stator ring of radial clearance delta; where the shaft's deflection r = |(u, v)| exceeds it,
the ring pushes back with a normal force N = k_rub (r - delta) and a Coulomb friction mu N against the sliding of
the shaft's surface, which turns from +x towards +y (the surface speed Omega R of a rotor far exceeds its whirl
speed, so the friction's sense is the rotation's, whatever the whirl):

    F_u = -g (u - mu v),   F_v = -g (v + mu u),   g = k_rub max(0, 1 - delta / r)

(the normal part -N (u, v) / r, the friction -mu N (-v, u) / r). Non-smooth at r = delta: its spectrum falls off
slowly, so it declares the harmonics its harmonic balance needs (``RUB_HARMONICS``, ``Effect.needs_harmonics``:
a fit that compares fewer solves with them, ``forward.SolverModel``) and the time samples (``RUB_TIME_SAMPLES``, the
solver's default for a force of no polynomial degree); ``hybridtwin.solvers.resolution`` says when an orbit is not
resolved by them. The time integrator evaluates it as it is. Absent at k_rub = 0 whatever delta and mu: all three
are its switches, so at the diagnosis's zero the score sees the light-rub limit, a ring touching all round (a
stiffness at the plane), and the refit frees the clearance and the friction (``fault_candidates``: ``rub@PLANE``).
Place it with ``Rub(node=..., place=...)`` in a file under the config's ``effects_files`` (its parameters then named
delta_PLACE, k_rub_PLACE, mu_PLACE), or ``Machine.place(Rub(), "bearing")``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from .effect_base import Array, Context, Effect, Parameter, Params


#: the harmonics a rub's harmonic balance carries (``Rub.needs_harmonics``) and its time samples a period: those of
#: a fit's run-ups, the solver's for a force of no polynomial degree. Measured on the stepped rotor rubbing at its
#: disk on an ellipse, against Radau settled (tests/test_rub.py): at 3 harmonics the 1X..3X are 3e-4 of the 1X
#: off, at 9 5e-5 (no better at 15: the aliasing of 64 samples is then what is left; 256 samples reach 3e-6)
RUB_HARMONICS, RUB_TIME_SAMPLES = 9, 64
#: the same for a loose bearing (``Looseness.needs_harmonics``): its spring acts only near the ends of an ellipse, a
#: short contact whose spectrum falls off more slowly. Measured on the stepped rotor's bearing b (k 1e7 N/m, the
#: clearance 0.6 of the mean semi-axis, tests/test_rub.py): 1X..3X 2 % of the 1X off at 3 harmonics, 1.2e-4 at 9,
#: 1.1e-5 at 15
LOOSENESS_HARMONICS = 15


@dataclass(frozen=True)
class Signature:
    """What a fault leaves in a residual the model without it cannot absorb (one form of its fingerprint; a fault's
    ``signatures`` list its forms; ``diagnose.fingerprint.resembles`` matches a residual's fingerprint against them).

    ``family``: the fault ("a breathing crack"); ``with_orders``: harmonics beyond 1X whose residual must be above
    the noise; ``without_orders``: those that must not be (either only where the data hold that harmonic);
    ``one_x``: what its 1X does, "changed" (above the noise), "unchanged", "held down" (below the model's), "raised"
    (above it) or "any"."""

    family: str
    with_orders: tuple[int, ...]
    without_orders: tuple[int, ...] = ()
    one_x: str = "any"


@dataclass(eq=False)
class Rub(Effect):
    """Rub on a stator ring of clearance delta at ``node`` (module docstring)."""

    #: a ring touched all round an ellipse holds the 1X down (a stiffness where the orbit reaches it, below a
    #: critical speed) and its kinks add 3X; a ring touched on one side (off-centre, or a static load) a series 2X,
    #: 3X, 4X, the clipped orbit's
    signatures: ClassVar[tuple[Signature, ...]] = (Signature("a rub", (3,), one_x="held down"),
                                                   Signature("a rub", (2, 3, 4)))

    name: str = "rub"
    node: int = 0
    place: str = ""
    clearance_m: tuple[float, float] = (0.0, 1e-2)  # 0 in it: a candidate's switches are absent at 0
    stiffness_n_m: tuple[float, float] = (0.0, 1e5)
    friction: tuple[float, float] = (0.0, 0.5)
    #: how far each range may widen (``Parameter.limits``): clearance, stiffness, friction
    limits: tuple[tuple[float, float], tuple[float, float], tuple[float, float]] = (
        (0.0, np.inf), (0.0, np.inf), (0.0, 2.0))
    #: the ring's centre (x, y) [m] off the bearings' axis (a seal or casing set off-centre: a partial rub on one side,
    #: 2X and 3X even on a circular orbit); default centred
    centre_m: tuple[float, float] = (0.0, 0.0)
    meaning: str = "rub on a stator ring at node 0: normal contact force k_rub (r - delta) beyond the clearance, " \
                   "Coulomb friction mu along the rotation"
    parameters: tuple[Parameter, ...] = field(init=False)
    dofs: tuple[str, ...] = field(init=False)
    switches: tuple[str, ...] = field(init=False)
    degree: int | None = None
    needs_harmonics: int | None = RUB_HARMONICS
    needs_time_samples: int | None = RUB_TIME_SAMPLES

    def __post_init__(self) -> None:
        suffix = f"_{self.place}" if self.place else "" if self.node == 0 else f"_{self.node}"
        self._names = (f"delta{suffix}", f"k_rub{suffix}", f"mu{suffix}")
        lo, hi = self.clearance_m
        self.parameters = (
            Parameter(self._names[0], "m", (lo, hi), float(np.sqrt(lo * hi)) if lo > 0 else 0.1 * hi,
                      f"radial clearance of the stator ring at node {self.node}", self.limits[0]),
            Parameter(self._names[1], "N/m", self.stiffness_n_m, 0.0,
                      f"contact stiffness of the ring at node {self.node} (0: no rub)", self.limits[1]),
            Parameter(self._names[2], "1", self.friction, 0.2 if self.friction[0] <= 0.2 <= self.friction[1]
                      else self.friction[0], "Coulomb friction coefficient of the contact", self.limits[2]),
        )
        self.switches = (self._names[1], self._names[0], self._names[2])  # absent at k_rub = 0 (module docstring)
        self.dofs = (f"u{self.node}", f"v{self.node}")
        self.meaning = self.meaning.replace("at node 0", f"at node {self.node}")

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        """F (S, 2, N) on the shaft at (u, v) and its derivative (S, 2, 2, N) (module docstring, with (u, v) from the
        ring's centre); zero inside the clearance."""
        delta, k, mu = (p[name][:, None] for name in self._names)
        u, v = q[:, 0] - self.centre_m[0], q[:, 1] - self.centre_m[1]  # the shaft's centre seen from the ring's
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


# --- a breathing crack ----------------------------------------------------------------------------------------

#: the breathing functions: the share of the crack open at the crack's angle theta, as Fourier cosine coefficients
#: {order: coefficient} of f(theta) = sum_m a_m cos(m theta). Mayes: f = (1 - cos theta) / 2, smooth; Gasch: open
#: half the turn (cos theta < 0), the square wave's first 18 odd harmonics (as ROSS 2.3.0 sums them).
BREATHING = {
    "mayes": {0: 0.5, 1: -0.5},
    "gasch": {0: 0.5} | {2 * i + 1: -(2 / np.pi) * (-1) ** i / (2 * i + 1) for i in range(18)},
}
#: time samples a turn for the crack's forcing harmonics (the Gasch wave's 35th harmonic times the 2nd of the
#: rotation, the 37th, folds to the 91st and beyond: no harmonic up to 36 is touched)
CRACK_SAMPLES = 128
#: the crack's forcing harmonics: 1X .. 3X, the whole of Mayes's law acting on the sag (Gasch's square wave has
#: more, cut here: the data's harmonics rarely reach beyond 3X)
CRACK_HARMONICS = 3
#: the weight's acceleration along x and y [m/s^2] of a horizontal machine, y up (ROSS's convention)
GRAVITY_M_S2 = (0.0, -9.81)


def tip_vector(h: float) -> Array:
    """t over an element's (w1, theta1, w2, theta2) of one plane: t . q = w2 - w1 - h theta1, the deflection of the
    element's right end relative to a cantilever clamped at its left end, the one a crack's compliance adds to."""
    return np.array([-1.0, -h, 1.0, 0.0])


def static_sag(shaft, M: Array, K: Array, gravity_m_s2: tuple[float, float] = GRAVITY_M_S2) -> Array:
    """The static deflection (S, n) of the structure of stiffness K (S, n, n) under its weight: K q = M a, a the
    acceleration ``gravity_m_s2`` (x, y) on every translational DOF (the consistent mass's load, moments included).
    For a crack's ``sag_m`` where the supports are tables over speed: K from ``Model.system(values, rpm).K``."""
    a = np.zeros(shaft.n_dof)
    a[shaft.translational("x")], a[shaft.translational("y")] = gravity_m_s2
    return np.linalg.solve(K, (M @ a)[..., None])[..., 0]


@dataclass(eq=False)
class Crack(Effect):
    """A breathing crack in the shaft element from ``node`` to ``node + 1``, driven by the rotor's own weight.

    The crack lowers the element's cantilever tip stiffness (``tip_vector``) by dk_xi along the crack's own xi
    axis and dk_eta along eta when fully open; it turns with the shaft, theta = Omega t + psi (psi: the crack's
    angle at t = 0; the unbalance's then is angle_me), and is open by f(theta) (``BREATHING``: Mayes or Gasch).
    In the fixed frame the element loses, in each plane, dk_xx(theta) = f (dk_xi cos^2 + dk_eta sin^2),
    dk_yy(theta) = f (dk_xi sin^2 + dk_eta cos^2) and (``cross_terms``) dk_xy = f (dk_xi - dk_eta) sin cos
    times t t^T, i.e. a force dk(theta) (t . q) t back on the shaft (ROSS 2.3.0 keeps dk_xx and dk_yy only:
    ``cross_terms=False`` is its convention).

    Weight-dominated breathing (the premise of both models): the shaft's deflection at the crack is its static sag
    q_s under ``gravity_m_s2`` (K at rest, this effect's mean loss included, the consistent mass's load; or
    ``sag_m``, t . q_s in x and y [m], given where the supports' stiffness is a table over speed: ``static_sag``).
    Then
    - its mean loss, averaged over a turn, is a stiffness (``stiffness``): exact for every deflection;
    - the rest acting on the sag is a forcing at 1X, 2X, 3X, ... (``forcing``, harmonics 1 .. ``harmonics``);
    - the rest acting on the dynamic deflection (a parametric term, harmonics mixing) is left out: relative to the
      forcing it is |q_dyn| / |q_s| at the crack (docs/model.md, "Faults").
    Absent at dk_xi = dk_eta = 0 (its switches). A vertical rotor (no sag across the shaft) shows no such forcing.
    """

    #: its breathing forces 2X beside 1X and 3X (Mayes: -1/8, -1/4, +1/8 of dk s, nothing beyond), its mean loss
    #: changes the 1X
    signatures: ClassVar[tuple[Signature, ...]] = (Signature("a breathing crack", (2,), (4,), one_x="changed"),)

    name: str = "crack"
    node: int = 0
    place: str = ""
    element_length_m: float = 0.0
    model: str = "mayes"
    cross_terms: bool = True
    harmonics: int = CRACK_HARMONICS
    gravity_m_s2: tuple[float, float] = GRAVITY_M_S2
    sag_m: tuple[float, float] | None = None
    bounds_n_m: tuple[float, float] = (0.0, 1e6)
    limits_n_m: tuple[float, float] | None = None
    meaning: str = "breathing crack in the shaft element right of node 0, opening and closing with the rotation " \
                   "under the rotor's weight: 1X, 2X, 3X"
    parameters: tuple[Parameter, ...] = field(init=False)
    switches: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        if self.model not in BREATHING:
            raise ValueError(f"effect {self.name}: crack model must be one of {sorted(BREATHING)}, got {self.model!r}")
        if not self.element_length_m > 0:
            raise ValueError(f"effect {self.name}: element_length_m (the cracked element's length) must be > 0")
        suffix = f"_{self.place}" if self.place else "" if self.node == 0 else f"_{self.node}"
        self._names = (f"dk_xi{suffix}", f"dk_eta{suffix}", f"psi{suffix}")
        lo, hi = self.bounds_n_m
        limits = self.limits_n_m or (0.0, np.inf)
        self.parameters = (
            Parameter(self._names[0], "N/m", (lo, hi), 0.0, f"tip stiffness the open crack takes from the element "
                      f"right of node {self.node} along its xi axis (0: no crack)", limits),
            Parameter(self._names[1], "N/m", (lo, hi), 0.0, f"the same along its eta axis (node {self.node})",
                      limits),
            Parameter(self._names[2], "rad", (-np.pi, np.pi), 0.0, "the crack's angle at t = 0 (the unbalance's "
                      "is angle_me), in the sense of rotation", (-2 * np.pi, 2 * np.pi)),
        )
        self.switches = self._names[:2]
        self.meaning = self.meaning.replace("node 0", f"node {self.node}")

    def _loss(self, ctx: Context, theta: Array) -> tuple[Array, Array, Array]:
        """dk_xx, dk_yy, dk_xy (S, N) at the crack angles theta (S, N)."""
        xi, eta = (ctx.p[name][:, None] for name in self._names[:2])
        f = sum(a * np.cos(m * theta) for m, a in BREATHING[self.model].items())
        c, s = np.cos(theta), np.sin(theta)
        xy = f * (xi - eta) * s * c if self.cross_terms else np.zeros_like(theta)
        return f * (xi * c * c + eta * s * s), f * (xi * s * s + eta * c * c), xy

    def _dofs(self, ctx: Context) -> tuple[list[int], list[int]]:
        n = self.node
        return ([ctx.dof(d) for d in (f"u{n}", f"du{n}", f"u{n + 1}", f"du{n + 1}")],
                [ctx.dof(d) for d in (f"v{n}", f"dv{n}", f"v{n + 1}", f"dv{n + 1}")])

    def stiffness(self, ctx: Context) -> Array:
        """Minus the loss averaged over a turn, in both planes (the cross term averages to zero)."""
        theta = np.linspace(0.0, 2 * np.pi, CRACK_SAMPLES, endpoint=False)[None, :]
        xx, yy, _ = self._loss(ctx, np.broadcast_to(theta, (ctx.n_scenarios, CRACK_SAMPLES)))
        t = tip_vector(self.element_length_m)
        out = ctx.zeros()
        for dofs, mean in zip(self._dofs(ctx), (xx.mean(axis=1), yy.mean(axis=1))):
            for i, row in enumerate(dofs):
                for j, col in enumerate(dofs):
                    out[:, row, col] -= mean * t[i] * t[j]
        return out

    def forcing(self, ctx: Context) -> dict[int, Array]:
        """The oscillating loss acting on the static sag: harmonics 1 .. ``harmonics`` (class docstring)."""
        if not (np.any(ctx.p[self._names[0]]) or np.any(ctx.p[self._names[1]])):
            return {}  # absent: no harmonic at all (a solver of fewer harmonics must still run)
        (x_dofs, y_dofs), t = self._dofs(ctx), tip_vector(self.element_length_m)
        if self.sag_m is None:
            sag = static_sag(ctx.shaft, ctx.M, ctx.K, self.gravity_m_s2)  # (S, n)
            sx, sy = sag[:, x_dofs] @ t, sag[:, y_dofs] @ t  # (S,)
        else:
            sx, sy = (np.full(ctx.n_scenarios, float(s)) for s in self.sag_m)
        turn = np.linspace(0.0, 2 * np.pi, CRACK_SAMPLES, endpoint=False)  # Omega t over one turn
        xx, yy, xy = self._loss(ctx, turn[None, :] + ctx.p[self._names[2]][:, None])
        fx, fy = xx * sx[:, None] + xy * sy[:, None], xy * sx[:, None] + yy * sy[:, None]  # (S, N) along t
        out = {}
        for h in range(1, self.harmonics + 1):
            phasor = np.exp(-1j * h * turn) * (2.0 / CRACK_SAMPLES)
            f = ctx.zero_vector()
            f[:, x_dofs] = (fx @ phasor)[:, None] * t
            f[:, y_dofs] = (fy @ phasor)[:, None] * t
            out[h] = f
        return out


# --- coupling misalignment ----------------------------------------------------------------------------------


@dataclass(eq=False)
class Misalignment(Effect):
    """A misaligned coupling: a 2X force F(t) on node ``node`` and -F(t) on its neighbour ``partner``.

    F(t) = Re((a_x, a_y) exp(2 i Omega t)), a_x = f2x_c + i f2x_s, a_y = f2y_c + i f2y_s [N] (t = 0: the unbalance
    along +x): a force pair across the element between the two nodes, i.e. a 2X bending moment |F| h on the shaft
    there and no net force, what a flexible coupling's reaction to a parallel or angular offset adds at twice the
    speed (its elements pass the offset twice a turn). Not restricted to forward whirl: x and y independent, as an
    offset in one direction gives. The coupling's constant part (the static preload) moves the mean position only;
    its 4X and higher are not in this effect. Absent at 0 (its switches: all four).
    """

    #: 2X alone: no 1X (ROSS's coupling's is 2 % of its 2X), no 3X
    signatures: ClassVar[tuple[Signature, ...]] = (
        Signature("a misaligned coupling", (2,), (3,), one_x="unchanged"),)

    name: str = "misalignment"
    node: int = 0
    partner: int = 1
    place: str = ""
    bounds_n: tuple[float, float] = (-1.0, 1.0)
    limits_n: tuple[float, float] | None = None
    meaning: str = "misaligned coupling: a 2X force pair across the element at node 0 (a 2X moment, no net force)"
    parameters: tuple[Parameter, ...] = field(init=False)
    switches: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        if self.partner == self.node:
            raise ValueError(f"effect {self.name}: the pair needs two nodes, got {self.node} twice")
        suffix = f"_{self.place}" if self.place else "" if self.node == 0 else f"_{self.node}"
        self._names = tuple(f"f2{axis}_{part}{suffix}" for axis in "xy" for part in "cs")
        words = {"c": "its cos(2 Omega t) coefficient", "s": "minus its sin(2 Omega t) coefficient"}
        self.parameters = tuple(
            Parameter(name, "N", self.bounds_n, 0.0, f"2X force of the pair along {name[2]}, {words[name[4]]} "
                      f"(node {self.node}, minus it at node {self.partner})", self.limits_n)
            for name in self._names)
        self.switches = self._names
        self.meaning = self.meaning.replace("node 0", f"node {self.node}")

    def forcing(self, ctx: Context) -> dict[int, Array]:
        ax = ctx.p[self._names[0]] + 1j * ctx.p[self._names[1]]
        ay = ctx.p[self._names[2]] + 1j * ctx.p[self._names[3]]
        if not (np.any(ax) or np.any(ay)):
            return {}
        f = ctx.zero_vector()
        for node, sign in ((self.node, 1.0), (self.partner, -1.0)):
            f[:, ctx.dof(f"u{node}")] += sign * ax
            f[:, ctx.dof(f"v{node}")] += sign * ay
        return {2: f}


# --- mechanical looseness -------------------------------------------------------------------------------------


@dataclass(eq=False)
class Looseness(Effect):
    """A bearing of stiffness k loose in its housing by a radial clearance delta: its spring acts only beyond it.

    The bearing's linear spring -k (u, v) stays in the model (its ``linear_bearing``); this effect adds what the
    clearance takes away, k min(1, delta / r) (u, v) at r = |(u, v)|: the total -k max(0, r - delta) (u, v) / r,
    nothing inside the clearance, a spring beyond. Piecewise, so it declares the harmonics its balance needs
    (``LOOSENESS_HARMONICS``, sampled at 64 instants a period): on an elliptic orbit it adds odd harmonics (3X, 5X),
    with a static load (the weight) 2X as well;
    subharmonics (1/2X) lie outside a harmonic balance at the rotation's period and show as its non-convergence.
    Absent at delta = 0 (its switch).
    """

    #: the clearance softens the support (the 1X raised below a critical speed) and adds 3X
    signatures: ClassVar[tuple[Signature, ...]] = (Signature("a loose bearing", (3,), one_x="raised"),)

    name: str = "looseness"
    node: int = 0
    place: str = ""
    k_n_m: float = 0.0
    bounds_m: tuple[float, float] = (0.0, 1e-4)
    limits_m: tuple[float, float] | None = None
    meaning: str = "loose bearing at node 0: its spring acts only beyond a radial clearance"
    parameters: tuple[Parameter, ...] = field(init=False)
    dofs: tuple[str, ...] = field(init=False)
    switches: tuple[str, ...] = field(init=False)
    degree: int | None = None
    needs_harmonics: int | None = LOOSENESS_HARMONICS
    needs_time_samples: int | None = RUB_TIME_SAMPLES

    def __post_init__(self) -> None:
        if not self.k_n_m > 0:
            raise ValueError(f"effect {self.name}: k_n_m (the bearing's stiffness) must be > 0")
        suffix = f"_{self.place}" if self.place else "" if self.node == 0 else f"_{self.node}"
        name = f"delta_loose{suffix}"
        self.parameters = (Parameter(name, "m", self.bounds_m, 0.0, f"radial clearance of the bearing at node "
                                     f"{self.node} in its housing (0: tight)", self.limits_m or (0.0, np.inf)),)
        self.switches = (name,)
        self.dofs = (f"u{self.node}", f"v{self.node}")
        self.meaning = self.meaning.replace("node 0", f"node {self.node}")

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        """F = k g (u, v), g = min(1, delta / r), and its derivative (class docstring)."""
        delta = p[self.switches[0]][:, None]
        u, v = q[:, 0], q[:, 1]
        r = np.hypot(u, v)
        beyond = r > delta
        safe = np.where(r > 0, r, 1.0)
        g = np.where(beyond, delta / safe, 1.0)
        dg = np.where(beyond, -delta / safe**3, 0.0)  # dg/du = dg u, dg/dv = dg v
        k = self.k_n_m
        F = np.stack([k * g * u, k * g * v], axis=1)
        J = np.empty(q.shape[:1] + (2, 2) + q.shape[2:])
        J[:, 0, 0] = k * (dg * u * u + g)
        J[:, 0, 1] = k * dg * u * v
        J[:, 1, 0] = k * dg * v * u
        J[:, 1, 1] = k * (dg * v * v + g)
        return F, J


# --- the faults as candidates of a machine of one's own ----------------------------------------------------------

#: a loose bearing's clearance range [m]: up to 20 um, the scale of a proximity probe's 1X on a machine; limits to
#: 1 mm, far beyond any housing fit
LOOSENESS_RANGE_M, LOOSENESS_LIMIT_M = 2e-5, 1e-3
#: the crack's loss range as a share of the element's cantilever tip stiffness 3 E I / h^3 (ROSS's Mayes crack of
#: depth ratio 0.2 in a 19 mm shaft takes 17 % along eta); limits: all of it
CRACK_RANGE, CRACK_LIMIT = 0.2, 1.0
#: a rub's clearance range as a share of the shaft's diameter at the plane: a seal's or a stator ring's radial
#: clearance is of the order of 1-5 thousandths of the diameter (ROSS's example rubs at 79.5 um on a 19 mm shaft,
#: 4.2 thousandths); limits 5 %, far beyond any running clearance
RUB_CLEARANCE_RANGE, RUB_CLEARANCE_LIMIT = 5e-3, 5e-2
#: its contact stiffness range as a multiple of the bearings' summed stiffness (a stator's contact, like a support,
#: stiff beside the shaft's own bending; ROSS's example 1.1e6 N/m beside bearings of 1e6 and 8e5 each); limits 100 x
RUB_STIFFNESS_RANGE, RUB_STIFFNESS_LIMIT = 1.0, 100.0
#: its friction coefficient's range (dry steel on a seal's or a casing's material, 0.1-0.3) and limits
RUB_FRICTION_RANGE, RUB_FRICTION_LIMIT = (0.0, 0.3), (0.0, 1.0)


def fault_candidates(machine, force_n: float) -> list[Effect]:
    """The faults as candidates on ``machine`` (``Machine.sized_candidates``), each absent at 0 (its switches):

    - ``looseness@B`` at every bearing B with nominal k: its clearance delta_loose_B in 0 .. 20 um;
    - ``misalignment@B`` at every such bearing: the 2X force pair across the element from B's node towards the
      nearer shaft end (where a coupling sits beyond a bearing; inwards at an end node), each component within
      +-``force_n`` [N] (the 2X, 3X forces' range: what moves the rotor 10 um on its supports), limits ten times;
    - ``crack@P`` at every unbalance plane P (a disk's node, where the bending moment is large): the element from
      P's node to the next (the previous at the last node), losses within 20 % of its 3 E I / h^3, psi free; the
      weight along -y (a horizontal machine, y up, as ROSS's rotors);
    - ``rub@P`` at every unbalance plane P (a disk, where the orbit is large and a seal or a casing is near): its
      clearance within 5 thousandths of the shaft's diameter there, its contact stiffness within the bearings'
      summed k, its friction within 0.3; all three tested (absent at k_rub = 0: ``Rub``).

    None where no bearing has a nominal k (``force_n`` 0: the VARM, a vertical rotor whose weight does not bend it).
    """
    if not force_n > 0:
        return []
    out: list[Effect] = []
    last = machine.n_nodes - 1
    for bearing in machine.bearings:
        if not bearing.k:
            continue
        n = bearing.node
        out.append(Looseness(name=f"looseness@{bearing.name}", node=n, place=bearing.name, k_n_m=bearing.k,
                             bounds_m=(0.0, LOOSENESS_RANGE_M), limits_m=(0.0, LOOSENESS_LIMIT_M),
                             meaning=f"loose bearing {bearing.name} at node 0: its spring acts only beyond a radial "
                                     "clearance"))
        outwards = n - 1 if n <= last - n else n + 1
        partner = outwards if 0 <= outwards <= last else (n + 1 if n == 0 else n - 1)
        out.append(Misalignment(name=f"misalignment@{bearing.name}", node=n, partner=partner,
                                place=bearing.name, bounds_n=(-force_n, force_n),
                                limits_n=(-10 * force_n, 10 * force_n),
                                meaning=f"misaligned coupling beside bearing {bearing.name}: a 2X force pair "
                                        f"across the element at node 0 and {partner} (a 2X moment)"))
    for plane in machine.unbalance_planes:
        n = plane.node if plane.node < last else plane.node - 1
        h = float(machine.z[n + 1] - machine.z[n])
        tip = 3 * sum(s.E * s.bending_I for e, s in machine._elements if e == n) / h**3
        out.append(Crack(name=f"crack@{plane.name}", node=n, place=plane.name, element_length_m=h,
                         bounds_n_m=(0.0, CRACK_RANGE * tip), limits_n_m=(0.0, CRACK_LIMIT * tip),
                         meaning=f"breathing crack at unbalance plane {plane.name} (the element right of node 0), "
                                 "opening and closing with the rotation under the rotor's weight: 1X, 2X, 3X"))
    k_sum = sum(b.k for b in machine.bearings if b.k)
    for plane in machine.unbalance_planes:
        d = max(s.d_out for e, s in machine._elements if e in (plane.node - 1, plane.node))
        out.append(Rub(name=f"rub@{plane.name}", node=plane.node, place=plane.name,
                       clearance_m=(0.0, RUB_CLEARANCE_RANGE * d), stiffness_n_m=(0.0, RUB_STIFFNESS_RANGE * k_sum),
                       friction=RUB_FRICTION_RANGE,
                       limits=((0.0, RUB_CLEARANCE_LIMIT * d), (0.0, RUB_STIFFNESS_LIMIT * k_sum),
                               RUB_FRICTION_LIMIT),
                       meaning=f"rub on a stator ring at unbalance plane {plane.name} (node {plane.node}): a contact "
                               "spring "
                               "beyond a clearance and its friction; a held-down 1X, 3X (2X with a static load)"))
    return out


#: the fault effects, each with its ``signatures`` (``diagnose.fingerprint.resembles``)
FAULTS = (Crack, Misalignment, Rub, Looseness)
