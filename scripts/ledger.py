"""Rule ledger: every variant of the config side by side, normalised error, BIC, validation error (thin wrapper)."""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.report import report
from hybridtwin.report import report_plots
from hybridtwin.identify.run_fits import read_fit_summary
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "ledger")
rows, errors = [], {}
for variant, summary_path, fit_path, validation_path in zip(smk.params.variants, smk.input.summaries,
                                                             smk.input.errors, smk.input.validation_errors):
    summary = read_fit_summary(summary_path)["final"]
    errors[variant] = pd.concat([report.read_errors(path) for path in (fit_path, validation_path)],
                                ignore_index=True)
    rows.append(report.ledger_row(variant, smk.params.descriptions[variant], summary, errors[variant]))
    log.info("%s: chi^2/dof %.4g, BIC %.6g", variant, rows[-1]["chi2_dof"], rows[-1]["bic"])
ledger = report.ledger_table(rows)
report.write_ledger(ledger, smk.output.table)
save_png(report_plots.plot_ledger(ledger, errors), smk.output.plot, dpi=100)
