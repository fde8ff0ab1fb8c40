# Measured runs (issue 4): check the runs sheet and every record, preprocess each run (true speed,
# synchronous analysis), and the virtual rig that writes such data sets from a truth model.
# The sheet (config key `runs`, paths in it relative to its folder) is common.smk's SHEET, read once per plan.
import os

from hybridtwin.config import data_check_settings, whirl_settings
from hybridtwin.data.measurements import sheet_entry

RUNS_SHEET = config.get("runs", "data/default/runs.tsv")
# The records' channels are the machine's sensors, one column each named after it (issue 24), a param of the rules
# that read records: a change of sensors reruns them. Without a machine: no param, the VARM's channels x, y (so
# the VARM's jobs keep the params they had before several sensor planes were read).
SENSOR_PARAMS = {"sensors": config["machine"].get("sensors")} if config.get("machine") else {}
# what the data checks take from the config, derived once (as `hybridtwin check-data` derives its defaults)
CHECK_SETTINGS = data_check_settings(config)
# the machine's model of the 1X whirl (its machine, variants, effects files): backward whirl is flagged only where
# the model predicts forward (docs/data-checks.md); without a machine none, the VARM's jobs keep their params
WHIRL_PARAMS = {"whirl": whirl_settings(config)} if whirl_settings(config) else {}


rule check_data:
    """First step on measured data: validate the sheet and every record; per-run summary."""
    input:
        sheet=RUNS_SHEET,
        records=list(SHEET["record"]),
        # relative to the working directory (the project root, or another with --directory): a moved or copied
        # project reruns nothing
        schema=os.path.relpath(Path(workflow.basedir) / "workflow" / "schemas" / "runs.schema.yaml"),
    output:
        summary="results/data/check.tsv",
        # the whirl model's answers at each run's speed, read by preprocess (computed once; empty without a model)
        whirl="results/data/whirl.tsv",
    log:
        "logs/data/check_data.log",
    benchmark:
        "results/benchmarks/data/check_data.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **CHECK_SETTINGS,  # harmonics, coverage, sensor_range_mm (the lasers'; a sheet's column overrides it)
        **SENSOR_PARAMS,
        **WHIRL_PARAMS,
    script:
        "../../scripts/check_data.py"


rule preprocess:
    """One run: refined speed, harmonics 1X..HX with uncertainties, offsets, noise; two-cycle waveforms; the full
    spectrum (for the cascade)."""
    input:
        check="results/data/check.tsv",
        whirl="results/data/whirl.tsv",
        record=lambda wildcards: sheet_entry(SHEET, wildcards.run)["record"],
    output:
        harmonics="results/data/runs/{run}/harmonics.tsv",
        waveforms="results/data/runs/{run}/waveforms.tsv",
        spectrum="results/data/runs/{run}/spectrum.tsv",
    log:
        "logs/data/preprocess/{run}.log",
    benchmark:
        "results/benchmarks/data/preprocess/{run}.tsv"
    wildcard_constraints:
        run="[A-Za-z0-9_-]+",
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **SENSOR_PARAMS,
        **WHIRL_PARAMS,
        row=lambda wildcards: sheet_entry(SHEET, wildcards.run),
        harmonics=CHECK_SETTINGS["harmonics"],
        sensor_range_mm=CHECK_SETTINGS["sensor_range_mm"],
    script:
        "../../scripts/preprocess.py"


rule track_record:
    """One run-up or coast-down (issue 38): its speed profile from the keyphasor, the slow-roll runout removed, the
    order vectors of windows of a few revolutions (Bode and polar points), and one row per speed band of the
    harmonics table (a pseudo-run <run>_b<RPM>, hybridtwin.data.transient)."""
    input:
        check="results/data/check.tsv",
        record=lambda wildcards: sheet_entry(SHEET, wildcards.run)["record"],
    output:
        bands="results/data/records/{run}/bands.tsv",
        orders="results/data/records/{run}/orders.tsv",
        runout="results/data/records/{run}/runout.tsv",
        speed="results/data/records/{run}/speed.tsv",
    log:
        "logs/data/track_record/{run}.log",
    benchmark:
        "results/benchmarks/data/track_record/{run}.tsv"
    wildcard_constraints:
        run="[A-Za-z0-9_-]+",
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **SENSOR_PARAMS,
        **WHIRL_PARAMS,
        row=lambda wildcards: sheet_entry(SHEET, wildcards.run),
        harmonics=CHECK_SETTINGS["harmonics"],
        sensor_range_mm=CHECK_SETTINGS["sensor_range_mm"],
    script:
        "../../scripts/track_record.py"


rule measured_harmonics:
    """All runs' preprocessing results in one table, in the sheet's order."""
    input:
        runs=measured_tables,
    output:
        table="results/data/harmonics.tsv",
    log:
        "logs/data/measured_harmonics.log",
    benchmark:
        "results/benchmarks/data/measured_harmonics.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/measured_harmonics.py"


rule rig:
    """Virtual rig: a data set (runs.tsv, records/, answer key truth.tsv/.yaml) from config rig: {name}, on the
    config's machine."""
    input:
        plan=lambda wildcards: config["rig"][wildcards.name].get("plan", "data/default/runs.tsv"),
    output:
        sheet="results/rig/{name}/runs.tsv",
        records=directory("results/rig/{name}/records"),
        truth="results/rig/{name}/truth.tsv",
        key="results/rig/{name}/truth.yaml",
    log:
        "logs/rig/{name}.log",
    benchmark:
        "results/benchmarks/rig/{name}.tsv"
    wildcard_constraints:
        name="[A-Za-z0-9_-]+",
    conda:
        "../envs/hybridtwin.yaml"
    params:
        spec=lambda wildcards: config["rig"][wildcards.name],
        machine=config.get("machine"),  # the rotor the truth is built on (None: the VARM); a change reruns the rig
        effects_files=[str(Path("config") / f) for f in config.get("effects_files", [])],
    script:
        "../../scripts/rig.py"
