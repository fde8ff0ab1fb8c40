"""Rule identify_run: one run's parameters from its library by the paper's protocol (thin wrapper).

Outputs: parameters.tsv (value, normalised, stderr, 95 % interval, at_bound, ...), history.tsv (loss of
every trial after each iteration, on the measured data), fit.zarr (measured and fitted response).
"""

import time

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin import forward as fwd
from hybridtwin import identification as idn
from hybridtwin import polish as pol
from hybridtwin.library import Library

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "identify_run")
variant = cfg.variant(smk.config, smk.wildcards.variant)
options = idn.settings(smk.config, variant.name)
run = smk.wildcards.run
data = idn.run_data(idn.read_harmonics(smk.input.harmonics), run, keyphasor=options["keyphasor"])
library = Library.load(smk.input.library)
units = idn.units(variant)
if not data.usable:
    log.warning("run %s is not usable (%s): not fitted", run, data.note)
    idn.excluded_table(data, library.parameters, units).to_csv(smk.output.parameters, sep="\t", index=False)
    pd.DataFrame(columns=["trial", "iteration", "loss", "selected"]).to_csv(smk.output.history, sep="\t",
                                                                            index=False)
    import zarr

    zarr.open_group(smk.output.fit, mode="w").attrs.update({"runs": [run], "note": data.note})
else:
    errors = idn.model_errors(pd.read_csv(smk.input.validation, sep="\t"), [run], options["model_error"])
    start = time.perf_counter()
    fit = idn.identify([fwd.SensorSurrogate(library)], [data], (), idn.protocol_options(options), errors,
                       units=units)
    log.info("run %s: %d trials x (1 + %d Monte Carlo repeats) = %d LM problems in %.2f s; best loss %.4g "
             "(chi^2/dof %.3g, %s); %d of %d trials reached it", run, len(fit.protocol.trials.loss),
             len(fit.protocol.monte_carlo), fit.protocol.n_lm, time.perf_counter() - start, fit.loss,
             fit.chi2_dof, fit.message, fit.summary()["trials_at_best"], len(fit.protocol.trials.loss))
    if options["polish"]["runs"]:
        solver = [fwd.SolverModel(variant, run, data.rpm, data.eccentric_mass_g, library.parameters, library.lower,
                                  library.upper, smk.config["harmonics"])]
        exact = pol.polish(fit, solver, int(options["polish"]["max_iterations"]))
        for row in pol.compare_polish(fit, exact).itertuples():
            log.info("polish %s: library %.6g, solver %.6g (%.2g stderr)", row.parameter, row.library_value,
                     row.solver_value, row.difference_in_stderr)
        fit = exact
    table = fit.table()
    table["note"] = "; ".join(fit.uncertainty.notes) or "ok"
    table.to_csv(smk.output.parameters, sep="\t", index=False, float_format="%.9g")
    fit.history_table().to_csv(smk.output.history, sep="\t", index=False, float_format="%.9g")
    idn.write_fit(smk.output.fit, fit, [data.rpm])
    for note in fit.uncertainty.notes:
        log.warning("run %s: %s", run, note)
