"""Rule solve_chunk: one slice of the scenarios solved at every run by run-up (thin wrapper). Reads only the rule's
input, params and output."""

import time

import numpy as np

from hybridtwin import config as cfg
from hybridtwin.offline.scenarios import read_scenarios, solve_runs
from hybridtwin.offline.snapshots import write_chunk

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "solve_chunk")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
scenarios = read_scenarios(smk.input.scenarios)
chunk = int(smk.wildcards.chunk)
mine = scenarios.iloc[np.array_split(np.arange(len(scenarios)), smk.params.n_chunks)[chunk]]
runs = cfg.run_plan(smk.input.runs, smk.input.speeds if smk.params.measured else None)
log.info("chunk %d: scenarios %d..%d (%d) at %d runs, H = %d", chunk, mine["scenario"].min(),
         mine["scenario"].max(), len(mine), len(runs), smk.params.harmonics)
start = time.perf_counter()
solutions = solve_runs(variant, runs, {k: mine[k].to_numpy() for k in variant.unknown_names}, smk.params.harmonics)
elapsed = time.perf_counter() - start
for run, ok, stable in zip(solutions.runs, solutions.success, solutions.stable):
    log.info("run %s: %d of %d converged, %d of them unstable", run, ok.sum(), ok.size, (ok & ~stable).sum())
log.info("solved in %.1f s (%.2f ms per scenario and run)", elapsed, 1e3 * elapsed / solutions.success.size)
write_chunk(smk.output[0], variant.name, mine, variant.unknown_names, solutions)
log.info("wrote %s, its manifest.sha256 last (gather_snapshots verifies it)", smk.output[0])
