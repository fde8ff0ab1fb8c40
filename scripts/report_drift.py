"""Rule report_drift: do the per-run estimates of the model's constants drift with speed? (thin wrapper)"""

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.identify import identification as idn
from hybridtwin.report import drift
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_drift")
per_run = idn.read_parameters(smk.input.per_run)  # the per-run fits' drift table, a parameter table
joint = idn.read_parameters(smk.input.parameters)
statistics = drift.drift_statistics(per_run, joint)
tables.DRIFT.write(statistics, smk.output.table)
for row in statistics.itertuples():
    log.info("%s: %s", row.parameter, row.verdict)
figure = drift.plot_drift(per_run, statistics, joint, smk.wildcards.variant)
save_png(figure, smk.output.plot, dpi=100)
