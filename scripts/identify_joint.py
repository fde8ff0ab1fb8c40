"""Rule identify_joint: all fit runs at once, shared physical parameters, per-run ones (thin wrapper).

The library protocol finds the optimum (random trials + a start from the per-run fits), the full solver
polishes it when asked (identification: polish: joint), and the per-run fits are gathered into the drift
table and plot.
"""

import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from hybridtwin import config as cfg
from hybridtwin import forward as fwd
from hybridtwin import identification as idn
from hybridtwin import polish as pol
from hybridtwin import validation as val
from hybridtwin import variants
from hybridtwin.library import Library
from hybridtwin.run_fits import start_from_runs

smk = snakemake  # noqa: F821 (injected by Snakemake)
NESTED_MISMATCH = 1e-6  # a simpler variant's fit is a start when this variant reproduces it (round-off: ~1e-16)
log = cfg.rule_logger(smk.log[0], "identify_joint")
variant = cfg.variant(smk.config, smk.wildcards.variant)
options = idn.settings(smk.config, variant.name)
units = idn.units(variant)
table = idn.read_harmonics(smk.input.harmonics)
per_run = {path.split("/")[-2]: idn.read_parameters(path) for path in smk.input.per_run}
data, models = [], []
for path in smk.input.libraries:
    library = Library.load(path)
    run = idn.run_data(table, library.run, keyphasor=options["keyphasor"])
    if not run.usable:
        log.warning("run %s left out of the joint fit: %s", run.run, run.note)
        continue
    data.append(run)
    models.append(fwd.SensorSurrogate(library))
if not data:
    raise ValueError("no usable fit run for the joint identification")
errors = idn.model_errors(pd.read_csv(smk.input.validation, sep="\t"), [d.run for d in data], options["model_error"])
parameters = models[0].parameters
layout = idn.Layout.for_data(parameters, models[0].lower, models[0].upper, data, options["per_run"])
start_theta = start_from_runs(layout, {d.run: idn.Identification.from_table(per_run[d.run]) for d in data
                                       if d.run in per_run})
start = time.perf_counter()
fit = idn.identify(models, data, options["per_run"], idn.protocol_options(options, joint=True), errors,
                   extra_starts=start_theta, units=units)
log.info("joint fit of %d runs (%d unknowns): %d LM problems in %.1f s, loss %.4g, chi^2/dof %.3g (%s)",
         len(data), layout.n, fit.protocol.n_lm, time.perf_counter() - start, fit.loss, fit.chi2_dof, fit.message)
library_table = fit.table()
idn.write_parameters(library_table, smk.output.library_table)
summary = {"library": fit.summary()}
comparison = pd.DataFrame(columns=["parameter", "run", "unit", "library_value", "solver_value", "difference",
                                   "difference_rel", "difference_in_stderr", "stderr"])
if options["polish"]["joint"]:
    solver = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, parameters, models[0].lower,
                              models[0].upper, smk.config["harmonics"]) for d in data]
    start = time.perf_counter()
    starts = pol.next_best_trials(fit)
    labels = ["library optimum"] + [f"library trial {i + 2}" for i in range(len(starts))]
    if "refits" in smk.input.keys():  # this variant adds one effect to another: its diagnosis refit is a start
        parent, extra = variants.parent_variant(smk.config["variants"], variant.name)
        refits = idn.read_parameters(smk.input.refits)
        refit = idn.theta_from_table(refits[refits["effect"] == extra], layout)
        log.info("polish also starts from %s's diagnosis refit with %s: %s", parent, extra,
                 "found" if refit is not None else "not there (not refitted)")
        if refit is not None:
            starts = np.vstack([starts, refit[None]])
            labels.append(f"{parent}'s diagnosis refit with {extra}")
    nested = smk.input.get("nested", [])
    own = fit.table()  # entries a nested fit does not give
    for path in [nested] if isinstance(nested, str) else nested:  # the simpler variants this one contains
        parent = Path(path).parent.name
        theta, mismatch = idn.theta_from_nested(idn.read_parameters(path),
                                               cfg.variant(smk.config, parent), variant, layout, own)
        usable = theta is not None and mismatch < NESTED_MISMATCH
        log.info("%s's joint fit mapped onto %s's parameters: coefficient mismatch %.2g, %s", parent, variant.name,
                 mismatch, "a polish start" if usable else "not nested exactly, not used" if theta is not None
                 else "an entry is missing, not used")
        if usable:
            starts = np.vstack([starts, theta[None]])
            labels.append(f"{parent}'s joint fit")
    exact = pol.polish(fit, solver, int(options["polish"]["max_iterations"]), starts, labels, seed=int(options["seed"]))
    if np.isfinite(exact.loss):
        comparison = pol.compare_polish(fit, exact)
        exact.protocol.monte_carlo = fit.protocol.monte_carlo  # the library's Monte Carlo spread, for reference
        summary["solver"] = exact.summary() | {"seconds": time.perf_counter() - start,
                                               "solves": int(sum(m.n_solves for m in solver)),
                                               "starts": exact.starts["start"].tolist(),
                                               "best_start": exact.starts["start"][exact.protocol.best]}
        for row in exact.starts.itertuples():
            log.info("polish start %-40s solver chi^2 %.6g -> %.6g (chi^2/dof %.4g, %d iterations)%s", row.start,
                     row.chi2_start, row.chi2, row.chi2_dof, row.iterations, " <- selected" if row.selected else "")
        log.info("polished with the full solver in %.1f s from %d starts, the best from %s: loss %.4g -> %.4g, "
                 "chi^2/dof %.3g (%s)", time.perf_counter() - start, len(exact.starts),
                 exact.starts["start"][exact.protocol.best],
                 fit.loss, exact.loss, exact.chi2_dof, exact.message)
        fit = exact
    else:
        note = ("the full solver has no periodic solution at the library's best trials (a fold or an unstable "
                "region next to them): the library's estimate is kept, with the library's error in its weights")
        fit.uncertainty.notes.append(note)
        summary["solver"] = {"failed": note, "seconds": time.perf_counter() - start}
        log.warning("polish failed: %s", note)
result = fit.table()
idn.write_parameters(result, smk.output.table)
comparison.to_csv(smk.output.polish, sep="\t", index=False, float_format="%.9g")
starts_table = fit.starts if fit.starts is not None else pd.DataFrame(
    columns=["start", "chi2_start", "chi2", "chi2_dof", "iterations", "status", "selected"])
starts_table.to_csv(smk.output.polish_starts, sep="\t", index=False, float_format="%.9g")
fit.correlation_table().to_csv(smk.output.correlation, sep="\t", float_format="%.6g")
fit.history_table().to_csv(smk.output.history, sep="\t", index=False, float_format="%.9g")
idn.write_fit(smk.output.fit, fit, [d.rpm for d in data])
runs = pd.DataFrame({"run": [d.run for d in data], "rpm": [d.rpm for d in data],
                     "eccentric_mass_g": [d.eccentric_mass_g for d in data]})
drift = val.drift_table([per_run[r] for r in per_run if r in set(runs["run"])], runs)
drift.to_csv(smk.output.per_run, sep="\t", index=False, float_format="%.9g")
val.plot_per_run(drift, result, variant.name).savefig(smk.output.plot, dpi=120)
summary["final"] = fit.summary()
with open(smk.output.summary, "w") as stream:
    yaml.safe_dump(summary, stream, sort_keys=False)
for note in fit.uncertainty.notes:
    log.warning("%s", note)
