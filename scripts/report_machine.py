"""Rule report_machine: the Campbell diagram (run speeds marked) and the mode shapes of a variant's fitted model on
the config's machine (thin wrapper; hybridtwin.report.machine_plots). Reads only the rule's input, params and output.

The model's values: the joint fit's estimates, each per-run parameter's median over the runs, the eccentric mass
the runs' median; the mode shapes at the runs' median speed.
"""

import numpy as np
import pandas as pd

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.identify import identification as idn
from hybridtwin.report import interactive, interactive_machine
from hybridtwin.report import machine_plots as mp
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_machine")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
runs = pd.DataFrame(smk.params.runs)
mass_g = float(runs["eccentric_mass_g"].median())
values = variant.values(mp.fitted_values(idn.read_parameters(smk.input.parameters)) | {"m_e": 1e-3 * mass_g})
values = {name: float(value) for name, value in values.items()}
machine = getattr(variant.model.shaft, "name", "shaft")
speeds = mp.report_speeds(runs["rpm"])
title = f"Campbell diagram, {smk.wildcards.variant} on {machine} (eccentric mass {mass_g:g} g)"
figure = mp.campbell_figure(variant.model, values, speeds, run_rpm=runs["rpm"], n_modes=6, title=title)
tables.CAMPBELL.write(figure.campbell, smk.output.table)
save_png(figure, smk.output.campbell, dpi=100)
interactive.write_html(interactive_machine.campbell_figure(variant.model, values, speeds, run_rpm=runs["rpm"],
                                                           n_modes=6, title=title, table=figure.campbell),
                       smk.output.campbell_html)
for row in figure.critical.itertuples():
    log.info("critical speed (1X crossing): %.1f RPM, %s whirl, branch %d", row.rpm, row.whirl, row.branch)
mp.plt.close(figure)
rpm = float(np.median(runs["rpm"]))
title = f"Undamped mode shapes at {rpm:g} RPM (the runs' median speed), {smk.wildcards.variant} on {machine}"
figure = mp.mode_shape_figure(variant.model, values, rpm, n_modes=4, title=title)
save_png(figure, smk.output.modes, dpi=100)
interactive.write_html(interactive_machine.mode_shapes_figure(variant.model, values, rpm, n_modes=4, title=title),
                       smk.output.modes_html)
for row in figure.modes.itertuples():
    log.info("mode %d at %g RPM: %.4g Hz, %s", row.mode + 1, rpm, row.frequency_hz,
             "x and y planes alike" if row.pair else f"{row.whirl} whirl")
mp.plt.close(figure)
