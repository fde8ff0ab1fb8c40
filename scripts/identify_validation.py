"""Rule predict_validation: validation runs predicted with the joint parameters, never fitted (thin wrapper).

Only each run's phase (a nuisance) is aligned; per-run parameters come from their law over the fitted runs.
A run predicted beyond the noise is explained (hybridtwin.identify.validation_refit): the fit runs leave a
direction loose that this run pins, the per-run parameters' law fails there, or the model lacks something; the
refit with the run included goes to validation_refits.tsv. Writes the scores (validation.tsv), the predicted
harmonics (validation_harmonics.tsv, for the report) and those refits. Reads only the rule's input, params and output.
"""

from hybridtwin import config as cfg
from hybridtwin.identify import forward as fwd
from hybridtwin.identify import identification as idn
from hybridtwin.identify import validation as val
from hybridtwin.identify import validation_refit as vr
from hybridtwin.identify.run_fits import ranges
from hybridtwin.offline.library import Library, read_library_validation

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "predict_validation")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.options
joint = idn.read_parameters(smk.input.parameters)
table = idn.read_harmonics(smk.input.harmonics)
errors = idn.model_errors(read_library_validation(smk.input.validation) if smk.input.validation else None,
                          list(table["run"]), options["model_error"])
fitted_runs = table[["run", "rpm_true", "eccentric_mass_g"]].rename(columns={"rpm_true": "rpm"})
rows, predictions, explanations = [], [], []
names, lower, upper = ranges(variant)
libraries = [Library.load(path) for path in smk.input.libraries]
pairs = [(library, library.run) for library in libraries] or [(None, run) for run in smk.params.runs]  # none: solver
for library, run in pairs:
    data = idn.run_data(table, run, keyphasor=options["keyphasor"], channels=variant.channels)
    if not data.usable:
        rows.append({"run": data.run, "rpm": data.rpm, "eccentric_mass_g": data.eccentric_mass_g,
                     "model": "none", "note": data.note, "explanation": "not_checked"})
        continue
    values = val.validation_values(joint, data, options["validation_bow"], fitted_runs)
    models = [("library", fwd.SensorSurrogate(library), errors.get(data.run, 0.0))] if library else []
    if options["solver"] or library is None:  # the joint fit was polished with the full solver: predict with it too
        models.append(("solver", fwd.SolverModel.for_data(variant, data, names, lower, upper,
                                                          int(smk.params.harmonics)), 0.0))
    run_rows = []
    for name, model, error in models:
        row = val.predict_run(model, data, values, error)
        predictions.append(val.PredictedRun.from_prediction(row, name, data.channels))
        row.pop("fitted")
        outside = row["outside_range"]  # predicted at the range's edge: the values' law left the range there
        note = f"{outside} beyond its range: predicted at the range's edge" if outside else "ok"
        row.update({"model": name, **{f"{p}_used": v for p, v in values.items()}, "note": note,
                    "beyond_noise": vr.beyond_noise(row["chi2_per_residual"], 2 * data.X.size)})
        run_rows.append(row)
        log.info("%s (%s): relative error %.3g, chi^2 per residual %.3g", data.run, name, row["error_rel"],
                 row["chi2_per_residual"])
    last = run_rows[-1]  # the solver's prediction when there is one: the refit is on the solver
    if last["model"] == "solver":
        why = vr.explain_run(variant, joint, table, data, values, last["phase_rad"], last["chi2_per_residual"],
                             options, int(smk.params.harmonics), fitted_runs)
    else:
        why = vr.Explanation(data.run, "not_checked" if last["beyond_noise"] else "within_noise",
                             detail="the joint fit was not polished with the full solver (identification: polish)")
    explanations.append(why)
    if why.code != "within_noise":
        log.info("%s: %s", data.run, why.sentence)
    for row in run_rows:
        row.update({"explanation": why.code, "explanation_note": why.sentence,
                    "pinned": ",".join(m[0] for m in why.pinned), "refit_chi2_per_residual": why.chi2_refit,
                    "fit_runs_chi2_rise": why.fit_rise, "allowed_chi2_rise": why.allowed})
        rows.append(row)
vr.write_validation(rows, smk.output.table)  # every column, also when no validation run could be predicted
val.write_predictions(smk.output.harmonics, predictions)  # the report reads them instead of predicting again
idn.write_parameters(vr.refits_table(explanations), smk.output.refits)
