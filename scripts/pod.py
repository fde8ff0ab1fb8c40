"""Rule pod: per run, the POD of the observable training snapshots (thin wrapper). Reads only the rule's input,
params and output."""

import sys

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.data import measured
from hybridtwin.offline.pod import ThinLibraryError, pod_of_runs

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "pod")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.offline
kept_out = measured.kept_out(measured.read_harmonics(smk.input.harmonics))["run"].tolist()
try:
    table = pod_of_runs(smk.input.snapshots, smk.output.store, variant.model.shaft, options["sensor_range_mm"] * 1e-3,
                        options["pod_energy_tolerance"], kept_out)
except ThinLibraryError as err:
    log.error("%s", err)
    sys.exit(f"pod: error: variant {variant.name}: too few usable scenarios for a library at "
             f"{len(err.lines) - 1} run(s):\n  " + "\n  ".join(err.lines))
tables.POD.write(table, smk.output.table)
for row in table.itertuples():
    log.info("run %s: %d snapshots, m_d = %d, sigma_2/sigma_1 = %.3g", row.run, row.n_snapshots, row.n_modes,
             row.sigma2_over_sigma1)
    if row.n_unstable:
        log.warning("run %s: %d scenarios with an unstable steady state left out", row.run, row.n_unstable)
print(f"pod: {int(table['n_unstable'].sum())} unstable (run, scenario) steady states left out of the POD "
      f"({', '.join(f'{r.run}: {r.n_unstable}' for r in table.itertuples() if r.n_unstable) or 'none'})")
