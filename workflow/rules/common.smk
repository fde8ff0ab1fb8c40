# Shared helpers: config validation, the runs sheet, the variants, the offline options.
import pandas as pd
from snakemake.utils import validate

from hybridtwin.config import offline, run_plan


validate(config, "../schemas/config.schema.yaml")

VARIANTS = list(config["variants"])
OFFLINE = offline(config)
CHUNKS = [f"{i:03d}" for i in range(OFFLINE["chunks"])]
RUNS = list(run_plan(config)["run"])
# the speeds the libraries are built at: refined from the records, or the sheet's nominal ones
SPEEDS = "results/data/harmonics.tsv" if OFFLINE["speed"] == "measured" else config["runs"]


wildcard_constraints:
    variant="|".join(VARIANTS),
    chunk=r"\d{3}",
    run="|".join(RUNS),
