# Snapshots: the chunks gathered into one zarr v3 store per variant; every failure listed.
# Each chunk store carries the checksum manifest its solve_chunk job wrote last (manifest.sha256): a chunk
# that is incomplete, or lost or changed a file since, is removed and named, and the job fails, so that
# the next run solves it again (a missing zarr chunk file would otherwise read as zeros).


rule gather_snapshots:
    """Verify the chunks against their manifests, check they hold exactly the sampled scenarios, join them."""
    input:
        unpack(gather_input),
    output:
        store=directory("results/{variant}/snapshots.zarr"),
        # every point without a steady state (thousands of rows: outside the report, which shows the counts)
        failures="results/{variant}/failures.tsv",
        summary=report(
            "results/{variant}/failures_summary.tsv",
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
