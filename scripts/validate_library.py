"""Rule validate_library: libraries vs the full solver on the test scenarios (thin wrapper). Reads only the rule's
input, params and output."""

from hybridtwin import config as cfg
from hybridtwin.offline.library import Library, validate_libraries, write_library_validation
from hybridtwin.plots import plot_parity
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "validate_library")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
libraries = [Library.load(path) for path in smk.input.libraries]
table, parity = validate_libraries(libraries, smk.input.snapshots, cfg.run_plan(smk.input.runs),
                                   variant.model.shaft, smk.params.offline["sensor_range_mm"] * 1e-3)
write_library_validation(table, smk.output.table)
save_png(plot_parity(parity, variant.name), smk.output.plot, dpi=120)
for row in table.itertuples():
    log.info("%s: median %.3g %%, p95 %.3g %%, max %.3g %% over %d test scenarios", row.run,
             row.median_error_pct, row.p95_error_pct, row.max_error_pct, row.n_test)
