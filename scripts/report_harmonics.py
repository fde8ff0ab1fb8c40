"""Rule report_harmonics: measured and model harmonics of every fit and validation run, model frame (thin wrapper).

Fit runs come from the joint fit's store; validation runs from the harmonics predict_validation wrote
(validation_harmonics.tsv: same model, same parameter values, only the phase aligned), never predicted again.
Reads only the rule's input, params and output.
"""

from hybridtwin import config as cfg
from hybridtwin.identify import identification as idn
from hybridtwin.report import report
from hybridtwin.identify import validation as val
from hybridtwin.identify import validation_refit as vr
from hybridtwin.offline.library import read_library_validation
from hybridtwin.identify.run_fits import read_fit_summary

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_harmonics")
options = smk.params.options
table = idn.read_harmonics(smk.input.harmonics)
joint = idn.read_parameters(smk.input.parameters)
summary = read_fit_summary(smk.input.summary)["final"]
comparisons = report.fit_comparisons(smk.input.fit, joint, summary, table)
validation = vr.read_validation(smk.input.validation)
for row in validation[validation["model"] == "none"].to_dict("records"):
    log.warning("validation run %s has no prediction: %s", row["run"], row["note"])
predictions = val.read_predictions(smk.input.predictions)
source = "solver" if any(p.model == "solver" for p in predictions) else "library"
library_errors = read_library_validation(smk.input.library_validation) if smk.input.library_validation else None
errors = idn.model_errors(library_errors, list(table["run"]), options["model_error"])  # None: no libraries
scores = validation.set_index(["run", "model"])["error_rel"]
for prediction in predictions:
    if prediction.model != source:
        continue
    data = idn.run_data(table, prediction.run, keyphasor=options["keyphasor"], channels=prediction.channels)
    error = errors.get(data.run, 0.0) if source == "library" else 0.0
    comparison = report.validation_comparison(prediction, data, error)
    comparisons.append(comparison)
    log.info("%s (%s): chi^2/dof %.4g, relative error %.3g (validation.tsv: %.3g)", data.run, source,
             comparison.chi2_dof, comparison.error_rel, scores.get((prediction.run, source), float("nan")))
report.write_comparisons(comparisons, smk.output.table)
log.info("%d runs compared (%s model)", len(comparisons), source)
