"""Rule report_transient: per transient record (run-up or coast-down), its Bode and polar plots with the fitted twin
on top and the residual in units of the noise, and its orbits at chosen speeds (thin wrapper;
hybridtwin.report.transient_plots). Reads only the rule's input, params and output.

The model: the fitted twin's response by continuation at every window's speed of every record, one batched sweep
for all records (response_plots.dense_response, as report_response: the joint fit's values, the bow from its law),
compensated for slow roll as each record was (transient_plots.compensated_like_the_data).
"""

from pathlib import Path

import numpy as np
import pandas as pd

from hybridtwin import config as cfg
from hybridtwin.tables import TRANSIENT
from hybridtwin.data.measured import read_harmonics
from hybridtwin.data.preprocessing import read_tsv
from hybridtwin.data.records import probe_angles, read_record, record_channels
from hybridtwin.data.order_tracking import read_orders, speed_profile, table_channels
from hybridtwin.identify import identification as idn
from hybridtwin.identify.forward import SLOW_ROLL_RPM
from hybridtwin.report import transient_plots as tp
from hybridtwin.plots import save_png

smk = snakemake  # noqa: F821 (injected by Snakemake)
log = cfg.rule_logger(smk.log[0], "report_transient")
variant = cfg.variant(smk.params.model, smk.wildcards.variant)
options = smk.params.display  # frame, amplitude, phase, orbit_rpm (config report: transient:)
display = tp.Display.of(options)
sensors = getattr(smk.params, "sensors", None)
records = smk.params.records  # the sheet's transient rows (run, kind, role, eccentric_mass_g), the inputs' order
orders = [read_orders(path) for path in smk.input.orders]
bands = [read_harmonics(path) for path in smk.input.bands]
runouts = [read_tsv(path) for path in smk.input.runout]
harmonics = min([int(smk.params.harmonics)] + [tp.table_harmonics(o) for o in orders])
speeds = np.concatenate([o["rpm"].to_numpy(float) for o in orders])
log.info("%s: the fitted twin at %d window speeds of %d record(s), %.0f-%.0f RPM, 1X..%dX", variant.name,
         speeds.size, len(records), speeds.min(), speeds.max(), harmonics)
if any(r is not None and not r.empty for r in runouts):  # the model is compensated as the records were
    speeds = np.append(speeds, SLOW_ROLL_RPM)
dense = tp.model_response(variant, idn.read_parameters(smk.input.parameters), pd.DataFrame(smk.params.runs),
                          speeds, harmonics, smk.params.law)
names, pairs = record_channels(sensors)
folder = Path(smk.output.figures)
points_tables = []
for record, table, band, runout, path in zip(records, orders, bands, runouts, smk.input.records):
    channels = table_channels(table)
    mass, angle = float(record["eccentric_mass_g"]), float(record.get("eccentric_mass_angle_deg") or 0.0)
    model = tp.compensated_like_the_data(
        dense, tp.model_at(dense, mass, record["kind"], table["rpm"], harmonics, angle), mass, record["kind"],
        runout, angle)
    points = tp.points(table, model, tp.probe_matrix(channels, sensors, options["frame"]), record, band,
                       options["frame"])
    points_tables.append(points)
    used = points[points["used"] & (points["harmonic"] == 1)]
    log.info("%s: %d windows, %d in used bands; 1X |z| median %.3g over those; %d window(s) without a model",
             record["run"], len(table), used["window"].nunique(), float(used["z_abs"].median()),
             int(np.isnan(model[:, 0, 0]).sum()))
    out = folder / record["run"]
    out.mkdir(parents=True, exist_ok=True)
    for name, plot in (("bode", tp.plot_bode), ("polar", tp.plot_polar)):
        figure = plot(points, variant.name, display)
        save_png(figure, out / f"{name}.png", dpi=90)
        tp.plt.close(figure)
    data = read_record(path, sensors, record.get("channels"))  # the orbits: the record's own samples over the chosen windows
    profile = speed_profile(data, record["kind"])
    inside = (data.time_s >= profile.marks_s[0]) & (data.time_s <= profile.marks_s[-1])
    theta = np.where(inside, profile.theta(np.where(inside, data.time_s, profile.marks_s[0])), np.nan)
    orbits, notes = tp.record_orbits(data.time_s, np.column_stack([data.channels[c] for c in channels]), theta,
                                     table, band, runout, model, options.get("orbit_rpm"))
    for note in notes:
        log.warning("%s: %s", record["run"], note)
    figure = tp.plot_orbits(orbits, record["run"], variant.name, [(names[i], names[j]) for i, j in pairs],
                            probe_angles(sensors))
    save_png(figure, out / "orbits.png", dpi=90)
    tp.plt.close(figure)
    log.info("%s: orbits at %s RPM", record["run"], ", ".join(f"{o['rpm']:.0f}" for o in orbits))
TRANSIENT.write(pd.concat(points_tables, ignore_index=True), smk.output.table)
