"""Rule design_runs: the next runs to take from a variant's joint fit (thin wrapper of hybridtwin.identify.design).

Reads only the rule's input, params and output.
"""

from hybridtwin import config as cfg
from hybridtwin.identify import design
from hybridtwin.identify import identification as idn
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "design_runs")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
table = idn.read_harmonics(smk.input.harmonics)
runs = table[["run", "rpm_true", "eccentric_mass_g"]].rename(columns={"rpm_true": "rpm"})  # the bow's law
rpm, masses = smk.params.grid
result = design.design_runs(variant, idn.read_parameters(smk.input.parameters), table, runs, smk.params.options,
                            int(smk.params.harmonics), rpm, masses, int(smk.params.runs),
                            float(smk.params.sensor_range_mm) * 1e-3, keyphasor=smk.params.keyphasor)
log.info("parameters of interest: %s", ", ".join(result.interest))
for row in result.chosen.itertuples():
    log.info("run %d: %g RPM, %g g, keyphasor %s: log det +%.3g", row.step, row.rpm, row.eccentric_mass_g,
             row.keyphasor, row.gain)
for row in result.intervals.itertuples():
    log.info("%s: 95 %% half-width %.4g -> %.4g %s expected (x%.3g)", row.parameter, row.linear_half_width,
             row.expected_half_width, row.unit, row.shrink)
for note in result.notes:
    log.warning("%s", note)
design.write_design(result, smk.output.chosen, smk.output.intervals, smk.output.candidates)
save_png(design.plot_design(result, variant.name), smk.output.plot, dpi=110)
