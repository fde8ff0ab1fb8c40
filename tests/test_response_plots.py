"""The dense model response of the report (hybridtwin.report.response_plots): the sweeps against the linear rotor solved by
hand, the table's reader against its writer, the multi-valued band, and the Bode and polar figures."""

import matplotlib
import numpy as np
import pandas as pd
import pytest

from example_machines import LINEAR_EFFECTS, SENSOR_NODE, linear_response, stepped_machine
from hybridtwin.report import response_plots as rp
from hybridtwin.model.model import Model
from hybridtwin.report.report import RunComparison
from hybridtwin.model.variants import Variant

MASSES_G = (20.0, 10.0)
K_A, C_B = 2.5e7, 600.0  # the "fitted" values, away from the machine's nominal ones (2e7, 500)


def _fitted_linear():
    """The stepped rotor, its linear variant and a joint table with the two unknowns shared at K_A, C_B."""
    machine = stepped_machine()
    fx = machine.effects()
    variant = Variant("linear", Model([fx[e] for e in LINEAR_EFFECTS], machine),
                      {"k_a": (1e7, 4e7), "c_b": (100.0, 1000.0)})
    joint = pd.DataFrame({"parameter": ["k_a", "c_b"], "run": ["all", "all"], "kind": ["shared", "shared"],
                          "value": [K_A, C_B]})
    return machine, variant, joint


@pytest.fixture(scope="module")
def linear():
    """The stepped rotor's linear variant, a joint table with its two unknowns shared, fit runs at two masses
    around the critical speeds (~3800-4100 RPM), and the dense response over them (41 speeds)."""
    machine, variant, joint = _fitted_linear()
    runs = pd.DataFrame({"run": [f"r{rpm}_m{m:g}" for m in MASSES_G for rpm in (3000, 3900, 4600)],
                         "rpm": [float(rpm) for _ in MASSES_G for rpm in (3000, 3900, 4600)],
                         "eccentric_mass_g": [m for m in MASSES_G for _ in range(3)]})
    dense = rp.dense_response(variant, joint, runs, rp.dense_speeds(runs["rpm"], 41), harmonics=2)
    return machine, runs, dense


def test_sweeps_of_a_linear_rotor_are_its_response_solved_by_hand(linear):
    """Every speed of both sweeps and both masses: the sensor's 1X is (K - Omega^2 M + i Omega (C + G)) X = F
    assembled and solved by hand (tests/example_machines.linear_response, no Model, no harmonic balance); a
    linear system's harmonic balance is one exact solve, so the two agree to round-off (1e-9 of the largest
    amplitude; the condition number near the critical speeds costs a few digits of the 1e-16); 2X is zero."""
    machine, runs, dense = linear
    assert set(dense["sweep"]) == {"run-up", "run-down"} and set(dense["eccentric_mass_g"]) == set(MASSES_G)
    first = dense[dense["harmonic"] == 1]
    expected = np.array([linear_response(machine, r.rpm, 1e-3 * r.eccentric_mass_g, k={"a": K_A}, c={"b": C_B})
                         for r in first.itertuples()])
    u, v = machine.dof(f"u{SENSOR_NODE}"), machine.dof(f"v{SENSOR_NODE}")
    scale = np.abs(expected[:, u]).max()
    assert rp.channels_of(dense) == ["x1", "y1"]  # the machine's sensors, by name
    np.testing.assert_allclose(first["x1_re_m"] + 1j * first["x1_im_m"], expected[:, u], atol=1e-9 * scale)
    np.testing.assert_allclose(first["y1_re_m"] + 1j * first["y1_im_m"], expected[:, v], atol=1e-9 * scale)
    second = dense[dense["harmonic"] == 2]
    assert np.abs(second[["x1_re_m", "x1_im_m", "y1_re_m", "y1_im_m"]].to_numpy()).max() < 1e-9 * scale
    # the grid covers the runs with a margin, and the resonance lies inside it
    assert dense["rpm"].min() < runs["rpm"].min() and dense["rpm"].max() > runs["rpm"].max()
    assert bool(first["stable"].all())  # a damped linear rotor below any instability
    band = rp.multivalued(dense)
    assert band["rpm_from"].isna().all()  # linear: run-up and run-down are the same curve


def test_the_dense_table_reader_is_the_writers_exact_inverse(linear, tmp_path):
    _, _, dense = linear
    table = dense.copy()
    table.loc[3, "stable"] = np.nan  # a speed where the sweep did not converge
    table.loc[3, ["x1_re_m", "x1_im_m"]] = np.nan
    rp.write_dense(table, tmp_path / "response.tsv")
    back = rp.read_dense(tmp_path / "response.tsv")
    pd.testing.assert_frame_equal(back, table, check_dtype=False)
    assert back.loc[3, "stable"] is np.nan or pd.isna(back.loc[3, "stable"])


def test_multivalued_band_is_where_run_up_and_run_down_differ():
    """A hand-made table: the run-down's 1X x amplitude 30 % lower at 950-1000 RPM only (a jump band), the rest
    equal; the band reported is exactly those speeds, and nothing for a mass whose sweeps agree."""
    rpm = np.arange(900.0, 1051.0, 25.0)
    rows = []
    for mass in (14.8, 25.9):
        for sweep in ("run-up", "run-down"):
            for speed in rpm:
                x = 1e-3 * (0.7 if mass == 14.8 and sweep == "run-down" and 950 <= speed <= 1000 else 1.0)
                rows.append((mass, 0.0, sweep, speed, 1, x, 0.0, 0.0, x, True, "direct"))
    band = rp.multivalued(pd.DataFrame(rows, columns=rp.COLUMNS)).set_index("eccentric_mass_g")
    assert (band.loc[14.8, "rpm_from"], band.loc[14.8, "rpm_to"]) == (950.0, 1000.0)
    assert np.isnan(band.loc[25.9, "rpm_from"])


def test_bode_and_polar_draw_both_sweeps_and_the_measured_runs(linear, tmp_path):
    """Measured = the model at the run speeds times 1.05 (x1), 1.3 (y1): the figures draw one run-up and one run-down
    curve per mass in every amplitude panel, and one measured point per fit run."""
    machine, runs, dense = linear
    comparisons = []
    for r in runs.itertuples():
        X = linear_response(machine, r.rpm, 1e-3 * r.eccentric_mass_g, k={"a": K_A}, c={"b": C_B})
        model = np.array([[X[machine.dof(f"u{SENSOR_NODE}")], X[machine.dof(f"v{SENSOR_NODE}")]], [0j, 0j]])
        comparisons.append(RunComparison(r.run, "fit", r.rpm, r.eccentric_mass_g, model * [1.05, 1.3], model,
                                         np.full((2, 2), 1e-7), 8.0, "solver", ("x1", "y1")))
    fig = rp.plot_bode(dense, comparisons, "linear", orders=(1,))
    amplitude = fig.axes[0]
    curves = [line for line in amplitude.get_lines() if len(line.get_xdata()) == 41]
    assert len(curves) == 2 * len(MASSES_G)  # run-up and run-down per mass, the full grid each
    assert sorted(line.get_linestyle() for line in curves) == ["-", "-", "--", "--"]
    points = [c for c in amplitude.containers]  # errorbar containers: one per measured run
    assert len(points) == len(runs)
    # the runs' channels are matched to the model's by name: the same runs with their columns stored y1, x1 give
    # the same measured points in each panel
    drawn = [ax.containers[0].lines[0].get_ydata()[0] for ax in fig.axes[0::2]]
    assert drawn[1] / drawn[0] == pytest.approx(1.3 / 1.05, rel=1e-6)  # an isotropic rotor: |x1| = |y1| in the model
    matplotlib.pyplot.close(fig)
    swapped = [RunComparison(c.run, c.role, c.rpm, c.eccentric_mass_g, c.measured[:, ::-1], c.model[:, ::-1],
                             c.sigma[:, ::-1], c.dof, c.source, ("y1", "x1")) for c in comparisons]
    fig = rp.plot_bode(dense, swapped, "linear", orders=(1,))
    assert [ax.containers[0].lines[0].get_ydata()[0] for ax in fig.axes[0::2]] == drawn
    matplotlib.pyplot.close(fig)
    with pytest.raises(ValueError, match="channels x, y, but the model's response has x1, y1"):
        rp.plot_bode(dense, [RunComparison(c.run, c.role, c.rpm, c.eccentric_mass_g, c.measured, c.model, c.sigma,
                                           c.dof, c.source, ("x", "y")) for c in comparisons], "linear")
    fig = rp.plot_bode(dense, comparisons, "linear", orders=(1,))
    fig.savefig(tmp_path / "bode.png")
    matplotlib.pyplot.close(fig)
    fig = rp.plot_polar(dense, comparisons, "linear", orders=(1,))
    fig.savefig(tmp_path / "polar.png")
    assert (tmp_path / "polar.png").stat().st_size > 10_000
    matplotlib.pyplot.close(fig)


def test_validation_runs_phase_is_drawn_on_the_curves_branch():
    """A validation run predicted exactly on a forward-whirling one-mode response (x = u / (1 - r^2 + 2 i zeta r),
    y = -i x: y lags x by a quarter turn, so past the critical speed its phase goes beyond -180 degrees): the
    predicted phase (cross) lies on the drawn curve, whose phase is unwrapped along speed, not a whole turn away
    where np.angle's (-180, 180] put it. Reference: the response's own phase, unwrapped from rest, in closed form
    (-90 - atan2(2 zeta r, 1 - r^2) degrees for y)."""
    critical, zeta, u = 3000.0, 0.05, 1e-4
    rpm = np.linspace(1000.0, 5000.0, 81)
    rows = []
    for sweep in rp.SWEEPS.values():
        for speed in rpm:
            r = speed / critical
            x = u * r * r / (1 - r * r + 2j * zeta * r)
            for h, z in ((1, x), (2, 0.01 * x)):
                y = -1j * z
                rows.append((10.0, 0.0, sweep, speed, h, z.real, z.imag, y.real, y.imag, True, "run-up"))
    dense = pd.DataFrame(rows, columns=rp.columns(("x1", "y1")))
    speeds = [2000.0, 3300.0, 4500.0]
    comparisons = []
    for speed in speeds:
        r = speed / critical
        x = u * r * r / (1 - r * r + 2j * zeta * r)
        model = np.array([[x, -1j * x], [0.01 * x, -0.01j * x]])
        comparisons.append(RunComparison(f"v{speed:g}", "validate", speed, 10.0, model * 1.01, model,
                                         np.full((2, 2), 1e-8), 8.0, "solver", ("x1", "y1")))
    fig = rp.plot_bode(dense, comparisons, "synthetic", orders=(1,))
    y_phase = fig.axes[3]
    crosses = [line.get_ydata()[0] for line in y_phase.get_lines() if line.get_marker() == "x"]
    expected = [-90.0 - np.degrees(np.arctan2(2 * zeta * s / critical, 1 - (s / critical) ** 2)) for s in speeds]
    assert expected[-1] < -180  # past the critical speed: beyond np.angle's range
    np.testing.assert_allclose(crosses, expected, atol=1e-9)
    matplotlib.pyplot.close(fig)


def test_the_dense_grid_resolves_the_resonance_peaks():
    """The stepped rotor's linear variant through its second pair of critical speeds (runs 6000-7800 RPM; the
    probes at d1 see the first pair only faintly): the grid gains speeds
    around each critical speed of the fitted model's Campbell diagram, so that the dense curve's peak is the
    response's. Reference: the closed-form linear response (example_machines.linear_response, a direct solve
    of (K - Omega^2 M + i Omega C) X = F) on 4001 speeds: its peak and where it lies. Tolerances: the critical
    speed (1X crossing of the damped whirl frequency) lies within 1 % of the response's peak speed at these
    damping ratios (a few %); the refined curve's peak within 1 % of the true one, the coarse 41-speed grid's
    further (the premise)."""
    machine, variant, joint = _fitted_linear()
    runs = pd.DataFrame({"run": ["r6000", "r7800"], "rpm": [6000.0, 7800.0], "eccentric_mass_g": [20.0, 20.0]})
    coarse = rp.dense_speeds(runs["rpm"], 41)
    fine = np.linspace(coarse[0], coarse[-1], 4001)
    probe = machine.dof(f"u{SENSOR_NODE}")
    truth = np.array([abs(linear_response(machine, rpm, 0.02, k={"a": K_A}, c={"b": C_B})[probe]) for rpm in fine])
    peak_rpm, peak = fine[np.argmax(truth)], truth.max()
    criticals = rp.critical_speeds(variant, joint, coarse, 20.0)
    assert min(abs(rpm - peak_rpm) for rpm, _ in criticals) < 0.01 * peak_rpm
    assert all(0 < zeta < 0.2 for _, zeta in criticals)
    refined = rp.refined_speeds(coarse, criticals)
    assert set(coarse) <= set(refined) and np.all(np.diff(refined) > 0)
    assert np.array_equal(rp.refined_speeds(fine, criticals), fine)  # a grid fine enough already: as it is

    def drawn_peak(speeds):
        dense = rp.dense_response(variant, joint, runs.iloc[:1], speeds, harmonics=1)
        up = dense[(dense["sweep"] == rp.SWEEPS["up"]) & (dense["harmonic"] == 1)]
        return np.hypot(up["x1_re_m"], up["x1_im_m"]).max()

    assert abs(drawn_peak(coarse) / peak - 1) > 0.01  # the premise: the coarse grid misses the peak
    assert drawn_peak(refined) == pytest.approx(peak, rel=0.01)


@pytest.mark.parametrize("plot", ["plot_bode", "plot_polar"])
def test_the_two_line_title_clears_the_first_rows_panel_titles(plot):
    """Two planes of probes (x1, y1, x2, y2): the figure's title sits above every panel's title (it overlapped
    the first row's on a probe's four-channel machine). Checked on the drawn figure's text boxes."""
    rpm = np.linspace(1000.0, 5000.0, 41)
    rows = []
    for sweep in rp.SWEEPS.values():
        for speed in rpm:
            z = 1e-4 / (1 - (speed / 3000) ** 2 + 0.1j * speed / 3000)
            for h in (1, 2, 3):
                rows.append((10.0, 0.0, sweep, speed, h, *[part for c in (z, -1j * z, z / 2, -0.5j * z)
                                                      for part in (c.real, c.imag)], True, "run-up"))
    dense = pd.DataFrame(rows, columns=rp.columns(("x1", "y1", "x2", "y2")))
    fig = getattr(rp, plot)(dense, [], "two planes")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    title = fig._suptitle.get_window_extent(renderer)
    assert all(title.y0 >= ax.title.get_window_extent(renderer).y1 for ax in fig.axes if ax.get_title())
    matplotlib.pyplot.close(fig)


def test_spectrum_gives_each_sinusoids_amplitude_and_order():
    """x = 1 mm at 1X + 0.05 mm at 0.43X (a subharmonic the order analysis would not see) + offset, y = 0.2 mm at
    3X, each at an exact frequency bin of the 4 s record: the spectrum's peaks are the amplitudes (0-peak, the
    window's gain divided out; np.hanning is the symmetric window, whose leakage at an exact bin is of order
    1/N = 1e-4 relative) at the right orders; the offset is gone."""
    from hybridtwin.data.records import Record
    from hybridtwin.data.preprocessing import spectrum

    fs, n, rpm = 2000.0, 8000, 900.0  # 4 s; bins every 0.25 Hz; 1X = 15 Hz
    t = np.arange(n) / fs
    f1, f_sub = rpm / 60.0, 6.5  # 6.5 Hz: 0.433X, on a bin
    x = 1e-3 * np.cos(2 * np.pi * f1 * t + 0.3) + 5e-5 * np.sin(2 * np.pi * f_sub * t) + 4e-4
    y = 2e-4 * np.cos(2 * np.pi * 3 * f1 * t)
    table = spectrum(Record.xy(None, t, x, y, None, "m"), rpm, max_order=5.0)
    assert table["order"].max() <= 5.0 and table["frequency_hz"].iloc[0] == 0.0

    def at(f: float) -> pd.Series:  # the bin of f (the grid is the record's, rounded as the record's steps)
        return table.iloc[int((table["frequency_hz"] - f).abs().argmin())]
    assert at(f1)["x_amplitude_m"] == pytest.approx(1e-3, rel=1e-3)
    assert at(f_sub)["x_amplitude_m"] == pytest.approx(5e-5, rel=1e-2)  # 1/20 of the 1X line: its leakage too
    assert at(3 * f1)["y_amplitude_m"] == pytest.approx(2e-4, rel=1e-3)
    assert at(f1)["order"] == pytest.approx(1.0, rel=1e-6) and at(0.0)["x_amplitude_m"] < 1e-3 * 4e-4
    far = table[(table["frequency_hz"] - f1).abs() > 2.0]
    assert far["y_amplitude_m"].drop(far.index[(far["frequency_hz"] - 3 * f1).abs() <= 2.0]).max() < 1e-7

    runs = pd.DataFrame({"run": ["a", "b"], "rpm": [rpm, 1.1 * rpm], "eccentric_mass_g": [14.8, 14.8]})
    fig = rp.plot_cascade({"a": table, "b": table.assign(frequency_hz=1.1 * table["frequency_hz"])}, runs)
    assert len(fig.axes[0].collections) == 2  # one row per run
    matplotlib.pyplot.close(fig)


def test_every_plane_of_a_two_plane_machine_gets_its_curves():
    """Probes at d1 (node 8) and at the overhung disk d2 (node 16): the dense table has the four channels in
    declared order, each the linear rotor's response solved by hand at its own node (1e-9 of the largest, as
    above), and the Bode figure draws both sweeps per mass in each channel's amplitude panel (8 rows)."""
    from hybridtwin.model.machine_parts import Sensor

    machine = stepped_machine()
    machine = type(machine)(machine.name, machine.segments, machine.disks, machine.bearings,
                            machine.unbalance_planes, list(machine.sensors) + [Sensor("x2", 16, "x"),
                                                                               Sensor("y2", 16, "y")])
    fx = machine.effects()
    variant = Variant("linear", Model([fx[e] for e in LINEAR_EFFECTS], machine), {"k_a": (1e7, 4e7)})
    joint = pd.DataFrame({"parameter": ["k_a"], "run": ["all"], "kind": ["shared"], "value": [K_A]})
    runs = pd.DataFrame({"run": ["r3000_m20", "r4600_m20"], "rpm": [3000.0, 4600.0], "eccentric_mass_g": [20.0, 20.0]})
    dense = rp.dense_response(variant, joint, runs, rp.dense_speeds(runs["rpm"], 11), harmonics=1)
    assert rp.channels_of(dense) == ["x1", "y1", "x2", "y2"]
    first = dense[dense["harmonic"] == 1]
    expected = np.array([linear_response(machine, r.rpm, 1e-3 * r.eccentric_mass_g, k={"a": K_A})
                         for r in first.itertuples()])
    scale = np.abs(expected).max()
    for channel, dof in (("x1", "u8"), ("y1", "v8"), ("x2", "u16"), ("y2", "v16")):
        np.testing.assert_allclose(first[f"{channel}_re_m"] + 1j * first[f"{channel}_im_m"],
                                   expected[:, machine.dof(dof)], atol=1e-9 * scale)
    comparisons = [RunComparison(r.run, "fit", r.rpm, 20.0, np.ones((1, 4)) * 1e-5, np.ones((1, 4)) * 1e-5,
                                 np.full((1, 4), 1e-7), 8.0, "solver", ("x1", "y1", "x2", "y2"))
                   for r in runs.itertuples()]
    fig = rp.plot_bode(dense, comparisons, "linear", orders=(1,))
    amplitude_panels = fig.axes[0::2]
    assert len(fig.axes) == 8 and [ax.get_title() for ax in amplitude_panels] == ["1X, x1", "1X, y1", "1X, x2",
                                                                                   "1X, y2"]
    for ax in amplitude_panels:
        assert len([line for line in ax.get_lines() if len(line.get_xdata()) == 11]) == 2  # run-up, run-down
    matplotlib.pyplot.close(fig)
    fig = rp.plot_polar(dense, comparisons, "linear", orders=(1,))
    assert len(fig.axes) == 4
    matplotlib.pyplot.close(fig)


def test_a_trial_mass_at_an_angle_gets_its_own_curve_turned_by_that_angle(tmp_path):
    """Trial weights at chosen angles (the runs sheet's eccentric_mass_angle_deg): runs of the same 10 g at 0 and
    120 degrees get a curve each. On a linear rotor whose only forcing is the unbalance the response is linear in
    the force m_e r_me Omega^2 exp(i angle_me) (1, -i), so the 120-degree curve is the 0-degree one times
    exp(i 2 pi / 3) at every speed, both sweeps and both channels (superposition: the harmonic balance of a linear
    system is one exact solve, round-off only: 1e-9 of the largest amplitude), while the 0-degree curve is still the
    response solved by hand (tests/example_machines.linear_response). The Bode figure names each trial and draws
    each measured run on its own trial's colour; the comparison table carries the angle back and forth."""
    from hybridtwin.report.report import load_comparisons, write_comparisons

    machine, variant, joint = _fitted_linear()
    runs = pd.DataFrame({"run": ["a0", "a120", "b120"], "rpm": [3000.0, 3900.0, 4600.0],
                         "eccentric_mass_g": [10.0, 10.0, 10.0], "eccentric_mass_angle_deg": [0.0, 120.0, -240.0]})
    assert rp.trials_of(runs) == [(10.0, 0.0), (10.0, 120.0)]  # -240 is 120
    dense = rp.dense_response(variant, joint, runs, rp.dense_speeds(runs["rpm"], 21), harmonics=1)
    at = {angle: part.sort_values(["sweep", "rpm"]) for angle, part in dense.groupby("eccentric_mass_angle_deg")}
    assert set(at) == {0.0, 120.0}
    turn = np.exp(2j * np.pi / 3)
    for channel in ("x1", "y1"):
        zero = (at[0.0][f"{channel}_re_m"] + 1j * at[0.0][f"{channel}_im_m"]).to_numpy()
        turned = (at[120.0][f"{channel}_re_m"] + 1j * at[120.0][f"{channel}_im_m"]).to_numpy()
        np.testing.assert_allclose(turned, turn * zero, atol=1e-9 * np.abs(zero).max())
    first = at[0.0]
    expected = np.array([linear_response(machine, r.rpm, 1e-2, k={"a": K_A}, c={"b": C_B})[machine.dof(f"u{SENSOR_NODE}")]
                         for r in first.itertuples()])
    np.testing.assert_allclose(first["x1_re_m"] + 1j * first["x1_im_m"], expected, atol=1e-9 * np.abs(expected).max())
    rp.write_dense(dense, tmp_path / "response.tsv")
    pd.testing.assert_frame_equal(rp.read_dense(tmp_path / "response.tsv"), dense, check_dtype=False)

    comparisons = []
    for r in runs.itertuples():
        row = dense[(dense["eccentric_mass_angle_deg"] == np.mod(r.eccentric_mass_angle_deg, 360))
                    & (dense["sweep"] == "run-up")].iloc[0]
        z = np.array([[row["x1_re_m"] + 1j * row["x1_im_m"], row["y1_re_m"] + 1j * row["y1_im_m"]]])
        comparisons.append(RunComparison(r.run, "fit", r.rpm, r.eccentric_mass_g, z, z, np.full((1, 2), 1e-7), 4.0,
                                         "solver", ("x1", "y1"), r.eccentric_mass_angle_deg))
    write_comparisons(comparisons, tmp_path / "harmonics.tsv")
    assert [c.eccentric_mass_angle_deg for c in load_comparisons(tmp_path / "harmonics.tsv")] == [0.0, 120.0, -240.0]
    fig = rp.plot_bode(dense, comparisons, "angles", orders=(1,))
    amplitude = fig.axes[0]
    labels = {line.get_label(): line.get_color() for line in amplitude.get_lines()}
    assert {"10 g model, run-up", "10 g at 120 deg model, run-up"} <= set(labels)
    points = {c.get_label(): c.lines[0].get_color() for c in amplitude.containers}
    assert points["10 g at 120 deg measured"] == labels["10 g at 120 deg model, run-up"]
    assert points["10 g measured"] == labels["10 g model, run-up"] != labels["10 g at 120 deg model, run-up"]
    matplotlib.pyplot.close(fig)
