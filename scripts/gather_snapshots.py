"""Rule gather_snapshots: chunks -> one snapshot store, failures listed (thin wrapper).

A chunk store that fails its manifest check (a file missing, changed or unlisted, or no
manifest: see hybridtwin.offline.snapshots) is removed and the job fails naming it, so the next
`snakemake` run solves that chunk again instead of gathering zeros.
"""

import shutil
import sys

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.offline.scenarios import read_scenarios
from hybridtwin.offline.snapshots import UNSTABLE, failure_summary, gather
from hybridtwin.offline.stores import CorruptStoreError

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "gather_snapshots")
expected = read_scenarios(smk.input.scenarios)
chunks = list(smk.input.chunks)
if "enrichment" in smk.input.keys():  # offline.enrichment: the adaptive scenarios join the first design
    expected = pd.concat([expected, read_scenarios(smk.input.enrichment)], ignore_index=True)
    chunks += list(smk.input.enrichment_chunks)
try:
    snapshots = gather(chunks, expected, smk.output.store)
except CorruptStoreError as error:
    for path in error.problems:
        shutil.rmtree(path, ignore_errors=True)
    message = (f"{error}\nremoved {len(error.problems)} chunk store(s): {', '.join(error.problems)}; "
               "run snakemake again to solve them anew")
    log.error(message)
    sys.exit(message)
failures = snapshots.failures()
tables.FAILURES.write(failures, smk.output.failures)
tables.FAILURE_SUMMARY.write(failure_summary(failures), smk.output.summary)  # the report's view (counts)
unstable = failures["reason"] == UNSTABLE
log.info("%d scenarios (%d from the enrichment) x %d runs gathered; %d failed solves, %d unstable steady states "
         "(left out downstream)", snapshots.success.shape[1], int((snapshots.design == "enrichment").sum()),
         len(snapshots.runs), int((~unstable).sum()), int(unstable.sum()))
for run, count in failures.loc[~unstable, "run"].value_counts().items():
    log.warning("run %s: %d scenarios without a periodic solution (see %s)", run, count, smk.output.failures)
for run, count in failures.loc[unstable, "run"].value_counts().items():
    log.warning("run %s: %d scenarios whose periodic solution is unstable, left out (see %s)", run, count,
                smk.output.failures)
