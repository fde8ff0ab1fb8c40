# POD: per run, the SVD of the observable training snapshots, truncated by energy (paper eq. 4-5).


rule pod:
    input:
        snapshots="results/{variant}/snapshots.zarr",
        harmonics="results/data/harmonics.tsv",  # the runs the data checks kept out (usable false)
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        store=directory("results/{variant}/pod.zarr"),
        table=report(
            "results/{variant}/pod.tsv",
            caption="../report/pod.rst",
            category="Offline library",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/pod.log",
    benchmark:
        "results/benchmarks/{variant}/pod.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "pod"),
    script:
        "../../scripts/pod.py"
