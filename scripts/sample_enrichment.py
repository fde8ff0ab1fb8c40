"""Rule sample_enrichment: extra scenarios where the thin runs can be measured (thin wrapper).

Reads the first design's chunk stores (verified against their manifests), finds the runs
where fewer than offline.enrichment.observable_below of the fitting scenarios are observable,
and samples offline.enrichment.n_scenarios more per eccentric mass of such runs
(hybridtwin.offline.scenarios.sample_enrichment). Reads only the rule's input, params and output.
"""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.offline.scenarios import read_scenarios, sample_enrichment, write_scenarios
from hybridtwin.model.sensor import observable
from hybridtwin.offline.snapshots import read_chunks

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "sample_enrichment")
options = smk.params.offline
enrichment = options["enrichment"]
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
scenarios = read_scenarios(smk.input.scenarios)
snaps = read_chunks(smk.input.chunks, scenarios)
runs = pd.DataFrame({"run": snaps.runs, "eccentric_mass_g": snaps.eccentric_mass_g})
shaft = variant.model.shaft
seen = observable(snaps.harmonics, shaft, 1e-3 * options["sensor_range_mm"]) & snaps.steady  # unstable: not seen
table, summary = sample_enrichment(variant, snaps.values, snaps.split, seen, runs, int(scenarios["scenario"].max()) + 1,
                                   enrichment["n_scenarios"], enrichment["observable_below"], options["seed"],
                                   options["validation_fraction"])
write_scenarios(table, smk.output.scenarios, float_format=None)
tables.ENRICHMENT_SUMMARY.write(summary, smk.output.summary)
if summary.empty:
    log.info("no run has fewer than %.0f %% observable fitting scenarios: nothing to enrich",
             100 * enrichment["observable_below"])
for row in summary.itertuples():
    log.info("run %s (%g g): %.1f %% of the fitting scenarios observable; %.1f %% of the candidates predicted "
             "observable; %d scenarios added for its eccentric mass", row.run, row.eccentric_mass_g,
             100 * row.observable_share, row.candidates_kept_pct, row.added)
