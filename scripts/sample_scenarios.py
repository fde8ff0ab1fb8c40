"""Rule sample_scenarios: Latin-hypercube scenarios of one variant (thin wrapper). Reads only the rule's input,
params and output."""

from hybridtwin import config as cfg
from hybridtwin.offline.scenarios import sample_scenarios, write_scenarios

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "sample_scenarios")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.offline
n = int(options["n_scenarios"])  # n_s of this variant (hybridtwin.config.offline_for)
table = sample_scenarios(variant, n, options["seed"], options["validation_fraction"], options["n_test"])
write_scenarios(table, smk.output[0])
log.info("%d scenarios over %s (seed %d): %s", len(table), variant.unknown_names, options["seed"],
         table["split"].value_counts().to_dict())
