# hybridtwin workflow: model -> solver -> scenarios -> snapshots -> POD -> sPGD library
#                      -> identification -> diagnosis -> report -> the twin online
# Run: snakemake --cores 2   (the default profile in profiles/default sets the options)

from pathlib import Path

from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


# the virtual rig's data sets (results/rig/NAME/...), apart from the main job's settings where a project has them
RIG_CONFIG = "config/rig.yaml"
if Path(RIG_CONFIG).exists():

    configfile: RIG_CONFIG


# the whole config checked before any job is planned, the one validation against the schema (the package's,
# hybridtwin.settings.SCHEMA_FILE, whose default: entries are the only defaults), then every name in it (variants,
# parameters, effects, candidates); each problem one line naming its file and line, key and allowed values
from hybridtwin.config import check_or_exit
from hybridtwin.settings import SCHEMA_FILE

check_or_exit(
    config,
    SCHEMA_FILE,
    ["config/config.yaml", *[RIG_CONFIG] * Path(RIG_CONFIG).exists(), *workflow.overwrite_configfiles],
    workflow.config_settings.config,
)


report: "workflow/report/workflow.rst"  # the report's first page: the answer first (results/summary.rst)


include: "workflow/rules/common.smk"
include: "workflow/rules/whitebox.smk"
include: "workflow/rules/scenarios.smk"
include: "workflow/rules/snapshots.smk"
include: "workflow/rules/pod.smk"
include: "workflow/rules/library.smk"
include: "workflow/rules/measurements.smk"
include: "workflow/rules/identification.smk"
include: "workflow/rules/diagnosis.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/online.smk"


localrules:
    check_data,
    measured_harmonics,
    sample_scenarios,  # seconds-long, run on the submit host under profiles/slurm


rule all:
    default_target: True
    input:
        "results/data/check.tsv",
        "results/data/harmonics.tsv",
        "results/data/report/cascade.png",
        expand("results/{variant}/whitebox/sweep.tsv", variant=VARIANTS),
        expand("results/{variant}/whitebox/sweep.png", variant=VARIANTS),
        # the offline libraries, where the fits use them (offline.scope run or global; none: the full solver)
        expand("results/{variant}/library_validation.tsv", variant=LIBRARY_VARIANTS),
        expand("results/{variant}/library_parity.png", variant=LIBRARY_VARIANTS),
        expand("results/{variant}/pod.tsv", variant=LIBRARY_VARIANTS),
        expand("results/{variant}/runs/{run}/parameters.tsv", variant=VARIANTS, run=FIT_RUNS),
        expand("results/{variant}/parameters.tsv", variant=VARIANTS),
        expand("results/{variant}/validation.tsv", variant=VARIANTS),
        expand("results/{variant}/design/next_runs.tsv", variant=VARIANTS if DESIGN.runs else []),
        expand("results/{variant}/diagnosis.tsv", variant=VARIANTS),
        expand("results/{variant}/diagnosis.md", variant=VARIANTS),
        expand("results/{variant}/twin.yaml", variant=VARIANTS),  # the twin's card: `hybridtwin assess` reads it
        expand("results/{variant}/report/{name}", variant=VARIANTS, name=REPORT_FILES),
        "results/ledger.tsv",
        "results/ledger.png",
        "results/summary.tsv",
        "results/interactive.html",  # every interactive figure in one page (the report's, plotly.js once)
        # a sheet with run-ups or coast-downs: their Bode, polar and orbit figures per variant, and waterfalls
        expand(
            "results/{variant}/report/{name}",
            variant=VARIANTS if transient_records() else [],
            name=["transient", "transient.tsv"],
        ),
        expand("results/data/report/records/{run}/waterfall.png", run=[r["run"] for r in transient_records()]),
        # the twin online (config online:): every record of its sheet judged against the twin, and the trend
        expand("results/online/{variant}/trend.tsv", variant=[ONLINE.variant] if ONLINE else []),
