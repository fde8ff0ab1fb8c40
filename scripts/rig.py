"""Rule rig: generate a virtual-rig data set from a config rig entry on the config's machine (thin wrapper)."""

import logging
from pathlib import Path

from hybridtwin.config import CONFIG_DIR, machine as config_machine
from hybridtwin.rig.rig import RigSpec, generate, peak_columns, read_plan
from hybridtwin.model.variants import load_effects_file
from hybridtwin.config import on_disk_full

smk = snakemake  # noqa: F821 (injected by Snakemake)
logging.basicConfig(filename=smk.log[0], level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
on_disk_full(logging.getLogger("rig"))  # a full disk: one message naming the file and what to free
logging.captureWarnings(True)  # non-unique steady states, records beyond the sensor range
log = logging.getLogger("rig")

effects = {}
for path in smk.params.effects_files:
    effects |= load_effects_file(path)
machine = config_machine({"machine": smk.params.machine}, CONFIG_DIR)  # the config's machine: (None: the VARM)
spec = RigSpec.from_mapping(smk.params.spec, effects, machine)
log.info("truth on machine %s", machine.name)
plan = read_plan(smk.input.plan)
truth = generate(plan, spec, Path(smk.output.sheet).parent)
peaks = peak_columns(truth)  # one per sensor
for _, row in truth.iterrows():
    log.info("%s: %.3f RPM, unique %s (run-up/run-down %.1e), peak %s mm, inside range %s", row["run"],
             row["rpm_true"], row["unique"], row["updown_difference_rel"],
             " / ".join(f"{1e3 * row[c]:.3f}" for c in peaks), row["inside_range"])
