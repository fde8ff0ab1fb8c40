"""Rule diagnose: score tests of the candidate effects at the joint fit, refits of the best (thin wrapper). Reads only
the rule's input, params and output."""

from hybridtwin import config as cfg
from hybridtwin import tables
from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.diagnose import diagnosis_report as dgr
from hybridtwin.identify import identification as idn
from hybridtwin.diagnose import score_test as st
from hybridtwin.model.candidates import candidates_for
from hybridtwin.model.fixed_values import fixed_value_candidates
from hybridtwin.report import interactive
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "diagnose")
model = smk.params.model  # the variant's spec (and the sparse variant's), the machine, the effects files
variant = cfg.variant(model, smk.wildcards.variant)
options = smk.params.options
table = idn.read_parameters(smk.input.parameters)
harmonics = idn.read_harmonics(smk.input.harmonics)
runs = idn.fit_runs(table)  # the runs with a phase (a record's runout offsets are rows of its own)
keyphasor = smk.params.keyphasor  # as the identification used it (identification: keyphasor)
data = [idn.run_data(harmonics, run, keyphasor=keyphasor, channels=variant.channels) for run in runs]
base = st.BaseFit.from_table(variant, table, data, int(smk.params.harmonics))
candidates = candidates_for([e.name for e in variant.model.effects], cfg.candidate_names(options["candidates"], model),
                            cfg.candidate_effects(model))
candidates += fixed_value_candidates(variant)  # each fixed value freed: "zeta_s fixed at 0.0271 is wrong"
log.info("diagnosing %s on %d fit runs: %d candidates (%s)", variant.name, len(data), len(candidates),
         ", ".join(c.name for c in candidates))
result = dg.diagnose(base, candidates, options, log)
sparse, sparse_name = None, options["sparse_variant"]
if "sparse" in smk.input.keys():
    sparse = dgr.sparse_route(idn.read_parameters(smk.input.sparse),
                             cfg.variant(model, sparse_name))
    result.summary["sparse_route"] = {"variant": sparse_name,
                                      "active": sparse.loc[sparse["active"], "parameter"].tolist()}
dgr.write(result, smk.output.table, smk.output.recommendation, smk.output.summary, sparse, sparse_name)
tables.FINGERPRINT.write(result.fingerprint.table(), smk.output.fingerprint)
result.intervals.write(smk.output.intervals)
tables.DIAGNOSIS_REFITS.write(dg.refits_table(result), smk.output.refits)
save_png(dgr.plot(result), smk.output.plot, dpi=120)
interactive.write_html(interactive.diagnosis_figure(result), smk.output.plot_html)
log.info("%s", result.conclusion)
