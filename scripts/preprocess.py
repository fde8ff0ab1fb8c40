"""Rule preprocess: one run's harmonics table, two-cycle waveforms and full spectrum (thin wrapper).

A flagged run (usable False: flat, clipped, noise only, backward whirl, spikes) is written with its note and
said on the console; identify_run / identify_joint / identify_validation then leave it out.
"""

import logging
import sys

import math

from hybridtwin.config import whirl_model
from hybridtwin.model.whirl import read_whirl
from hybridtwin.data.measurements import DataError
from hybridtwin.data.records import read_record
from hybridtwin.data.measured import write_harmonics
from hybridtwin.data.preprocessing import preprocess_run, spectrum, write_tsv
from hybridtwin.config import on_disk_full

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
on_disk_full(logging.getLogger("preprocess"))  # a full disk: one message naming the file and what to free
logging.captureWarnings(True)
log = logging.getLogger("preprocess")

try:
    # once, for the harmonics and the spectrum; one channel per sensor of the config's machine (params.sensors, its
    # config form; absent: the VARM's x, y)
    record = read_record(smk.params.row["record"], getattr(smk.params, "sensors", None),
                         smk.params.row.get("channels"))
    # the machine's model of the 1X whirl as check_data asked it (results/data/whirl.tsv: computed once), the model
    # itself only at a speed the check did not ask at; none without one (the VARM's model-free rule)
    settings = getattr(smk.params, "whirl", None) or {}
    whirl = read_whirl(smk.input.whirl, lambda: whirl_model(settings)) if settings else None
    table, waves = preprocess_run(smk.params.row, smk.params.harmonics, smk.params.sensor_range_mm * 1e-3,
                                  record=record, whirl=whirl)
except DataError as err:  # check_data has passed the record: only a record changed since fails here
    log.error("%s", err)
    sys.exit(f"preprocess: error: {err}")
row = table.iloc[0]
log.info("%s: %.3f RPM (nominal %g), %d revolutions, noise %s mm, phase %s: %s", row["run"],
         row["rpm_true"], row["rpm"], row["n_revolutions"],
         " / ".join(f"{1e3 * row[f'noise_{c}_m']:.4f}" for c in record.names), row["phase_reference"], row["note"])
if not row["usable"]:
    print(f"preprocess: run {row['run']} is kept out of the fit: {row['note']}", file=sys.stderr)
write_harmonics(table, smk.output.harmonics)
write_tsv(waves, smk.output.waveforms)
rpm = row["rpm_true"] if math.isfinite(row["rpm_true"]) else float(row["rpm"])
write_tsv(spectrum(record, rpm), smk.output.spectrum)
