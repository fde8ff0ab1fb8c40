"""Rule rig: generate a virtual-rig data set from a config rig entry on the config's machine (thin wrapper)."""

import logging
from pathlib import Path

from hybridtwin.machine import Machine
from hybridtwin.rig import RigSpec, generate, read_plan
from hybridtwin.variants import load_effects_file

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
logging.captureWarnings(True)  # non-unique steady states, records beyond the sensor range
log = logging.getLogger("rig")

effects = {}
for path in smk.params.effects_files:
    effects |= load_effects_file(path)
machine = Machine.from_mapping(smk.params.machine)  # the config's machine: section (None: the VARM)
spec = RigSpec.from_mapping(smk.params.spec, effects, machine)
log.info("truth on machine %s", machine.name)
plan = read_plan(smk.input.plan)
truth = generate(plan, spec, Path(smk.output.sheet).parent)
for row in truth.itertuples():
    log.info("%s: %.3f RPM, unique %s (run-up/run-down %.1e), peak %.3f / %.3f mm, inside range %s", row.run,
             row.rpm_true, row.unique, row.updown_difference_rel, 1e3 * row.peak_x_m, 1e3 * row.peak_y_m,
             row.inside_range)
