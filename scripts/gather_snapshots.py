"""Rule gather_snapshots: chunks -> one snapshot store, failures listed (thin wrapper)."""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.snapshots import gather

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "gather_snapshots")
snapshots = gather(smk.input.chunks, pd.read_csv(smk.input.scenarios, sep="\t"), smk.output.store)
failures = snapshots.failures()
failures.to_csv(smk.output.failures, sep="\t", index=False)
log.info("%d scenarios x %d runs gathered; %d failed solves", snapshots.success.shape[1], len(snapshots.runs),
         len(failures))
for run, count in failures["run"].value_counts().items():
    log.warning("run %s: %d scenarios without a periodic solution (see %s)", run, count, smk.output.failures)
