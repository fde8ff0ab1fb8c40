"""The pictures of a transient record (hybridtwin.report.transient_plots, issue 38 item 7): the Bode points are the
order table's, the residual is (measured - model) / sigma, kept-out bands are marked not dropped, the probes'
frame and the display conventions, the waterfall's lines on the orders of a closed-form sweep, the orbits' samples,
and the figures written. No solver: the model is given (closed form) wherever a model is needed."""

import matplotlib
import numpy as np
import pandas as pd
import pytest

from swept_signals import Response, Sweep, swept_record
from hybridtwin import tables
from hybridtwin.data.order_tracking import order_vector, speed_profile, track_orders
from hybridtwin.report import transient_plots as tp
from hybridtwin.report.response_plots import columns as dense_columns
from hybridtwin.settings import defaults, transient_settings

matplotlib.use("Agg")

SWEEP = Sweep(r0=300.0, r1=900.0, duration_s=24.0, bow=30.0)
RECORD_ROW = {"run": "up", "kind": "runup", "role": "fit", "eccentric_mass_g": 10.0}


@pytest.fixture(scope="module")
def tracked():
    """A closed-form run-up 300 -> 900 RPM (resonance at 650 RPM, runout, offsets, 5 um noise), its order table
    (1X..3X) and bands of 50 RPM from 350 RPM, the one at 600-650 RPM flagged too fast."""
    record = swept_record(SWEEP, Response(), noise_m=5e-6, seed=3, harmonics=2)
    orders = track_orders(record, harmonics=3, direction="runup")
    lo = np.arange(350.0, 900.0, 50.0)
    bands = pd.DataFrame({"band_lo_rpm": lo, "band_hi_rpm": lo + 50.0, "usable": lo != 600.0,
                          "flags": np.where(lo == 600.0, "sweep_too_fast", "")})
    return record, orders, bands


def _true_model(orders, response=Response(), harmonics=3):
    """(W, H, C): the closed-form vectors at the windows' speeds, scaled by 1.01 (a model 1 % off)."""
    rpm = orders["rpm"].to_numpy()
    return 1.01 * np.stack([np.stack(response.vector(rpm, h), 1) for h in range(1, harmonics + 1)], 1)


def test_points_are_the_order_tables_vectors_and_z_is_the_residual_over_sigma(tracked):
    """Frame model: each point's measured vector and sigma are the order table's, bit for bit, its model the one
    given, and z = (measured - model) / sigma per part, computed here from the table's columns."""
    _, orders, bands = tracked
    model = _true_model(orders)
    table = tp.points(orders, model, tp.probe_matrix(["x", "y"], None, "model"), RECORD_ROW, bands, "model")
    assert list(table.columns) == list(tables.TRANSIENT.columns)
    assert len(table) == len(orders) * 3 * 2
    for h in (1, 2, 3):
        for j, c in enumerate(("x", "y")):
            part = table[(table["harmonic"] == h) & (table["channel"] == c)].sort_values("window")
            np.testing.assert_array_equal(part["measured_re_m"], orders[f"{c}{h}_re_m"])
            np.testing.assert_array_equal(part["measured_im_m"], orders[f"{c}{h}_im_m"])
            np.testing.assert_array_equal(part["sigma_m"], orders[f"{c}{h}_sigma_m"])
            np.testing.assert_array_equal(part["model_re_m"] + 1j * part["model_im_m"], model[:, h - 1, j])
            z_re = (orders[f"{c}{h}_re_m"] - model[:, h - 1, j].real) / orders[f"{c}{h}_sigma_m"]
            z_im = (orders[f"{c}{h}_im_m"] - model[:, h - 1, j].imag) / orders[f"{c}{h}_sigma_m"]
            np.testing.assert_allclose(part["z_re"], z_re, rtol=1e-12)
            np.testing.assert_allclose(part["z_im"], z_im, rtol=1e-12)
            np.testing.assert_allclose(part["z_abs"], np.hypot(z_re, z_im), rtol=1e-12)


def test_a_model_that_is_the_truth_leaves_residuals_of_the_noise():
    """With the closed-form truth as the model (a sweep without resonance: the vectors barely change within a
    window), |z| of every order is Rayleigh-distributed as a complex residual in units of sigma: E[|z|^2 / 2] = 1
    (here within 0.8-1.25, ~4 standard errors over 2 x 3 x 60 points) and 95 % below RAYLEIGH_95 (here >= 90 %)."""
    response = Response(amplitude_m=0.0)
    record = swept_record(Sweep(300.0, 900.0, 40.0, 30.0), response, noise_m=5e-6, seed=2, harmonics=2)
    orders = track_orders(record, harmonics=3, direction="runup")
    bands = pd.DataFrame({"band_lo_rpm": [0.0], "band_hi_rpm": [1e4], "usable": [True], "flags": [""]})
    table = tp.points(orders, _true_model(orders, response) / 1.01, np.eye(2), RECORD_ROW, bands, "model")
    assert len(table) >= 300
    assert 0.8 < (table["z_abs"] ** 2).mean() / 2 < 1.25
    assert (table["z_abs"] < tp.RAYLEIGH_95).mean() >= 0.9


def test_windows_in_kept_out_bands_are_marked_not_dropped(tracked):
    """Every window is in the table; those below the first band are slow_roll, those in the flagged band carry
    its flag, the others are used; the Bode figure shades the kept-out spans."""
    _, orders, bands = tracked
    status = tp.window_status(orders["rpm"], bands)
    rpm = orders["rpm"].to_numpy()
    assert len(status) == len(orders)
    for r, s in zip(rpm, status):
        expected = ("slow_roll" if r < 350 else "sweep_too_fast" if 600 <= r < 650 else
                    "beyond_bands" if r >= 900 else "used")
        assert s == expected, (r, s)
    table = tp.points(orders, _true_model(orders), np.eye(2), RECORD_ROW, bands, "model")
    spans = tp._kept_spans(table)
    assert [s[2] for s in spans][:2] == ["slow_roll", "sweep_too_fast"]
    inside = rpm[(rpm >= 600) & (rpm < 650)]
    assert spans[1][:2] == (inside.min(), inside.max())


def test_the_bode_figure_draws_the_tables_points_and_the_models_curve(tracked):
    """The first amplitude panel (1X, x): the used points' heights are |measured| in um peak-to-peak, the kept-out
    ones hollow, the model's line |model| at every window's speed; the residual panel's points are z_abs; every
    amplitude axis says pk-pk, every phase axis lag."""
    _, orders, bands = tracked
    model = _true_model(orders)
    table = tp.points(orders, model, np.eye(2), RECORD_ROW, bands, "model")
    fig = tp.plot_bode(table, "v", tp.Display("peak-to-peak", "lag"))
    amp, ph, res = fig.axes[0], fig.axes[3], fig.axes[6]  # first column: 1X amplitude, phase, residual of x
    part = table[(table["harmonic"] == 1) & (table["channel"] == "x")].sort_values("rpm")
    used = part["used"].to_numpy()
    Z = orders["x1_re_m"].to_numpy() + 1j * orders["x1_im_m"].to_numpy()
    order = np.argsort(orders["rpm"].to_numpy())
    used_points, kept_points = amp.containers[0].lines[0], amp.containers[1].lines[0]
    np.testing.assert_allclose(used_points.get_ydata(), 2e6 * np.abs(Z[order][used]), rtol=1e-12)
    np.testing.assert_allclose(kept_points.get_xdata(), orders["rpm"].to_numpy()[order][~used])
    assert kept_points.get_markerfacecolor() == "none"
    curve = [line for line in amp.get_lines() if line.get_label().startswith("twin")][0]
    np.testing.assert_allclose(curve.get_ydata(), 2e6 * np.abs(model[order, 0, 0]), rtol=1e-12)
    dots = np.concatenate([line.get_ydata() for line in res.get_lines() if line.get_marker() == "o"])
    np.testing.assert_allclose(np.sort(dots), np.sort(part["z_abs"]), rtol=1e-12)
    rows = [fig.axes[3 * row:3 * row + 3] for row in range(6)]  # x: amplitude, phase, residual; then y
    assert all("[um pk-pk]" in ax.get_ylabel() for row in (0, 3) for ax in rows[row])
    assert all("phase lag [deg]" in ax.get_ylabel() for row in (1, 4) for ax in rows[row])
    tp.plt.close(fig)


def test_display_conventions():
    """Peak-to-peak is twice 0-peak; a lag is minus the lead (arg U); the labels say which."""
    z = np.array([3e-6 * np.exp(0.7j)])
    pp, op = tp.Display("peak-to-peak", "lag"), tp.Display("0-peak", "lead")
    assert pp.amp(z)[0] == pytest.approx(6.0) and op.amp(z)[0] == pytest.approx(3.0)
    assert pp.angle(z)[0] == pytest.approx(-0.7) and op.angle(z)[0] == pytest.approx(0.7)
    assert "pk-pk" in pp.amp_label("x", 1) and "0-pk" in op.amp_label("x", 1)
    assert "lag" in pp.phase_label("x", 2) and "lead" in op.phase_label("x", 2)
    with pytest.raises(ValueError):
        tp.Display("rms", "lag")
    assert transient_settings({}).as_dict() == defaults("report")["transient"]  # the schema's, the only defaults
    assert transient_settings({"report": {"transient": {"phase": "lead"}}}).phase == "lead"
    assert tp.Display.of(transient_settings({}).as_dict()) == tp.Display("peak-to-peak", "lag")


def test_the_probes_frame_shows_each_probe_as_it_reads():
    """Probes at 45 and 135 deg: each shown channel is x cos a + y sin a (the order table's x, y), its sigma
    sqrt(cos^2 sigma_x^2 + sin^2 sigma_y^2); at the default angles, or in frame model, the identity."""
    sensors = {"x": {"node": 1, "direction": "x", "angle_deg": 45}, "y": {"node": 1, "direction": "y",
                                                                           "angle_deg": 135}}
    P = tp.probe_matrix(["x", "y"], sensors, "probes")
    c = np.sqrt(0.5)
    np.testing.assert_allclose(P, [[c, c], [-c, c]], atol=1e-15)
    Z = np.array([[1e-5 + 2e-5j, -3e-5 + 1e-6j]])
    S = np.array([[1e-6, 2e-6]])
    shown, sigma = tp.project(P, Z, S)
    np.testing.assert_allclose(shown[0, 1], -c * Z[0, 0] + c * Z[0, 1])
    np.testing.assert_allclose(sigma[0], np.sqrt(0.5 * 1e-12 + 0.5 * 4e-12))
    np.testing.assert_array_equal(tp.probe_matrix(["x", "y"], None, "probes"), np.eye(2))
    np.testing.assert_array_equal(tp.probe_matrix(["x", "y"], sensors, "model"), np.eye(2))


def test_model_at_reads_the_records_own_sweep_at_each_windows_speed():
    """A run-up reads the dense table's run-up rows, a coast-down its run-down rows, at the window speeds exactly;
    a speed the table lacks, or another mass, is NaN."""
    rows = []
    for sweep, sign in (("run-up", 1.0), ("run-down", -1.0)):
        for rpm in (100.0, 200.0, 300.0):
            for h in (1, 2):
                rows.append((5.0, 0.0, sweep, rpm, h, sign * rpm * h, 1.0, sign, 0.0, True, "main"))
    dense = pd.DataFrame(rows, columns=dense_columns(("x", "y")))
    up = tp.model_at(dense, 5.0, "runup", [300.0, 100.0, 150.0], 2)
    down = tp.model_at(dense, 5.0, "coastdown", [200.0], 2)
    assert up[0, 1, 0] == 600 + 1j and up[1, 0, 1] == 1.0 and np.isnan(up[2]).all()
    assert down[0, 0, 0] == -200 + 1j and down[0, 0, 1] == -1.0
    assert np.isnan(tp.model_at(dense, 7.0, "runup", [100.0], 2)).all()


def test_the_twin_is_compensated_for_slow_roll_as_the_record_was():
    """The fit compares the record with the model less its own response at forward.SLOW_ROLL_RPM on the runout's
    harmonics (SolverModel's slow_roll_harmonics); the figures must draw that model. A dense table whose 2X holds
    a constant (a 2X force's static deflection, the same at every speed) and whose 1X and 3X grow with speed: with
    a 1X/2X runout table the 2X constant is gone and 1X loses its (tiny) slow-roll value, 3X is untouched; without
    a runout table (compensation off) nothing changes."""
    from hybridtwin.identify.forward import SLOW_ROLL_RPM

    rows = []
    for rpm in (SLOW_ROLL_RPM, 300.0, 600.0):
        for h, value in ((1, 1e-9 * rpm**2), (2, 4e-6 + 1e-12 * rpm**2), (3, 1e-10 * rpm**2)):
            rows.append((5.0, 0.0, "run-up", rpm, h, value, 0.0, 0.0, value, True, "main"))
    dense = pd.DataFrame(rows, columns=dense_columns(("x", "y")))
    model = tp.model_at(dense, 5.0, "runup", [300.0, 600.0], 3)
    runout = pd.DataFrame({"channel": ["x", "x", "y", "y"], "harmonic": [1, 2, 1, 2]})
    out = tp.compensated_like_the_data(dense, model, 5.0, "runup", runout)
    rpm = np.array([300.0, 600.0])
    assert np.allclose(out[:, 1, 0], 1e-12 * (rpm**2 - SLOW_ROLL_RPM**2), rtol=1e-12, atol=0)
    assert np.allclose(out[:, 0, 0], 1e-9 * (rpm**2 - SLOW_ROLL_RPM**2), rtol=1e-12, atol=0)
    assert np.array_equal(out[:, 2], model[:, 2])
    assert np.array_equal(tp.compensated_like_the_data(dense, model, 5.0, "runup", None), model)
    assert np.array_equal(tp.compensated_like_the_data(dense, model, 5.0, "runup", runout.iloc[:0]), model)


def test_the_waterfalls_strongest_line_follows_1x_on_a_closed_form_sweep():
    """A run-up 300 -> 900 RPM whose 1X dominates: in every segment the strongest line lies at the segment's
    speed / 60 Hz within a frequency bin plus the speed's change over the segment; with a constant 1X of 20 um
    and no resonance, the line reads 20 um 0-peak to within the Hann window's scalloping (at most 1.42 dB low)."""
    flat = Response(amplitude_m=0.0, runout_1x_m=(20e-6, -20e-6j), runout_2x_m=(0j, 0j))
    for response in (Response(), flat):
        record = swept_record(SWEEP, response, noise_m=2e-6, seed=5, harmonics=2)
        speed = speed_profile(record, "runup").table()
        fall = tp.waterfall(record.time_s, record.channels, speed)
        df = fall.frequency_hz[1] - fall.frequency_hz[0]
        segment = 2 * (fall.t_s[1] - fall.t_s[0])
        assert fall.rpm.size >= 10 and df <= speed["rpm"].min() / 60.0 / 4 * 1.001  # a quarter of the lowest 1X
        change = 0.5 * segment * (SWEEP.r1 - SWEEP.r0 + np.pi * SWEEP.bow) / SWEEP.duration_s / 60.0
        assert np.allclose(fall.rpm, SWEEP.rpm(fall.t_s), atol=2.0)  # the keyphasor's speed at the middle
        for name in ("x", "y"):
            peak = fall.frequency_hz[np.argmax(fall.amplitude[name], axis=1)]
            assert np.all(np.abs(peak - fall.rpm / 60.0) <= df + change), name
        if response is flat:
            top = fall.amplitude["x"].max(axis=1)
            assert np.all((top > 20e-6 * 10 ** (-1.5 / 20)) & (top < 20e-6 * 1.05))


def test_orbit_samples_are_the_record_less_offset_drift_and_runout():
    """A noiseless record: the samples of a window, less the window's offset and drift (the order table's) and the
    true runout, are the dynamic response alone, Re(sum_h D_h exp(i h theta)) with the closed form's vectors less
    the runout at each sample's speed, to 2 % of the orbit's size, below (400 RPM) and through (650 RPM) the
    resonance (there the window's offset, fitted beside a 1X that changes across the window, is off by ~1 %:
    0.9 um of 125 um, measured)."""
    response = Response()
    record = swept_record(SWEEP, response, noise_m=0.0, seed=1, harmonics=2)
    orders = track_orders(record, harmonics=3, direction="runup")
    profile = speed_profile(record, "runup")
    xy = np.column_stack([record.channels["x"], record.channels["y"]])
    inside = (record.time_s >= profile.marks_s[0]) & (record.time_s <= profile.marks_s[-1])
    theta = np.where(inside, profile.theta(np.where(inside, record.time_s, profile.marks_s[0])), np.nan)
    runout = pd.DataFrame([{"channel": c, "harmonic": h, "runout_re_m": r.real, "runout_im_m": r.imag}
                           for h, table in ((1, response.runout_1x_m), (2, response.runout_2x_m))
                           for c, r in zip(("x", "y"), table)])
    for speed in (400.0, 650.0):
        w = int(np.argmin(np.abs(orders["rpm"].to_numpy() - speed)))
        window = orders.iloc[w]
        samples, th = tp.orbit_samples(record.time_s, xy, theta, window, ["x", "y"], runout)
        t = record.time_s[(record.time_s >= window["t_start_s"]) & (record.time_s < window["t_end_s"])]
        dynamic = response.dynamic_1x(SWEEP.rpm(t))
        for j in range(2):
            expected = (dynamic[j] * np.exp(1j * th)).real
            assert np.abs(samples[:, j] - expected).max() < 0.02 * np.abs(expected).max(), (speed, j)


def test_orbit_speeds_default_and_requested(tracked):
    """Default: the lowest band's speed, the largest 1X's and the top speed (as the nearest windows); a requested
    speed outside the record is a note, not an orbit."""
    _, orders, bands = tracked
    rpm = orders["rpm"].to_numpy()
    picks, notes = tp.orbit_speeds(orders, bands)
    assert notes == [] and len(picks) == 3
    first = np.hypot(orders["x1_amp_m"], orders["y1_amp_m"])
    assert int(np.argmax(orders["x1_amp_m"].combine(orders["y1_amp_m"], max))) in picks and first.size
    assert rpm[picks[0]] == pytest.approx(350.0, abs=15) and picks[-1] == int(np.argmax(rpm))
    picks, notes = tp.orbit_speeds(orders, bands, [500.0, 2000.0])
    assert [round(rpm[w] / 50) for w in picks] == [10] and len(notes) == 1 and "2000" in notes[0]


def test_the_figures_are_written(tracked, tmp_path):
    """Bode, polar, waterfall and orbits of one record to PNG files, in either display and frame."""
    record, orders, bands = tracked
    model = _true_model(orders)
    for display, frame in ((tp.Display("peak-to-peak", "lag"), "probes"), (tp.Display("0-peak", "lead"), "model")):
        table = tp.points(orders, model, np.eye(2), RECORD_ROW, bands, frame)
        for name, plot in (("bode", tp.plot_bode), ("polar", tp.plot_polar)):
            fig = plot(table, "v", display)
            fig.savefig(tmp_path / f"{name}_{frame}.png", dpi=40)
            tp.plt.close(fig)
    fall = tp.waterfall(record.time_s, record.channels, speed_profile(record, "runup").table())
    fig = tp.plot_waterfall(fall, "up", tp.Display.of({"frame": "probes", "amplitude": "peak-to-peak"}))
    fig.savefig(tmp_path / "waterfall.png", dpi=40)
    tp.plt.close(fig)
    profile = speed_profile(record, "runup")
    inside = (record.time_s >= profile.marks_s[0]) & (record.time_s <= profile.marks_s[-1])
    theta = np.where(inside, profile.theta(np.where(inside, record.time_s, profile.marks_s[0])), np.nan)
    orbits, _ = tp.record_orbits(record.time_s, np.column_stack([record.channels["x"], record.channels["y"]]),
                                 theta, orders, bands, None, model)
    fig = tp.plot_orbits(orbits, "up", "v", [("x", "y")], {})
    fig.savefig(tmp_path / "orbits.png", dpi=40)
    tp.plt.close(fig)
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == ["bode_model.png", "bode_probes.png", "orbits.png", "polar_model.png", "polar_probes.png",
                       "waterfall.png"]
    assert all((tmp_path / name).stat().st_size > 10_000 for name in written)


def test_a_sheet_with_transient_rows_has_their_pictures_among_the_default_targets(tmp_path):
    """A dry run of the workflow on a sheet with a run-up and a coast-down: the default target plans one
    report_transient per variant and one report_waterfall per record (the bundled steady sheet plans none: the
    rules exist only for sheets with transient rows)."""
    import subprocess
    import sys

    from test_workflow import SMALL, _copy_workflow

    work = _copy_workflow(tmp_path, runs=[], config=SMALL.replace("data/small/runs.tsv", "runs.tsv"))
    (work / "records").mkdir()
    for name in ("up.csv", "down.csv"):
        record = swept_record(Sweep(300.0, 600.0, 3.0, 0.0), Response(), harmonics=1)
        pd.DataFrame({"time_s": record.time_s, "x_mm": 1e3 * record.channels["x"],
                      "y_mm": 1e3 * record.channels["y"], "keyphasor": record.keyphasor.astype(int)}
                     ).to_csv(work / "records" / name, index=False)
    (work / "runs.tsv").write_text("run\tkind\trpm_start\trpm_end\teccentric_mass_g\tpath\trole\n"
                                   "up\trunup\t300\t600\t10\trecords/up.csv\tfit\n"
                                   "down\tcoastdown\t600\t300\t10\trecords/down.csv\tvalidate\n")
    run = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1"], cwd=work, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    counts = {line.split()[0]: int(line.split()[1]) for line in run.stdout.splitlines()
              if len(line.split()) == 2 and line.split()[1].isdigit()}
    assert counts.get("report_transient") == 2 and counts.get("report_waterfall") == 2, counts
