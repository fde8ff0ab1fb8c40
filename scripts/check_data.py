"""Rule check_data: validate the runs sheet and every record, write the per-run summary (thin wrapper).

Flagged runs (kept out of the fit) and invalid records are said on the console, not only in the log.
"""

import logging
import sys
import warnings

from snakemake.utils import validate

from hybridtwin.data.measurements import DataError, DataWarning, read_runs
from hybridtwin.config import whirl_model
from hybridtwin.model.whirl import write_whirl
from hybridtwin.data.preprocessing import check_data, has_usable_fit_run, write_tsv
from hybridtwin.data.shared_problems import group_messages, group_problems
from hybridtwin.config import on_disk_full

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
on_disk_full(logging.getLogger("check_data"))  # a full disk: one message naming the file and what to free
log = logging.getLogger("check_data")

try:
    validate(read_runs(smk.input.sheet, require_mass=True), smk.input.schema, set_default=False)  # documented schema
    coverage = smk.params.coverage or {}
    whirl = whirl_model(getattr(smk.params, "whirl", None) or {})  # the model's 1X whirl (None: the VARM's rule)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        summary, errors = check_data(smk.input.sheet, smk.params.harmonics, coverage.get("rpm"),
                                     coverage.get("eccentric_mass_g"), smk.params.sensor_range_mm * 1e-3,
                                     range_names=("config coverage.rpm", "config coverage.eccentric_mass_g"),
                                     sensors=getattr(smk.params, "sensors", None),  # the records' channels
                                     whirl=whirl)
except DataError as err:
    log.error("%s", err)
    sys.exit(f"check_data: error: {err}")
for warning in caught:
    log.warning("%s", warning.message)
# on the console, a problem several runs share once, with the runs it concerns (data/shared_problems.py)
runs, paths = list(summary["run"]), dict(zip(summary["run"], summary["path"].astype(str)))
for message, count in group_messages([str(w.message) for w in caught], runs, paths):
    print(f"check_data: warning: {message}" + (f" (the same in {count - 1} more run(s))" if count > 1 else ""),
          file=sys.stderr)
for row in summary.itertuples():
    log.info("%s: %s", row.run, row.status)
flagged = summary.loc[~summary["usable"].astype(bool) & ~summary["run"].isin(list(errors)), ["run", "status"]]
for problem in group_problems(dict(zip(flagged["run"], flagged["status"])), paths):
    said = (f"run {problem.runs[0]} is kept out of the fit: {problem.message}" if len(problem.runs) == 1
            else f"kept out of the fit: {problem.describe(len(summary))}")
    print(f"check_data: {said}", file=sys.stderr)
if errors:
    for run, message in errors.items():
        log.error("run %s: %s", run, message)
    sys.exit(f"check_data: {len(errors)} invalid record(s) in {smk.input.sheet}:\n"
             + "\n".join(problem.describe(len(summary)) for problem in group_problems(errors, paths)))
if not has_usable_fit_run(summary):
    log.error("no usable fit run in %s", smk.input.sheet)
    sys.exit(f"check_data: no usable fit run in {smk.input.sheet}: every run with role fit is kept out of the fit "
             "(each said above, with why); nothing could be identified, so nothing is built")
write_whirl(whirl, smk.output.whirl)  # its answers, for the runs' preprocessing (computed once)
write_tsv(summary, smk.output.summary)
