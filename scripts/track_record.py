"""Rule track_record: one run-up or coast-down as speed bands, with its runout, order vectors and speed (thin
wrapper around hybridtwin.data.transient.track_record). A band kept out (not reached, too few revolutions,
clipped) is written with its note and said on the console."""

import logging
import sys

from hybridtwin.data.measurements import DataError
from hybridtwin.data.records import read_record
from hybridtwin.data.measured import write_harmonics
from hybridtwin.data.order_tracking import write_orders
from hybridtwin.data.preprocessing import write_tsv
from hybridtwin.data.transient import track_record
from hybridtwin.config import on_disk_full

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
on_disk_full(logging.getLogger("track_record"))  # a full disk: one message naming the file and what to free
log = logging.getLogger("track_record")
row = smk.params.row
try:
    record = read_record(row["record"], getattr(smk.params, "sensors", None), row.get("channels"))
    tracked = track_record(record, row, smk.params.harmonics, smk.params.sensor_range_mm * 1e-3)
except DataError as err:  # check_data has passed the record: only a record changed since fails here
    log.error("%s", err)
    sys.exit(f"track_record: error: {err}")
bands = tracked.bands
log.info("%s: %d revolutions, %.1f-%.1f RPM, %d of %d bands usable", row["run"], len(tracked.speed),
         tracked.speed["rpm"].min(), tracked.speed["rpm"].max(), int(bands["usable"].sum()), len(bands))
for warning in tracked.warnings:
    log.warning("%s", warning)
    print(f"track_record: {row['run']}: warning: {warning}", file=sys.stderr)
for band in bands[~bands["usable"].astype(bool)].itertuples():
    print(f"track_record: band {band.run} of {row['run']} is kept out of the fit: {band.note}", file=sys.stderr)
write_harmonics(bands, smk.output.bands)
write_orders(tracked.orders, smk.output.orders)
write_tsv(tracked.runout, smk.output.runout)
write_tsv(tracked.speed, smk.output.speed)
