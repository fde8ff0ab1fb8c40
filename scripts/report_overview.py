"""Rule report_overview: per-run errors (fit and validation runs apart) and the error map (thin wrapper)."""

from hybridtwin import config as cfg
from hybridtwin.report import report
from hybridtwin.report import report_plots
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_overview")
variant = smk.wildcards.variant
comparisons = report.load_comparisons(smk.input.table)
errors = report.error_table(comparisons)
for role, path in (("fit", smk.output.errors), ("validate", smk.output.validation_errors)):
    report.write_errors(errors[errors["role"] == role], path)
    log.info("%s runs: %s", role, report.pooled(errors[errors["role"] == role]))
figure = report_plots.plot_error_map(errors, variant)
save_png(figure, smk.output.error_map, dpi=100)
report_plots.plt.close(figure)
