"""Rule spgd_library: the sPGD library of every run of a variant, fitted on each run's own snapshots on the job's
threads (processes), or sliced from the global library (offline.scope) (thin wrapper). Reads only the rule's input,
params and output."""

from functools import partial

from hybridtwin import config as cfg
from hybridtwin.offline.library import build_run_libraries, global_run_library, pieces_note

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "spgd_library")
options = smk.params.offline
if options["scope"] == "global":
    for run, path in zip(smk.params.runs, smk.output):
        library = global_run_library(smk.input.global_library, smk.input.snapshots, run)
        library.save(path)
        log.info("run %s: the global library at %s (%d POD modes, %d sPGD terms)", run,
                 library.info["operating_point"], library.n_modes, library.model.n_terms)
else:
    infos = build_run_libraries(partial(cfg.variant, smk.params.model, smk.wildcards.variant), smk.params.runs, smk.input.snapshots,
                                smk.input.pod, list(smk.output), options["sensor_range_mm"] * 1e-3, options["spgd"],
                                options["pieces"], workers=smk.threads, log=log)
    for run, info in zip(smk.params.runs, infos):
        log.info("run %s: %d training / %d validation scenarios (left out: %s), %d POD modes, %d sPGD terms, "
                 "validation error %.3g%s", run, info["n_train"], info["n_validation"], info["n_left_out"],
                 info["n_modes"], info["n_terms"], min(info["validation_error"]), pieces_note(info))
