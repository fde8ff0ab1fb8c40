"""A variant's fixed values as candidates: "the fixed value is wrong" tested like a missing effect (docs/diagnosis.md,
"Wrong fixed values").

A variant fixes some parameters at values it takes as known (the paper's expansion variant: zeta_s = 0.0271,
zeta_bup = 0.0215). When such a value is wrong, the fit bends the free parameters to make up for it and the
diagnosis, offered only new effects, names one that stands in for the wrong value. ``FixedValueShift`` frees one
fixed parameter p as an effect of its own: its parameter d_p (absent at 0) is what the data add to the fixed
value, and its contribution to eq. 29 is that of the variant's effects that read p, evaluated at p + d_p, minus
the same at p:

    term(p + d_p) - term(p)            for each hook (mass, stiffness, speed terms, damping, forcing, local force)

so the model with it *is* the model with p = value + d_p, and at d_p = 0 it adds exactly nothing (each
difference is that of two identical evaluations). Every hook sees the context the model assembles (the first mode,
the support stiffness) with the shift already in it, so a damping that reads omega_1 sees the shifted
stiffness, as the model with p changed would. A wrong value can enter several effects (l_i, a shared
stiffness): all of them are shifted. The score test and the refits then treat it like any candidate; the
conclusion says "zeta_s fixed at 0.0271: the data say 0.024 [...]" and the recommendation frees p (moves it
from ``fixed:`` to ``unknown:``) instead of adding an effect.

Range of d_p: the parameter's own range (``Parameter.bounds``) minus the fixed value when it holds the value,
else +-50 % of the value; limits: the parameter's physical limits minus the value, when it declares them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from .candidates import Candidate
from .effect_base import Array, Context, Effect, LocalMatrix, Parameter, Params
from .variants import Variant

#: the name of the candidate freeing parameter p: ``fixed_value@p``; its parameter: ``d_p``
KIND = "fixed_value"


def _shifted(p: Params, name: str, shift: str) -> Params:
    """``p`` with parameter ``name`` replaced by name + shift (the same rows)."""
    values = {k: p[k] for k in p}
    values[name] = values[name] + values[shift]
    return Params(values)


class FixedValueShift(Effect):
    """Variant parameter ``parameter`` fixed at ``value``, freed: the ``owners`` (the effects reading it) at
    parameter + d_parameter minus at parameter (module docstring)."""

    def __init__(self, owners: Sequence[Effect], parameter: Parameter, value: float):
        self.owners = tuple(owners)
        if not self.owners:
            raise ValueError(f"{KIND}@{parameter.name}: no effect reads {parameter.name}")
        nonlinear = [e for e in self.owners if e.is_nonlinear]
        if len(nonlinear) > 1:
            raise ValueError(f"{KIND}@{parameter.name}: {parameter.name} enters {len(nonlinear)} local forces "
                             f"({', '.join(e.name for e in nonlinear)}); one only can be shifted")
        self.local = nonlinear[0] if nonlinear else None
        if self.local is not None:
            self.dofs, self.degree = self.local.dofs, self.local.degree
        self.fixed_parameter, self.fixed_value = parameter.name, float(value)
        lo, hi = parameter.bounds
        if not lo <= value <= hi or lo == hi:
            lo, hi = value - 0.5 * abs(value), value + 0.5 * abs(value)
        if not lo < hi:
            raise ValueError(f"{KIND}@{parameter.name}: fixed at 0 with no range around it to test")
        limits = None if parameter.limits is None else (parameter.limits[0] - value, parameter.limits[1] - value)
        self.shift = f"d_{parameter.name}"
        self.name = f"{KIND}@{parameter.name}"
        self.unit = parameter.unit
        unit = "" if parameter.unit == "1" else f" {parameter.unit}"
        self.meaning = (f"the fixed value {parameter.name} = {value:g}{unit} is wrong ({parameter.meaning}): "
                        f"{parameter.name} = {value:g} + {self.shift}")
        self.parameters = (Parameter(self.shift, parameter.unit, (lo - value, hi - value), 0.0,
                                     f"what the data add to the fixed value {parameter.name} = {value:g}", limits),)
        self.switches = (self.shift,)

    def _at(self, ctx: Context) -> Context:
        return replace(ctx, p=_shifted(ctx.p, self.fixed_parameter, self.shift))

    def _difference(self, hook: str, ctx: Context) -> Array | None:
        shifted, out = self._at(ctx), None
        for effect in self.owners:
            a, b = (t.dense(ctx) if isinstance(t, LocalMatrix) else t
                    for t in (getattr(effect, hook)(shifted), getattr(effect, hook)(ctx)))
            if a is None and b is None:
                continue
            term = (0.0 if a is None else a) - (0.0 if b is None else b)
            out = term if out is None else out + term
        return out

    def mass(self, ctx: Context) -> Array | None:
        return self._difference("mass", ctx)

    def stiffness(self, ctx: Context) -> Array | None:
        return self._difference("stiffness", ctx)

    def speed_stiffness(self, ctx: Context) -> Array | None:
        return self._difference("speed_stiffness", ctx)

    def damping(self, ctx: Context) -> Array | None:
        return self._difference("damping", ctx)

    def forcing(self, ctx: Context) -> dict[int, Array]:
        shifted, out = self._at(ctx), {}
        for effect in self.owners:
            a, b = effect.forcing(shifted), effect.forcing(ctx)
            for h in set(a) | set(b):
                out[h] = out.get(h, 0.0) + a.get(h, 0.0) - b.get(h, 0.0)
        return {h: f for h, f in out.items() if np.any(f)}  # absent: not even a zero harmonic

    def force(self, q: Array, p: Params) -> tuple[Array, Array]:
        F_a, J_a = self.local.force(q, _shifted(p, self.fixed_parameter, self.shift))
        F_b, J_b = self.local.force(q, p)
        return F_a - F_b, J_a - J_b

    def value_text(self, shift: float, low: float, high: float, digits: int = 4) -> str:
        """The freed value and its interval from the shift's estimate and interval, beside the fixed one."""
        v, unit = self.fixed_value, "" if self.unit == "1" else f" {self.unit}"
        return (f"{self.fixed_parameter} fixed at {v:.{digits}g}: the data say {v + shift:.{digits}g} "
                f"[{v + low:.{digits}g}, {v + high:.{digits}g}]{unit}")


def fixed_value_candidates(variant: Variant) -> list[Candidate]:
    """A ``fixed_value@p`` candidate for each parameter p the variant fixes (its ``fixed:``), in that order; a
    parameter no effect reads, or one in several local forces, is said in a ValueError."""
    out = []
    for name, value in variant.fixed.items():
        owners = [e for e in variant.model.effects if any(p.name == name for p in e.parameters)]
        parameter = variant.model.parameters[name]
        out.append(Candidate.of(FixedValueShift(owners, parameter, value)))
    return out


def is_fixed_value(candidate: Candidate) -> bool:
    """Whether ``candidate`` frees a fixed value (``FixedValueShift``) rather than adding an effect."""
    return isinstance(candidate.effect, FixedValueShift)
