# Compare and see where it fails (issue 6): per variant, the joint fit's runs and the validation runs against the
# measurements (per-run figures, Bode and polar plots, error map, drift of the per-run estimates), the machine's
# Campbell diagram and mode shapes (issue 24), and the ledger of all variants. Everything reads the identification
# outputs (the validation runs' predicted harmonics included); nothing is predicted again.


REPORT_FILES = [
    "harmonics.tsv",
    "runs",
    "errors.tsv",
    "validation_errors.tsv",
    "bode.png",
    "polar.png",
    "bode.html",
    "polar.html",
    "response.tsv",
    "error_map.png",
    "drift.tsv",
    "drift.png",
    "campbell.png",
    "campbell.tsv",
    "mode_shapes.png",
    "runs.html",
    "campbell.html",
    "mode_shapes.html",
]

# The interactive figures (each also its own page, plotly.js inside, beside its PNG) go into the report as one page
# with one copy of plotly.js (issue 55): (menu key, file, menu label), the summary first, then per variant.
INTERACTIVE_FIGURES = [("summary", "results/summary.html", "summary: chi^2/dof per run and variant")] + [
    (f"{variant}/{name}", f"results/{variant}/{path}", f"{variant}: {label}")
    for variant in VARIANTS
    for name, path, label in (
        ("runs", "report/runs.html", "measured vs model per run"),
        ("bode", "report/bode.html", "Bode plot"),
        ("polar", "report/polar.html", "polar plot"),
        ("campbell", "report/campbell.html", "Campbell diagram"),
        ("mode_shapes", "report/mode_shapes.html", "mode shapes"),
        ("diagnosis", "diagnosis.html", "diagnosis"),
    )
]


rule report_harmonics:
    """Measured and model harmonics of every fit and validation run, in the model's frame."""
    input:
        fit="results/{variant}/identification/fit.zarr",
        parameters="results/{variant}/parameters.tsv",
        summary="results/{variant}/identification/summary.yaml",
        validation="results/{variant}/validation.tsv",
        predictions="results/{variant}/validation_harmonics.tsv",
        library_validation=library_validation_input,
        harmonics="results/data/harmonics.tsv",
    output:
        table="results/{variant}/report/harmonics.tsv",
    log:
        "logs/{variant}/report_harmonics.log",
    benchmark:
        "results/benchmarks/{variant}/report_harmonics.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "validation"),
    script:
        "../../scripts/report_harmonics.py"


rule report_runs:
    """One figure per run: orbit, x and y over two revolutions with the residual, residual whirl spectrum."""
    input:
        table="results/{variant}/report/harmonics.tsv",
    output:
        runs=report(
            directory("results/{variant}/report/runs"),
            patterns=["{run}.png"],
            caption="../report/report_runs.rst",
            category="Comparison per run",
            subcategory="{variant}",
            labels={"variant": "{variant}", "run": "{run}"},
        ),
        interactive="results/{variant}/report/runs.html",  # in the report: results/interactive.html
    log:
        "logs/{variant}/report_runs.log",
    benchmark:
        "results/benchmarks/{variant}/report_runs.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **SENSOR_PARAMS,  # the machine's probes: which channels are a plane's x and y (an orbit each)
    script:
        "../../scripts/report_runs.py"


rule report_overview:
    """Errors per run (fit and validation runs apart) and the error map."""
    input:
        table="results/{variant}/report/harmonics.tsv",
    output:
        errors=report(
            "results/{variant}/report/errors.tsv",
            caption="../report/report_errors.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
        validation_errors=report(
            "results/{variant}/report/validation_errors.tsv",
            caption="../report/report_validation_errors.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
        error_map=report(
            "results/{variant}/report/error_map.png",
            caption="../report/report_error_map.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/report_overview.log",
    benchmark:
        "results/benchmarks/{variant}/report_overview.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/report_overview.py"


rule report_response:
    """Bode and polar plots of 1X-3X: the fitted model as dense curves by continuation (run-up and run-down per
    eccentric mass) with the fit and validation runs on top (hybridtwin.report.response_plots)."""
    input:
        table="results/{variant}/report/harmonics.tsv",
        parameters="results/{variant}/parameters.tsv",
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        response="results/{variant}/report/response.tsv",
        bode=report(
            "results/{variant}/report/bode.png",
            caption="../report/report_bode.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
        polar=report(
            "results/{variant}/report/polar.png",
            caption="../report/report_polar.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
        bode_html="results/{variant}/report/bode.html",
        polar_html="results/{variant}/report/polar.html",
    log:
        "logs/{variant}/report_response.log",
    benchmark:
        "results/benchmarks/{variant}/report_response.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        runs=lambda wildcards: run_plan(SHEET).reindex(columns=TRIAL_RUN_COLUMNS + ["role"]).to_dict("list"),
        harmonics=config["harmonics"],
        options=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "validation"),
    script:
        "../../scripts/report_response.py"


rule report_cascade:
    """The measured full spectra of every run as a cascade (hybridtwin.report.response_plots.plot_cascade)."""
    input:
        spectra=lambda wildcards: expand("results/data/runs/{run}/spectrum.tsv", run=steady_runs()),
        harmonics="results/data/harmonics.tsv",
    output:
        cascade=report(
            "results/data/report/cascade.png",
            caption="../report/report_cascade.rst",
            category="Measurements",
        ),
    log:
        "logs/data/report_cascade.log",
    benchmark:
        "results/benchmarks/data/report_cascade.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/report_cascade.py"


rule report_machine:
    """The machine the variant runs on: Campbell diagram of the fitted model with the run speeds, and its mode
    shapes (hybridtwin.report.machine_plots)."""
    input:
        parameters="results/{variant}/parameters.tsv",
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        campbell=report(
            "results/{variant}/report/campbell.png",
            caption="../report/report_campbell.rst",
            category="Machine",
            subcategory="{variant}",
        ),
        table="results/{variant}/report/campbell.tsv",
        modes=report(
            "results/{variant}/report/mode_shapes.png",
            caption="../report/report_mode_shapes.rst",
            category="Machine",
            subcategory="{variant}",
        ),
        campbell_html="results/{variant}/report/campbell.html",
        modes_html="results/{variant}/report/mode_shapes.html",
    log:
        "logs/{variant}/report_machine.log",
    benchmark:
        "results/benchmarks/{variant}/report_machine.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        runs=lambda wildcards: run_plan(SHEET)[["run", "rpm", "eccentric_mass_g"]].to_dict("list"),  # marked
    script:
        "../../scripts/report_machine.py"


rule report_drift:
    """Per-run estimates vs speed: does a constant of the model drift? (chi^2 and slope tests)"""
    input:
        per_run="results/{variant}/identification/per_run.tsv",
        parameters="results/{variant}/parameters.tsv",
    output:
        table=report(
            "results/{variant}/report/drift.tsv",
            caption="../report/report_drift_table.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
        plot=report(
            "results/{variant}/report/drift.png",
            caption="../report/report_drift.rst",
            category="Comparison",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/report_drift.log",
    benchmark:
        "results/benchmarks/{variant}/report_drift.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/report_drift.py"


rule ledger:
    """All variants of the config side by side: normalised error, BIC, validation error (results/ledger.tsv)."""
    input:
        summaries=expand("results/{variant}/identification/summary.yaml", variant=VARIANTS),
        errors=expand("results/{variant}/report/errors.tsv", variant=VARIANTS),
        validation_errors=expand("results/{variant}/report/validation_errors.tsv", variant=VARIANTS),
    output:
        table=report("results/ledger.tsv", caption="../report/ledger.rst", category="Ledger"),
        plot=report("results/ledger.png", caption="../report/ledger_plot.rst", category="Ledger"),
    log:
        "logs/ledger.log",
    benchmark:
        "results/benchmarks/ledger.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        variants=VARIANTS,
        descriptions={name: spec.get("description", "") for name, spec in config["variants"].items()},
    script:
        "../../scripts/ledger.py"


rule report_summary:
    """The report's first page, the answer first: the ledger, each diagnosis's recommendation and where each variant
    fails, linked to the per-run figures (results/summary.rst, included by workflow/report/workflow.rst)."""
    input:
        ledger="results/ledger.tsv",
        errors=expand("results/{variant}/report/errors.tsv", variant=VARIANTS),
        validation_errors=expand("results/{variant}/report/validation_errors.tsv", variant=VARIANTS),
        diagnoses=expand("results/{variant}/diagnosis.yaml", variant=VARIANTS),
        validation=expand("results/{variant}/validation.tsv", variant=VARIANTS),  # why a validation run fails
        next_runs=expand("results/{variant}/design/next_runs.tsv", variant=VARIANTS if DESIGN.runs else []),
        intervals=expand("results/{variant}/design/intervals.tsv", variant=VARIANTS if DESIGN.runs else []),
        figures=expand("results/{variant}/report/runs", variant=VARIANTS),  # what the page links to
        harmonics="results/data/harmonics.tsv",  # the runs the data checks kept out (usable false)
    output:
        table=report("results/summary.tsv", caption="../report/summary_table.rst", category="Summary"),
        plot=report("results/summary.png", caption="../report/summary_plot.rst", category="Summary"),
        plot_html="results/summary.html",  # in the report: results/interactive.html
        page="results/summary.rst",
    log:
        "logs/report_summary.log",
    benchmark:
        "results/benchmarks/report_summary.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        variants=VARIANTS,
        specs={name: {"effects": list(spec.get("effects", []))} for name, spec in config["variants"].items()},
        design=bool(DESIGN.runs),
    script:
        "../../scripts/report_summary.py"


rule report_interactive:
    """Every interactive figure in one page with one copy of plotly.js, a menu to choose the figure: the report's
    one HTML entry (hybridtwin.report.interactive_pages.write_gallery)."""
    input:
        figures=[path for _, path, _ in INTERACTIVE_FIGURES],
    output:
        page=report(
            "results/interactive.html",
            caption="../report/interactive.rst",
            category="Interactive figures",
        ),
    log:
        "logs/report_interactive.log",
    benchmark:
        "results/benchmarks/report_interactive.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        figure_keys=[key for key, _, _ in INTERACTIVE_FIGURES],
        labels=[label for _, _, label in INTERACTIVE_FIGURES],
    script:
        "../../scripts/report_interactive.py"


# Run-ups and coast-downs (issue 38, item 7): the pictures engineers read of each transient record of the sheet
# (transient_records, transient_input and TRANSIENT in common.smk).
rule report_transient:
    """Per transient record: Bode and polar plots of its tracked order vectors with the fitted twin on top and the
    residual in units of the noise, and its orbits at chosen speeds (hybridtwin.report.transient_plots)."""
    input:
        unpack(transient_input),
        parameters="results/{variant}/parameters.tsv",
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        figures=report(
            directory("results/{variant}/report/transient"),
            patterns=["{run}/{figure}.png"],
            caption="../report/report_transient.rst",
            category="Transient records",
            subcategory="{variant}",
            labels={"variant": "{variant}", "record": "{run}", "figure": "{figure}"},
        ),
        table=report(
            "results/{variant}/report/transient.tsv",
            caption="../report/report_transient_table.rst",
            category="Transient records",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/report_transient.log",
    benchmark:
        "results/benchmarks/{variant}/report_transient.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **SENSOR_PARAMS,
        model=variant_model,
        runs=lambda wildcards: run_plan(SHEET).reindex(columns=TRIAL_RUN_COLUMNS).to_dict("list"),  # the bow's law
        records=lambda wildcards: [
            {k: r.get(k) for k in ("run", "kind", "role", "eccentric_mass_g", "eccentric_mass_angle_deg")}
            for r in transient_records()
        ],
        harmonics=config["harmonics"],
        law=lambda wildcards: SETTINGS.identification.rule(wildcards.variant, "validation")["validation_bow"],
        display=TRANSIENT.as_dict(),
    script:
        "../../scripts/report_transient.py"


rule report_waterfall:
    """The waterfall of one transient record: its short-time spectra against the keyphasor's speed, per probe
    (hybridtwin.report.transient_plots.waterfall)."""
    input:
        record=lambda wildcards: sheet_entry(SHEET, wildcards.run)["record"],
        speed="results/data/records/{run}/speed.tsv",
    output:
        waterfall=report(
            "results/data/report/records/{run}/waterfall.png",
            caption="../report/report_waterfall.rst",
            category="Measurements",
            labels={"record": "{run}", "figure": "waterfall"},
        ),
    log:
        "logs/data/report_waterfall/{run}.log",
    benchmark:
        "results/benchmarks/data/report_waterfall/{run}.tsv"
    wildcard_constraints:
        run="[A-Za-z0-9_-]+",
    conda:
        "../envs/hybridtwin.yaml"
    params:
        **SENSOR_PARAMS,
        display={k: getattr(TRANSIENT, k) for k in ("frame", "amplitude")},
        channels=lambda wildcards: sheet_entry(SHEET, wildcards.run).get("channels"),  # an instrument's file
    script:
        "../../scripts/report_waterfall.py"
