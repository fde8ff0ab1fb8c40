"""Candidate effects: physics a model may be missing (issue 6, the diagnosis stage).

A candidate is an effect plus the parameters that switch it on: at zero they
are absent and the effect contributes nothing to eq. 29 (no stiffness, damping,
forcing or force), so a base model extended by any set of candidates at zero
*is* the base model. The diagnosis tests each candidate by the sensitivity of
the response to its parameters at zero (``hybridtwin.diagnose.diagnosis``) and, for the
most promising, refits with it added.

Which parameters switch an effect on is declared on the effect itself, as its ``switches``
(``Effect.switches``); their ranges are those of its ``Parameter``s. Built in: every effect of
effects.py that declares them, in ``builtin_effects()`` order: the slope force and the Expansion
model's extra terms (eq. 23-24, 38-39), and the "candidate effects" of effects.py: upper-bearing
anisotropy, cross-coupled stiffness and damping, moment stiffness at the upper bearing,
lower-bearing compliance, 2X and 3X rotating forces and speed-dependent damping (ranges and why:
the comment above them there).

Users add their own: any Effect in a file listed under the config's ``effects_files`` whose name
appears in ``diagnosis: candidates``. Its ``switches`` are tested if it declares them; if not, all
its parameters are (so they must vanish at zero).
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
                             f"parameters {sorted(own)} (check the effect's switches)")
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

    @classmethod
    def of(cls, effect: Effect) -> "Candidate":
        """``effect`` as a candidate: its declared ``switches`` tested, or all its parameters if it declares none."""
        return cls(effect, tuple(effect.switches) or tuple(p.name for p in effect.parameters))


def builtin_candidates() -> dict[str, Candidate]:
    """The candidate effects the package ships, by name: the built-in effects that declare ``switches``."""
    return {name: Candidate(effect, tuple(effect.switches))
            for name, effect in builtin_effects().items() if effect.switches}


def candidates_for(present: Sequence[str], names: Sequence[str] | None = None,
                   user_effects: Mapping[str, Effect] | None = None) -> list[Candidate]:
    """The candidates to test on a variant whose effects are ``present`` (those already in it are skipped).

    names: which candidates (default: every built-in one); a name of ``user_effects`` (the config's effects
    files; also one that a built-in candidate has: the user's effect overrides it, as it does in a variant) has
    its ``switches`` tested, or all its parameters if it declares none; any other name must be built in.
    """
    available = builtin_candidates()
    user_effects = dict(user_effects or {})
    chosen = []
    for name in (list(available) if names is None else names):
        if name in user_effects:  # an effect of the config's files overrides a built-in one of its name, as in variants
            candidate = Candidate.of(user_effects[name])
        elif name in available:
            candidate = available[name]
        else:
            raise ValueError(f"no candidate effect named {name!r} (built in: {sorted(available)}; "
                             f"from effects files: {sorted(user_effects)})")
        if candidate.name not in present:
            chosen.append(candidate)
    return chosen
