"""Rule spgd_global: one sPGD library over the unknowns and the operating point, for every run (thin wrapper).
Reads only the rule's input, params and output."""

from hybridtwin import config as cfg
from hybridtwin.offline.library import build_variant_global_library, pieces_note

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "spgd_global")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.offline
library = build_variant_global_library(variant, smk.input.snapshots, cfg.run_plan(smk.input.runs),
                                       options["sensor_range_mm"] * 1e-3, options["pod_energy_tolerance"],
                                       options["spgd"], options["pieces"])
library.save(smk.output[0])
info = library.info
log.info("global library over %s from the fit runs %s: %d training / %d validation samples, %d POD modes, "
         "%d sPGD terms, validation error %.3g%s", library.parameters, info["fit_runs"], info["n_train"],
         info["n_validation"], library.n_modes, library.model.n_terms, min(info["validation_error"]),
         pieces_note(info))
