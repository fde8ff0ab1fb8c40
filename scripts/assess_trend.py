"""Rule assess_trend: the twin's trend from every record's assessment, in time order (thin wrapper of
hybridtwin.online.trend)."""

from pathlib import Path

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.online.assess import Assessment
from hybridtwin.online.trend import TREND_COLUMNS, plot_trend, rows, write_trend
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "assess_trend")
assessments = [Assessment.read(Path(path).parent) for path in smk.input.summaries]
trend = write_trend(pd.concat([rows(a) for a in assessments], ignore_index=True) if assessments
                    else pd.DataFrame(columns=TREND_COLUMNS), smk.output.table)
save_png(plot_trend(trend, smk.wildcards.variant), smk.output.figure, dpi=110)
log.info("%d record(s): %s", len(assessments), ", ".join(f"{a.summary['record']} {a.summary['verdict']}"
                                                         for a in assessments))
