"""Rule identify_joint: all fit runs at once, shared physical parameters, per-run ones (thin wrapper of
hybridtwin.identify.run_fits.fit_joint).

The library protocol finds the optimum (random trials + a start from the per-run fits), the full solver
polishes it when asked (identification: polish: joint), and the per-run fits are gathered into the drift
table and plot. Reads only the rule's input, params and output.
"""

from pathlib import Path

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.identify import identification as idn
from hybridtwin.offline.library import Library, read_library_validation
from hybridtwin.report import drift as dft
from hybridtwin.identify.run_fits import fit_joint, write_fit, write_fit_summary
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "identify_joint")
model = smk.params.model  # the variant's spec, the machine, the effects files, and the nested variants' specs
variant = cfg.variant(model, smk.wildcards.variant)
per_run = {path.split("/")[-2]: idn.read_parameters(path) for path in smk.input.per_run}
parent_refit = None
if "refits" in smk.input.keys():  # this variant adds one effect to another (params.parent: that one, the effect)
    parent, effect = smk.params.parent
    parent_refit = (parent, effect, idn.read_parameters(smk.input.refits))
nested = smk.input.get("nested", [])
nested = [(cfg.variant(model, Path(path).parent.name), idn.read_parameters(path))
          for path in ([nested] if isinstance(nested, str) else nested)]
validation = read_library_validation(smk.input.validation) if smk.input.validation else None  # none: no libraries
result = fit_joint(variant, smk.params.options, [Library.load(path) for path in smk.input.libraries],
                   idn.read_harmonics(smk.input.harmonics), per_run, validation, int(smk.params.harmonics),
                   parent_refit, nested, runs=smk.params.runs)
for message in result.messages:
    log.info("%s", message)
fit = result.fit
idn.write_parameters(result.library_fit.table(), smk.output.library_table)
joint = fit.table()
idn.write_parameters(joint, smk.output.table)
tables.POLISH.write(result.comparison, smk.output.polish)
tables.POLISH_STARTS.write(result.starts_table(), smk.output.polish_starts)
tables.PROFILE.write(result.profile_table(), smk.output.profile)
tables.CORRELATION.write(fit.correlation_table(), smk.output.correlation)
tables.HISTORY.write(fit.history_table(), smk.output.history)
runs = result.runs()
write_fit(smk.output.fit, fit, runs["rpm"].tolist())
drift = dft.drift_table([per_run[r] for r in per_run if r in set(runs["run"])], runs)
idn.write_parameters(drift, smk.output.per_run)
save_png(dft.plot_per_run(drift, joint, variant.name), smk.output.plot, dpi=120)
write_fit_summary(result.summary, smk.output.summary)
for warning in result.warnings:
    log.warning("%s", warning)
