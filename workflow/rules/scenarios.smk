# Scenarios: Latin-hypercube parameter sets, solved in chunks at every run (paper eq. 1-3).


rule sample_scenarios:
    """Seeded Latin hypercube over the variant's unknown ranges, split train/validation/test."""
    input:
        runs=config["runs"],
    output:
        "results/{variant}/scenarios.tsv",
    params:
        spec=lambda wildcards: config["variants"][wildcards.variant],
        offline=lambda wildcards: offline_for(config, wildcards.variant, OFFLINE_USED["sample_scenarios"]),
    log:
        "logs/{variant}/sample_scenarios.log",
    benchmark:
        "results/benchmarks/{variant}/sample_scenarios.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/sample_scenarios.py"


rule solve_chunk:
    """One chunk (hundreds of scenarios) solved at every run by run-up, written as a zarr v3 group."""
    input:
        scenarios="results/{variant}/scenarios.tsv",
        runs=config["runs"],
        speeds=SPEEDS,
    output:
        directory("results/{variant}/chunks/{chunk}.zarr"),
    params:
        spec=lambda wildcards: config["variants"][wildcards.variant],
        measured=OFFLINE["speed"] == "measured",
        n_chunks=OFFLINE["chunks"],
        harmonics=config["harmonics"],
    resources:
        mem_mb=2000,
    log:
        "logs/{variant}/solve_chunk_{chunk}.log",
    benchmark:
        "results/benchmarks/{variant}/solve_chunk_{chunk}.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/solve_chunk.py"
