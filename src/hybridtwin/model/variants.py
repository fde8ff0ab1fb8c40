"""Model variants: the shaft + a list of effects + which parameters are unknown.

A variant is declared as plain data (the workflow's config/config.yaml uses the
same form)::

    geometric:
      description: Geometric upper bearing model (paper section 4.1)
      effects: [centrifugal_softening, structural_damping, upper_housing,
                lower_bearing, unbalance, shaft_bow, geometric_spring]
      unknown: {k_b: [2000, 3500], zeta_s: [0.01, 0.05], ...}   # ranges, SI units
      fixed: {l_i: 0.0508}                                      # overrides of nominal values

Effect names refer to the package's built-in effects or to effects defined in
a user's Python file (``load_effects_file``): any module-level ``Effect``
instance there is usable by its ``name``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from .effect_base import Array, Effect, Params, PolynomialBearing
from .effects import builtin_effects
from .model import Model, System
from .sensor import sensor_names
from .shaft import Shaft

BASE = ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "unbalance", "shaft_bow"]
BOW = {"q_x": (0.001, 0.01), "q_y": (0.001, 0.01)}

BUILTIN_VARIANTS: dict[str, dict] = {
    "geometric": {
        "description": "Geometric upper bearing model, four springs (eq. 22; paper section 4.1)",
        "effects": BASE + ["geometric_spring"],
        "unknown": {"k_b": (2000.0, 3500.0), "zeta_s": (0.01, 0.05), "zeta_bup": (0.0, 0.05), **BOW},
        "fixed": {},
    },
    "expansion": {
        "description": "Expansion model of the upper bearing force, seven terms (eq. 23-24; paper section 4.2)",
        "effects": BASE + [f"expansion_k{i}" for i in range(1, 8)],
        "unknown": {
            "k1": (0.0, 3500.0), "k2": (-1000.0, 1000.0), "k3": (0.0, 7000.0), "k4": (-1000.0, 1000.0),
            "k5": (-1000.0, 1000.0), "k6": (-1000.0, 1000.0), "k7": (-14000.0, 14000.0), **BOW,
        },
        "fixed": {"zeta_s": 0.0271, "zeta_bup": 0.0215},
    },
    "final": {
        "description": "Final model: cubic spring plus slope force at the upper bearing (eq. 38-39; section 4.3)",
        "effects": BASE + ["radial_spring", "slope_spring"],
        "unknown": {
            "k_b": (2000.0, 3500.0), "k_w": (0.0, 1000.0), "k_z": (0.0, 1000.0),
            "zeta_s": (0.01, 0.05), "zeta_bup": (0.0, 0.05), **BOW,
        },
        "fixed": {},
    },
}


@dataclass
class Variant:
    """A named model with its unknown parameters (ranges) and fixed values."""

    name: str
    model: Model
    unknown: dict[str, tuple[float, float]] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        known = self.model.parameters
        for kind, names in (("unknown", self.unknown), ("fixed", self.fixed)):
            stray = sorted(set(names) - set(known))
            if stray:
                raise ValueError(
                    f"variant {self.name!r}: {kind} parameter(s) {stray} belong to none of its effects "
                    f"(parameters: {sorted(known)})"
                )
        both = sorted(set(self.unknown) & set(self.fixed))
        if both:
            raise ValueError(f"variant {self.name!r}: parameter(s) {both} are both unknown and fixed")
        for name, (lo, hi) in self.unknown.items():
            if not lo < hi:
                raise ValueError(f"variant {self.name!r}: range of {name} [{lo}, {hi}] is empty")

    @classmethod
    def from_spec(cls, name: str, spec: Mapping, effects: Mapping[str, Effect] | None = None,
                  shaft: Shaft | None = None) -> "Variant":
        """Build from the config form (see module docstring); ``effects`` adds user effects. On a ``Machine``
        (``shaft``) the effects placed on it are known by name too (``linear_bearing@<bearing>``,
        ``unbalance@<plane>``, ``gyroscopic``: ``Machine.effects``), as in a config's variants."""
        placed = shaft.effects() if callable(getattr(shaft, "effects", None)) else {}
        registry = builtin_effects() | placed | dict(effects or {})
        # per_run: which unknowns the joint fit estimates per run, an identification option
        # (``hybridtwin.settings.IdentificationSettings``), not part of the model
        unknown_keys = sorted(set(spec) - {"description", "effects", "unknown", "fixed", "per_run"})
        if unknown_keys:
            raise ValueError(f"variant {name!r}: unknown key(s) {unknown_keys} "
                             "(expected description, effects, unknown, fixed, per_run)")
        chosen = []
        for effect_name in spec.get("effects", []):
            kind, _, place = str(effect_name).partition("@")
            if effect_name not in registry and kind == "unbalance" and place:
                planes = [p.name for p in getattr(shaft, "unbalance_planes", ())]
                raise ValueError(f"variant {name!r}: no effect named {effect_name!r}: {unbalance_hint(place, planes)}")
            if effect_name not in registry:
                raise ValueError(f"variant {name!r}: no effect named {effect_name!r} "
                                 f"(available: {sorted(registry)})")
            chosen.append(registry[effect_name])
        unknown = {}
        for par, bounds in dict(spec.get("unknown", {})).items():
            if len(bounds) != 2:
                raise ValueError(f"variant {name!r}: range of {par} must be [low, high], got {bounds!r}")
            unknown[par] = (float(bounds[0]), float(bounds[1]))
        fixed = {k: float(v) for k, v in dict(spec.get("fixed", {})).items()}
        model = Model(chosen, shaft)
        unset = [p for k, p in model.parameters.items() if np.isnan(p.nominal) and k not in fixed and k not in unknown]
        if unset:  # e.g. the plain `unbalance` on a machine without an unbalance plane: no place to assume
            raise ValueError(f"variant {name!r}: {', '.join(p.name for p in unset)} has no nominal value on this "
                             f"machine ({'; '.join(p.meaning for p in unset)}): give it under fixed: (or unknown:)"
                             + ("; or declare an unbalance plane (machine: unbalance_planes: {NAME: NODE}) and use "
                                "unbalance@NAME" if any(p.name == "z_me" for p in unset) else ""))
        return cls(name, model, unknown, fixed, spec.get("description", ""))

    @property
    def unknown_names(self) -> list[str]:
        return list(self.unknown)

    @property
    def channels(self) -> tuple[str, ...]:
        """The model's sensor channels, in the machine's order (``sensor.sensor_names``; x, y on the VARM)."""
        return sensor_names(self.model.shaft)

    def bounds(self, names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper ends of the unknowns' ranges, in the order of ``names`` (default: as declared)."""
        names = self.unknown_names if names is None else list(names)
        return (np.array([self.unknown[k][0] for k in names], float),
                np.array([self.unknown[k][1] for k in names], float))

    def values(self, overrides: Mapping[str, float | Array] | None = None) -> dict[str, Array]:
        """All parameter values: nominal (an unknown without one: the middle of its range), then the variant's fixed
        values, then ``overrides``."""
        overrides = dict(overrides or {})
        stray = sorted(set(overrides) - set(self.model.parameters))
        if stray:
            raise ValueError(f"variant {self.name!r} has no parameter(s) {stray} "
                             f"(parameters: {sorted(self.model.parameters)})")
        out = {k: np.asarray(p.nominal, dtype=float) for k, p in self.model.parameters.items()}
        for k, (lo, hi) in self.unknown.items():  # an unknown without a nominal value: the middle of its range
            if k in out and np.isnan(out[k]):
                out[k] = np.asarray(0.5 * (lo + hi))
        out.update({k: np.asarray(v, dtype=float) for k, v in self.fixed.items()})
        out.update({k: np.asarray(v, dtype=float) for k, v in overrides.items()})
        return out

    def system(self, rpm: Array | float, overrides: Mapping[str, float | Array] | None = None) -> System:
        return self.model.system(self.values(overrides), rpm)

    def describe(self) -> str:
        lines = [f"variant {self.name}: {self.description}", "effects:"]
        lines += ["  " + e.describe().replace("\n", "\n  ") for e in self.model.effects]
        lines.append("unknown: " + ", ".join(f"{k} in [{lo:g}, {hi:g}]" for k, (lo, hi) in self.unknown.items()))
        if self.fixed:
            lines.append("fixed: " + ", ".join(f"{k} = {v:g}" for k, v in self.fixed.items()))
        return "\n".join(lines)


def unbalance_hint(plane: str, planes: Sequence[str]) -> str:
    """Why ``unbalance@<plane>`` does not exist and what to write instead (never the VARM's plain ``unbalance`` at
    its 0.425 m by default: on another machine it needs z_me)."""
    return (f"the machine has no unbalance plane {plane!r} (unbalance planes: {', '.join(planes) or 'none'}); "
            f"declare it (machine: unbalance_planes: {{{plane}: NODE}}) and use unbalance@{plane}, or use the plain "
            "'unbalance' with the eccentric mass's axial position given (fixed: {z_me: METRES})")


Monomial = tuple[int, tuple[int, int, int, int]]  # (node, powers of u, v, u', v')


def bearing_polynomial(variant: Variant, values: Mapping[str, float] | None = None) -> dict[Monomial, float]:
    """The variant's polynomial bearing forces summed into one polynomial, F_x = -sum c u^a v^b (u')^c (v')^d
    (eq. 22-24, 38-39): the coefficient c [SI] of each (node, powers) at ``values`` (default: nominal and
    fixed values)."""
    p = Params({k: np.atleast_1d(v) for k, v in variant.values(values).items()})
    out: dict[Monomial, float] = {}
    for effect in variant.model.effects:
        if isinstance(effect, PolynomialBearing):
            for term in effect.terms:
                key = (effect.node, term.powers)
                out[key] = out.get(key, 0.0) + float(term.coefficient(p)[0])
    return out


def _other_effects(variant: Variant) -> set[str]:
    return {e.name for e in variant.model.effects if not isinstance(e, PolynomialBearing)}


def contains(child: Variant, parent: Variant) -> bool:
    """Whether ``child`` has ``parent`` as a special case and is larger: every effect of ``parent`` other than
    its polynomial bearings is one of ``child``'s, every monomial of ``parent``'s bearing polynomial is one of
    ``child``'s, and ``child`` reproduces ``parent``'s polynomial at the middle of ``parent``'s ranges
    (``embed``). The Expansion model contains the Geometric and Final ones (eq. 22 and 38-39 are eq. 23-24
    at particular k_i); Geometric + slope force does not contain Final (its u v^2 term is tied to k_b)."""
    if child.name == parent.name:
        return False
    monomials_child, monomials_parent = set(bearing_polynomial(child)), set(bearing_polynomial(parent))
    others_child, others_parent = _other_effects(child), _other_effects(parent)
    if not (others_parent <= others_child and monomials_parent <= monomials_child):
        return False
    if others_child <= others_parent and monomials_child <= monomials_parent:
        return False  # the same structure: neither is the larger
    middle = {k: 0.5 * (lo + hi) for k, (lo, hi) in parent.unknown.items()}
    return embed(parent, child, middle)[1] < 1e-9


def nested_parents(variants: Mapping[str, Variant], name: str) -> list[str]:
    """The variants that ``name`` contains (``contains``) and that contain no other variant: the simplest
    models nested in it, whose fits never wait for another variant's, so a start from them makes no cycle."""
    child = variants[name]
    roots = [n for n, v in variants.items() if not any(contains(v, w) for w in variants.values())]
    return [n for n in roots if contains(child, variants[n])]


def embed(parent: Variant, child: Variant, values: Mapping[str, float]) -> tuple[dict[str, float], float]:
    """``child``'s unknowns that reproduce ``parent`` at ``values`` (its parameters, SI) and the mismatch.

    The unknowns of ``child``'s polynomial bearings are fitted (bounded least squares, in their ranges) so
    that its bearing polynomial matches ``parent``'s coefficient by coefficient, each monomial's row scaled
    by the largest coefficient it has in either; other unknowns are copied by name from ``values``, or else
    take their nominal value (clipped to the range). The mismatch is the scaled residual's norm over the
    number of monomials: 0 when ``child`` contains ``parent`` at these values (``contains``).
    """
    target = bearing_polynomial(parent, {k: v for k, v in values.items() if k in parent.model.parameters})
    bearing = {p.name for e in child.model.effects if isinstance(e, PolynomialBearing) for p in e.parameters}
    free = [k for k in child.unknown if k in bearing]
    out = {k: float(np.clip(values.get(k, child.model.parameters[k].nominal), *child.unknown[k]))
           for k in child.unknown if k not in free}
    if not free:
        return out, 0.0
    lower, upper = child.bounds(free)
    keys = sorted(set(target) | set(bearing_polynomial(child)))

    def coefficients(x: Array) -> Array:  # x in [0, 1] over each free unknown's range
        own = bearing_polynomial(child, out | dict(zip(free, lower + x * (upper - lower))))
        return np.array([own.get(key, 0.0) for key in keys])

    origin = coefficients(np.zeros(len(free)))
    A = np.stack([coefficients(e) - origin for e in np.eye(len(free))], axis=1)  # exact if affine in x
    wanted = np.array([target.get(key, 0.0) for key in keys])
    scale = np.maximum(np.abs(np.column_stack([A + origin[:, None], origin, wanted])).max(axis=1), 1e-300)
    half = np.full(len(free), 0.5)
    if np.allclose(coefficients(half), origin + A @ half, rtol=1e-12, atol=1e-12 * scale.max()):
        x = lsq_linear(A / scale[:, None], (wanted - origin) / scale, bounds=(0.0, 1.0), method="bvls").x
    else:  # coefficients nonlinear in a bearing unknown (e.g. a free spring length l_i)
        x = least_squares(lambda x: (coefficients(x) - wanted) / scale, half, bounds=(0.0, 1.0), xtol=1e-15,
                          ftol=1e-15, gtol=1e-15).x
    out |= dict(zip(free, (lower + x * (upper - lower)).tolist()))
    residual = (coefficients(x) - wanted) / scale
    return {k: out[k] for k in child.unknown}, float(np.linalg.norm(residual) / np.sqrt(len(keys)))


def builtin_variant(name: str, shaft: Shaft | None = None) -> Variant:
    """One of the paper's variants: "geometric", "expansion" or "final"."""
    if name not in BUILTIN_VARIANTS:
        raise ValueError(f"no built-in variant {name!r} (available: {sorted(BUILTIN_VARIANTS)})")
    return Variant.from_spec(name, BUILTIN_VARIANTS[name], shaft=shaft)


def load_effects_file(path: str | Path) -> dict[str, Effect]:
    """Effects defined in a user's Python file: every module-level Effect instance, by name."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"effects file {path} does not exist")
    spec = importlib.util.spec_from_file_location(f"hybridtwin_user_effects_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # the user's code: say which file failed
        raise RuntimeError(f"effects file {path}: {type(err).__name__}: {err}") from err
    found = {obj.name: obj for obj in vars(module).values() if isinstance(obj, Effect)}
    nameless = [k for k, obj in vars(module).items() if isinstance(obj, Effect) and not obj.name]
    if nameless:
        raise ValueError(f"effects file {path}: effect(s) {nameless} have no name")
    if not found:
        raise ValueError(f"effects file {path} defines no Effect instance")
    return found


class EffectsFileError(ValueError):
    """An effects file is missing, fails to run, or defines no Effect: the message names the file."""


def load_effects_files(paths: Sequence[str | Path]) -> dict[str, Effect]:
    """Effects of several user files, by name; any problem raises EffectsFileError naming the file."""
    effects: dict[str, Effect] = {}
    for path in paths:
        try:
            effects |= load_effects_file(path)
        except (OSError, ValueError, RuntimeError) as err:
            raise EffectsFileError(str(err)) from None
    return effects


def parent_variant(variants: Mapping[str, Mapping], name: str) -> tuple[str, str] | None:
    """The variant that ``name`` extends by exactly one effect (same other effects, its unknowns a subset),
    i.e. the one whose diagnosis may have refitted it, and that effect; None when there is none."""
    spec = variants[name]
    effects = set(spec.get("effects", []))
    for other, base in variants.items():
        extra = effects - set(base.get("effects", []))
        if (other != name and len(extra) == 1 and set(base.get("effects", [])) <= effects
                and set(base.get("unknown", {})) <= set(spec.get("unknown", {}))):
            return other, extra.pop()
    return None
