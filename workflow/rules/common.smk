# Shared helpers: the settings, the runs sheet, the variants, the offline options.
import os
import sys
from functools import cache
from pathlib import Path

import pandas as pd

from hybridtwin.config import (
    CONFIG_DIR,
    angles_on_libraries,
    effects_files_used,
    run_plan,
    variant as config_variant,
)
from hybridtwin.data.measurements import DataError, read_runs, sheet_of
from hybridtwin.data.run_kinds import is_transient_row
from hybridtwin.model.variants import nested_parents, parent_variant
from hybridtwin.settings import Settings

# Every option section, built once from the config the Snakefile checked (its only validation against the schema):
# frozen, typed objects, the schema's defaults where the config leaves a key out (hybridtwin.settings). The config
# itself stays as written: nothing fills the defaults into it.
SETTINGS = Settings.from_config(config)
OFFLINE = SETTINGS.offline

VARIANTS = list(config["variants"])
# the variants fitted on sPGD libraries (offline.scope run or global); the others fit on the full solver (none)
LIBRARY_VARIANTS = list(VARIANTS) if OFFLINE.scope != "none" else []
CHUNKS = [f"{i:03d}" for i in range(OFFLINE.chunks)]
ENRICHMENT_CHUNKS = [f"{i:03d}" for i in range(OFFLINE.enrichment.chunks if OFFLINE.enrichment.n_scenarios else 0)]
# The runs sheet, read once per plan, here, by the reader check-data uses (hybridtwin.data.measurements.read_runs):
# white space, case, BOM, CRLF handled one way; any problem (a missing column, an unknown role, an empty mass, a
# missing record...) stops here in one message naming file, line, column. Every rule's input function and param
# takes this SHEET (run_plan, runs_with_role and sheet_entry accept the sheet already read), none reads it again.
try:
    SHEET = read_runs(config["runs"], require_mass=True)
    RUNS = list(run_plan(SHEET)["run"])
except DataError as err:
    sys.exit(f"error: {err}")
if angles_on_libraries(config, SHEET):  # a trial mass at an angle needs the full solver (offline.scope: none)
    sys.exit(f"error: {angles_on_libraries(config, SHEET)}")
# the offline options each job uses: a job reruns only when one of its own options changes
OFFLINE_USED = {
    "sample_scenarios": ("seed", "n_scenarios", "n_test", "validation_fraction"),
    "sample_enrichment": ("seed", "validation_fraction", "sensor_range_mm", "enrichment"),
    "pod": ("sensor_range_mm", "pod_energy_tolerance"),
    "spgd_global": ("sensor_range_mm", "pod_energy_tolerance", "spgd", "pieces"),
    "spgd_library": ("scope", "sensor_range_mm", "spgd", "pieces"),
    "validate_library": ("sensor_range_mm",),
}


@cache
def n_unknown(name):
    """The number of unknowns of variant ``name`` (its n_s default; built once per variant, not once per job)."""
    return len(config_variant(config, name).unknown)


def offline_options(wildcards, rule):
    """The offline options the variant's job of ``rule`` uses (OFFLINE_USED; OfflineSettings.for_variant, as
    hybridtwin.config.offline_for)."""
    return OFFLINE.for_variant(wildcards.variant, n_unknown(wildcards.variant), OFFLINE_USED[rule])


# the config's effects files (hybridtwin.config.user_effects: paths relative to the config folder): those a variant
# uses are an input of every rule whose params.model carries them (variant_effects), so that editing one reruns the
# jobs that build the variant; all of them of the diagnosis (its candidates)
EFFECTS_FILES = [str(CONFIG_DIR / path) for path in config.get("effects_files") or []]
# the speeds the libraries are built at: refined from the records, or the sheet's nominal ones
SPEEDS = "results/data/harmonics.tsv" if OFFLINE.speed == "measured" else config["runs"]


wildcard_constraints:
    variant="|".join(VARIANTS),
    chunk=r"\d{3}",
    run="|".join(RUNS),


def project_place():
    """Where this project is, as its user runs it from the repository root (the diagnosis's what to do): a project
    run with --directory DIR names DIR's config, command and ledger; the root's, the defaults
    (recommendation.PROJECT)."""
    here = os.path.relpath(os.getcwd(), workflow.basedir)
    if here == ".":
        return {}
    where = os.getcwd() if here.startswith("..") else here
    return {
        "config": f"{where}/config/config.yaml",
        "command": f"snakemake --cores 2 --directory {where}",
        "ledger": f"{where}/results/ledger.tsv",
    }


def diagnosis_options(wildcards):
    """The diagnosis's options, with where the project is (``project_place``) and, when the variant's libraries are
    sized under ``offline: n_scenarios:``, its scope and that entry (the recommendation sizes the new variant's alike:
    ``recommendation.scenarios_entry``); only this variant's entry, so that another's never reruns this diagnosis."""
    options = SETTINGS.diagnosis.options() | {"project": project_place()}
    counts = OFFLINE.n_scenarios or {}
    scope = OFFLINE.scope
    if wildcards.variant in counts and scope != "none":
        options["offline"] = {
            "scope": scope,
            "n_scenarios": {wildcards.variant: counts[wildcards.variant]},
        }
    return options


def sparse_route_input(wildcards):
    """The paper's route shown side by side: the L1-sparse variant's joint fit, when declared and not this one."""
    name = SETTINGS.diagnosis.sparse_variant
    if name in config["variants"] and name != wildcards.variant:
        return {"sparse": f"results/{name}/parameters.tsv"}
    return {}


def parent_refits_input(wildcards):
    """A variant that adds one effect to another (the model-improvement loop) starts its polish from that
    variant's diagnosis refit with the effect: the full-solver fit is already there."""
    parent = parent_variant(config["variants"], wildcards.variant)
    return {"refits": f"results/{parent[0]}/diagnosis_refits.tsv"} if parent else {}


@cache
def nested_variants(name):
    """The simplest variants that ``name`` contains (built once per variant, not once per job)."""
    return nested_parents({other: config_variant(config, other) for other in VARIANTS}, name)


def nested_fits_input(wildcards):
    """The joint fits of the simplest variants this one contains (identification: polish: nested): its polish
    also starts from each of them, mapped onto its own parameters."""
    polish = SETTINGS.identification.polish
    if not (polish.joint and polish.nested):
        return {}
    parents = nested_variants(wildcards.variant)
    return {"nested": [f"results/{name}/parameters.tsv" for name in parents]} if parents else {}


def variant_model(wildcards, nested=(), all_effects=False):
    """What building the variant takes (hybridtwin.config.variant on this part of the config): its spec, and those
    of the ``nested`` variants, the machine and the effects files that define effects they use (``all_effects``:
    every one, e.g. the diagnosis's candidates)."""
    names = [wildcards.variant, *nested]
    files = list(config.get("effects_files") or []) if all_effects else effects_files_used(config, names, CONFIG_DIR)
    return {
        "variants": {name: config["variants"][name] for name in names},
        "machine": config.get("machine"),
        "effects_files": files,
    }


def model_effects(model):
    """The effects files of a job's params.model as its input paths, and the machine's ROSS rotor file when the
    config names one (machine: {ross: ...}): editing one reruns the job."""
    machine = model["machine"] or {}
    rotor = [str(CONFIG_DIR / machine["ross"])] if "ross" in machine else []
    return [str(CONFIG_DIR / path) for path in model["effects_files"]] + rotor


def variant_effects(wildcards):
    """The effects files that build the variant (variant_model's), as input."""
    return model_effects(variant_model(wildcards))


def joint_model(wildcards):
    """variant_model with the variants whose joint fits start this one's polish (its nested_fits_input)."""
    nested = nested_fits_input(wildcards).get("nested", [])
    return variant_model(wildcards, [Path(path).parent.name for path in nested])


def joint_effects(wildcards):
    """joint_model's effects files, as input."""
    return model_effects(joint_model(wildcards))


def diagnosis_model(wildcards):
    """variant_model with the L1-sparse variant the diagnosis shows side by side, when it is an input
    (sparse_route_input)."""
    sparse = [SETTINGS.diagnosis.sparse_variant] if sparse_route_input(wildcards) else []
    return variant_model(wildcards, sparse, all_effects=True)  # the candidates: every effects file's


def joint_parent(wildcards):
    """The variant this one extends by one effect, and that effect (as parent_refits_input), or None."""
    parent = parent_variant(config["variants"], wildcards.variant)
    return list(parent) if parent else None


def gather_input(wildcards):
    """The first design's chunk stores and, with offline.enrichment.n_scenarios > 0, the enrichment's."""
    inputs = {
        "scenarios": f"results/{wildcards.variant}/scenarios.tsv",
        "chunks": expand("results/{variant}/chunks/{chunk}.zarr", variant=wildcards.variant, chunk=CHUNKS),
    }
    if not ENRICHMENT_CHUNKS:
        return inputs
    return inputs | {
        "enrichment": f"results/{wildcards.variant}/enrichment.tsv",
        "enrichment_chunks": expand(
            "results/{variant}/enrichment/{chunk}.zarr", variant=wildcards.variant, chunk=ENRICHMENT_CHUNKS
        ),
    }


def has_libraries(variant):
    """offline.scope run or global: the variant's fits run on sPGD libraries; none: on the full solver."""
    return OFFLINE.scope != "none"


def fit_libraries(wildcards, runs):
    """The libraries of ``runs`` (none without libraries: the fits then run on the full solver)."""
    if not has_libraries(wildcards.variant):
        return []
    return expand("results/{variant}/library/{run}.zarr", variant=wildcards.variant, run=runs)


def library_validation_input(wildcards):
    """The libraries' test errors (their share of the fits' weights), none without libraries."""
    return f"results/{wildcards.variant}/library_validation.tsv" if has_libraries(wildcards.variant) else []


def library_input(wildcards):
    """A run's library: fitted on its own snapshots and POD (offline.scope: run), or sliced from the variant's
    global library (offline.scope: global)."""
    inputs = {"snapshots": f"results/{wildcards.variant}/snapshots.zarr"}
    if OFFLINE.scope == "global":
        return inputs | {"global_library": f"results/{wildcards.variant}/library_global.zarr"}
    return inputs | {"pod": f"results/{wildcards.variant}/pod.zarr"}


def steady_runs():
    """The sheet's steady runs (each preprocessed alone); the others are run-ups and coast-downs (track_record)."""
    return [r["run"] for r in SHEET.to_dict("records") if not is_transient_row(r)]


def measured_tables(wildcards):
    """Each sheet row's harmonics table, in the sheet's order: a steady run's, or a transient record's bands."""
    return [
        (
            f"results/data/records/{r['run']}/bands.tsv"
            if is_transient_row(r)
            else f"results/data/runs/{r['run']}/harmonics.tsv"
        )
        for r in SHEET.to_dict("records")
    ]


# the figures of run-ups and coast-downs (report_transient, report_waterfall; issue 38 item 7)
TRANSIENT = SETTINGS.transient  # config report: transient: (orbit_rpm, frame, amplitude, phase)


def transient_records():
    """The sheet's run-ups and coast-downs (``kind`` runup or coastdown), in its order, as plain rows."""
    rows = SHEET.to_dict("records")
    return [
        {
            "run": str(r["run"]),
            "kind": str(r["kind"]).strip().lower(),
            "role": r["role"] if isinstance(r.get("role"), str) else "fit",  # no role column: every run fits
            "eccentric_mass_g": float(r["eccentric_mass_g"]),
            "eccentric_mass_angle_deg": float(r.get("eccentric_mass_angle_deg") or 0.0),  # no such column: 0
            "record": str(r["record"]),
            "channels": r.get("channels") if isinstance(r.get("channels"), str) else "",  # an instrument's file
        }
        for r in rows
        if is_transient_row(r)
    ]


#: the runs-sheet columns that place a run's trial mass (the report's model curves: one per mass and angle; the
#: angle column NaN where the sheet has none, read as 0)
TRIAL_RUN_COLUMNS = ["run", "rpm", "eccentric_mass_g", "eccentric_mass_angle_deg"]


def transient_input(wildcards):
    """Each transient record's tracking outputs and the record itself (its orbits), in the sheet's order."""
    runs = [r["run"] for r in transient_records()]
    return {
        name: expand(f"results/data/records/{{run}}/{name}.tsv", run=runs) for name in ("orders", "bands", "runout")
    } | {"records": [r["record"] for r in transient_records()]}
