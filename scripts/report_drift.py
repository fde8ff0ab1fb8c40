"""Rule report_drift: do the per-run estimates of the model's constants drift with speed? (thin wrapper)"""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.report import report

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_drift")
per_run = pd.read_csv(smk.input.per_run, sep="\t", dtype={"run": str})
joint = pd.read_csv(smk.input.parameters, sep="\t", dtype={"run": str})
statistics = report.drift_statistics(per_run, joint)
statistics.to_csv(smk.output.table, sep="\t", index=False, float_format="%.6g")
for row in statistics.itertuples():
    log.info("%s: %s", row.parameter, row.verdict)
figure = report.plot_drift(per_run, statistics, joint, smk.wildcards.variant)
figure.savefig(smk.output.plot, dpi=100)
