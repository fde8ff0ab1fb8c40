"""Rule report_cascade: the measured full spectra of every run as a cascade (thin wrapper;
hybridtwin.report.response_plots.plot_cascade). Reads only the rule's input and output."""

from pathlib import Path

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.data.preprocessing import read_tsv
from hybridtwin.identify import identification as idn
from hybridtwin.report import response_plots as rp
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_cascade")
table = idn.read_harmonics(smk.input.harmonics)
runs = pd.DataFrame({"run": table["run"], "rpm": table["rpm_true"].fillna(table["rpm"]),
                     "eccentric_mass_g": table["eccentric_mass_g"]})
spectra = {Path(path).parent.name: read_tsv(path) for path in smk.input.spectra}
log.info("cascade of %d runs' spectra", len(spectra))
figure = rp.plot_cascade(spectra, runs)
save_png(figure, smk.output.cascade, dpi=100)
rp.plt.close(figure)
