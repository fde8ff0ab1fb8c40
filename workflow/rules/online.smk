# The twin online (issue 40): a built twin's card, and every new record of a folder judged against it.
# results/{variant}/ is the twin; its card twin.yaml says what the twin is (the variant as configured, its fit runs,
# harmonics, keyphasor, candidates, the sPGD library it has), so that `hybridtwin assess RECORD --twin results/{variant}`
# needs nothing else; with a library, the record's first verdict comes from it (hybridtwin.online.library_route).


rule twin_card:
    """The twin's card: what `hybridtwin assess` reads besides the joint fit (hybridtwin.online.twin)."""
    input:
        parameters="results/{variant}/parameters.tsv",
        correlation="results/{variant}/identification/correlation.tsv",
        summary="results/{variant}/identification/summary.yaml",
        harmonics="results/data/harmonics.tsv",
        library=library_validation_input,  # the library's test errors (none without libraries): the card names it
        libraries=lambda wildcards: fit_libraries(wildcards, RUNS),  # anchored on the solver at the twin
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        card="results/{variant}/twin.yaml",
    log:
        "logs/{variant}/twin_card.log",
    benchmark:
        "results/benchmarks/{variant}/twin_card.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        harmonics=config["harmonics"],
        keyphasor=SETTINGS.identification.keyphasor,
        candidates=SETTINGS.diagnosis.candidates,
        sensor_range_mm=CHECK_SETTINGS["sensor_range_mm"],
        scope=OFFLINE.scope,
    script:
        "../../scripts/twin_card.py"


# Every record of the sheet config["online"]["records"] judged against the twin config["online"]["variant"]: one job
# per record (a new record in the sheet is the only new job on a rerun), then the trend rebuilt from every
# assessment (never appended to: a failed record leaves the last trend as it was).
ONLINE = SETTINGS.online  # None: the config has no online: section
ONLINE_SHEET = sheet_of(ONLINE.records) if ONLINE else None  # read once per plan, as the runs sheet
ONLINE_RECORDS = list(ONLINE_SHEET["run"]) if ONLINE else []


rule assess_record:
    """One new record judged against the twin: consistent, changed or a new discrepancy (hybridtwin.online)."""
    input:
        card="results/{variant}/twin.yaml",
        parameters="results/{variant}/parameters.tsv",
        correlation="results/{variant}/identification/correlation.tsv",
        record=lambda wildcards: sheet_entry(ONLINE_SHEET, wildcards.record)["record"],
        effects=variant_effects,  # their contents build the variant (the card has only the paths)
    output:
        summary="results/online/{variant}/{record}/assessment.tsv",
        parameters="results/online/{variant}/{record}/parameters.tsv",
        harmonics="results/online/{variant}/{record}/harmonics.tsv",
        candidates="results/online/{variant}/{record}/candidates.tsv",
        figure=report(
            "results/online/{variant}/{record}/figure.png",
            caption="../report/online_record.rst",
            category="Online",
            subcategory="{variant}",
        ),
    log:
        "logs/online/{variant}/{record}.log",
    benchmark:
        "results/benchmarks/online/{variant}/{record}.tsv"
    wildcard_constraints:
        record="[A-Za-z0-9_-]+",
    conda:
        "../envs/hybridtwin.yaml"
    params:
        row=lambda wildcards: sheet_entry(ONLINE_SHEET, wildcards.record),
        alpha=lambda wildcards: ONLINE.alpha,  # lazily: a config without online: plans no such job
    script:
        "../../scripts/assess_record.py"


rule assess_trend:
    """The twin's trend over every record of the sheet, in time order, with control limits."""
    input:
        summaries=lambda wildcards: expand(
            "results/online/{variant}/{record}/assessment.tsv", variant=wildcards.variant, record=ONLINE_RECORDS
        ),
    output:
        table="results/online/{variant}/trend.tsv",
        figure=report(
            "results/online/{variant}/trend.png",
            caption="../report/online_trend.rst",
            category="Online",
            subcategory="{variant}",
        ),
    log:
        "logs/online/{variant}/trend.log",
    benchmark:
        "results/benchmarks/online/{variant}/trend.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/assess_trend.py"
