"""Rule whitebox_sweep: one variant's sensor response over the run plan (thin wrapper)."""

import logging
from pathlib import Path

import pandas as pd

from hybridtwin.plots import plot_sweep
from hybridtwin.scenarios import solve_operating_points
from hybridtwin.variants import Variant, load_effects_file

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
log = logging.getLogger("whitebox_sweep")

user_effects = {}
for path in smk.params.effects_files:
    user_effects |= load_effects_file(Path("config") / path)
variant = Variant.from_spec(smk.wildcards.variant, smk.params.spec, user_effects)
points = pd.read_csv(smk.input.points, sep="\t", dtype={"run": str})
log.info("variant %s: %d operating points, H = %d", variant.name, len(points), smk.params.harmonics)
table = solve_operating_points(variant, points, harmonics=smk.params.harmonics)
for row in table.itertuples():
    log.info("%s %g RPM %g g: %s (%s)", row.run, row.rpm, row.eccentric_mass_g, row.message, row.branch)
failed = table[~table["success"]]
if len(failed):
    log.warning("%d point(s) without a periodic solution: %s", len(failed), ", ".join(failed["run"]))
table.to_csv(smk.output.table, sep="\t", index=False, float_format="%.9e")
plot_sweep(table, variant.name).savefig(smk.output.plot, dpi=120)
