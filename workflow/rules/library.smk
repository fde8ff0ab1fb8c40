# sPGD library per run (paper eq. 6-7), then its validation against the full solver.


rule spgd_global:
    """offline.scope: global: one sPGD over the unknowns, rpm and eccentric mass, fitted on the fit runs."""
    input:
        snapshots="results/{variant}/snapshots.zarr",
        runs=config["runs"],
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        directory("results/{variant}/library_global.zarr"),
    log:
        "logs/{variant}/spgd_global.log",
    benchmark:
        "results/benchmarks/{variant}/spgd_global.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "spgd_global"),
    script:
        "../../scripts/spgd_global.py"


rule spgd_library:
    """The library of every run of a variant in one job, its runs fitted in parallel on the job's threads (a run's
    fit takes seconds: one job per run paid the start-up and the snapshots' loading once per run)."""
    input:
        unpack(library_input),
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
    output:
        [directory(path) for path in expand("results/{{variant}}/library/{run}.zarr", run=RUNS)],
    log:
        "logs/{variant}/spgd_library.log",
    benchmark:
        "results/benchmarks/{variant}/spgd_library.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    threads: 2
    params:
        runs=RUNS,
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "spgd_library"),
    script:
        "../../scripts/spgd_library.py"


rule validate_library:
    """Library vs full solver on the held-out test scenarios, per run: table and parity plot."""
    input:
        snapshots="results/{variant}/snapshots.zarr",
        libraries=expand("results/{{variant}}/library/{run}.zarr", run=RUNS),
        runs=config["runs"],
        effects=variant_effects,  # their contents build the variant (params.model has only the paths)
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
    log:
        "logs/{variant}/validate_library.log",
    benchmark:
        "results/benchmarks/{variant}/validate_library.tsv"
    conda:
        "../envs/hybridtwin.yaml"
    params:
        model=variant_model,
        offline=lambda wildcards: offline_options(wildcards, "validate_library"),
    script:
        "../../scripts/validate_library.py"
