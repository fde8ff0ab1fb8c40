"""Rule report_waterfall: the waterfall of one transient record, its short-time spectra against the keyphasor's
speed, per probe (thin wrapper; hybridtwin.report.transient_plots.waterfall). Reads only the rule's input, params
and output."""

from hybridtwin import config as cfg
from hybridtwin.data.records import read_record
from hybridtwin.data.preprocessing import read_tsv
from hybridtwin.report import transient_plots as tp
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_waterfall")
options = smk.params.display  # frame, amplitude (config report: transient:)
record = read_record(smk.input.record, getattr(smk.params, "sensors", None), smk.params.channels)
# frame probes: what each probe read (before a rotated pair is turned into x, y); model: the plane's x and y
channels = record.readings if options["frame"] == "probes" and record.readings else record.channels
fall = tp.waterfall(record.time_s, channels, read_tsv(smk.input.speed))
log.info("%s: %d segments of %.2f s, %.0f-%.0f RPM, resolution %.3g Hz", smk.wildcards.run, fall.rpm.size,
         2 * (fall.t_s[1] - fall.t_s[0]) if fall.t_s.size > 1 else float("nan"), fall.rpm.min(), fall.rpm.max(),
         fall.frequency_hz[1] - fall.frequency_hz[0])
figure = tp.plot_waterfall(fall, smk.wildcards.run, tp.Display.of(options))
save_png(figure, smk.output.waterfall, dpi=90)
tp.plt.close(figure)
