# Scenarios: Latin-hypercube parameter sets, solved in chunks at every run (paper eq. 1-3).


rule sample_scenarios:
    """Seeded Latin hypercube over the variant's unknown ranges, split train/validation/test."""
    input:
        runs=config["runs"],
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        "results/{variant}/scenarios.tsv",
    log:
        "logs/{variant}/sample_scenarios.log",
    benchmark:
        "results/benchmarks/{variant}/sample_scenarios.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "sample_scenarios"),
    script:
        "../../scripts/sample_scenarios.py"


rule solve_chunk:
    """One chunk (hundreds of scenarios) solved at every run by run-up, written as a zarr v3 group."""
    input:
        scenarios="results/{variant}/scenarios.tsv",
        runs=config["runs"],
        speeds=SPEEDS,
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        directory("results/{variant}/chunks/{chunk}.zarr"),
    log:
        "logs/{variant}/solve_chunk_{chunk}.log",
    benchmark:
        "results/benchmarks/{variant}/solve_chunk_{chunk}.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    resources:
        mem_mb=2000,
    params:
        model=variant_model,
        measured=OFFLINE.speed == "measured",
        n_chunks=OFFLINE.chunks,
        harmonics=config["harmonics"],
    script:
        "../../scripts/solve_chunk.py"


# Enrichment (offline.enrichment): runs where little of the box is observable (near the resonance) get extra
# scenarios where the first design says they can be measured; solved at those runs' eccentric mass only.
rule sample_enrichment:
    """Thin runs found in the first design's chunks; candidates kept where their nearest scenarios are observable."""
    input:
        scenarios="results/{variant}/scenarios.tsv",
        chunks=expand("results/{{variant}}/chunks/{chunk}.zarr", chunk=CHUNKS),
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        scenarios="results/{variant}/enrichment.tsv",
        summary=report(
            "results/{variant}/enrichment_summary.tsv",
            caption="../report/enrichment.rst",
            category="Offline library",
            subcategory="{variant}",
        ),
    log:
        "logs/{variant}/sample_enrichment.log",
    benchmark:
        "results/benchmarks/{variant}/sample_enrichment.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "sample_enrichment"),
    script:
        "../../scripts/sample_enrichment.py"


rule solve_enrichment:
    """One slice of the enrichment scenarios solved by run-up at their eccentric mass's runs (zarr v3 group)."""
    input:
        scenarios="results/{variant}/enrichment.tsv",
        runs=config["runs"],
        speeds=SPEEDS,
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        directory("results/{variant}/enrichment/{chunk}.zarr"),
    log:
        "logs/{variant}/solve_enrichment_{chunk}.log",
    benchmark:
        "results/benchmarks/{variant}/solve_enrichment_{chunk}.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    resources:
        mem_mb=2000,
    params:
        model=variant_model,
        measured=OFFLINE.speed == "measured",
        n_chunks=OFFLINE.enrichment.chunks,
        harmonics=config["harmonics"],
    script:
        "../../scripts/solve_enrichment.py"
