"""Rule whitebox_sweep: one variant's sensor response over the run plan (thin wrapper). Reads only the rule's input,
params and output."""

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.plots import plot_sweep
from hybridtwin.offline.scenarios import solve_operating_points
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "whitebox_sweep")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
points = cfg.run_plan(smk.input.points)
log.info("variant %s: %d runs, H = %d", variant.name, len(points), smk.params.harmonics)
table = solve_operating_points(variant, points, harmonics=smk.params.harmonics)
for row in table.itertuples():
    log.info("%s %g RPM %g g: %s (%s)", row.run, row.rpm, row.eccentric_mass_g, row.message, row.branch)
failed = table[~table["success"]]
if len(failed):
    log.warning("%d run(s) without a periodic solution: %s", len(failed), ", ".join(failed["run"]))
unstable = table[table["success"] & ~table["stable"]]
if len(unstable):
    log.warning("%d run(s) whose periodic solution is unstable: %s", len(unstable), ", ".join(unstable["run"]))
tables.WHITEBOX.write(table, smk.output.table)
save_png(plot_sweep(table, variant.name), smk.output.plot, dpi=120)
