# sPGD library per run (paper eq. 6-7), then its validation against the full solver.


rule spgd_global:
    """offline.scope: global: one sPGD over the unknowns, rpm and eccentric mass, fitted on the fit runs."""
    input:
        snapshots="results/{variant}/snapshots.zarr",
        runs=config["runs"],
    output:
        directory("results/{variant}/library_global.zarr"),
    params:
        spec=lambda wildcards: config["variants"][wildcards.variant],
        offline=lambda wildcards: offline_for(config, wildcards.variant, OFFLINE_USED["spgd_global"]),
    log:
        "logs/{variant}/spgd_global.log",
    benchmark:
        "results/benchmarks/{variant}/spgd_global.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/spgd_global.py"


rule spgd_library:
    input:
        unpack(library_input),
    output:
        directory("results/{variant}/library/{run}.zarr"),
    params:
        spec=lambda wildcards: config["variants"][wildcards.variant],
        offline=lambda wildcards: offline_for(config, wildcards.variant, OFFLINE_USED["spgd_library"]),
    log:
        "logs/{variant}/spgd_library_{run}.log",
    benchmark:
        "results/benchmarks/{variant}/spgd_library_{run}.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/spgd_library.py"


rule validate_library:
    """Library vs full solver on the held-out test scenarios, per run: table and parity plot."""
    input:
        snapshots="results/{variant}/snapshots.zarr",
        libraries=expand("results/{{variant}}/library/{run}.zarr", run=RUNS),
        runs=config["runs"],
    output:
        table=report(
            "results/{variant}/library_validation.tsv",
            caption="../report/library_validation.rst",
            category="Offline library",
            subcategory="{variant}",
        ),
        plot=report(
            "results/{variant}/library_parity.png",
            caption="../report/library_parity.rst",
            category="Offline library",
            subcategory="{variant}",
        ),
    params:
        spec=lambda wildcards: config["variants"][wildcards.variant],
        offline=lambda wildcards: offline_for(config, wildcards.variant, OFFLINE_USED["validate_library"]),
    log:
        "logs/{variant}/validate_library.log",
    benchmark:
        "results/benchmarks/{variant}/validate_library.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    script:
        "../../scripts/validate_library.py"
