"""The machine before any data (issue 39, item 1): `hybridtwin campbell`, `modes` and `response` against closed forms
of a one-mode (Jeffcott) rotor, their tables read back exactly, their errors; and `simulate`'s defects of item 5
(every probe plane, an unstable solution shown, no phase for a zero harmonic, the runs sheet's mass guard), each
test failing on the code before. At the end, the three commands on the overhung example rotor and tests/test_ross.py's
stepped rotor (shear on) against ROSS (issue 39's done-when; skipped where ROSS cannot be imported).

The one-mode rotor: a disk of 10 kg at the middle of a short, very stiff shaft (EI = 2e7 N m^2, 1 kg/m) on two
equal bearings (k = 5e4 N/m, c = 20 N s/m each), unbalance and probes at the disk. Its translation is the one mode
the unbalance excites (the tilt mode is not: symmetric); m = 10 + 0.4 kg (disk and the whole shaft, which
translates rigidly), k = 1e5 N/m, c = 40 N s/m: omega_n = sqrt(k / m), zeta = c / (2 sqrt(k m)) = 0.0196. The shaft's
own flexibility, ignored by the closed forms, is k / (48 EI / L^3) = 6.7e-6 of the bearings' and shifts the
frequencies by half that (3.3e-6): the tolerances below are set from it and from the sweep's resolution, each
where it is used.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy.optimize import brentq

from hybridtwin.cli import main
from hybridtwin.cli.machine import read_table, write_table
from hybridtwin.report import machine_plots as mp
from hybridtwin.report import machine_response as mr
from hybridtwin.report.response_plots import read_dense

JEFFCOTT = """\
machine:
  name: jeffcott
  segments:
    - {length: 0.4, d_out: 0.05, E: 2.0e+11, rho: 7800, n_elements: 2, I: 1.0e-4, m: 1.0}
  disks: [{node: 1, mass: 10.0, I_p: 0.0, I_d: 0.1, name: disk}]
  bearings: {a: {node: 0, k: 5.0e+4, c: 20.0}, b: {node: 2, k: 5.0e+4, c: 20.0}}
  unbalance_planes: {disk: 1}
  sensors: {x1: {node: 1, direction: x}, y1: {node: 1, direction: y}}
variants:
  linear:
    effects: [linear_bearing@a, linear_bearing@b, unbalance@disk]
"""
K, C, MASS, R_ME = 1e5, 40.0, 10.0 + 0.4 * 1.0, 0.04  # N/m, N s/m, kg (disk + shaft), m (the default r_me)


def _closed(m_e: float = 0.0):
    """omega_n [rad/s] and zeta of the one-mode rotor with the eccentric mass m_e [kg] (a point mass of the model)."""
    m = MASS + m_e
    return np.sqrt(K / m), C / (2 * np.sqrt(K * m))


def _rpm(omega: float) -> float:
    return omega * 60 / (2 * np.pi)


@pytest.fixture
def jeffcott(tmp_path):
    path = tmp_path / "jeffcott.yaml"
    path.write_text(JEFFCOTT)
    return path


def _run(capsys, *args):
    code = main(list(map(str, args)))
    out, err = capsys.readouterr()
    return code, out, err


# --- closed forms -----------------------------------------------------------------------------------------------


def test_log_decrement_is_the_closed_form():
    zeta = np.array([0.0, 0.02, 0.3, -0.01, 1.0])
    expected = 2 * np.pi * zeta[:4] / np.sqrt(1 - zeta[:4] ** 2)
    np.testing.assert_allclose(mp.log_decrement(zeta)[:4], expected, rtol=1e-15)
    assert mp.log_decrement(zeta)[3] < 0 and np.isinf(mp.log_decrement(zeta)[4])
    # the free vibration exp(-zeta w_n t) cos(w_d t): the ratio of two peaks one period 2 pi / w_d apart
    z = 0.05
    assert mp.log_decrement(z) == pytest.approx(z * 2 * np.pi / np.sqrt(1 - z**2), rel=1e-15)


def test_campbell_of_the_one_mode_rotor(capsys, jeffcott, tmp_path):
    """The 1X crossing is where the damped frequency w_n sqrt(1 - zeta^2) (constant with speed: no gyroscopic
    coupling, isotropic) equals the speed: exact by the linear interpolation of a constant; its damping ratio and log
    decrement are the closed forms. Tolerance 2e-5: the shaft's flexibility (3.3e-6, module docstring) with margin."""
    out = tmp_path / "campbell"
    code, stdout, err = _run(capsys, "campbell", "--config", jeffcott, "--rpm", 0, 2500, "--operating-range", 1200,
                             1500, "--out", out)
    assert code == 0, err
    omega, zeta = _closed()
    critical = read_table(out / "critical_speeds.tsv")
    first = critical[critical["rpm"] < 1500]
    assert sorted(first["whirl"]) == ["backward", "forward"]  # a planar mode: both senses cross together
    np.testing.assert_allclose(first["rpm"], _rpm(omega * np.sqrt(1 - zeta**2)), rtol=2e-5)
    np.testing.assert_allclose(first["damping_ratio"], zeta, rtol=2e-5)
    np.testing.assert_allclose(first["log_decrement"], 2 * np.pi * zeta / np.sqrt(1 - zeta**2), rtol=2e-5)
    # the separation margin from the operating range above it: (N_min - N_c) / N_c
    np.testing.assert_allclose(first["separation_margin_pct"], 100 * (1200 - first["rpm"]) / first["rpm"],
                               rtol=1e-12)
    table = read_table(out / "campbell.tsv")
    assert {"rpm", "frequency_hz", "damping_ratio", "log_decrement", "whirl", "branch"} <= set(table.columns)
    np.testing.assert_allclose(table["log_decrement"], mp.log_decrement(table["damping_ratio"]), rtol=1e-15)
    assert (out / "campbell.png").stat().st_size > 10_000
    assert "backward" in stdout and "log_decrement" in stdout


def _exact_half_power(m_e: float) -> tuple[float, float, float]:
    """Peak speed [RPM], peak amplitude [m] and half-power amplification factor of the one-mode unbalance response
    |X| = m_e r W^2 / |k - m W^2 + i c W| (m with m_e), from the closed form itself (root finding to 1e-12)."""
    m = MASS + m_e

    def amplitude(w):
        return m_e * R_ME * w**2 / np.hypot(K - m * w**2, C * w)

    omega, zeta = _closed(m_e)
    top = omega / np.sqrt(1 - 2 * zeta**2)  # where d|X|/dW = 0
    level = amplitude(top) / np.sqrt(2)
    low = brentq(lambda w: amplitude(w) - level, 0.5 * omega, top, xtol=1e-12)
    high = brentq(lambda w: amplitude(w) - level, top, 2 * omega, xtol=1e-12)
    return _rpm(top), amplitude(top), top / (high - low)


def test_response_amplification_factor_is_the_half_power_closed_form(capsys, jeffcott, tmp_path):
    """The computed response's resonance (run-up and run-down alike: linear) against the closed form: the peak
    speed w_n / sqrt(1 - 2 zeta^2) and height to 1e-4 (the shaft's flexibility 3.3e-6 and the parabola through
    grid points zeta N_c / 10 apart: ~2e-6 measured); the half-power amplification factor to 1e-3 of the closed
    form's own half-power AF (the ends interpolated from points 1/20 of the band apart: 5e-5 measured), and to 1 %
    of 1 / (2 zeta) (they differ by ~4 zeta^2 = 1.6e-3)."""
    m_e = 1e-3
    out = tmp_path / "response"
    code, stdout, err = _run(capsys, "response", "--config", jeffcott, "--rpm", 300, 2000, "--eccentric-mass-g",
                             m_e * 1e3, "--operating-range", 1200, 1500, "--out", out)
    assert code == 0, err
    peaks = read_table(out / "peaks.tsv")
    assert sorted(peaks["sweep"]) == ["run-down"] * 2 + ["run-up"] * 2  # one peak per probe and sweep
    rpm, height, af = _exact_half_power(m_e)
    np.testing.assert_allclose(peaks["rpm_peak"], rpm, rtol=1e-4)
    np.testing.assert_allclose(peaks["amplitude_0pk_m"], height, rtol=1e-4)
    np.testing.assert_allclose(peaks["amplification_factor"], af, rtol=1e-3)
    _, zeta = _closed(m_e)
    np.testing.assert_allclose(peaks["amplification_factor"], 1 / (2 * zeta), rtol=1e-2)
    assert (peaks["stable"] == True).all()  # noqa: E712
    # below the operating range by (1200 - N_c) / N_c = 26 %: API 617 asks min(16, 17 (1 - 1/(AF - 1.5))) = 16 %
    np.testing.assert_allclose(peaks["separation_margin_pct"], 100 * (1200 - peaks["rpm_peak"]) / peaks["rpm_peak"])
    assert (peaks["required_margin_pct"] == 16.0).all() and peaks["meets"].all()
    # the response table: the run-up and run-down at every probe, read back by the report's reader
    table = read_dense(out / "response.tsv")
    assert set(table["sweep"]) == {"run-up", "run-down"} and {"x1_re_m", "y1_im_m"} <= set(table.columns)
    up = table[table["sweep"] == "run-up"]
    x = np.abs(up["x1_re_m"] + 1j * up["x1_im_m"]).to_numpy()
    w = up["rpm"].to_numpy() * 2 * np.pi / 60
    closed = m_e * R_ME * w**2 / np.hypot(K - (MASS + m_e) * w**2, C * w)
    np.testing.assert_allclose(x, closed, rtol=1e-4)  # the flexibility's 3.3e-6 of the frequency, near the peak
    for name in ("bode.png", "polar.png"):
        assert (out / name).stat().st_size > 10_000
    assert "amplification_factor" in stdout and "x1" in stdout


def test_a_critical_speed_inside_the_operating_range_fails_its_margin(capsys, jeffcott, tmp_path):
    code, _, err = _run(capsys, "response", "--config", jeffcott, "--rpm", 300, 2000, "--eccentric-mass-g", 1,
                        "--operating-range", 900, 1000, "--out", tmp_path)
    assert code == 0, err
    peaks = read_table(tmp_path / "peaks.tsv")
    assert (peaks["separation_margin_pct"] < 0).all() and not peaks["meets"].any()


def test_separation_margin_and_required_margin():
    assert mr.separation_margin(800.0, (1000.0, 2000.0)) == pytest.approx(25.0)  # (1000 - 800) / 800
    assert mr.separation_margin(2500.0, (1000.0, 2000.0)) == pytest.approx(25.0)  # (2500 - 2000) / 2000
    assert mr.separation_margin(1100.0, (1000.0, 2000.0)) == pytest.approx(-100 / 11)
    assert mr.required_margin(2.4, above=False) == 0.0  # critically damped: none required
    assert mr.required_margin(3.0, above=False) == pytest.approx(17 * (1 - 1 / 1.5))
    assert mr.required_margin(3.0, above=True) == pytest.approx(10 + 17 * (1 - 1 / 1.5))
    assert mr.required_margin(50.0, above=False) == 16.0 and mr.required_margin(50.0, above=True) == 26.0
    assert mr.amplification_factor(1000.0, 950.0, 1050.0) == pytest.approx(10.0)
    assert np.isnan(mr.amplification_factor(1000.0, np.nan, 1050.0))


def test_peaks_of_a_curve_skip_shoulders_and_report_missing_half_power_points():
    rpm = np.linspace(0.0, 100.0, 1001)
    lorentz = 1 / np.sqrt(1 + ((rpm - 40) / 2) ** 2)  # half-power points at 38 and 42
    rising = 0.01 * rpm + 1e-5 * np.exp(-((rpm - 70) / 0.5) ** 2)  # a bump of 1e-5 on a slope: no resonance
    (top, height, low, high), = mr.peaks_of(rpm, lorentz + rising * 0)
    assert (top, height) == pytest.approx((40.0, 1.0)) and (low, high) == pytest.approx((38.0, 42.0), abs=1e-4)
    assert mr.peaks_of(rpm, rising) == []
    edge = 1 / np.sqrt(1 + ((rpm - 99) / 5) ** 2)  # the sweep ends before the high half-power point
    (_, _, low, high), = mr.peaks_of(rpm, edge)
    assert low == pytest.approx(94.0, abs=1e-3) and np.isnan(high)


def test_tables_read_back_exactly(tmp_path):
    from hybridtwin.model.machine import Machine
    from hybridtwin.model.model import Model, campbell

    machine = Machine.from_mapping(yaml.safe_load(JEFFCOTT)["machine"])
    effects = machine.effects()
    model = Model([effects["linear_bearing@a"], effects["linear_bearing@b"], effects["unbalance@disk"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 1e-3}
    table = mp.branches(campbell(model, values, np.linspace(0, 2500, 7), 4))
    peaks = mr.separation_margins(mr.amplification_factors(mr.unbalance_response(model, values, (500, 1500),
                                                                                 n_speeds=21)), (1200, 1500))
    modes = mp.undamped_modes(model, values, 0.0, 4).table()
    for name, frame in (("campbell", table.reset_index(drop=True)), ("peaks", peaks), ("modes", modes)):
        write_table(frame, tmp_path / f"{name}.tsv")
        back = read_table(tmp_path / f"{name}.tsv")
        pd.testing.assert_frame_equal(back, frame, check_exact=True)


def test_campbell_figure_draws_the_log_decrement():
    from hybridtwin.model.machine import Machine
    from hybridtwin.model.model import Model

    machine = Machine.from_mapping(yaml.safe_load(JEFFCOTT)["machine"])
    effects = machine.effects()
    model = Model([effects["linear_bearing@a"], effects["linear_bearing@b"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()}
    fig = mp.campbell_figure(model, values, np.linspace(0, 2500, 11), n_modes=2, operating=(1200, 1500))
    damping = fig.axes[1]
    lines = {line.get_gid(): line for line in damping.get_lines()}
    branch = fig.campbell[(fig.campbell.whirl == "forward") & (fig.campbell.branch == 0)].sort_values("rpm")
    np.testing.assert_array_equal(lines["log_decrement:forward:0"].get_ydata(), branch.log_decrement)
    assert "stability limit" in lines
    assert any(p.get_gid() == "operating" for p in fig.axes[0].patches)
    mp.plt.close(fig)


def test_modes_of_the_one_mode_rotor(capsys, jeffcott, tmp_path):
    """Undamped: the translation at sqrt(k / m) (x and y planes alike), the tilt at sqrt(k (L/2)^2 2 / I_d) with
    I_d = 0.1 plus the shaft's own (negligible, 0.1 kg/m: 1.3e-3 kg m^2... of the disk's 0.1: see the tolerance)."""
    code, stdout, err = _run(capsys, "modes", "--config", jeffcott, "--out", tmp_path, "--modes", 2)
    assert code == 0, err
    modes = read_table(tmp_path / "modes.tsv")
    omega, _ = _closed()
    assert modes["frequency_hz"].iloc[0] == pytest.approx(omega / (2 * np.pi), rel=2e-5)
    assert modes["pair"].iloc[0]
    shapes = read_table(tmp_path / "mode_shapes.tsv")
    assert list(shapes.columns) == ["z_m", "mode_1", "mode_2"]
    np.testing.assert_allclose(shapes["mode_1"], 1.0, atol=1e-5)  # the translation: flat along the shaft
    assert shapes["mode_2"].iloc[0] == pytest.approx(-shapes["mode_2"].iloc[-1])  # the tilt: a node in the middle
    assert (tmp_path / "mode_shapes.png").stat().st_size > 10_000


@pytest.mark.parametrize("args, message", [
    (["campbell"], "give the speeds: --rpm LOW HIGH, or --operating-range MIN MAX"),
    (["campbell", "--rpm", "900", "300"], "--rpm 900 300: HIGH must be above LOW"),
    (["campbell", "--operating-range", "900", "300"], "--operating-range 900 300: MIN above MAX"),
    (["response", "--rpm", "300", "900", "--eccentric-mass-g", "0.0148"], "0.0148 g looks like kilograms (14.8 g?)"),
    (["response", "--rpm", "300", "900", "--eccentric-mass-g", "5", "--variant", "nope"], "unknown variant 'nope'"),
    (["modes", "--set", "k_a=-1"], "outside its physical limits"),
])
def test_machine_commands_refuse_bad_input_in_one_line(capsys, jeffcott, tmp_path, args, message):
    code, out, err = _run(capsys, *args, "--config", jeffcott, "--out", tmp_path / "out")
    assert code == 2 and out == ""
    lines = [line for line in err.strip().splitlines() if not line.startswith("#")]
    assert len(lines) == 1 and message in lines[0], err


def _project(tmp_path: Path, sheet: str) -> Path:
    """A project folder as the workflow lays it out: config/config.yaml (the one-mode rotor, ``runs: runs.tsv``)
    and the runs sheet beside config/ (its records need not exist for the machine commands)."""
    project = tmp_path / "project"
    (project / "config").mkdir(parents=True)
    (project / "config" / "config.yaml").write_text(JEFFCOTT + "runs: runs.tsv\n")
    (project / "runs.tsv").write_text(sheet)
    return project


def test_campbell_takes_its_speeds_from_the_runs_sheet_and_writes_under_results(capsys, tmp_path, monkeypatch):
    """Issue 55: without --rpm and --out, the speeds are 0 to 1.25 times the sheet's fastest run (the report's
    Campbell diagram's: a run-up's end counts), the files land in <project>/results/machine/<variant>/, whatever
    the current folder."""
    project = _project(tmp_path, "run\trpm\teccentric_mass_g\tpath\tkind\trpm_start\trpm_end\n"
                                 "r1\t600\t10\tr1.csv\tsteady\t\t\n"
                                 "up\t\t10\tup.csv\trunup\t300\t1400\n")
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, "campbell", "--config", project / "config" / "config.yaml", "--speeds", 11)
    assert code == 0, err
    out = project / "results" / "machine" / "linear"
    table = read_table(out / "campbell.tsv")
    np.testing.assert_allclose(np.unique(table["rpm"]), np.linspace(0.0, 1.25 * 1400.0, 11), rtol=1e-12)
    assert (out / "critical_speeds.tsv").exists() and (out / "campbell.png").exists()
    assert "runs sheet" in err and str(project / "runs.tsv") in err


def test_a_runs_sheet_that_cannot_be_read_is_named(capsys, tmp_path):
    project = _project(tmp_path, "run\tspeed\n")
    code, out, err = _run(capsys, "campbell", "--config", project / "config" / "config.yaml")
    lines = [line for line in err.strip().splitlines() if not line.startswith("#")]
    assert code == 2 and out == "" and len(lines) == 1, err
    assert "runs: runs.tsv" in lines[0] and "rpm" in lines[0]
    assert not (project / "results").exists()


def test_machine_commands_refuse_an_out_that_is_a_file_and_need_the_mass(capsys, jeffcott, tmp_path):
    (tmp_path / "file").write_text("")
    code, _, err = _run(capsys, "modes", "--config", jeffcott, "--out", tmp_path / "file")
    assert code == 2 and "is a file, not a folder" in err
    with pytest.raises(SystemExit) as stop:
        main(["response", "--config", str(jeffcott), "--rpm", "300", "900", "--out", str(tmp_path)])
    assert stop.value.code == 2 and "--eccentric-mass-g" in capsys.readouterr().err


def test_response_of_the_varm_marks_its_unstable_stretch(capsys, tmp_path):
    """The VARM's Geometric model at nominal values and 14.8 g: no stable steady state near 900 RPM (the bundled
    runs' simulate defect, below), drawn dotted and said; the peak's stability is in peaks.tsv."""
    code, _, err = _run(capsys, "response", "--config", Path(__file__).resolve().parents[1] / "config" / "config.yaml",
                        "--rpm", 700, 1100, "--speeds", 41, "--eccentric-mass-g", 14.8, "--out", tmp_path)
    assert code == 0, err
    assert "unstable stretches" in err
    table = read_dense(tmp_path / "response.tsv")
    assert set(table["harmonic"]) == {1, 2, 3}  # a nonlinear model: 3 harmonics by default
    assert (table["stable"] == False).any() and (table["stable"] == True).any()  # noqa: E712
    peaks = read_table(tmp_path / "peaks.tsv")
    assert len(peaks) and set(peaks["channel"]) == {"x", "y"}


@pytest.mark.parametrize("shear", [False, True])
def test_log_decrement_matches_ross(shear):
    """ROSS's log decrements of the stepped rotor of tests/test_ross.py (its own assembly and eigensolver), mode by
    mode, to its tolerance (1e-6: the same beam theory and mesh, round-off only), Euler-Bernoulli and Timoshenko
    (shear and rotary inertia on)."""
    pytest.importorskip("ross")
    import ross as rs

    from test_ross import RTOL, _ours, _ross
    from hybridtwin.model.model import campbell

    _, model, values = _ours(shear, shear)
    rotor = _ross(rs, shear, shear)
    for speed in (0.0, 500.0):  # rad/s
        table = mp.branches(campbell(model, values, [speed * 60 / (2 * np.pi)], n_modes=8)).sort_values("mode")
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        lateral = np.array([w is not None and w != "None" for w in modal.whirl_direction()])
        np.testing.assert_allclose(table["log_decrement"].to_numpy(), modal.log_dec[lateral][:8], rtol=RTOL,
                                   atol=1e-9)


# --- simulate (item 5) ------------------------------------------------------------------------------------------

def _stepped_two_planes(tmp_path) -> Path:
    from example_machines import STEPPED_YAML

    config = yaml.safe_load(STEPPED_YAML)
    config["machine"]["sensors"] |= {"x2": {"node": 16, "direction": "x"}, "y2": {"node": 16, "direction": "y"}}
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_simulate_reaches_every_probe_plane(capsys, tmp_path):
    """--plane all: every probe's harmonics (the hand-solved linear response at both planes); --plane 16 and
    --plane x2: the second plane's pair in the first's columns."""
    from example_machines import linear_response, stepped_machine

    config = _stepped_two_planes(tmp_path)
    base = ["simulate", "--config", config, "--variant", "linear", "--rpm", 2000, "--eccentric-mass-g", 20,
            "--harmonics", 1]
    code, out, err = _run(capsys, *base, "--plane", "all")
    assert code == 0, err
    table = pd.read_csv(io.StringIO(out))
    assert list(table.columns) == ["harmonic"] + [f"{p}_{part}_m" for p in ("x1", "y1", "x2", "y2")
                                                  for part in ("re", "im")]
    machine = stepped_machine()
    X = linear_response(machine, 2000.0, 0.02)
    for probe, dof in (("x1", "u8"), ("y1", "v8"), ("x2", "u16"), ("y2", "v16")):
        got = table[f"{probe}_re_m"][1] + 1j * table[f"{probe}_im_m"][1]
        # %.9e printed, solver to ~1e-12: 1e-8 relative
        assert got == pytest.approx(X[machine.dof(dof)], rel=1e-8, abs=1e-8 * abs(X).max())
    second = [pd.read_csv(io.StringIO(_run(capsys, *base, "--plane", plane)[1])) for plane in ("16", "x2")]
    pd.testing.assert_frame_equal(second[0], second[1])
    assert second[0]["u_re_m"][1] == table["x2_re_m"][1] and second[0]["v_im_m"][1] == table["y2_im_m"][1]
    code, out, err = _run(capsys, *base, "--plane", "all", "--polar")
    assert code == 0 and "x2_amplitude_0pk_um" in out.splitlines()[0]
    code, out, err = _run(capsys, *base, "--plane", "3")
    assert code == 2 and "node 3 has no x and y probe pair (pairs at node(s) 8, 16)" in err


@pytest.mark.parametrize("rpm, mass", [(950, 0.0), (900, 7.6)])  # two bundled runs' own points
def test_simulate_shows_an_unstable_solution_marked(capsys, rpm, mass):
    args = ["simulate", "--rpm", rpm, "--eccentric-mass-g", mass]
    code, out, err = _run(capsys, *args)
    assert code == 1 and out == "" and "unstable" in err and "--unstable prints it" in err
    code, out, err = _run(capsys, *args, "--unstable")
    assert code == 0, err
    table = pd.read_csv(io.StringIO(out))
    assert list(table.columns)[-2:] == ["stable", "floquet_radius"]
    assert not table["stable"].any() and (table["floquet_radius"] > 1).all()
    assert "UNSTABLE" in err and f"|mu| = {table['floquet_radius'][0]:.4g}" in err


def test_simulate_leaves_the_phase_of_a_zero_harmonic_blank(capsys):
    """The VARM's even harmonics vanish (its forces are odd in the deflection): amplitudes ~1e-16 um of round-off,
    whose phase means nothing and is left blank; the odd ones keep theirs."""
    code, out, err = _run(capsys, "simulate", "--rpm", 700, "--eccentric-mass-g", 14.8, "--polar")
    assert code == 0, err
    lines = out.splitlines()
    table = pd.read_csv(io.StringIO(out))
    for h in (0, 2, 4):
        assert lines[h + 1].split(",")[2] == "" and lines[h + 1].split(",")[4] == ""
        assert table["x_amplitude_0pk_um"][h] < 1e-9
    assert table[["x_phase_deg", "y_phase_deg"]].iloc[[1, 3, 5]].notna().all().all()


def test_simulate_refuses_a_mass_in_kilograms_as_the_runs_sheet_does(capsys, tmp_path):
    """The same check and words as the runs sheet's (``measurements.kg_looking``)."""
    from hybridtwin.data.measurements import DataError, read_runs

    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\tpath\nr1\t700\t0.0148\tr1.csv\n")
    with pytest.raises(DataError) as refused:
        read_runs(sheet, check_files=False)
    assert "0.0148 g looks like kilograms (14.8 g?)" in str(refused.value)
    code, out, err = _run(capsys, "simulate", "--rpm", 700, "--eccentric-mass-g", 0.0148)
    assert code == 2 and out == ""
    assert "--eccentric-mass-g 0.0148: 0.0148 g looks like kilograms (14.8 g?)" in err
    assert _run(capsys, "simulate", "--rpm", 700, "--eccentric-mass-g", 0.1)[0] == 0  # the sheet's smallest mass


# --- one's own machine without the VARM (item 4) ----------------------------------------------------------------


def _stepped_config(plane: bool = True, effects=None, **variant) -> dict:
    from example_machines import STEPPED_YAML

    config = yaml.safe_load(STEPPED_YAML)
    if not plane:
        del config["machine"]["unbalance_planes"]
    config["variants"]["linear"] = {"effects": effects or ["linear_bearing@a", "linear_bearing@b", "unbalance"],
                                    **variant}
    return config


def test_the_plain_unbalance_sits_on_the_machine_not_at_the_varms_place():
    """On a machine of one's own the built-in `unbalance` ranges over its length (1.0 m here, not the VARM's 0-0.85)
    and sits at its unbalance plane (node 8, z = 0.4 m), not at the VARM's 0.425 m; an overhung position is in range."""
    from hybridtwin import config as cfg

    variant = cfg.variant(_stepped_config(), "linear")
    z_me = variant.model.parameters["z_me"]
    assert z_me.bounds == (0.0, 1.0) and z_me.nominal == pytest.approx(0.4)
    assert float(variant.values()["z_me"]) == pytest.approx(0.4)
    overhung = cfg.variant(_stepped_config(fixed={"z_me": 0.95}), "linear")
    assert z_me.bounds[0] <= float(overhung.values()["z_me"]) <= z_me.bounds[1]
    # the VARM's rotor with probes of its own (the run-up example's, rotated) keeps the VARM's unbalance
    runup = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "runup" / "config" /
                            "config.yaml").read_text())
    varm = cfg.variant(runup, next(iter(runup["variants"]))).model.parameters["z_me"]
    assert (varm.nominal, varm.bounds, varm.meaning) == (0.425, (0.0, 0.85), "axial position of the eccentric mass")


def test_the_plain_unbalance_without_a_plane_is_never_placed_silently(capsys, tmp_path):
    from hybridtwin import config as cfg

    with pytest.raises(ValueError, match=r"z_me has no nominal value on this machine.*fixed:.*unbalance_planes"):
        cfg.variant(_stepped_config(plane=False), "linear")
    given = cfg.variant(_stepped_config(plane=False, fixed={"z_me": 0.95}), "linear")
    assert float(given.values()["z_me"]) == 0.95
    unknown = cfg.variant(_stepped_config(plane=False, unknown={"z_me": [0.3, 0.9]}), "linear")
    assert float(unknown.values()["z_me"]) == pytest.approx(0.6)  # no nominal: the middle of its range
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(_stepped_config(plane=False)))
    code, out, err = _run(capsys, "simulate", "--config", path, "--rpm", 2000, "--eccentric-mass-g", 20)
    assert code == 2 and out == "" and "z_me has no nominal value" in err and len(err.strip().splitlines()) == 1


def test_a_missing_unbalance_plane_is_named_not_hinted_to_the_varms_unbalance(tmp_path):
    from hybridtwin import config as cfg
    from hybridtwin.model.machine import Machine
    from hybridtwin.model.variants import Variant

    config = _stepped_config(plane=False, effects=["linear_bearing@a", "linear_bearing@b", "unbalance@d1"])
    with pytest.raises(ValueError) as refused:
        Variant.from_spec("linear", config["variants"]["linear"], shaft=Machine.from_mapping(config["machine"]))
    message = str(refused.value)
    assert "no unbalance plane 'd1' (unbalance planes: none)" in message and "did you mean" not in message
    assert "unbalance_planes: {d1: NODE}" in message and "fixed: {z_me: METRES}" in message
    example = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "stepped_rotor" / "config" /
                              "config.yaml").read_text())
    del example["machine"]["unbalance_planes"]
    with pytest.raises(cfg.ConfigError) as problems:
        cfg.check(example, config_dir=tmp_path)
    found = [p for p in problems.value.problems if "variants.linear.effects" in p]
    assert found and "no unbalance plane 'd1'" in found[0] and "did you mean" not in found[0]


def test_effects_placed_at_ones_bearings_speak_of_them():
    """Parameters named after the bearing (f2_c_b, not the node's f2_c_13), no VARM words ("rubber bushing",
    "upper bearing"), and a nominal value that is the VARM's said to be so."""
    from example_machines import stepped_machine

    effects = stepped_machine().effects()
    assert [p.name for p in effects["excitation_2x@b"].parameters] == ["f2_c_b", "f2_s_b"]
    assert effects["excitation_2x@b"].switches == ("f2_c_b", "f2_s_b")
    for name in ("lower_bearing@a", "geometric_spring@b", "upper_housing@a"):
        effect = effects[name]
        words = effect.meaning + " ".join(p.meaning for p in effect.parameters)
        assert not any(w in words for w in ("rubber", "upper bearing", "lower bearing")), (name, words)
        assert all("the VARM's value" in p.meaning for p in effect.parameters if p.nominal), name
    # the VARM's own effects keep their words
    from hybridtwin.model.machine import Machine

    assert Machine.varm().effects()["lower_bearing@lower"].parameters[0].meaning == "lower bearing mass"


def test_from_spec_knows_the_machines_placed_effects():
    """docs/model.md's `Variant.from_spec(..., shaft=machine)` with the placed names of a config's variants."""
    from example_machines import LINEAR_EFFECTS, stepped_machine
    from hybridtwin.model.variants import Variant

    variant = Variant.from_spec("linear", {"effects": LINEAR_EFFECTS}, shaft=stepped_machine())
    assert [e.name for e in variant.model.effects] == LINEAR_EFFECTS


def test_summary_figure_keeps_long_variant_names_inside(tmp_path):
    """summary.png with long variant names (one's own, e.g. a recommended variant's): every label inside the
    figure once drawn, and the whole name readable (wrapped at '_', not cut)."""
    from hybridtwin.report import report, summary

    names = ["linear", "linear_bearing_anisotropy_at_b_with_cross_coupled_stiffness", "linear_plus_slope_force"]
    errors = {name: pd.DataFrame({"run": ["a", "b"], "rpm": [2000.0, 3000.0], "eccentric_mass_g": 20.0,
                                  "role": "fit", "source": "solver", "chi2": [10.0, 30.0], "dof": 10.0,
                                  "chi2_dof": [1.0, 3.0], "p_value": 0.5, "beyond_noise": [False, True],
                                  "error_pct": 1.0, "signal_m": 1e-5}) for name in names}
    ledger = report.ledger_table([report.ledger_row(name, "", {"n_data": 20, "dof": 18, "chi2": 36.0}, errors[name])
                                  for name in names])
    figure = summary.plot_summary(ledger, errors)
    figure.savefig(tmp_path / "summary.png", dpi=100)
    renderer = figure.canvas.get_renderer()
    box = figure.bbox
    for ax in figure.axes[:2]:
        for label in ax.get_xticklabels():
            extent = label.get_window_extent(renderer)
            assert box.x0 - 1 <= extent.x0 and extent.x1 <= box.x1 + 1, (label.get_text(), extent, box)
        shown = [label.get_text().replace("\n", "") for label in ax.get_xticklabels()]
        assert shown == names
    mp.plt.close(figure)


# --- the commands against ROSS (issue 39's done-when) -----------------------------------------------------------
#
# "The commands above give the overhung rotor's and the stepped rotor's Campbell, modes and response in seconds
# without data, equal to ROSS within 0.1 % (shear on) for frequencies and log decrements, tested." The commands run
# as a user runs them (``main``, tables to tmp_path, read back with ``read_table`` / ``read_dense``) on two machines
# with Timoshenko beams (shear and rotary inertia on), gyroscopic coupling and isotropic linear bearings:
#
# - "overhung": examples/stepped_rotor's machine (disk d2 overhung beyond bearing b, probes at d1 and d2), its
#   config as shipped with ``shear: true, rotary_inertia: true`` added;
# - "stepped": tests/test_ross.py's rotor (three solid sections, G given, node 19 overhung), as a config written here
#   from test_ross's numbers, probes at its two disks.
#
# ROSS's rotor is built by hand from the config's numbers (``_ross_rotor``: ROSS's ShaftElement per element, its
# Material from E, rho and G, or Poisson 0.3 where the config gives no G, as our default G = E / 2.6; not
# model/ross_io.machine_to_ross, which tests/test_ross_io.py checks only by round trip). ROSS assembles and solves its
# own matrices (6 DOFs per node). The two codes use the same beam theory (Timoshenko, Cowper's shear coefficient) on
# the same mesh, so they agree to round-off: observed (largest relative difference, both machines) 2.2e-12 on the
# frequencies, 1.1e-9 on the log decrements (small numbers, ~0.02-0.2: the eigensolver's round-off relative to
# |lambda|), 2.4e-11 on the mode shapes (of their largest 1), 1.7e-10 on the probes' complex 1X response. What the
# commands interpolate between their grid speeds differs by more, still far inside: the critical speeds (linear
# between Campbell speeds 67 RPM apart) 2.6e-7 and their log decrements 2.1e-6; the peaks (a parabola through
# three speeds) 8.8e-6 in speed, 1.2e-5 in height, the half-power points 7.6e-7, the amplification factors 4.5e-5.
# The tests hold every one to the 0.1 % (ROSS_RTOL): that is what the issue asks of the commands; a change of
# beam theory (shear off moves these machines' six lowest frequencies at 0-8000 RPM by 0.20-0.67 %) or a lost
# damping or gyroscopic term fails it.

ROSS_RTOL = 1e-3  # the 0.1 %: see the comment above


def _overhung_config() -> dict:
    config = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "stepped_rotor" / "config" /
                             "config.yaml").read_text())
    config["machine"] |= {"shear": True, "rotary_inertia": True}
    del config["runs"]  # a sheet relative to the example's folder; the commands need none
    return config


def _stepped_ross_config() -> dict:
    from test_ross import BEARINGS, DISKS, E, G, RHO, SEGMENTS

    machine = {
        "name": "stepped_ross", "shear": True, "rotary_inertia": True,
        "segments": [{"length": length, "d_out": d, "E": E, "rho": RHO, "G": G, "n_elements": n}
                     for length, d, n in SEGMENTS],
        "disks": [{"node": node, "mass": float(m), "I_p": float(I_p), "I_d": float(I_d)}
                  for node, m, I_p, I_d in DISKS],
        "bearings": {name: {"node": node, "k": k, "c": c} for name, node, k, c in BEARINGS},
        "unbalance_planes": {"disk": DISKS[0][0]},
        "sensors": {"x1": {"node": DISKS[0][0], "direction": "x"}, "y1": {"node": DISKS[0][0], "direction": "y"},
                    "x2": {"node": DISKS[1][0], "direction": "x"}, "y2": {"node": DISKS[1][0], "direction": "y"}}}
    effects = [f"linear_bearing@{name}" for name, *_ in BEARINGS] + ["gyroscopic", "unbalance@disk"]
    return {"machine": machine, "variants": {"linear": {"effects": effects}}}


#: machine: (config, response's speed range [RPM] through its first two pairs of critical speeds, mass [g])
ROSS_MACHINES = {"overhung": (_overhung_config, (1000, 8000), 20.0),
                 "stepped": (_stepped_ross_config, (1000, 7000), 2.0)}


@pytest.fixture(scope="module")
def ross_module():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pytest.importorskip("ross")


def _ross_rotor(rs, machine: dict, extra_mass: float = 0.0, damped: bool = True):
    """ROSS's rotor of a config's ``machine:`` section, built from its numbers: one ShaftElement per element (shear,
    rotary inertia and gyroscopic terms on), the disks (``extra_mass`` [kg] on the first unbalance plane's disk: our
    eccentric mass is a point mass of the model), the bearings (k, c; ``damped`` False: c = 0)."""
    shaft = []
    for i, s in enumerate(machine["segments"]):
        moduli = {"G_s": s["G"]} if "G" in s else {"Poisson": 0.3}
        material = rs.Material(name=f"segment_{i}", rho=s["rho"], E=s["E"], **moduli)
        n = s["n_elements"]
        shaft += [rs.ShaftElement(L=s["length"] / n, idl=s.get("d_in", 0.0), odl=s["d_out"], material=material,
                                  shear_effects=True, rotary_inertia=True, gyroscopic=True) for _ in range(n)]
    plane = next(iter(machine["unbalance_planes"].values()))
    disks = [rs.DiskElement(n=d["node"], m=d["mass"] + (extra_mass if d["node"] == plane else 0.0), Id=d["I_d"],
                            Ip=d["I_p"]) for d in machine["disks"]]
    bearings = [rs.BearingElement(n=b["node"], kxx=b["k"], cxx=b["c"] if damped else 0.0)
                for b in machine["bearings"].values()]
    return rs.Rotor(shaft, disks, bearings)


def _ross_modal(rotor, rpm: float):
    """ROSS's lateral modes at ``rpm``: (indices into its modes, wd [rad/s], log decrement, whirl lower case)."""
    modal = rotor.run_modal(rpm * np.pi / 30, num_modes=40, sparse=False)
    whirl = modal.whirl_direction()
    lateral = np.flatnonzero([w is not None and w != "None" for w in whirl])
    return modal, lateral, modal.wd[lateral], modal.log_dec[lateral], np.char.lower(whirl[lateral].astype(str))


def _config_file(tmp_path, machine: str) -> Path:
    path = tmp_path / f"{machine}.yaml"
    path.write_text(yaml.safe_dump(ROSS_MACHINES[machine][0](), sort_keys=False))
    return path


def _relative(ours, theirs) -> float:
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    return float(np.max(np.abs(ours - theirs) / np.abs(theirs)))


@pytest.mark.parametrize("machine", ROSS_MACHINES)
def test_campbell_command_matches_ross(capsys, tmp_path, ross_module, machine):
    """`hybridtwin campbell`'s campbell.tsv at five of its speeds: every mode's damped whirl frequency and log
    decrement the ROSS mode of its frequency's (each ROSS lateral mode used once), the whirl sense ROSS's (speed >
    0; at rest the pairs are degenerate); and critical_speeds.tsv's 1X crossings those of ROSS's branches (ROSS's
    run_modal solved for wd(N) = N by brentq), with their log decrement."""
    from scipy.optimize import brentq

    config = _config_file(tmp_path, machine)
    spec = yaml.safe_load(config.read_text())["machine"]
    code, _, err = _run(capsys, "campbell", "--config", config, "--rpm", 0, 8000, "--out", tmp_path)
    assert code == 0, err
    table = read_table(tmp_path / "campbell.tsv")
    rotor = _ross_rotor(ross_module, spec)
    speeds = sorted(set(table["rpm"]))
    errors = {"frequency": 0.0, "log_decrement": 0.0}
    for rpm in (speeds[0], speeds[20], speeds[55], speeds[90], speeds[-1]):
        _, _, wd, log_dec, whirl = _ross_modal(rotor, rpm)
        ours = table[table["rpm"] == rpm].sort_values("frequency_hz")
        assert len(ours) >= 6
        f = ours["frequency_hz"].to_numpy() * 2 * np.pi
        match = np.array([np.argmin(np.abs(wd - w)) for w in f])  # the ROSS mode nearest in frequency
        if rpm > 0:  # at rest the pairs are degenerate (two of ours at one frequency) and their sense arbitrary
            assert len(set(match)) == len(match), (rpm, match)  # one ROSS mode each
            assert list(whirl[match]) == list(ours["whirl"]), rpm
        errors["frequency"] = max(errors["frequency"], _relative(f, wd[match]))
        errors["log_decrement"] = max(errors["log_decrement"], _relative(ours["log_decrement"], log_dec[match]))
    print(f"\n{machine}: campbell vs ROSS, largest relative differences: {errors}")
    assert errors["frequency"] < ROSS_RTOL and errors["log_decrement"] < ROSS_RTOL, errors
    # the critical speeds: ROSS's branch of the same whirl and rank, its crossing of 1X found to 1e-10
    critical = read_table(tmp_path / "critical_speeds.tsv")
    assert len(critical) >= 4
    worst = {"rpm": 0.0, "log_decrement": 0.0}
    for row in critical.itertuples():
        def gap(rpm, row=row):
            _, _, wd, _, whirl = _ross_modal(rotor, rpm)
            return wd[whirl == row.whirl][row.branch] * 30 / np.pi - rpm

        rpm = brentq(gap, 0.97 * row.rpm, 1.03 * row.rpm, xtol=1e-10 * row.rpm)
        _, _, _, log_dec, whirl = _ross_modal(rotor, rpm)
        worst["rpm"] = max(worst["rpm"], _relative(row.rpm, rpm))
        worst["log_decrement"] = max(worst["log_decrement"],
                                     _relative(row.log_decrement, log_dec[whirl == row.whirl][row.branch]))
    print(f"{machine}: critical speeds vs ROSS's crossings, largest relative differences: {worst}")
    assert worst["rpm"] < ROSS_RTOL and worst["log_decrement"] < ROSS_RTOL, worst


@pytest.mark.parametrize("machine", ROSS_MACHINES)
def test_modes_command_matches_ross(capsys, tmp_path, ross_module, machine):
    """`hybridtwin modes --rpm 3000 --modes 6` (undamped, gyroscopic coupling kept) against ROSS's rotor with the
    bearings' damping set to 0 at the same speed: each mode's frequency and whirl, and its shape in mode_shapes.tsv
    (the whirl ellipse's semi-major axis along the shaft, signed, largest +1) against ROSS's own: the magnitude at
    every point ROSS draws (its Shape.major_axis, its own interpolation between the nodes: nodes and quarter
    points), the sign at the nodes from ROSS's nodal whirl (module docstring of machine_plots: + along the largest
    ellipse's deflection at the instant it peaks), both after scaling ROSS's shape to ours at its largest node."""
    config = _config_file(tmp_path, machine)
    spec = yaml.safe_load(config.read_text())["machine"]
    code, _, err = _run(capsys, "modes", "--config", config, "--rpm", 3000, "--modes", 6, "--out", tmp_path)
    assert code == 0, err
    modes, shapes = read_table(tmp_path / "modes.tsv"), read_table(tmp_path / "mode_shapes.tsv")
    assert len(modes) == 6 and not modes["pair"].any()  # at speed, the gyroscopic coupling splits every pair
    modal, lateral, wd, _, whirl = _ross_modal(_ross_rotor(ross_module, spec, damped=False), 3000.0)
    frequency = _relative(modes["frequency_hz"] * 2 * np.pi, wd[:6])
    assert frequency < ROSS_RTOL and list(modes["whirl"]) == list(whirl[:6]), (frequency, list(whirl[:6]))
    z = shapes["z_m"].to_numpy()
    worst = 0.0
    for k in range(6):
        shape = modal.shapes[lateral[k]]
        ours = shapes[f"mode_{k + 1}"].to_numpy()
        at = [int(np.argmin(np.abs(z - p))) for p in shape.zn]
        assert np.abs(z[at] - shape.zn).max() < 1e-12  # ROSS's points are among ours (12 per element)
        # the sign of each node's deflection: along or against the largest ellipse's at the instant it peaks
        U, V = (modal.modes[offset::modal.number_dof, lateral[k]] for offset in (0, 1))
        major = np.array([orbit.major_axis for orbit in shape.orbits])
        r = int(np.argmax(major))
        turn = np.exp(-0.5j * np.angle(U[r] ** 2 + V[r] ** 2))  # the instant (U_r, V_r) exp(i tau) is longest
        peak = np.array([(U[r] * turn).real, (V[r] * turn).real])
        sign = np.sign((U * turn).real * peak[0] + (V * turn).real * peak[1])
        nodes = [int(np.argmin(np.abs(z - p))) for p in shape.nodes_pos]
        theirs_nodes = sign * major / major[r]
        scale = ours[nodes][r]
        big = np.abs(theirs_nodes) > 1e-3  # a sign at a nodal point means nothing
        assert (np.sign(ours[nodes])[big] == sign[big]).all(), (k, ours[nodes], theirs_nodes)
        worst = max(worst, np.abs(np.abs(ours[at]) - scale * shape.major_axis / major[r]).max(),
                    np.abs(ours[nodes] - scale * theirs_nodes).max())
    print(f"\n{machine}: modes vs ROSS, frequencies {frequency:.2e}, shapes {worst:.2e} (of the largest 1)")
    assert worst < ROSS_RTOL, worst


@pytest.mark.parametrize("machine", ROSS_MACHINES)
def test_response_command_matches_ross(capsys, tmp_path, ross_module, machine):
    """`hybridtwin response` through the first two pairs of critical speeds: every probe's 1X (x1 .. y2, complex) at
    every speed of both sweeps of response.tsv against ROSS's run_unbalance_response (the unbalance m_e r_me at
    phase 0 on the unbalance plane's node; m_e, our model's point mass, on ROSS's disk there); and each resonance
    peak of peaks.tsv (its speed, height, half-power points, amplification factor) against ROSS's curve itself:
    its top by bounded minimisation and its half-power points by brentq, to 1e-10 of the speed."""
    from functools import lru_cache

    from scipy.optimize import brentq, minimize_scalar

    from hybridtwin import config as cfg

    config = _config_file(tmp_path, machine)
    spec = yaml.safe_load(config.read_text())
    (lo, hi), mass_g = ROSS_MACHINES[machine][1:]
    code, stdout, err = _run(capsys, "response", "--config", config, "--rpm", lo, hi, "--eccentric-mass-g", mass_g,
                             "--out", tmp_path)
    assert code == 0, err
    table = read_dense(tmp_path / "response.tsv")
    peaks = read_table(tmp_path / "peaks.tsv")
    values = cfg.variant(spec, "linear").values()
    m_e, r_me = mass_g * 1e-3, float(values["r_me"])
    assert float(values["angle_me"]) == 0.0
    rotor = _ross_rotor(ross_module, spec["machine"], extra_mass=m_e)
    plane = next(iter(spec["machine"]["unbalance_planes"].values()))
    dofs = {name: rotor.number_dof * s["node"] + (0 if s["direction"] == "x" else 1)
            for name, s in spec["machine"]["sensors"].items()}
    assert (table["harmonic"] == 1).all() and (table["stable"] == True).all()  # noqa: E712
    speeds = table["rpm"].to_numpy() * np.pi / 30
    theirs = rotor.run_unbalance_response(plane, m_e * r_me, 0.0, speeds).forced_resp
    response = 0.0
    for name, dof in dofs.items():
        ours = table[f"{name}_re_m"].to_numpy() + 1j * table[f"{name}_im_m"].to_numpy()
        response = max(response, _relative(ours, theirs[dof]))
    assert response < ROSS_RTOL, response

    @lru_cache(maxsize=None)
    def amplitudes(rpm: float) -> np.ndarray:
        return np.abs(rotor.run_unbalance_response(plane, m_e * r_me, 0.0, [rpm * np.pi / 30]).forced_resp[:, 0])

    worst = {"rpm_peak": 0.0, "amplitude_0pk_m": 0.0, "half_power": 0.0, "amplification_factor": 0.0}
    compared = 0
    for row in peaks[peaks["sweep"] == "run-up"].itertuples():
        dof = dofs[row.channel]
        width = 0.005 * row.rpm_peak  # ours is the top of a parabola through grid points: near ROSS's top
        top = minimize_scalar(lambda r, d=dof: -amplitudes(float(r))[d], bounds=(row.rpm_peak - width,
                              row.rpm_peak + width), method="bounded", options={"xatol": 1e-9 * row.rpm_peak})
        assert abs(top.x - row.rpm_peak) < 0.9 * width, (row, top.x)  # a local maximum of ROSS's curve, inside
        height = -top.fun
        worst["rpm_peak"] = max(worst["rpm_peak"], _relative(row.rpm_peak, top.x))
        worst["amplitude_0pk_m"] = max(worst["amplitude_0pk_m"], _relative(row.amplitude_0pk_m, height))
        if not np.isfinite(row.amplification_factor):
            continue
        level = height / np.sqrt(2)
        low, high = (brentq(lambda r, d=dof: amplitudes(float(r))[d] - level, a, b, xtol=1e-10 * row.rpm_peak)
                     for a, b in ((row.rpm_half_power_low - width, top.x), (top.x, row.rpm_half_power_high + width)))
        worst["half_power"] = max(worst["half_power"], _relative([row.rpm_half_power_low, row.rpm_half_power_high],
                                                                 [low, high]))
        worst["amplification_factor"] = max(worst["amplification_factor"],
                                             _relative(row.amplification_factor, top.x / (high - low)))
        compared += 1
    print(f"\n{machine}: response vs ROSS {response:.2e}; peaks (largest relative differences): {worst}; "
          f"{compared} amplification factors of {len(peaks[peaks['sweep'] == 'run-up'])} peaks")
    assert compared >= 2
    assert max(worst.values()) < ROSS_RTOL, worst
