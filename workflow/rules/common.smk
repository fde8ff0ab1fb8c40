# Shared helpers: config validation, the operating points, the variants.
import pandas as pd
from snakemake.utils import validate


validate(config, "../schemas/config.schema.yaml")

VARIANTS = list(config["variants"])

operating_points = pd.read_csv(config["operating_points"], sep="\t", dtype={"run": str})
validate(operating_points, "../schemas/operating_points.schema.yaml")


wildcard_constraints:
    variant="|".join(VARIANTS),
