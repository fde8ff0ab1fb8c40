# Grey box (issue 5): the variant's unknowns identified from the measured harmonics on the libraries
# (paper sec. 2.3, eq. 9-11): per fit run by the paper's protocol, then all fit runs jointly (shared
# physical parameters, per-run bow), polished with the full solver; validation runs only predicted.
# With offline.scope: none there are no libraries: the same rules fit on the full solver (run_fits.py).
# The scripts read only their input, params and output: what a job uses of the config is in its params (a
# change reruns only the jobs that use it).
from hybridtwin.identify.identification import runs_with_role
from hybridtwin.identify.design import candidate_grid

FIT_RUNS = runs_with_role(SHEET, "fit")
VALIDATION_RUNS = runs_with_role(SHEET, "validate")


rule identify_run:
    """Every fit run alone: tau random trials x (1 + n_MC) Monte Carlo repeats of batched LM on its library.
    One job for all runs of a variant: a run's fit takes about a second, less than a job's start-up."""
    input:
        libraries=lambda wildcards: fit_libraries(wildcards, FIT_RUNS),
        harmonics="results/data/harmonics.tsv",
        validation=library_validation_input,
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        parameters=expand("results/{{variant}}/runs/{run}/parameters.tsv", run=FIT_RUNS),
        history=expand("results/{{variant}}/runs/{run}/history.tsv", run=FIT_RUNS),
        fit=[directory(path) for path in expand("results/{{variant}}/runs/{run}/fit.zarr", run=FIT_RUNS)],
    log:
        "logs/{variant}/identify_run.log",
    benchmark:
        "results/benchmarks/{variant}/identify_run.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        runs=FIT_RUNS,
        model=variant_model,
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "run"),
        harmonics=config["harmonics"],
    script:
        "../../scripts/identify_run.py"


rule identify_joint:
    """All fit runs jointly: shared physical parameters, per-run ones and phases; polish; drift of the per-run fits."""
    input:
        unpack(parent_refits_input),
        unpack(nested_fits_input),
        libraries=lambda wildcards: fit_libraries(wildcards, FIT_RUNS),
        per_run=expand("results/{{variant}}/runs/{run}/parameters.tsv", run=FIT_RUNS),
        harmonics="results/data/harmonics.tsv",
        validation=library_validation_input,
        effects=joint_effects,  # their contents build the variants (params.model has only the paths)
    output:
        table=report(
            "results/{variant}/parameters.tsv",
            caption="../report/identification_parameters.rst",
            category="Identification",
            subcategory="{variant}",
        ),
        library_table="results/{variant}/identification/library_parameters.tsv",
        polish="results/{variant}/identification/polish.tsv",
        polish_starts="results/{variant}/identification/polish_starts.tsv",
        profile="results/{variant}/identification/profile.tsv",  # the intervals over a loose parameter
        correlation="results/{variant}/identification/correlation.tsv",
        history="results/{variant}/identification/history.tsv",
        summary="results/{variant}/identification/summary.yaml",
        per_run="results/{variant}/identification/per_run.tsv",
        plot=report(
            "results/{variant}/identification/per_run.png",
            caption="../report/identification_per_run.rst",
            category="Identification",
            subcategory="{variant}",
        ),
        fit=directory("results/{variant}/identification/fit.zarr"),
    log:
        "logs/{variant}/identify_joint.log",
    benchmark:
        "results/benchmarks/{variant}/identify_joint.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        runs=FIT_RUNS,
        model=joint_model,
        parent=joint_parent,
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "joint"),
        harmonics=config["harmonics"],
    script:
        "../../scripts/identify_joint.py"


rule predict_validation:
    """Validation runs predicted with the joint parameters (never fitted): error per run, predicted harmonics; a run
    beyond the noise explained by its refit with the fit runs (loose parameters, the bow's law, or the model)."""
    input:
        parameters="results/{variant}/parameters.tsv",
        libraries=lambda wildcards: fit_libraries(wildcards, VALIDATION_RUNS),
        harmonics="results/data/harmonics.tsv",
        validation=library_validation_input,
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        table=report(
            "results/{variant}/validation.tsv",
            caption="../report/identification_validation.rst",
            category="Identification",
            subcategory="{variant}",
        ),
        harmonics="results/{variant}/validation_harmonics.tsv",
        refits="results/{variant}/validation_refits.tsv",  # a run beyond the noise refitted with the fit runs
    log:
        "logs/{variant}/predict_validation.log",
    benchmark:
        "results/benchmarks/{variant}/predict_validation.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        runs=VALIDATION_RUNS,
        model=variant_model,
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "validation"),
        harmonics=config["harmonics"],
    script:
        "../../scripts/identify_validation.py"


DESIGN = SETTINGS.design


rule design_runs:
    """The next runs to take (issue 41): candidate speeds x masses x keyphasor ranked by the information they would
    add on the loosely pinned parameters (D-optimal design on the fitted twin; hybridtwin.identify.design)."""
    input:
        parameters="results/{variant}/parameters.tsv",
        harmonics="results/data/harmonics.tsv",
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        chosen=report(
            "results/{variant}/design/next_runs.tsv",
            caption="../report/design_next_runs.rst",
            category="Next run",
            subcategory="{variant}",
        ),
        intervals=report(
            "results/{variant}/design/intervals.tsv",
            caption="../report/design_intervals.rst",
            category="Next run",
            subcategory="{variant}",
        ),
        candidates="results/{variant}/design/candidates.tsv",
        plot=report(
            "results/{variant}/design/design.png",
            caption="../report/design_plot.rst",
            category="Next run",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/design_runs.log",
    benchmark:
        "results/benchmarks/{variant}/design_runs.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "validation"),
        harmonics=config["harmonics"],
        grid=lambda wildcards: candidate_grid(DESIGN.rpm, DESIGN.step_rpm, DESIGN.masses_g, run_plan(SHEET)),
        runs=DESIGN.runs,
        keyphasor=DESIGN.keyphasor,
        sensor_range_mm=OFFLINE.sensor_range_mm,
    script:
        "../../scripts/design_runs.py"
