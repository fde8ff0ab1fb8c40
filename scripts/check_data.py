"""Rule check_data: validate the runs sheet and every record, write the per-run summary (thin wrapper).

Flagged runs (kept out of the fit) and invalid records are said on the console, not only in the log.
"""

import logging
import sys
import warnings

from snakemake.utils import validate

from hybridtwin.data.measurements import DataError, DataWarning, read_runs
from hybridtwin.data.preprocessing import check_data, has_usable_fit_run, write_tsv

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
log = logging.getLogger("check_data")

try:
    validate(read_runs(smk.input.sheet, require_mass=True), smk.input.schema, set_default=False)  # documented schema
    coverage = smk.params.coverage or {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        summary, errors = check_data(smk.input.sheet, smk.params.harmonics, coverage.get("rpm"),
                                     coverage.get("eccentric_mass_g"), smk.params.sensor_range_mm * 1e-3,
                                     range_names=("config coverage.rpm", "config coverage.eccentric_mass_g"),
                                     sensors=getattr(smk.params, "sensors", None))  # the records' channels
except DataError as err:
    log.error("%s", err)
    sys.exit(f"check_data: error: {err}")
for warning in caught:
    log.warning("%s", warning.message)
    print(f"check_data: warning: {warning.message}", file=sys.stderr)
for row in summary.itertuples():
    log.info("%s: %s", row.run, row.status)
flagged = summary.loc[~summary["usable"].astype(bool) & ~summary["run"].isin(list(errors)), ["run", "status"]]
for row in flagged.itertuples():
    print(f"check_data: run {row.run} is kept out of the fit: {row.status}", file=sys.stderr)
if errors:
    for run, message in errors.items():
        log.error("run %s: %s", run, message)
    sys.exit(f"check_data: {len(errors)} invalid record(s) in {smk.input.sheet}:\n" + "\n".join(errors.values()))
if not has_usable_fit_run(summary):
    log.error("no usable fit run in %s", smk.input.sheet)
    sys.exit(f"check_data: no usable fit run in {smk.input.sheet}: every run with role fit is kept out of the fit "
             "(each said above, with why); nothing could be identified, so nothing is built")
write_tsv(summary, smk.output.summary)
