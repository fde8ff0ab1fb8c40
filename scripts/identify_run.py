"""Rule identify_run: every fit run of a variant alone on its library by the paper's protocol, in one job
(thin wrapper of hybridtwin.identify.run_fits).

Outputs per run: parameters.tsv (value, normalised, stderr, 95 % interval, at_bound, ...), history.tsv (loss of
every trial after each iteration, on the measured data), fit.zarr (measured and fitted response). Reads only the
rule's input, params and output.
"""

from hybridtwin import config as cfg
from hybridtwin.identify import identification as idn
from hybridtwin.offline.library import Library, read_library_validation
from hybridtwin.identify.run_fits import fit_run, write_run_fit

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "identify_run")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)  # its spec, the machine, the effects files
options = smk.params.options
harmonics = idn.read_harmonics(smk.input.harmonics)
validation = read_library_validation(smk.input.validation) if smk.input.validation else None
libraries = list(smk.input.libraries) or [None] * len(smk.params.runs)  # none (offline.scope: none): the solver
outputs = zip(smk.params.runs, libraries, smk.output.parameters, smk.output.history, smk.output.fit)
for run, library, parameters, history, fit in outputs:
    data = idn.run_data(harmonics, run, keyphasor=options["keyphasor"], channels=variant.channels)
    result = fit_run(variant, options, library and Library.load(library), data, validation,
                     int(smk.params.harmonics))
    write_run_fit(result, parameters, history, fit)
    for message in result.messages:
        log.info("%s", message)
    for warning in result.warnings:
        log.warning("%s", warning)
