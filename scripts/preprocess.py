"""Rule preprocess: one run's harmonics table and two-cycle waveforms (thin wrapper)."""

import logging

from hybridtwin.preprocessing import preprocess_run, write_tsv

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
logging.captureWarnings(True)
log = logging.getLogger("preprocess")

table, waves = preprocess_run(smk.params.row, smk.params.harmonics)
row = table.iloc[0]
log.info("%s: %.3f RPM (nominal %g), %d revolutions, noise %.4f / %.4f mm, phase %s: %s", row["run"],
         row["rpm_true"], row["rpm"], row["n_revolutions"], 1e3 * row["noise_x_m"], 1e3 * row["noise_y_m"],
         row["phase_reference"], row["note"])
write_tsv(table, smk.output.harmonics)
write_tsv(waves, smk.output.waveforms)
