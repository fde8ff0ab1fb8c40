"""Rule spgd_library: the sPGD library of one run, fitted on its own snapshots or sliced from the global
library (offline.scope) (thin wrapper)."""

from hybridtwin import config as cfg
from hybridtwin.library import build_run_library, global_run_library, pieces_note

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "spgd_library")
run = smk.wildcards.run
options = smk.params.offline
if options["scope"] == "global":
    library = global_run_library(smk.input.global_library, smk.input.snapshots, run)
    log.info("run %s: the global library at %s (%d POD modes, %d sPGD terms)", run,
             library.info["operating_point"], library.n_modes, library.model.n_terms)
else:
    variant = cfg.variant(smk.config, smk.wildcards.variant)
    library = build_run_library(variant, run, smk.input.snapshots, smk.input.pod, options["sensor_range_mm"] * 1e-3,
                                options["spgd"], options["pieces"])
    info = library.info
    log.info("run %s: %d training / %d validation scenarios (left out: %s), %d POD modes, %d sPGD terms, "
             "validation error %.3g%s", run, info["n_train"], info["n_validation"], info["n_left_out"],
             library.n_modes, library.model.n_terms, min(info["validation_error"]), pieces_note(info))
library.save(smk.output[0])
