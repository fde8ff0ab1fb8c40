"""Rule twin_card: the twin's card, twin.yaml (thin wrapper of hybridtwin.online.twin.make_card). Reads only the rule's
input, params and output."""

from hybridtwin import config as cfg
from hybridtwin.identify import identification as idn
from hybridtwin.online.twin import make_card, write_card
from hybridtwin.identify.run_fits import read_summary

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "twin_card")
table = idn.read_parameters(smk.input.parameters)
runs = idn.fit_runs(table)
measured = idn.read_harmonics(smk.input.harmonics).set_index("run").loc[runs].reset_index()
measured["rpm"] = measured["rpm_true"].fillna(measured["rpm"])
fit = read_summary(smk.input.summary)["final"]
card = make_card(smk.wildcards.variant, smk.params.model, smk.params.harmonics, smk.params.keyphasor,
                 cfg.candidate_names(smk.params.candidates, smk.params.model), smk.params.sensor_range_mm,
                 measured[["run", "rpm", "eccentric_mass_g"]], fit)
write_card(card, smk.output.card)
log.info("twin %s: %d fit runs at %.0f-%.0f RPM, chi^2/dof %.3g", smk.wildcards.variant, len(runs),
         measured["rpm"].min(), measured["rpm"].max(), fit["chi2_dof"])
