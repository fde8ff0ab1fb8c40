"""Rule measured_harmonics: concatenate the per-run preprocessing tables (thin wrapper)."""

import logging

import pandas as pd

from hybridtwin.preprocessing import write_tsv

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
table = pd.concat([pd.read_csv(path, sep="\t", dtype={"run": str}) for path in smk.input.runs], ignore_index=True)
logging.getLogger("measured_harmonics").info("%d runs, %d usable", len(table), int(table["usable"].sum()))
write_tsv(table, smk.output.table)
