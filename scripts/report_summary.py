"""Rule report_summary: the report's first page, the answer first (results/summary.{tsv,png,rst}; thin wrapper)."""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.identify.design import read_design_table
from hybridtwin.identify.validation_refit import read_validation
from hybridtwin.plots import png_palette_bytes
from hybridtwin.report import interactive, report, summary
from hybridtwin.data.measured import read_harmonics
from hybridtwin.diagnose.diagnosis_report import read_diagnosis_summary

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_summary")
ledger = report.read_ledger(smk.input.ledger)
errors, diagnoses, why = {}, {}, {}
for variant, fit_path, validation_path, diagnosis_path, explained in zip(
        smk.params.variants, smk.input.errors, smk.input.validation_errors, smk.input.diagnoses, smk.input.validation):
    errors[variant] = pd.concat([report.read_errors(path) for path in (fit_path, validation_path)],
                                ignore_index=True)
    why[variant] = summary.explanations(read_validation(explained))
    diagnoses[variant] = read_diagnosis_summary(diagnosis_path)
table = summary.summary_table(ledger, errors, diagnoses, smk.params.specs)
tables.SUMMARY.write(table, smk.output.table)
figure = summary.plot_summary(ledger, errors)
png = png_palette_bytes(figure)  # at most 256 colours: the report embeds it
with open(smk.output.plot, "wb") as stream:
    stream.write(png)
interactive.write_html(interactive.summary_figure(ledger, errors), smk.output.plot_html)
best = summary.best_variant(table)
designs = dict(zip(smk.params.variants, zip(smk.input.next_runs, smk.input.intervals))) if smk.params.design else {}
line = ""
if best["variant"] in designs:
    chosen, intervals = (read_design_table(path) for path in designs[best["variant"]])
    line = summary.next_runs_line(best["variant"], chosen, intervals)
with open(smk.output.page, "w") as stream:
    stream.write(summary.landing_rst(table, errors, summary.kept_out(read_harmonics(smk.input.harmonics)), why, line,
                                     summary.assumptions_line(best["variant"], diagnoses[best["variant"]])))
log.info("best variant %s (chi^2/dof %.4g); %s", best["variant"], best["chi2_dof"], best["conclusion"])
