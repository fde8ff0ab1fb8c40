"""Rule check_data: validate the runs sheet and every record, write the per-run summary (thin wrapper)."""

import logging

from snakemake.utils import validate

from hybridtwin.measurements import read_runs
from hybridtwin.preprocessing import check_data, write_tsv

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
logging.captureWarnings(True)  # flagged (flat, clipped) runs are logged as warnings
log = logging.getLogger("check_data")

validate(read_runs(smk.input.sheet), smk.input.schema, set_default=False)  # the sheet's documented schema
coverage = smk.params.coverage or {}
summary, errors = check_data(smk.input.sheet, smk.params.harmonics, coverage.get("rpm"),
                             coverage.get("eccentric_mass_g"))
for row in summary.itertuples():
    log.info("%s: %s", row.run, row.status)
if errors:
    for run, message in errors.items():
        log.error("run %s: %s", run, message)
    raise SystemExit(f"check_data: {len(errors)} invalid record(s) in {smk.input.sheet}:\n"
                     + "\n".join(errors.values()))
write_tsv(summary, smk.output.summary)
