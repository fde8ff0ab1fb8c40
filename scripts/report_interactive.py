"""Rule report_interactive: every interactive figure in one page with one copy of plotly.js, a menu to choose the
figure (results/interactive.html, the report's one HTML entry; thin wrapper, hybridtwin.report.interactive_pages)."""

from hybridtwin import config as cfg
from hybridtwin.report import interactive_pages as pages

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_interactive")
entries = [(key, label, pages.read_figure(path))
           for key, label, path in zip(smk.params.figure_keys, smk.params.labels, smk.input.figures, strict=True)]
pages.write_gallery(entries, smk.output.page, title="hybridtwin: interactive figures")
log.info("%d figures in one page with one copy of plotly.js", len(entries))
