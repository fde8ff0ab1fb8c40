"""Rule assess_record: one new record judged against the twin (thin wrapper of hybridtwin.online). Reads only the
rule's input, params and output; the twin's folder is read, never written."""

import sys
from pathlib import Path

from hybridtwin import config as cfg
from hybridtwin.online.assess import assess
from hybridtwin.online.assess_plots import plot_assessment
from hybridtwin.online.intake import RecordError, intake
from hybridtwin.online.twin import load_twin
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "assess_record")
twin = load_twin(Path(smk.input.card).parent)
try:
    record = intake(twin, smk.params.row)
except RecordError as err:
    log.error("%s", err)
    sys.exit(f"assess_record: error: {err}")
result = assess(twin, record, smk.params.alpha)
for warning in result.warnings:
    log.warning("%s", warning)
for band, why in record.left_out.items():
    log.info("%s left out: %s", band, why)
result.write(Path(smk.output.summary).parent)
save_png(plot_assessment(result), smk.output.figure, dpi=110)
log.info("%s", result.line())
print(result.line())
