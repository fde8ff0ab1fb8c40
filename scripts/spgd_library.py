"""Rule spgd_library: the sPGD library of one run (thin wrapper)."""

from hybridtwin import config as cfg
from hybridtwin.library import build_run_library

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "spgd_library")
variant = cfg.variant(smk.config, smk.wildcards.variant)
options = smk.params.offline
library = build_run_library(variant, smk.wildcards.run, smk.input.snapshots, smk.input.pod,
                            options["sensor_range_mm"] * 1e-3, options["spgd"])
library.save(smk.output[0])
info = library.info
log.info("run %s: %d training / %d validation scenarios (left out: %s), %d POD modes, %d sPGD terms, "
         "validation error %.3g", library.run, info["n_train"], info["n_validation"], info["n_left_out"],
         library.n_modes, library.model.n_terms, min(info["validation_error"]))
