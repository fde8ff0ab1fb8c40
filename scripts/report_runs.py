"""Rule report_runs: one figure per run, orbit, signals with the residual, residual whirl spectrum, and every run in
one interactive figure (runs.html; thin wrapper)."""

from pathlib import Path

from hybridtwin import config as cfg
from hybridtwin.report import interactive, report, report_plots
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_runs")
folder = Path(smk.output.runs)
folder.mkdir(parents=True, exist_ok=True)
# each plane's x and y probes as the machine declares them (params.sensors; none: the VARM's x, y)
pairs = report_plots.sensor_pair_names(getattr(smk.params, "sensors", None))
comparisons = report.load_comparisons(smk.input.table)
for comparison in comparisons:
    figure = report_plots.plot_run(comparison, smk.wildcards.variant, pairs)
    save_png(figure, folder / f"{comparison.run}.png", dpi=80)  # 22 runs x 4 variants in the report: 51 -> ~35 kB
    report_plots.plt.close(figure)
    log.info("%s: chi^2/dof %.4g", comparison.run, comparison.chi2_dof)
interactive.write_html(interactive.runs_figure(comparisons, smk.wildcards.variant, pairs), smk.output.interactive)
