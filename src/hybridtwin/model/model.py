"""A model = the FE shaft + a composition of physical effects (docs/model.md).

``Model.system(params, rpm)`` assembles, for S scenarios at once, the second-order
system that the steady-state solver works on (eq. 29)::

    M q'' + C q' + K q = Re(sum_h F_h exp(i h Omega t)) + F_nl(q)

in the effects' stage order: mass, stiffness at rest, first mode (omega_1,
Phi_1 of the x plane at Omega = 0), then speed terms, damping and forcing.
``Model.at_rest`` runs the stages up to the first mode (they do not depend on the
speed) and ``Model.system_at`` the rest at any speed, so a sweep assembles the
former once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
import scipy.linalg

from .effect_base import Array, Context, Effect, LocalMatrix, Parameter, Params, PolynomialBearing
from .machine import Machine, default_machine
from .shaft import Shaft


def rpm_to_rad_s(rpm: Array | float) -> Array:
    """Omega = 2 pi RPM / 60."""
    return np.asarray(rpm, dtype=float) * (2.0 * np.pi / 60.0)


@dataclass
class LocalForce:
    """A nonlinear force acting at a few DOFs of the system.

    ``evaluate(q, rows)`` returns the force on the structure F (S', d, N) and its
    derivative dF/dq (S', d, d, N) at displacements q (S', d, N) of the DOFs
    ``dofs``, for the scenarios ``rows`` of the parameter set it was built with.
    """

    name: str
    dofs: np.ndarray
    evaluate: Callable[[Array, np.ndarray], tuple[Array, Array]]
    degree: int | None


@dataclass
class System:
    """Second-order system of S scenarios, each with its own fundamental Omega.

    M, C, K: (S, n, n), K including the speed terms; forcing: {h: (S, n) complex};
    ``rows``: each scenario's row in the parameter set the forces were built with.
    """

    M: Array
    C: Array
    K: Array
    Omega: Array
    forcing: dict[int, Array]
    forces: list[LocalForce] = field(default_factory=list)
    rows: np.ndarray | None = None
    problems: np.ndarray | None = None  # (S,) str: why a scenario has no steady state ("" if none known)

    def __post_init__(self) -> None:
        if self.rows is None:
            self.rows = np.arange(self.n_scenarios)
        if self.problems is None:
            self.problems = np.full(self.n_scenarios, "", dtype=object)

    @property
    def n_scenarios(self) -> int:
        return self.Omega.shape[0]

    @property
    def n_dof(self) -> int:
        return self.M.shape[-1]

    def subset(self, sel: np.ndarray) -> "System":
        """The same system restricted to scenarios ``sel`` (indices or mask)."""
        return System(self.M[sel], self.C[sel], self.K[sel], self.Omega[sel],
                      {h: f[sel] for h, f in self.forcing.items()}, self.forces, self.rows[sel], self.problems[sel])


def distinct_scenarios(*stacks: Array) -> tuple[Array, Array]:
    """The scenarios whose matrices ``stacks`` (each (S, ...)) are all equal found once: the index of the first of
    each distinct set and, per scenario, which set it is in (``first[inverse]`` is a scenario with the same
    matrices). Runs at one speed that differ in their forcing only, or a batch's repeated parameter sets, share their
    linear system: its eigenproblems are solved once, with the same numbers as each scenario's own.

    Candidates by a key (the bytes of a fixed pseudo-random sample of the entries: equal matrices give equal keys),
    confirmed entry by entry (NaN equals nothing); O(S n^2) at most, against O(n^3) for an eigenproblem."""
    S = stacks[0].shape[0]
    flat = [np.reshape(A, (S, -1)) for A in stacks]
    keys = np.concatenate([f[:, _sample(f.shape[1])] for f in flat], axis=1)
    first: list[int] = []
    inverse = np.empty(S, int)
    candidates: dict[bytes, list[int]] = {}
    for s in range(S):
        key = keys[s].tobytes()
        for g in candidates.get(key, []):
            if all(np.array_equal(f[s], f[first[g]]) for f in flat):
                inverse[s] = g
                break
        else:
            candidates.setdefault(key, []).append(len(first))
            inverse[s] = len(first)
            first.append(s)
    return np.array(first, int), inverse


@functools.lru_cache(maxsize=8)
def _sample(size: int) -> Array:
    """Up to 64 fixed pseudo-random positions among ``size`` entries, for ``distinct_scenarios``' keys (read-only)."""
    positions = np.sort(np.random.default_rng(53).choice(size, min(size, 64), replace=False))
    positions.flags.writeable = False
    return positions


def _first_mode(K: Array, M: Array) -> tuple[Array, Array]:
    """Lowest undamped natural frequency and mode shape of the pencils (K, M), batched.

    omega_1 is NaN where the lowest eigenvalue is not positive (unstable at rest).

    Scenario by scenario (so a scenario's mode does not depend on the others in its batch):
    symmetric K by Cholesky reduction and eigh, otherwise the general eigenproblem of M^-1 K,
    taking the eigenvalue of least real part.
    """
    # scenarios with the same pencil (another run's copy, a parameter that does not enter K or M at rest, e.g.
    # the sensitivities' perturbed damping or bow) are solved once: the same numbers, bit for bit
    first, inverse = distinct_scenarios(K, M)
    K, M = K[first], M[first]
    symmetric = np.isclose(K, np.swapaxes(K, -1, -2), rtol=1e-12, atol=0.0).all(axis=(-2, -1))
    lam1, phi, top = np.empty(K.shape[0]), np.empty(K.shape[:2]), np.empty(K.shape[0])
    for rows, mode in ((np.flatnonzero(symmetric), _symmetric_mode), (np.flatnonzero(~symmetric), _general_mode)):
        if rows.size:
            lam1[rows], phi[rows], top[rows] = mode(K[rows], M[rows])
    # a zero eigenvalue (a mechanism: no spring where the structure needs one) comes out as +- its round-off,
    # eps times the largest eigenvalue: its sign would follow the BLAS kernel (issue 42). Below REST_TOLERANCE
    # times the largest it counts as zero, i.e. not positive: unstable at rest. The VARM's first eigenvalue is
    # 1.5e-6 of its largest (four orders above), a zero one's round-off ~1e-16 of it (six below).
    return np.sqrt(np.where(lam1 > REST_TOLERANCE * top, lam1, np.nan))[inverse], phi[inverse]


#: the smallest eigenvalue of (K, M), relative to the largest, that counts as positive (``_first_mode``)
REST_TOLERANCE = 1e-10


def _symmetric_mode(K: Array, M: Array) -> tuple[Array, Array, Array]:
    """Lowest eigenvalue, its vector and the largest |eigenvalue| of symmetric pencils: L^-1 K L^-T, eigh."""
    L = np.linalg.cholesky(M)
    Linv = np.linalg.inv(L)
    A = Linv @ K @ np.swapaxes(Linv, -1, -2)
    lam, vec = np.linalg.eigh(0.5 * (A + np.swapaxes(A, -1, -2)))
    return lam[:, 0], (np.swapaxes(Linv, -1, -2) @ vec[:, :, :1])[:, :, 0], np.abs(lam).max(axis=1)


def _general_mode(K: Array, M: Array) -> tuple[Array, Array, Array]:
    """The eigenvalue of least real part of M^-1 K, its vector (real parts) and the largest |eigenvalue|."""
    lam, vec = np.linalg.eig(np.linalg.solve(M, K))
    first = np.argmin(lam.real, axis=1)
    rows = np.arange(K.shape[0])
    return lam[rows, first].real, vec[rows, :, first].real, np.abs(lam).max(axis=1)


class Model:
    """The FE structure plus a list of effects, e.g. the Geometric VARM model.

    ``shaft``: the structure the effects act on, a ``Machine`` (default: the VARM, ``Machine.varm()``) or a
    uniform ``Shaft``.
    """

    def __init__(self, effects: Sequence[Effect], shaft: Machine | Shaft | None = None):
        self.shaft = shaft or default_machine()
        self.effects = list(effects)
        names = [e.name for e in self.effects]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"model: effect(s) {duplicates} listed twice")
        self.parameters = _collect_parameters(self.effects)
        for effect in self.effects:
            for dof in effect.dofs:
                self.shaft.dof(dof)  # raises on a DOF the shaft does not have

    def __repr__(self) -> str:
        return f"Model({[e.name for e in self.effects]})"

    def mode_peak_node(self, values: Mapping[str, Array]) -> Array:
        """The node of the largest |entry| of the first mode at rest, which scales Phi_1 (eq. 30), (S,)."""
        return np.argmax(np.abs(self.at_rest(values).Phi_1), axis=1)

    def at_rest(self, values: Mapping[str, Array], n_scenarios: int = 1) -> Context:
        """The stages that do not depend on the speed: mass, stiffness at rest, first mode.

        ``values`` complete, each (S,) or scalar (S at least ``n_scenarios``); Omega is 0 until
        ``system_at`` (or ``context``) sets the speed. A sweep assembles this once and reuses it
        at every speed (``Context.rows`` for the scenarios of each step).
        """
        missing = sorted(set(self.parameters) - set(values))
        if missing:
            raise ValueError(f"model: no value for parameter(s) {missing}")
        S = max([n_scenarios] + [np.size(v) for v in values.values()])
        p = Params({k: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for k, v in values.items()})
        ctx = Context(shaft=self.shaft, p=p, Omega=np.zeros(S))
        K0, M0 = self.shaft.matrices()
        mass = self._sum("mass", ctx)
        ctx.M = np.add(M0, mass, out=mass)  # into the sum's own array: a large model's (S, n, n) allocated once
        ctx.K_support = self._sum("stiffness", ctx)
        ctx.K = K0 + ctx.K_support
        plane = slice(0, self.shaft.n_plane)
        ctx.omega_1, phi = _first_mode(ctx.K[:, plane, plane], ctx.M[:, plane, plane])
        phi = phi[:, 0::2]  # translational entries, node 0..n
        peak = phi[np.arange(S), np.argmax(np.abs(phi), axis=1)]
        ctx.Phi_1 = phi / peak[:, None]
        return ctx

    def context(self, values: Mapping[str, Array], rpm: Array | float) -> Context:
        """Assemble the linear part stage by stage; ``values`` complete, each (S,) or scalar."""
        return _at_speed(self.at_rest(values, np.size(rpm)), rpm)

    def system(self, values: Mapping[str, Array], rpm: Array | float) -> System:
        """The system for S scenarios at speed(s) ``rpm`` (eq. 29), ready for the solver."""
        return self.system_at(self.at_rest(values, np.size(rpm)), rpm)

    def system_at(self, rest: Context, rpm: Array | float) -> System:
        """The system (eq. 29) of the scenarios of ``rest`` (``at_rest``) at speed(s) ``rpm``."""
        ctx = _at_speed(rest, rpm)
        speed_stiffness = self._sum("speed_stiffness", ctx)
        K = np.add(ctx.K, speed_stiffness, out=speed_stiffness)  # (the same sums into the terms' own arrays)
        C = self._sum("damping", ctx)
        forcing: dict[int, Array] = {}
        for effect in self.effects:
            for h, f in effect.forcing(ctx).items():
                forcing[h] = forcing.get(h, 0) + np.broadcast_to(f, (ctx.n_scenarios, self.shaft.n_dof))

        def bind(effect: Effect) -> Callable[[Array, np.ndarray], tuple[Array, Array]]:
            return lambda q, rows: effect.force(q, ctx.p.rows(rows))

        forces = [
            LocalForce(e.name, np.array([self.shaft.dof(d) for d in e.dofs]), bind(e), e.degree)
            for e in _nonlinear_forces(self.effects)
        ]
        speed_mass = self._sum("speed_mass", ctx)  # a table's mass at the speed
        M = np.add(np.broadcast_to(ctx.M, K.shape), speed_mass, out=speed_mass)
        problems = np.where(np.isnan(ctx.omega_1), "the structure at rest is unstable (a natural frequency of "
                            "the x plane at Omega = 0 is not real): no steady state", "").astype(object)
        return System(M, C, K, ctx.Omega, forcing, forces, problems=problems)

    def _sum(self, hook: str, ctx: Context) -> Array:
        """The effects' ``hook`` terms summed into a new (S, n, n) array (zero where none has one)."""
        n = self.shaft.n_dof
        total = np.zeros((ctx.n_scenarios, n, n))
        for effect in self.effects:
            method = getattr(effect, hook, None)  # an effect written before a hook existed (speed_mass) has none
            term = None if method is None else method(ctx)
            if isinstance(term, LocalMatrix):
                term.add_to(total)
            elif term is not None:
                total += term
        return total


def _at_speed(rest: Context, rpm: Array | float) -> Context:
    """``rest`` with the speed set, for the stages that depend on it (speed terms, damping, forcing)."""
    Omega = np.broadcast_to(np.atleast_1d(rpm_to_rad_s(rpm)), (rest.n_scenarios,)).astype(float)
    return replace(rest, Omega=Omega)


def _nonlinear_forces(effects: Sequence[Effect]) -> list[Effect]:
    """The effects with a local force; polynomial bearings at one node are evaluated as one."""
    by_node: dict[int, list[PolynomialBearing]] = {}
    others = []
    for effect in effects:
        if isinstance(effect, PolynomialBearing) and effect.is_nonlinear:
            by_node.setdefault(effect.node, []).append(effect)
        elif effect.is_nonlinear:
            others.append(effect)
    return [group[0] if len(group) == 1 else PolynomialBearing.combined(group) for group in by_node.values()] + others


def _collect_parameters(effects: Sequence[Effect]) -> dict[str, Parameter]:
    """All parameters by name; effects may share one (e.g. k_b) if they agree on it."""
    out: dict[str, Parameter] = {}
    owner: dict[str, str] = {}
    for effect in effects:
        for par in effect.parameters:
            if par.name in out and (out[par.name].unit, out[par.name].nominal) != (par.unit, par.nominal):
                raise ValueError(
                    f"parameter {par.name!r} is declared differently by effects {owner[par.name]!r} "
                    f"({out[par.name].unit}, nominal {out[par.name].nominal}) and {effect.name!r} "
                    f"({par.unit}, nominal {par.nominal})"
                )
            out.setdefault(par.name, par)
            owner.setdefault(par.name, effect.name)
    return out


def campbell(model: Model, values: Mapping[str, Array | float], rpm: Array | Sequence[float],
             n_modes: int = 8) -> "pd.DataFrame":
    """Whirl frequencies of the model's linear part at each speed: the Campbell diagram's data.

    At each speed the eigenvalues lambda = -zeta w + i w_d of M q'' + C q' + K q = 0 (``Model.system``:
    speed terms, damping and gyroscopic coupling included; a polynomial bearing's degree-1 terms, i.e. the
    linearisation about q = 0), the ``n_modes`` lowest w_d > 0. ``values``: one parameter set (scalars).
    Whirl from the mode's x-plane entries U (u, du) and y-plane entries V (v, dv): whirl_index =
    -2 sum Im(conj(U) V) / sum(|U|^2 + |V|^2), +1 a circular forward whirl (turning with the shaft,
    V = -i U), -1 backward, 0 planar. Columns: rpm, mode (0 = lowest), frequency_hz, damping_ratio, whirl ("forward" or "backward"),
    whirl_index. A planar mode (|whirl_index| < PLANAR_WHIRL, e.g. at rest on anisotropic supports) is given the
    sense of the same mode at the nearest speed of ``rpm`` where it whirls.
    """
    rpm = np.atleast_1d(np.asarray(rpm, dtype=float))
    system = model.system({k: np.asarray(v, dtype=float) for k, v in values.items()}, rpm)
    n = system.n_dof
    x, y = np.arange(n // 2), np.arange(n // 2, n)
    rows = []
    for s in range(system.n_scenarios):
        Minv = np.linalg.inv(system.M[s])
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ system.K[s], -Minv @ system.C[s]]])
        lam, vec = np.linalg.eig(A)
        scale = np.abs(lam).max()
        keep = np.flatnonzero(lam.imag > 1e-9 * scale)  # oscillating modes; rigid-body and overdamped ones out
        keep = keep[np.argsort(lam.imag[keep])][:n_modes + 1]
        q = circular_modes(lam[keep], vec[:n, keep])
        for mode, j in enumerate(keep[:n_modes]):
            U, V = q[x, mode], q[y, mode]
            index = -2.0 * np.sum(np.imag(np.conj(U) * V)) / np.sum(np.abs(U) ** 2 + np.abs(V) ** 2)
            rows.append((rpm[s], mode, lam[j].imag / (2 * np.pi), -lam[j].real / abs(lam[j]),
                         "forward" if index >= 0 else "backward", index))
    table = pd.DataFrame(rows, columns=["rpm", "mode", "frequency_hz", "damping_ratio", "whirl", "whirl_index"])
    # a planar mode (at rest on anisotropic supports: whirl_index ~ 1e-11, its sign round-off) takes the sense of
    # the same mode at the nearest speed where it whirls, the branch it starts; else the branches jump at 0 RPM
    planar = table["whirl_index"].abs() < PLANAR_WHIRL
    whirling = table[~planar]
    for i in np.flatnonzero(planar):
        same = whirling[whirling["mode"] == table.at[i, "mode"]]
        if len(same):
            table.at[i, "whirl"] = same.at[(same["rpm"] - table.at[i, "rpm"]).abs().idxmin(), "whirl"]
    return table


#: |whirl_index| below which a mode is planar (``campbell``): far below any whirl the rotor's speed induces
PLANAR_WHIRL = 1e-6


def circular_modes(lam: Array, q: Array) -> Array:
    """The modes ``q`` (n, m) with each degenerate pair (equal eigenvalues to 1e-7, e.g. the two planes of an
    isotropic rotor without gyroscopic coupling, where the eigensolver returns any basis) replaced by its
    forward and backward circular combinations: the extreme vectors of the whirl form
    -2 Im(conj(U) V) = q^H B q, B = [[0, i], [-i, 0]] over the planes, in the pair's span."""
    q = q.copy()
    n = q.shape[0] // 2
    j = 0
    while j < len(lam) - 1:
        if abs(lam[j + 1] - lam[j]) <= 1e-7 * abs(lam[j]):
            span = q[:, j:j + 2]
            B = np.zeros((2 * n, 2 * n), complex)
            B[:n, n:], B[n:, :n] = 1j * np.eye(n), -1j * np.eye(n)
            _, c = scipy.linalg.eigh(span.conj().T @ B @ span, span.conj().T @ span)
            q[:, j:j + 2] = span @ c[:, ::-1]  # forward (largest whirl index) first
            j += 2
        else:
            j += 1
    return q
