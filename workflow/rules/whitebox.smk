# White box: the model solved at the run plan's operating points with its nominal values.


rule whitebox_sweep:
    """Sensor harmonics of one variant over the run plan, by run-up per eccentric mass."""
    input:
        points=config["runs"],
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        table="results/{variant}/whitebox/sweep.tsv",
        plot=report(
            "results/{variant}/whitebox/sweep.png",
            caption="../report/whitebox_sweep.rst",
            category="White box",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/whitebox_sweep.log",
    benchmark:
        "results/benchmarks/{variant}/whitebox_sweep.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        harmonics=config["harmonics"],
    script:
        "../../scripts/whitebox_sweep.py"
