# The twin online (issue 40): a built twin's card, and every new record of a folder judged against it.
# results/{variant}/ is the twin; its card twin.yaml says what the twin is (the variant as configured, its fit runs,
# harmonics, keyphasor, candidates), so that `hybridtwin assess RECORD --twin results/{variant}` needs nothing else.


rule twin_card:
    """The twin's card: what `hybridtwin assess` reads besides the joint fit (hybridtwin.online.twin)."""
    input:
        parameters="results/{variant}/parameters.tsv",
        correlation="results/{variant}/identification/correlation.tsv",
        summary="results/{variant}/identification/summary.yaml",
        harmonics="results/data/harmonics.tsv",
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        card="results/{variant}/twin.yaml",
    params:
        model=variant_model,
        harmonics=config["harmonics"],
        keyphasor=lambda wildcards: identification_settings(config, wildcards.variant)["keyphasor"],
        candidates=diagnosis_settings(config)["candidates"],
        sensor_range_mm=CHECK_SETTINGS["sensor_range_mm"],
    log:
        "logs/{variant}/twin_card.log",
    benchmark:
        "results/benchmarks/{variant}/twin_card.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/twin_card.py"
