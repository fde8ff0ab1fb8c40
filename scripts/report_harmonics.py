"""Rule report_harmonics: measured and model harmonics of every fit and validation run, model frame (thin wrapper).

Fit runs come from the joint fit's store; validation runs are predicted again exactly as predict_validation did
(same model, same parameter values, only the phase aligned), since validation.tsv keeps only their scores.
Reads only the rule's input, params and output.
"""

from pathlib import Path

import pandas as pd
import yaml

from hybridtwin import config as cfg
from hybridtwin import forward as fwd
from hybridtwin import identification as idn
from hybridtwin import report
from hybridtwin.library import Library

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_harmonics")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.options
table = idn.read_harmonics(smk.input.harmonics)
joint = idn.read_parameters(smk.input.parameters)
with open(smk.input.summary) as stream:
    summary = yaml.safe_load(stream)["final"]
comparisons = report.fit_comparisons(smk.input.fit, joint, summary, table)
validation = pd.read_csv(smk.input.validation, sep="\t", dtype={"run": str})
errors = idn.model_errors(pd.read_csv(smk.input.library_validation, sep="\t"), list(table["run"]),
                          options["model_error"])
source = "solver" if (validation["model"] == "solver").any() else "library"
libraries = {Path(path).stem: path for path in smk.input.libraries}
for row in validation.to_dict("records"):
    if row["model"] == "none":
        log.warning("validation run %s has no prediction: %s", row["run"], row["note"])
        continue
    if row["model"] != source:
        continue
    library = Library.load(libraries[row["run"]])
    data = idn.run_data(table, row["run"], keyphasor=options["keyphasor"])
    if source == "solver":
        model = fwd.SolverModel(variant, data.run, data.rpm, data.eccentric_mass_g, library.parameters,
                                library.lower, library.upper, int(smk.params.harmonics))
    else:
        model = fwd.SensorSurrogate(library)
    error = errors.get(data.run, 0.0) if source == "library" else 0.0
    comparison = report.validation_comparison(model, data, report.used_values(row, library.parameters), error, source)
    comparisons.append(comparison)
    log.info("%s (%s): chi^2/dof %.4g, relative error %.3g (validation.tsv: %.3g)", data.run, source,
             comparison.chi2_dof, comparison.error_rel, row["error_rel"])
report.comparison_table(comparisons).to_csv(smk.output.table, sep="\t", index=False, float_format="%.9g")
log.info("%d runs compared (%s model)", len(comparisons), source)
