"""Rule report_response: Bode and polar plots with the fitted model as dense curves by continuation (run-up and
run-down per eccentric mass) and the measured runs on top (thin wrapper; hybridtwin.report.response_plots). Reads only
the rule's input, params and output.

The model's values: the joint fit's shared estimates, each per-run parameter (the bow) from its law over the
fitted runs (identification.validation_bow), as for the validation runs.
"""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.identify import identification as idn
from hybridtwin.report import interactive, report
from hybridtwin.report import response_plots as rp
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_response")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
runs = pd.DataFrame(smk.params.runs)
comparisons = report.load_comparisons(smk.input.table)
joint = idn.read_parameters(smk.input.parameters)
criticals = rp.critical_speeds(variant, joint, rp.dense_speeds(runs["rpm"]),
                               float(runs["eccentric_mass_g"].median()))
speeds = rp.refined_speeds(rp.dense_speeds(runs["rpm"]), criticals)  # denser through each resonance
log.info("critical speeds of the fitted model in the range (RPM, damping ratio): %s",
         ", ".join(f"{rpm:.0f} ({zeta:.3g})" for rpm, zeta in criticals) or "none")
log.info("%s: run-up and run-down over %d speeds %.0f-%.0f RPM for trial masses %s", variant.name,
         len(speeds), speeds[0], speeds[-1], ", ".join(rp.trial_label(*t) for t in rp.trials_of(runs)))
dense = rp.dense_response(variant, joint, runs, speeds, int(smk.params.harmonics),
                          smk.params.options["validation_bow"])
rp.write_dense(dense, smk.output.response)
failed = dense[dense["harmonic"] == 1][f"{rp.channels_of(dense)[0]}_re_m"].isna()
if failed.any():
    log.warning("%d of %d sweep points without a steady state (left as gaps)", int(failed.sum()), len(failed))
for row in rp.multivalued(dense).dropna().itertuples():
    log.info("%s: run-up and run-down differ between %.0f and %.0f RPM (multi-valued response)",
             rp.trial_label(row.eccentric_mass_g, row.eccentric_mass_angle_deg), row.rpm_from, row.rpm_to)
for name, plot, live in (("bode", rp.plot_bode, interactive.bode_figure),
                         ("polar", rp.plot_polar, interactive.polar_figure)):
    figure = plot(dense, comparisons, variant.name)
    save_png(figure, smk.output[name], dpi=100)
    rp.plt.close(figure)
    interactive.write_html(live(dense, comparisons, variant.name), smk.output[f"{name}_html"])  # beside the PNG
