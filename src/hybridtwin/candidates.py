"""Candidate effects: physics a model may be missing (issue 6, the diagnosis stage).

A candidate is an effect plus the parameters that switch it on: at zero they
are absent and the effect contributes nothing to eq. 29 (no stiffness, damping,
forcing or force), so a base model extended by any set of candidates at zero
*is* the base model. The diagnosis tests each candidate by the sensitivity of
the response to its parameters at zero (``hybridtwin.diagnosis``) and, for the
most promising, refits with it added.

Built in (``BUILTIN_TESTED``): the Expansion model's extra terms and the slope force (eq. 23-24,
38-39), and the "candidate effects" of effects.py: upper-bearing anisotropy, cross-coupled
stiffness and damping, moment stiffness at the upper bearing, lower-bearing compliance, 2X and
3X rotating forces and speed-dependent damping (ranges and why: the comment above them there).

Users add their own: any Effect in a file listed under the config's
``effects_files`` whose name appears in ``diagnosis: candidates`` (all its
parameters are then tested, so they must vanish at zero).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .effect_base import Effect, Parameter
from .effects import builtin_effects


@dataclass(frozen=True)
class Candidate:
    """An effect a model may lack, and the parameters (absent at 0) that switch it on."""

    effect: Effect
    tested: tuple[str, ...]

    def __post_init__(self) -> None:
        own = {p.name for p in self.effect.parameters}
        stray = sorted(set(self.tested) - own)
        if stray:
            raise ValueError(f"candidate {self.effect.name!r}: tested parameter(s) {stray} are not among its "
                             f"parameters {sorted(own)}")
        if not self.tested:
            raise ValueError(f"candidate {self.effect.name!r} tests no parameter")

    @property
    def name(self) -> str:
        return self.effect.name

    @property
    def meaning(self) -> str:
        return self.effect.meaning

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """The tested parameters (unit, range), in ``tested`` order."""
        by_name = {p.name: p for p in self.effect.parameters}
        return tuple(by_name[name] for name in self.tested)

    def config_lines(self) -> str:
        """What to add to a variant of config/config.yaml to include this effect (YAML fragment)."""
        ranges = ", ".join(f"{p.name}: [{p.bounds[0]:g}, {p.bounds[1]:g}]" for p in self.parameters)
        return f"effects: [..., {self.name}]\nunknown: {{..., {ranges}}}"


#: built-in candidates: effect name -> the parameters tested (the others, e.g. l_i, keep their values)
BUILTIN_TESTED: dict[str, tuple[str, ...]] = {
    "slope_spring": ("k_w", "k_z"),  # the Final model's slope force (eq. 38-39)
    "expansion_k2": ("k2",),  # u^2 (eq. 23)
    "expansion_k4": ("k4",),  # u'
    "expansion_k5": ("k5",),  # u v
    "expansion_k6": ("k6",),  # (u')^3
    "expansion_k7": ("k7",),  # u v^2
    # effects.py, "candidate effects": what else the machine may have (ranges and their reasoning there)
    "upper_bearing_anisotropy": ("dk_up",),  # K[u0,u0] += dk_up, K[v0,v0] -= dk_up
    "cross_coupled_stiffness": ("k_xy",),  # K[u0,v0] = +k_xy, K[v0,u0] = -k_xy
    "cross_coupled_damping": ("c_xy",),  # C[u0,v0] = +c_xy, C[v0,u0] = -c_xy
    "moment_stiffness": ("k_rot",),  # K[du0,du0] = K[dv0,dv0] += k_rot
    "lower_bearing_compliance": ("dk_lo",),  # the known k off by dk_lo at the last node
    "excitation_2x": ("f2_c", "f2_s"),  # 2X rotating force at node 0 (misalignment)
    "excitation_2x_inertial": ("e2_c", "e2_s"),  # the same growing like Omega^2 (another law of the 2X force)
    "excitation_3x": ("f3_c", "f3_s"),  # 3X rotating force at node 0
    "speed_damping": ("zeta_v",),  # C += 2 zeta_v Omega M (extends eq. 31-32)
}


def builtin_candidates() -> dict[str, Candidate]:
    """The candidate effects the package ships, by name."""
    effects = builtin_effects()
    return {name: Candidate(effects[name], tested) for name, tested in BUILTIN_TESTED.items()}


def candidates_for(present: Sequence[str], names: Sequence[str] | None = None,
                   user_effects: Mapping[str, Effect] | None = None) -> list[Candidate]:
    """The candidates to test on a variant whose effects are ``present`` (those already in it are skipped).

    names: which candidates (default: every built-in one); a name that is not built in must be an effect
    of ``user_effects`` (the config's effects files), and then all its parameters are tested.
    """
    available = builtin_candidates()
    user_effects = dict(user_effects or {})
    chosen = []
    for name in (list(available) if names is None else names):
        if name in available:
            candidate = available[name]
        elif name in user_effects:
            effect = user_effects[name]
            candidate = Candidate(effect, tuple(p.name for p in effect.parameters))
        else:
            raise ValueError(f"no candidate effect named {name!r} (built in: {sorted(available)}; "
                             f"from effects files: {sorted(user_effects)})")
        if candidate.name not in present:
            chosen.append(candidate)
    return chosen
