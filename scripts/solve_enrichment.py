"""Rule solve_enrichment: one slice of the enrichment scenarios solved at their eccentric mass's runs (thin wrapper).
Reads only the rule's input, params and output."""

import time

import numpy as np

from hybridtwin import config as cfg
from hybridtwin.offline.scenarios import read_scenarios, solve_enrichment
from hybridtwin.offline.snapshots import write_chunk

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "solve_enrichment")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
table = read_scenarios(smk.input.scenarios)
chunk = int(smk.wildcards.chunk)
mine = table.iloc[np.array_split(np.arange(len(table)), smk.params.n_chunks)[chunk]].reset_index(drop=True)
runs = cfg.run_plan(smk.input.runs, smk.input.speeds if smk.params.measured else None)
log.info("enrichment chunk %d: %d scenarios at eccentric masses %s g, H = %d", chunk, len(mine),
         sorted(mine["eccentric_mass_g"].unique().tolist()), smk.params.harmonics)
start = time.perf_counter()
solutions = solve_enrichment(variant, runs, mine, smk.params.harmonics)
log.info("solved in %.1f s", time.perf_counter() - start)
for run, ok, stable, mass in zip(solutions.runs, solutions.success, solutions.stable, solutions.eccentric_mass_g):
    targeted = int((mine["eccentric_mass_g"] == mass).sum())
    if targeted:
        log.info("run %s: %d of %d converged, %d of them unstable", run, ok.sum(), targeted, (ok & ~stable).sum())
write_chunk(smk.output[0], variant.name, mine, variant.unknown_names, solutions, design="enrichment")
log.info("wrote %s, its manifest.sha256 last (gather_snapshots verifies it)", smk.output[0])
