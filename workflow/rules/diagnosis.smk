# Diagnosis (issue 6): which candidate effect is the variant missing? Score tests at the joint fit with the
# full solver's sensitivities, the best confirmed by refitting, ranked with verdicts and a recommendation.
# The script reads only its input, params and output (a config change reruns the jobs whose params it changes).
rule diagnose:
    """Score test of every candidate effect at the variant's joint fit, refits of the best, verdicts."""
    input:
        unpack(sparse_route_input),
        parameters="results/{variant}/parameters.tsv",
        harmonics="results/data/harmonics.tsv",
        effects=EFFECTS_FILES,  # all of them: the variant and the candidates (params.model: the paths)
    output:
        table=report(
            "results/{variant}/diagnosis.tsv",
            caption="../report/diagnosis_table.rst",
            category="Diagnosis",
            subcategory="{variant}",
        ),
        recommendation=report(
            "results/{variant}/diagnosis.md",
            caption="../report/diagnosis_recommendation.rst",
            category="Diagnosis",
            subcategory="{variant}",
        ),
        summary="results/{variant}/diagnosis.yaml",
        refits="results/{variant}/diagnosis_refits.tsv",
        fingerprint="results/{variant}/diagnosis_fingerprint.tsv",
        intervals=report(
            "results/{variant}/diagnosis_intervals.tsv",
            caption="../report/diagnosis_intervals.rst",
            category="Diagnosis",
            subcategory="{variant}",
        ),
        plot=report(
            "results/{variant}/diagnosis.png",
            caption="../report/diagnosis_plot.rst",
            category="Diagnosis",
            subcategory="{variant}",
        ),
        plot_html="results/{variant}/diagnosis.html",  # in the report: results/interactive.html
    log:
        "logs/{variant}/diagnose.log",
    benchmark:
        "results/benchmarks/{variant}/diagnose.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=diagnosis_model,
        keyphasor=SETTINGS.identification.keyphasor,
        options=diagnosis_options,
        harmonics=config["harmonics"],
    script:
        "../../scripts/diagnose.py"
