"""What an effect is: the types every physical effect is written with (docs/model.md).

An effect is a self-describing object: a ``name``, a one-line physical
``meaning``, its ``parameters`` (name, unit, range, nominal value) and its
contribution to the equations of motion

    M q'' + C q' + K q = f(t) + F_nl(q)                          (eq. 29)

through any of these hooks, all vectorised over S scenarios:

- ``mass(ctx)``, ``stiffness(ctx)``: linear terms at rest, arrays broadcastable
  to (S, n, n), or a ``LocalMatrix`` (a block at a few DOFs: an effect at one node, with no (S, n, n) of zeros);
- ``speed_mass(ctx)``: a mass term that changes with the speed (a bearing's or seal's added mass from a table
  over speed), evaluated at each scenario's speed and added to its mass matrix;
- ``speed_stiffness(ctx)``, ``damping(ctx)``: linear terms that may use the
  speed ``ctx.Omega``, the assembled mass ``ctx.M``, the first mode
  (``ctx.omega_1``, ``ctx.Phi_1``) or the support stiffness ``ctx.K_support``;
- ``forcing(ctx)``: harmonics {h: (S, n) complex} of the external force under
  f(t) = Re(sum_h F_h exp(i h Omega t)), t = 0 with the unbalance on +x;
- ``force(q, p)``: a local nonlinear force acting on the shaft at the DOFs
  ``dofs`` and its analytic derivative, evaluated pointwise in time (the AFT
  step of the solver).

A bearing force that is a polynomial of a node's deflections and slopes needs
no class of its own: it is a ``PolynomialBearing`` of ``Term``s (eq. 22-24,
38-39), with its linear part in the stiffness and the rest as a local force.

The solver only sees the assembled matrices, forcing and local forces, so a
new effect (in a user's own file) never needs a change to the solver. The
effects the package ships are in ``hybridtwin.model.effects``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from .shaft import Shaft

Array = np.ndarray



@dataclass(frozen=True)
class Parameter:
    """A model parameter: SI unit, plausible range, nominal value, meaning.

    ``limits``: how far the range may physically go when a fit needs more (the diagnosis widens a
    candidate's range up to them, e.g. a stiffness change that would make a spring negative is
    not physical); None: no limit known (the diagnosis then widens up to 100 times the range).
    """

    name: str
    unit: str
    bounds: tuple[float, float]
    nominal: float
    meaning: str
    limits: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        lo, hi = self.bounds
        if not lo <= hi:
            raise ValueError(f"parameter {self.name}: range {self.bounds} is empty")
        if self.limits is not None and not self.limits[0] <= lo <= hi <= self.limits[1]:
            raise ValueError(f"parameter {self.name}: range {self.bounds} is not inside its physical limits "
                             f"{self.limits}")


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


@dataclass(frozen=True)
class LocalMatrix:
    """A linear term that acts on a few DOFs only: ``block`` (S, r, r) (or broadcastable to it) at the rows and
    columns ``dofs`` (r,) of the (S, n, n) matrix, zero elsewhere. An effect at one node (a bearing or seal from a
    table, a point bearing, a point mass) returns it from any of the matrix hooks instead of an (S, n, n) array of
    zeros: the model adds the block where it acts, the same sums entry by entry (ROSS's compressor: 14 bearings and
    seals, 2 x 2 each, in 224 x 224 matrices)."""

    dofs: Array
    block: Array

    @classmethod
    def diagonal(cls, dofs: Sequence[int], value: Array, n_scenarios: int) -> "LocalMatrix":
        """``value`` (scalar or (S,)) on the diagonal at each of ``dofs``: a point spring, damper or mass."""
        block = np.zeros((n_scenarios, len(dofs), len(dofs)))
        for i in range(len(dofs)):
            block[:, i, i] = value
        return cls(np.asarray(dofs), block)

    def add_to(self, total: Array) -> None:
        """total[:, dofs, dofs] += block, in place (``total`` (S, n, n); block broadcastable to (S, r, r))."""
        total[:, self.dofs[:, None], self.dofs[None, :]] += self.block

    def dense(self, ctx: "Context") -> Array:
        """The term as an (S, n, n) array, for code that combines hook results."""
        out = ctx.zeros()
        self.add_to(out)
        return out


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

    def rows(self, rows: Array) -> "Context":
        """The same context for scenarios ``rows`` only: parameters and every assembled stage, sliced now
        (a system's forces slice its parameters again, lazily, at every evaluation). Every scenario in order:
        this context itself; consecutive scenarios (a sweep's step where the first columns go on): views, not
        copies (the copies of its (S, n, n) stages were a tenth of an offline chunk's solves)."""
        rows = np.asarray(rows)
        if rows.ndim == 1 and rows.dtype != bool and rows.size and (np.diff(rows) == 1).all():
            if rows.size == self.n_scenarios:
                return self
            rows = slice(int(rows[0]), int(rows[-1]) + 1)  # consecutive scenarios: views, no copies
        staged = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("shaft", "p")}
        return Context(shaft=self.shaft, p=Params({name: self.p[name][rows] for name in self.p}),
                       **{name: None if value is None else value[rows] for name, value in staged.items()})

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

    ``switches``: for an effect the diagnosis may test as a candidate (``hybridtwin.model.candidates``),
    the parameters that switch it on, each absent at 0 (the effect then adds nothing); the others
    (e.g. l_i) keep their values. Their ranges are those of their ``Parameter``s. Empty: not
    declared; a built-in effect is then no candidate, and an effect of a user's effects file
    named as a candidate has all its parameters tested.

    ``inertial``: True for an effect whose forcing is the inertia of a mass turning with the shaft (its
    Omega^2 coefficient A_h then becomes A_h (Omega^2 - i Omega' / h) at variable speed, ``hybridtwin.solvers.sweep``).
    """

    name: str = ""
    meaning: str = ""
    parameters: tuple[Parameter, ...] = ()
    dofs: tuple[str, ...] = ()
    degree: int | None = None
    switches: tuple[str, ...] = ()
    #: its forcing is the inertia of a rotating mass (unbalance, bow): at variable speed its Omega^2 term gets the
    #: tangential term too, A (Omega^2 - i Omega' / h) (hybridtwin.solvers.sweep); other forces read Omega(t) only
    inertial: bool = False
    #: a non-smooth local force (a contact, a clearance): the harmonics its harmonic balance must carry for the
    #: harmonics a fit compares to be right, and the time samples a period its AFT step takes (None: a smooth force,
    #: the data's harmonics and the solver's samples do). ``hybridtwin.solvers.resolution`` reads them
    needs_harmonics: int | None = None
    needs_time_samples: int | None = None

    def mass(self, ctx: Context) -> Array | None:
        return None

    def stiffness(self, ctx: Context) -> Array | None:
        return None

    def speed_mass(self, ctx: Context) -> Array | None:
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
        if self.switches:
            lines.append(f"  as a diagnosis candidate: switched on by {', '.join(self.switches)}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<Effect {self.name}>"


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
#: the y plane's (own deflection, other deflection, own slope, other slope) as indices into _VARIABLES
_OTHER_PLANE = (1, 0, 3, 2)


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
    switches: tuple[str, ...] = ()
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

    def stiffness(self, ctx: Context) -> LocalMatrix:
        """The linear terms, a block over the node's (u, v, du, dv)."""
        dofs = [ctx.dof(f"{v}{self.node}") for v in _VARIABLES]
        out = np.zeros((ctx.n_scenarios, len(dofs), len(dofs)))
        own = [_VARIABLES, tuple(_VARIABLES[i] for i in _OTHER_PLANE)]  # the x plane's force, the y plane's
        for term in self.terms:
            if term.degree != 1:
                continue
            c = term.coefficient(ctx.p)
            for variables in own:
                row = _VARIABLES.index(variables[0])
                col = _VARIABLES.index(variables[term.powers.index(1)])
                out[:, row, col] += c
        return LocalMatrix(np.array(dofs), out)

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        """F (S, n_local, N) and dF/dq (S, n_local, n_local, N) at the time samples q (S, n_local, N).

        Both planes at once: q's variables are stacked as (own deflection, other deflection, own slope,
        other slope) of the x plane and of the y plane, (2, S, n_local, N), so every monomial is one
        product for both (elementwise the same arithmetic as plane by plane)."""
        n_local = q.shape[1]
        swap = list(_OTHER_PLANE[:n_local])  # the y plane's variables in the x plane's order
        max_power = max(max(t.powers) for t in self.terms)
        powers = _powers(np.stack([q, q[:, swap]]), max_power)  # [e] -> (2, S, n_local, N)
        F = np.zeros((2,) + q.shape[:1] + q.shape[2:])  # (plane, S, N): the force on its own deflection
        J = np.zeros((2,) + q.shape)  # (plane, S, variable, N)
        for term in self.terms:
            if term.degree < 2:
                continue
            c = term.coefficient(p)[:, None]
            exps = [(k, e) for k, e in enumerate(term.powers) if e]
            factors = [powers[e][:, :, k] for k, e in exps]
            F -= c * _product(factors)
            for m, (k, e) in enumerate(exps):
                others = factors[:m] + factors[m + 1 :]
                J[:, :, k] -= c * _product(others + [e * powers[e - 1][:, :, k]])
        F_out = np.zeros_like(q)
        F_out[:, 0], F_out[:, 1] = F[0], F[1]
        J_out = np.zeros(q.shape[:2] + (n_local,) + q.shape[2:])
        J_out[:, 0], J_out[:, 1, swap] = J[0], J[1]
        return F_out, J_out

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
