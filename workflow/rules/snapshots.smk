# Snapshots: the chunks gathered into one zarr v3 store per variant; every failure listed.


rule gather_snapshots:
    """Check the chunks hold exactly the sampled scenarios and join them; list failures with reasons."""
    input:
        scenarios="results/{variant}/scenarios.tsv",
        chunks=expand("results/{{variant}}/chunks/{chunk}.zarr", chunk=CHUNKS),
    output:
        store=directory("results/{variant}/snapshots.zarr"),
        failures=report(
            "results/{variant}/failures.tsv",
            caption="../report/failures.rst",
            category="Offline library",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/gather_snapshots.log",
    benchmark:
        "results/benchmarks/{variant}/gather_snapshots.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/gather_snapshots.py"
