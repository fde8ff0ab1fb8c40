"""Rule twin_card: the twin's card, twin.yaml (thin wrapper of hybridtwin.online.twin.make_card). Reads only the rule's
input, params and output."""

from hybridtwin import config as cfg
from hybridtwin.identify import identification as idn
from hybridtwin.offline.library import read_library_validation
from hybridtwin.online.twin import library_card, make_card, write_card
from hybridtwin.identify.run_fits import read_fit_summary

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "twin_card")
table = idn.read_parameters(smk.input.parameters)
runs = idn.fit_runs(table)
measured = idn.read_harmonics(smk.input.harmonics).set_index("run").loc[runs].reset_index()
measured["rpm"] = measured["rpm_true"].fillna(measured["rpm"])
fit = read_fit_summary(smk.input.summary)["final"]
validation = smk.input.library  # a path, or none without libraries (offline.scope: none)
validation = [validation] if isinstance(validation, str) else list(validation)
library = library_card(smk.params.scope, read_library_validation(validation[0]) if validation else None)
card = make_card(smk.wildcards.variant, smk.params.model, smk.params.harmonics, smk.params.keyphasor,
                 cfg.candidate_names(smk.params.candidates, smk.params.model), smk.params.sensor_range_mm,
                 measured[["run", "rpm", "eccentric_mass_g"]], fit, library)
write_card(card, smk.output.card)
if library is not None and library["scope"] == "run":  # each library anchored on the solver at the twin
    from pathlib import Path

    from hybridtwin.online.library_route import anchors
    from hybridtwin.online.twin import load_twin

    anchored = anchors(load_twin(Path(smk.output.card).parent))
    for entry in library["runs"]:
        entry["anchor"] = anchored.get(entry["run"])
        log.info("library %s: %s", entry["run"], "not anchored (no steady state at a checked point)"
                 if entry["anchor"] is None else f"error at the twin {entry['anchor']['raw_error_pct']:.3g} %, "
                 f"anchored {entry['anchor']['error_pct']:.3g} % near it")
    write_card(make_card(smk.wildcards.variant, smk.params.model, smk.params.harmonics, smk.params.keyphasor,
                         cfg.candidate_names(smk.params.candidates, smk.params.model), smk.params.sensor_range_mm,
                         measured[["run", "rpm", "eccentric_mass_g"]], fit, library), smk.output.card)
log.info("twin %s: %d fit runs at %.0f-%.0f RPM, chi^2/dof %.3g; %s", smk.wildcards.variant, len(runs),
         measured["rpm"].min(), measured["rpm"].max(), fit["chi2_dof"],
         "no library" if library is None else f"library: scope {library['scope']}, {len(library['runs'])} runs")
