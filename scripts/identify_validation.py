"""Rule predict_validation: validation runs predicted with the joint parameters, never fitted (thin wrapper).

Only each run's phase (a nuisance) is aligned; per-run parameters come from their law over the fitted runs.
Writes the scores (validation.tsv) and the predicted harmonics (validation_harmonics.tsv, for the report).
Reads only the rule's input, params and output.
"""

import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.identify import forward as fwd
from hybridtwin.identify import identification as idn
from hybridtwin.identify import validation as val
from hybridtwin.identify.run_fits import ranges
from hybridtwin.offline.library import Library

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "predict_validation")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.options
joint = idn.read_parameters(smk.input.parameters)
table = idn.read_harmonics(smk.input.harmonics)
errors = idn.model_errors(pd.read_csv(smk.input.validation, sep="\t") if smk.input.validation else None,
                          list(table["run"]), options["model_error"])
fitted_runs = table[["run", "rpm_true", "eccentric_mass_g"]].rename(columns={"rpm_true": "rpm"})
rows, predictions = [], []
names, lower, upper = ranges(variant)
libraries = [Library.load(path) for path in smk.input.libraries]
pairs = [(library, library.run) for library in libraries] or [(None, run) for run in smk.params.runs]  # none: solver
for library, run in pairs:
    data = idn.run_data(table, run, keyphasor=options["keyphasor"], channels=variant.channels)
    if not data.usable:
        rows.append({"run": data.run, "rpm": data.rpm, "eccentric_mass_g": data.eccentric_mass_g,
                     "model": "none", "note": data.note})
        continue
    values = val.validation_values(joint, data, options["validation_bow"], fitted_runs)
    models = [("library", fwd.SensorSurrogate(library), errors.get(data.run, 0.0))] if library else []
    if options["solver"] or library is None:  # the joint fit was polished with the full solver: predict with it too
        models.append(("solver", fwd.SolverModel.for_data(variant, data, names, lower, upper,
                                                          int(smk.params.harmonics)), 0.0))
    for name, model, error in models:
        row = val.predict_run(model, data, values, error)
        predictions.append(val.PredictedRun.from_prediction(row, name, data.channels))
        row.pop("fitted")
        outside = row["outside_range"]  # predicted at the range's edge: the values' law left the range there
        note = f"{outside} beyond its range: predicted at the range's edge" if outside else "ok"
        row.update({"model": name, **{f"{p}_used": v for p, v in values.items()}, "note": note})
        rows.append(row)
        log.info("%s (%s): relative error %.3g, chi^2 per residual %.3g", data.run, name, row["error_rel"],
                 row["chi2_per_residual"])
columns = ["run", "rpm", "eccentric_mass_g", "model", "error_rel", "chi2_per_residual", "note"]
table = pd.DataFrame(rows)  # every column, also when no validation run could be predicted (all flagged)
table.reindex(columns=list(dict.fromkeys([*table.columns, *columns]))).to_csv(
    smk.output.table, sep="\t", index=False, float_format="%.9g")
val.write_predictions(smk.output.harmonics, predictions)  # the report reads them instead of predicting again
