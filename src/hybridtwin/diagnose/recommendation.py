"""The diagnosis's recommendation written out: the variant to add (the base and the confirmed effects), its name,
its config entry (``variant_spec``), the YAML lines to paste under ``variants:`` (``variant_lines``,
``yaml_number``) and what to do with them (``what_to_do``: where to paste them, the command that builds the new
variant, where to compare it, and, where the config sizes its libraries per variant, the new variant's
``offline: n_scenarios:`` entry: ``scenarios_entry``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

from ..model.candidates import Candidate
from ..model.fixed_values import KIND as FIXED
from ..model.fixed_values import is_fixed_value
from ..model.variants import Variant
from ..offline.scenarios import default_n_scenarios


def joined_variant_name(parts: Sequence[str]) -> str:
    """A recommended variant's name, valid in the config (a letter, then letters, digits, _): the base's and the
    effects' names joined by _, an effect placed at a bearing (``cross_coupled_stiffness@b``) spelled ``..._at_b``,
    any other character an effect's name may hold (``oil-film_b``) as _."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", "_".join(parts).replace(f"{FIXED}@", "free_").replace("@", "_at_"))
    return name if name[:1].isalpha() else f"v_{name}"


def variant_spec(base: Variant, candidate: Candidate | Sequence[Candidate],
                 ranges: Mapping[str, tuple[float, float]] | None = None, per_run: Sequence[str] | None = None
                 ) -> dict:
    """The config entry (``variants:`` form) of ``base`` + the candidate(s), their parameters unknown in their
    ranges (``ranges``: those a refit widened); ``per_run``: the variant's own parameters per run (its
    ``per_run`` key, overriding ``identification.per_run``; None: not set)."""
    added = [candidate] if isinstance(candidate, Candidate) else list(candidate)
    ranges = dict(ranges or {})
    # a fixed value freed (``fixed_values``) is no effect to add: its parameter moves from fixed: to unknown:, its
    # range the fixed value plus the shift's
    freed = {c.effect.fixed_parameter: tuple(c.effect.fixed_value + x for x in ranges.get(c.parameters[0].name,
                                                                                         c.parameters[0].bounds))
             for c in added if is_fixed_value(c)}
    effects = [c for c in added if not is_fixed_value(c)]
    unknown = (dict(base.unknown) | freed
               | {p.name: tuple(ranges.get(p.name, p.bounds)) for c in effects for p in c.parameters})
    said = [f"free {c.effect.fixed_parameter} (fixed at {c.effect.fixed_value:g})" if is_fixed_value(c)
            else f"{c.name}: {c.meaning}" for c in added]
    spec = {"description": f"{base.name} + " + " + ".join(said),
            "effects": [e.name for e in base.model.effects] + [c.name for c in effects],
            "unknown": {k: [float(lo), float(hi)] for k, (lo, hi) in unknown.items()}}
    fixed = {k: float(v) for k, v in base.fixed.items() if k not in freed}
    if fixed:
        spec["fixed"] = fixed
    if per_run is not None:
        spec["per_run"] = list(per_run)
    return spec


def yaml_number(value: float) -> str:
    """``value`` to 6 significant digits as YAML reads a number: 2000, 0.05, 3.0e+07, -2.0e+06 (``3e+07`` would
    be a string to YAML 1.1, the loader of PyYAML and Snakemake: a float's exponent form needs a point)."""
    text = f"{value:g}"
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def variant_lines(name: str, spec: Mapping) -> str:
    """``spec`` as YAML lines to paste under ``variants:`` in config/config.yaml."""
    def flow(value) -> str:
        if isinstance(value, Mapping):
            return "{" + ", ".join(f"{k}: {flow(v)}" for k, v in value.items()) + "}"
        if isinstance(value, list):
            return "[" + ", ".join(flow(v) for v in value) + "]"
        return yaml_number(value) if isinstance(value, float) else str(value)
    lines = [f"  {name}:", f"    description: \"{spec['description']}\""]
    lines += [f"    {key}: {flow(spec[key])}" for key in ("effects", "unknown", "fixed", "per_run") if key in spec]
    return "\n".join(lines)


#: where the user's project is, for the recommendation's what to do: a project at the repository root; the workflow
#: passes its own (``project`` of the options: a project run with --directory DIR names DIR's config and command)
PROJECT = {"config": "config/config.yaml", "command": "snakemake --cores 2", "ledger": "results/ledger.tsv"}


def scenarios_entry(spec: Mapping, parent: Variant | None, o: Mapping) -> int | None:
    """n_s for the new variant (``spec``) under ``offline: n_scenarios:``, where the config sizes its parent's libraries
    there (``o["offline"]``: the config's ``scope`` and the parent's entry of ``n_scenarios``, which the workflow
    passes only when the parent has one, ``diagnosis_options`` in common.smk): the parent's share of its default
    (``default_n_scenarios``) applied to the new variant's default, so that its libraries are as dense as its
    parent's (the README's quick overlay: geometric 500 of 1000, its geometric_expansion_k4 900 of 1800; at least 10,
    the schema's minimum). None where nothing is to be said: no libraries (scope none: the fits on the full solver),
    or no entry for the parent (the new variant then takes the default as its parent did)."""
    offline = dict(o.get("offline") or {})
    counts = dict(offline.get("n_scenarios") or {})
    if parent is None or offline.get("scope", "run") == "none" or parent.name not in counts:
        return None
    share = int(counts[parent.name]) / default_n_scenarios(len(parent.unknown))
    return max(10, round(share * default_n_scenarios(len(spec["unknown"]))))


def what_to_do(name: str, spec: Mapping, o: Mapping, parent: Variant | None = None) -> str:
    """The recommendation: the variant ``name`` (``spec``) to paste, where, and the command that builds it; with
    the variant it extends (``parent``), its ``offline: n_scenarios:`` entry where one is needed
    (``scenarios_entry``)."""
    place = PROJECT | dict(o.get("project") or {})
    n = scenarios_entry(spec, parent, o)
    scenarios = "" if n is None else (
        f" (and `{name}: {n}` under `offline: n_scenarios:`, beside {parent.name}: "
        f"{int(o['offline']['n_scenarios'][parent.name])}: the same share of the new variant's default, "
        f"{default_n_scenarios(len(spec['unknown']))}, which it takes otherwise, so that its libraries are as dense "
        f"as {parent.name}'s)")
    return (f"Add this variant under `variants:` in {place['config']}{scenarios}, then run `{place['command']}` (only "
            f"the new variant is built) and compare in {place['ledger']}:\n\n{variant_lines(name, spec)}\n")
