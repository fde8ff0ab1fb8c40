"""Rule sample_scenarios: Latin-hypercube scenarios of one variant (thin wrapper)."""

from hybridtwin import config as cfg
from hybridtwin.scenarios import sample_scenarios

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "sample_scenarios")
variant = cfg.variant(smk.config, smk.wildcards.variant)
options = smk.params.offline
n = cfg.n_scenarios(smk.config, variant)
table = sample_scenarios(variant, n, options["seed"], options["validation_fraction"], options["n_test"])
table.to_csv(smk.output[0], sep="\t", index=False, float_format="%.12g")
log.info("%d scenarios over %s (seed %d): %s", len(table), variant.unknown_names, options["seed"],
         table["split"].value_counts().to_dict())
