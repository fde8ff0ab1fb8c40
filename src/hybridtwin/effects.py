"""Physical effects: the building blocks of a model (shared/varm-model.md).

An effect is a self-describing object: a ``name``, a one-line physical
``meaning``, its ``parameters`` (name, unit, range, nominal value) and its
contribution to the equations of motion

    M q'' + C q' + K q = f(t) + F_nl(q)                          (eq. 29)

through any of these hooks, all vectorised over S scenarios:

- ``mass(ctx)``, ``stiffness(ctx)``: linear terms at rest, arrays broadcastable
  to (S, n, n);
- ``speed_stiffness(ctx)``, ``damping(ctx)``: linear terms that may use the
  speed ``ctx.Omega``, the assembled mass ``ctx.M``, the first mode
  (``ctx.omega_1``, ``ctx.Phi_1``) or the support stiffness ``ctx.K_support``;
- ``forcing(ctx)``: harmonics {h: (S, n) complex} of the external force under
  f(t) = Re(sum_h F_h exp(i h Omega t)), t = 0 with the unbalance on +x;
- ``force(q, p)``: a local nonlinear force acting on the shaft at the DOFs
  ``dofs`` and its analytic derivative, evaluated pointwise in time (the AFT
  step of the solver).

The solver only sees the assembled matrices, forcing and local forces, so a
new effect (in a user's own file) never needs a change to the solver.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .shaft import Shaft

Array = np.ndarray


@dataclass(frozen=True)
class Parameter:
    """A model parameter: SI unit, plausible range, nominal value, meaning."""

    name: str
    unit: str
    bounds: tuple[float, float]
    nominal: float
    meaning: str

    def __post_init__(self) -> None:
        lo, hi = self.bounds
        if not lo <= hi:
            raise ValueError(f"parameter {self.name}: range {self.bounds} is empty")


class Params(Mapping[str, Array]):
    """Parameter values of S scenarios: ``p.k_b`` or ``p["k_b"]``, each shape (S,)."""

    def __init__(self, values: Mapping[str, Array], rows: Array | slice | None = None):
        self._values = dict(values)
        self._rows = rows

    def rows(self, rows: Array) -> "Params":
        """The same parameters for scenarios ``rows`` only (sliced lazily, name by name)."""
        return Params(self._values, rows)

    def __getitem__(self, name: str) -> Array:
        try:
            value = self._values[name]
        except KeyError:
            raise KeyError(f"parameter {name!r} has no value (known: {sorted(self._values)})") from None
        return value if self._rows is None else value[self._rows]

    def __getattr__(self, name: str) -> Array:
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return self[name]
        except KeyError as err:
            raise AttributeError(str(err)) from None

    def __iter__(self):
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)


@dataclass
class Context:
    """What the effects see while a model is assembled, stage by stage.

    Stages: mass -> stiffness at rest -> first mode -> speed terms, damping, forcing.
    Attributes are None until their stage has run.
    """

    shaft: Shaft
    p: Params
    Omega: Array  # rotational speed per scenario [rad/s], shape (S,)
    M: Array | None = None  # assembled mass, (S, n, n)
    K: Array | None = None  # assembled stiffness at rest (shaft + effects), (S, n, n)
    K_support: Array | None = None  # the effects' part of K only (bearings, supports)
    omega_1: Array | None = None  # lowest undamped natural frequency of the x plane [rad/s], (S,)
    Phi_1: Array | None = None  # its mode, translational DOFs of node 0..n, max |entry| = +1, (S, n+1)

    @property
    def n_scenarios(self) -> int:
        return self.Omega.shape[0]

    def dof(self, name: str) -> int:
        return self.shaft.dof(name)

    def zeros(self, dtype: type = float) -> Array:
        """A zero (S, n, n) matrix to fill with a contribution."""
        n = self.shaft.n_dof
        return np.zeros((self.n_scenarios, n, n), dtype=dtype)

    def zero_vector(self) -> Array:
        """A zero (S, n) complex forcing vector."""
        return np.zeros((self.n_scenarios, self.shaft.n_dof), dtype=complex)


class Effect:
    """Base class of a physical effect; override the hooks that apply.

    Class attributes to set: ``name``, ``meaning``, ``parameters``; for a
    nonlinear force also ``dofs`` (the DOF names it reads and acts on, e.g.
    ("u0", "v0")) and ``degree`` (its polynomial degree, which sets the number
    of AFT time samples; None when not polynomial).
    """

    name: str = ""
    meaning: str = ""
    parameters: tuple[Parameter, ...] = ()
    dofs: tuple[str, ...] = ()
    degree: int | None = None

    def mass(self, ctx: Context) -> Array | None:
        return None

    def stiffness(self, ctx: Context) -> Array | None:
        return None

    def speed_stiffness(self, ctx: Context) -> Array | None:
        return None

    def damping(self, ctx: Context) -> Array | None:
        return None

    def forcing(self, ctx: Context) -> dict[int, Array]:
        return {}

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        """Nonlinear force on the shaft at ``dofs`` and its derivative.

        q: (S, d, N) displacements of the d = len(dofs) local DOFs at N instants.
        Returns F (S, d, N) and dF/dq (S, d, d, N).
        """
        raise NotImplementedError(f"effect {self.name!r} declares dofs but no force()")

    @property
    def is_nonlinear(self) -> bool:
        return bool(self.dofs)

    def describe(self) -> str:
        """Multi-line, human-readable summary (name, meaning, parameters)."""
        lines = [f"{self.name}: {self.meaning}"]
        for par in self.parameters:
            lo, hi = par.bounds
            lines.append(
                f"  {par.name} [{par.unit}] nominal {par.nominal:g}, range {lo:g} .. {hi:g}: {par.meaning}"
            )
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<Effect {self.name}>"


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

    def mass(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, 0, ctx.p.m_bup)

    def damping(self, ctx: Context) -> Array:
        out = ctx.zeros()
        for i in _node_pair(ctx, 0):
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

    def mass(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, ctx.shaft.n, ctx.p.m_blo)

    def stiffness(self, ctx: Context) -> Array:
        return _isotropic_point(ctx, ctx.shaft.n, ctx.p.k)

    def damping(self, ctx: Context) -> Array:
        c_blo = 2.0 * ctx.p.zeta_blo * np.sqrt(ctx.p.k * ctx.p.m_blo)
        return _isotropic_point(ctx, ctx.shaft.n, c_blo)


def _unbalance_nodes(ctx: Context) -> Array:
    return np.array([ctx.shaft.node_at(z) for z in np.broadcast_to(ctx.p.z_me, ctx.Omega.shape)])


class Unbalance(Effect):
    """Eccentric mass m_e at z_me: point mass and rotating force (eq. 14-15, 30).

    f = m_e r_me Omega^2 (cos Omega t, sin Omega t) at the node nearest z_me, so
    F_1 = m_e r_me Omega^2 in x and -i m_e r_me Omega^2 in y.
    """

    name = "unbalance"
    meaning = "eccentric (unbalance) mass: its point mass and the rotating force m_e r_me Omega^2 (eq. 14-15)"
    parameters = (
        Parameter("m_e", "kg", (0.0, 0.040), 0.0, "eccentric mass"),
        Parameter("r_me", "m", (0.0, 0.1), 0.040, "eccentricity of the eccentric mass"),
        Parameter("z_me", "m", (0.0, 0.85), 0.425, "axial position of the eccentric mass"),
    )

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
        amplitude = ctx.p.m_e * ctx.p.r_me * ctx.Omega**2
        f[rows, ctx.shaft.translational("x")[nodes]] = amplitude
        f[rows, ctx.shaft.translational("y")[nodes]] = -1j * amplitude
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

    def forcing(self, ctx: Context) -> dict[int, Array]:
        f = ctx.zero_vector()
        scale = (ctx.p.m_el * ctx.Omega**2)[:, None] * ctx.Phi_1
        f[:, ctx.shaft.translational("x")] = ctx.p.q_x[:, None] * scale
        f[:, ctx.shaft.translational("y")] = -1j * ctx.p.q_y[:, None] * scale
        return {1: f}


# --- polynomial bearing forces (eq. 22-24, 38-39) ---------------------------------------


@dataclass(frozen=True)
class Term:
    """One monomial of a bearing force: F_x -= coefficient * u^a v^b (u')^c (v')^d.

    ``powers`` = (a, b, c, d) in the variables (own deflection, other deflection,
    own slope, other slope); the y component swaps x <-> y.
    """

    coefficient: Callable[[Params], Array]
    powers: tuple[int, int, int, int]
    label: str

    @property
    def degree(self) -> int:
        return sum(self.powers)


_VARIABLES = ("u", "v", "du", "dv")


@dataclass(eq=False)
class PolynomialBearing(Effect):
    """A bearing force that is a polynomial of the node's deflections and slopes.

    F_x = -sum_terms c u^a v^b (u')^c (v')^d, and F_y the same with x <-> y.
    Terms of degree one go into the linear stiffness (the solver's linear
    operator); the others are the local nonlinear force with its exact derivative.
    """

    name: str = ""
    meaning: str = ""
    parameters: tuple[Parameter, ...] = ()
    terms: tuple[Term, ...] = ()
    node: int = 0
    dofs: tuple[str, ...] = field(init=False)
    degree: int | None = field(init=False)

    def __post_init__(self) -> None:
        nonlinear = [t for t in self.terms if t.degree > 1]
        uses_slope = any(t.powers[2] or t.powers[3] for t in nonlinear)
        names = _VARIABLES if uses_slope else _VARIABLES[:2]
        self.dofs = tuple(f"{v}{self.node}" for v in names) if nonlinear else ()
        self.degree = max((t.degree for t in nonlinear), default=None)
        if any(t.degree < 1 for t in self.terms):
            raise ValueError(f"effect {self.name}: a constant term is not a bearing stiffness")

    def stiffness(self, ctx: Context) -> Array:
        out = ctx.zeros()
        own = {"x": ("u", "v", "du", "dv"), "y": ("v", "u", "dv", "du")}
        for term in self.terms:
            if term.degree != 1:
                continue
            c = term.coefficient(ctx.p)
            for variables in own.values():
                row = ctx.dof(f"{variables[0]}{self.node}")
                col = ctx.dof(f"{variables[term.powers.index(1)]}{self.node}")
                out[:, row, col] += c
        return out

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        n_local = q.shape[1]
        F = np.zeros_like(q)
        J = np.zeros(q.shape[:2] + (n_local,) + q.shape[2:])
        max_power = max(max(t.powers) for t in self.terms)
        powers = [_powers(q[:, j], max_power) for j in range(n_local)]
        # local index of (own deflection, other deflection, own slope, other slope) per plane
        planes = ((0, 1, 2, 3), (1, 0, 3, 2))
        for term in self.terms:
            if term.degree < 2:
                continue
            c = term.coefficient(p)[:, None]
            for variables in planes:
                row = variables[0]
                factors = [powers[variables[k]][e] for k, e in enumerate(term.powers) if e]
                exps = [(variables[k], e) for k, e in enumerate(term.powers) if e]
                F[:, row] -= c * _product(factors)
                for m, (local, e) in enumerate(exps):
                    others = factors[:m] + factors[m + 1 :]
                    derivative = e * powers[local][e - 1]
                    J[:, row, local] -= c * _product(others + [derivative])
        return F, J

    @classmethod
    def combined(cls, bearings: Sequence["PolynomialBearing"]) -> "PolynomialBearing":
        """One bearing whose force is the sum of ``bearings``' (same node): one AFT evaluation, not many."""
        nodes = {b.node for b in bearings}
        if len(nodes) != 1:
            raise ValueError(f"only bearings at one node can be combined, got nodes {sorted(nodes)}")
        parameters = tuple({p.name: p for b in bearings for p in b.parameters}.values())
        return cls(name="+".join(b.name for b in bearings), meaning="combined bearing forces",
                   parameters=parameters, terms=tuple(t for b in bearings for t in b.terms), node=nodes.pop())

    def describe(self) -> str:
        text = super().describe()
        formula = " + ".join(t.label for t in self.terms)
        return f"{text}\n  F_x = -({formula}) at node {self.node}, F_y with x <-> y"


def _powers(x: Array, n: int) -> list[Array]:
    """[1, x, x*x, ...] up to x^n by repeated products (x**k is far slower)."""
    out = [np.ones_like(x), x]
    for _ in range(2, n + 1):
        out.append(out[-1] * x)
    return out


def _product(factors: Sequence[Array]) -> Array:
    out = factors[0]
    for f in factors[1:]:
        out = out * f
    return out


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
    )


def _expansion_term(index: int, powers: tuple[int, int, int, int], scale: str, meaning: str,
                    unit: str, bounds: tuple[float, float], nominal: float) -> PolynomialBearing:
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
    )


def expansion_terms() -> list[PolynomialBearing]:
    """The seven terms of the Expansion model of the upper bearing force (eq. 23-24)."""
    return [
        _expansion_term(1, (3, 0, 0, 0), "/l_i^2", "cubic stiffness of the upper bearing", "N/m", (0, 3500), 2562.7),
        _expansion_term(2, (2, 0, 0, 0), "/l_i", "quadratic (asymmetric) stiffness of the upper bearing", "N/m",
                        (-1000, 1000), -70.9),
        _expansion_term(3, (1, 0, 0, 0), "", "linear stiffness of the upper bearing", "N/m", (0, 7000), 5428.5),
        _expansion_term(4, (0, 0, 1, 0), "", "linear force on the shaft slope at the upper bearing", "N",
                        (-1000, 1000), 341.1),
        _expansion_term(5, (1, 1, 0, 0), "/l_i", "quadratic cross-coupling u v of the upper bearing", "N/m",
                        (-1000, 1000), 60.9),
        _expansion_term(6, (0, 0, 3, 0), "", "cubic force on the shaft slope at the upper bearing", "N",
                        (-1000, 1000), 293.0),
        _expansion_term(7, (1, 2, 0, 0), "/l_i^2", "cubic cross-coupling u v^2 of the upper bearing", "N/m",
                        (-14000, 14000), -627.7),
    ]


def base_effects() -> list[Effect]:
    """Effects every VARM variant shares: the machine without its upper bearing spring."""
    return [CentrifugalSoftening(), StructuralDamping(), UpperHousing(), LowerBearing(), Unbalance(), ShaftBow()]


def builtin_effects() -> dict[str, Effect]:
    """All effects the package ships, by name."""
    effects: list[Effect] = base_effects() + [geometric_spring(), radial_spring(), slope_spring()]
    effects += expansion_terms()
    return {e.name: e for e in effects}
