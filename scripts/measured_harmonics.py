"""Rule measured_harmonics: concatenate the per-run preprocessing tables (thin wrapper)."""

import logging
import sys

import pandas as pd

from hybridtwin.data.measured import read_harmonics, write_harmonics
from hybridtwin.config import on_disk_full

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
on_disk_full(logging.getLogger("measured_harmonics"))  # a full disk: one message naming the file and what to free
table = pd.concat([read_harmonics(path) for path in smk.input.runs], ignore_index=True)
usable = table["usable"]
logging.getLogger("measured_harmonics").info("%d runs, %d usable", len(table), int(usable.sum()))
for row in table[~usable].itertuples():
    print(f"measured_harmonics: run {row.run} is kept out of the fit: {row.note}", file=sys.stderr)
write_harmonics(table, smk.output.table)
