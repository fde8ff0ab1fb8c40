"""hybridtwin simulate / effects / variants: output contract and clear errors."""

import argparse
import io
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridtwin.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]

PAPER_ARGS = ["--rpm", "700", "--eccentric-mass-g", "14.8", "--set", "k_b=2411.3", "--set", "zeta_s=0.024",
              "--set", "zeta_bup=0.016", "--set", "q_x=0.004", "--set", "q_y=0.006"]


def _run(capsys, *args):
    code = main(["simulate", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_prints_sensor_harmonics_csv(capsys):
    code, out, err = _run(capsys, *PAPER_ARGS, "--harmonics", "3")
    assert code == 0, err
    table = pd.read_csv(io.StringIO(out))
    assert list(table.columns) == ["harmonic", "u_re_m", "u_im_m", "v_re_m", "v_im_m"]
    assert table["harmonic"].tolist() == [0, 1, 2, 3]
    U1 = complex(table.u_re_m[1], table.u_im_m[1])
    V1 = complex(table.v_re_m[1], table.v_im_m[1])
    # below the resonance the 1X response follows the forcing: x in phase with cos (|arg U1| small),
    # y lagging x by about 90 degrees (forcing sin = cos delayed by a quarter turn)
    assert abs(np.angle(U1)) < np.pi / 4
    assert np.angle(V1 / U1) == pytest.approx(-np.pi / 2, abs=np.pi / 8)
    # a millimetre-scale 1X response (docs/model.md: sensors range +-14 mm) with a much smaller 3X
    assert 1e-4 < abs(U1) < 14e-3
    assert abs(complex(table.u_re_m[3], table.u_im_m[3])) < 0.05 * abs(U1)
    assert "converged" in err and "branch direct" in err


def test_time_series_is_the_fourier_series_of_the_harmonics(capsys, tmp_path):
    ts = tmp_path / "ts.csv"
    code, out, _ = _run(capsys, *PAPER_ARGS, "--time-series", str(ts), "--dt", "1e-3")
    assert code == 0
    harmonics = pd.read_csv(io.StringIO(out))
    series = pd.read_csv(ts)
    assert list(series.columns) == ["time_s", "x_m", "y_m"]
    Omega = 700 * 2 * np.pi / 60
    period = 2 * np.pi / Omega
    assert series.time_s.iloc[-1] < 2 * period <= series.time_s.iloc[-1] + 1e-3 + 1e-12
    h = harmonics.harmonic.to_numpy()
    phase = np.exp(1j * np.outer(series.time_s, h) * Omega)
    x = (phase @ (harmonics.u_re_m + 1j * harmonics.u_im_m).to_numpy()).real
    # both come from the same harmonics, written with 10 significant digits
    np.testing.assert_allclose(series.x_m, x, rtol=0, atol=1e-9 * np.abs(x).max())


def test_output_file_and_sweep_branch(capsys, tmp_path):
    out_file = tmp_path / "h.csv"
    code, out, err = _run(capsys, *PAPER_ARGS, "--output", str(out_file), "--sweep-from", "400")
    assert code == 0 and out == ""
    assert "branch run-up" in err
    direct = pd.read_csv(out_file)
    code, out, _ = _run(capsys, *PAPER_ARGS)
    # at 700 RPM the response is unique: run-up and direct solve agree to the solver tolerance
    np.testing.assert_allclose(direct.to_numpy(), pd.read_csv(io.StringIO(out)).to_numpy(), rtol=1e-8, atol=1e-15)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rpm", "700", "--set", "k_bb=2000"], "has no parameter(s) ['k_bb']"),
        (["--rpm", "700", "--set", "k_b"], "expected NAME=VALUE"),
        (["--rpm", "700", "--set", "k_b=abc"], "value of k_b is not a number"),
        (["--rpm", "-700"], "must be positive"),
        (["--rpm", "fast"], "not a number"),
        (["--rpm", "700", "--harmonics", "0"], "must be >= 1"),
        (["--rpm", "700", "--variant", "nope"], "unknown variant 'nope'"),
        (["--rpm", "700", "--eccentric-mass-g", "-1"], "must be >= 0"),
        (["--rpm", "700", "--eccentric-mass-g", "5", "--set", "m_e=0.005"], "give the eccentric mass once"),
        (["--rpm", "700", "--effects-file", "/nonexistent/effects.py"], "/nonexistent/effects.py does not exist"),
        (["--rpm", "700", "--config", "/nonexistent/config.yaml"], "/nonexistent/config.yaml does not exist"),
        (["--rpm", "700", "--set", "k_b=nan"], "value of k_b is not a finite number: 'nan'"),
        (["--rpm", "700", "--set", "k_b=inf"], "value of k_b is not a finite number: 'inf'"),
        (["--rpm", "700", "--set", "zeta_s=-inf"], "value of zeta_s is not a finite number: '-inf'"),
        (["--rpm", "nan"], "not a finite number: 'nan'"),
        (["--rpm", "700", "--eccentric-mass-g", "inf"], "not a finite number: 'inf'"),
        (["--rpm", "700", "--set", "m_bup=-0.05"], "--set m_bup=-0.05: a mass cannot be negative"),
        (["--rpm", "700", "--set", "m_e=-0.01"], "--set m_e=-0.01: a mass cannot be negative"),
        (["--rpm", "700", "--add-effect", "cross_coupled_stiffness", "--set", "k_xy=1e5"],
         "--set k_xy=100000: outside its physical limits [-2000, 2000] N/m"),
        (["--rpm", "700", "--output", "/nonexistent/h.csv"], "--output /nonexistent/h.csv: folder /nonexistent does "
                                                               "not exist"),
        (["--rpm", "700", "--time-series", "/nonexistent/t.csv"], "--time-series /nonexistent/t.csv: folder"),
        (["--rpm", "700", "--output", "/"], "--output /: is a folder, not a file"),
        (["--rpm", "700", "--time-series", "/tmp/t.csv", "--dt", "1e-9"], "raise --dt or lower --cycles"),
        (["--rpm", "700", "--add-effect", "slope_sprung"], "--add-effect slope_sprung: no such effect"),
        (["--rpm", "700", "--add-effect", "geometric_spring"], "variant 'geometric' has it already"),
    ],
)
def test_bad_arguments_exit_2_with_a_clear_message(capsys, args, message):
    try:
        code = main(["simulate", *args])
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert len(err.strip().splitlines()) == 1, err  # one line, no usage block, no traceback


def test_unwritable_output_is_one_line(capsys, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        can_write = os.access(locked, os.W_OK)  # root writes anywhere: then only the folder check applies
        code, out, err = _run(capsys, "--rpm", "700", "--output", str(locked / "h.csv"))
    finally:
        locked.chmod(0o700)
    if can_write:
        assert code == 0
    else:
        assert code == 2 and err.strip() == f"hybridtwin simulate: error: --output {locked / 'h.csv'}: not writable " \
                                            "(permission denied)"


ISSUE_22_ARGS = ["--rpm", "900", "--eccentric-mass-g", "14.8", "--set", "k_b=2000", "--set", "zeta_s=0.05",
                 "--set", "zeta_bup=0.03", "--set", "q_x=0.002", "--set", "q_y=0.004"]


def test_a_failed_direct_solve_falls_back_to_continuation(capsys):
    """Issue 22's point: Newton from the linear response does not converge at 900 RPM, yet one periodic steady
    state exists (time integration below); simulate reaches it by a run-up by itself and says so."""
    code, out, err = _run(capsys, *ISSUE_22_ARGS)
    assert code == 0, err
    assert "the direct solve failed (Newton did not converge" in err
    assert "reported: the steady state reached by continuation from 300 RPM (= --sweep-from 300; run-up)" in err
    assert "continuation from 1350 RPM (run-down) reaches the same steady state" in err
    assert "branch run-up:" in err and "converged" in err
    fallback = pd.read_csv(io.StringIO(out))
    code, out, _ = _run(capsys, *ISSUE_22_ARGS, "--sweep-from", "300")
    assert code == 0
    swept = pd.read_csv(io.StringIO(out)).to_numpy()
    # the same continuation (300 RPM, 25 RPM steps) either way: equal to the CSV's 10 significant digits
    # (issue 22 found the run-up within 2e-8 of the time-integrated steady state)
    np.testing.assert_allclose(fallback.to_numpy(), swept, rtol=0, atol=2e-8 * np.abs(swept).max())


@pytest.mark.slow
def test_the_fallbacks_steady_state_is_the_time_integrated_one(capsys):
    """Independent reference: eq. 29 integrated in time from rest (Radau, hybridtwin.solvers.transient, no harmonic
    balance) until its harmonics settle; about 40 periods, ~10 s."""
    from hybridtwin.solvers import transient
    from hybridtwin.model.sensor import sensor_dofs
    from hybridtwin.model.variants import builtin_variant

    code, out, err = _run(capsys, *ISSUE_22_ARGS)
    assert code == 0, err
    table = pd.read_csv(io.StringIO(out))
    hb = np.stack([table.u_re_m + 1j * table.u_im_m, table.v_re_m + 1j * table.v_im_m], axis=1)
    variant = builtin_variant("geometric")
    values = variant.values({"m_e": 0.0148, "k_b": 2000, "zeta_s": 0.05, "zeta_bup": 0.03, "q_x": 0.002,
                             "q_y": 0.004})
    settled = transient.settle(transient.FirstOrder.from_system(variant.model.system(values, 900.0)),
                               sensor_dofs(variant.model.shaft), harmonics=5)
    # settle stops when the harmonics change by < 1e-6 of the largest from one period to the next, twice; a
    # transient decaying by rho per period leaves up to 1 / (1 - rho) = ~5 times that at 900 RPM (its
    # docstring), plus Radau's error: measured 1.4e-6 relative, 1e-5 allowed (another branch differs at O(1))
    np.testing.assert_allclose(settled.harmonics, hb, rtol=0, atol=1e-5 * np.abs(hb).max())


def test_no_branch_reaching_the_point_exits_1_with_the_reason(capsys):
    # no lower-bearing stiffness: the structure is unstable at rest, no steady state at any speed, so the direct
    # solve and both continuations fail alike, said once
    code, out, err = _run(capsys, "--rpm", "700", "--set", "k=0")
    assert code == 1
    assert out == ""
    last = err.strip().splitlines()[-1]
    assert last.startswith("hybridtwin simulate: failed at 700 RPM: the structure at rest is unstable")
    assert last.endswith("(direct solve, run-up and run-down alike)")


def test_polar_output_is_the_0_peak_amplitude_and_phase_of_the_series(capsys, tmp_path):
    ts = tmp_path / "ts.csv"
    code, out, err = _run(capsys, *PAPER_ARGS, "--polar", "--time-series", str(ts), "--dt", "1e-4")
    assert code == 0, err
    polar = pd.read_csv(io.StringIO(out))
    assert list(polar.columns) == ["harmonic", "x_amplitude_0pk_um", "x_phase_deg", "y_amplitude_0pk_um",
                                   "y_phase_deg"]
    series = pd.read_csv(ts)  # written from the complex harmonics, not from the polar table
    Omega = 700 * 2 * np.pi / 60
    h, t = polar.harmonic.to_numpy(), series.time_s.to_numpy()
    for axis in ("x", "y"):
        # a zero harmonic's phase is blank (NaN): it adds nothing whatever its phase
        amplitude = polar[f"{axis}_amplitude_0pk_um"].to_numpy()
        phase = np.radians(polar[f"{axis}_phase_deg"].fillna(0.0))
        rebuilt = (amplitude * np.cos(np.outer(t, h) * Omega + phase.to_numpy())).sum(axis=1) * 1e-6
        # the table has 6 decimals: phases to 0.5e-6 degrees (8.7e-9 rad, times the amplitude) and amplitudes to
        # 0.5e-6 um per harmonic; the series 10 significant digits: 2e-8 of the largest displacement allowed
        largest = np.abs(series[f"{axis}_m"]).max()
        np.testing.assert_allclose(rebuilt, series[f"{axis}_m"], rtol=0, atol=2e-8 * largest)
    # 0-peak: the 1X amplitude is half the peak-to-peak of the 1X motion, i.e. about the orbit's half-width
    # here (3X and 5X are < 5 % of 1X, test_simulate_prints_sensor_harmonics_csv)
    half_width = 0.5 * (series.x_m.max() - series.x_m.min()) * 1e6
    assert polar.x_amplitude_0pk_um[1] == pytest.approx(half_width, rel=0.1)


def test_config_with_user_variant(capsys, tmp_path):
    (tmp_path / "my_effects.py").write_text(
        "from hybridtwin import Parameter, PolynomialBearing, Term\n"
        "tilt = PolynomialBearing(name='tilt', meaning='tilt stiffness',\n"
        "    parameters=(Parameter('k_t', 'N', (0.0, 500.0), 100.0, 'slope stiffness'),),\n"
        "    terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), \"k_t u'\"),))\n"
    )
    (tmp_path / "config.yaml").write_text(
        "effects_files: [my_effects.py]\n"
        "variants:\n"
        "  tilted:\n"
        "    effects: [centrifugal_softening, structural_damping, upper_housing, lower_bearing, unbalance,\n"
        "              shaft_bow, geometric_spring, tilt]\n"
        "    unknown: {k_t: [0, 500]}\n"
    )
    code, out, err = _run(capsys, "--config", str(tmp_path / "config.yaml"), "--variant", "tilted", "--rpm", "500")
    assert code == 0, err
    assert "k_t=100" in err  # the nominal value used is reported
    assert main(["variants", "--config", str(tmp_path / "config.yaml"), "--variant", "tilted"]) == 0
    assert "tilt: tilt stiffness" in capsys.readouterr().out


def test_console_script_is_installed():
    result = subprocess.run([sys.executable, "-m", "hybridtwin.cli", "effects"], capture_output=True, text=True)
    assert result.returncode == 0
    assert "geometric_spring" in result.stdout and "k_b [N/m]" in result.stdout


def _readme_effects_example() -> tuple[str, str]:
    """The guide's own effects file (docs/commands.md, moved there from the README: the python block defining a
    PolynomialBearing) and its command line."""
    readme = (ROOT / "docs" / "commands.md").read_text()
    code = next(block for block in re.findall(r"```python\n(.*?)```", readme, re.DOTALL) if "PolynomialBearing(" in block)
    command = re.search(r"`(hybridtwin simulate --effects-file my_effects\.py[^`]*)`", readme)
    assert command, "docs/commands.md: the command line using my_effects.py is gone"
    return code, command.group(1)


def test_readme_effects_example_runs(capsys, tmp_path, monkeypatch):
    code_text, command = _readme_effects_example()
    (tmp_path / "my_effects.py").write_text(code_text)
    monkeypatch.chdir(tmp_path)  # no config/config.yaml here: the built-in variants
    args = shlex.split(command)[1:]
    assert main(args) == 0
    out, err = capsys.readouterr()
    added = pd.read_csv(io.StringIO(out))
    assert "+" in err.split(" at ")[0]  # the variant reported with the effect added, e.g. geometric+tilt_spring
    # independent route to the same model: a config declaring the variant with the effect in its list
    effect = re.search(r"--add-effect (\S+)", command).group(1)
    (tmp_path / "config.yaml").write_text(
        "effects_files: [my_effects.py]\n"
        f"variants: {{tilted: {{effects: [centrifugal_softening, structural_damping, upper_housing, lower_bearing,"
        f" unbalance, shaft_bow, geometric_spring, {effect}]}}}}\n")
    rest = [a for a in args if a not in ("--add-effect", effect, "--effects-file", "my_effects.py")]
    assert main([*rest, "--config", "config.yaml", "--variant", "tilted"]) == 0
    declared = pd.read_csv(io.StringIO(capsys.readouterr().out))
    pd.testing.assert_frame_equal(added, declared)  # the same model, the same floating-point operations
    # and the effect acts: without it (the base variant) the response differs by far more than round-off
    base = [a for i, a in enumerate(rest) if not (a == "--set" and rest[i + 1].startswith("k_t=")) and
            not a.startswith("k_t=")]
    assert main(base) == 0
    plain = pd.read_csv(io.StringIO(capsys.readouterr().out)).drop(columns="harmonic").to_numpy()
    assert np.abs(plain - added.drop(columns="harmonic").to_numpy()).max() > 1e-3 * np.abs(plain).max()


def test_add_effect_builds_the_variant_the_config_declares(capsys):
    """geometric + --add-effect expansion_k4 is config/config.yaml's geometric_expansion_k4 (the loop's next variant,
    as the diagnosis of geometric printed it)."""
    values = [*PAPER_ARGS, "--set", "k4=324.2", "--harmonics", "3"]
    config = ["--config", str(ROOT / "config" / "config.yaml")]
    assert main(["simulate", *config, "--variant", "geometric", "--add-effect", "expansion_k4", *values]) == 0
    added = capsys.readouterr().out
    assert main(["simulate", *config, "--variant", "geometric_expansion_k4", *values]) == 0
    assert capsys.readouterr().out == added


def test_variants_reads_the_project_config_from_the_project_root(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(ROOT)
    assert main(["variants"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# variants of config/config.yaml")
    declared = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())["variants"]
    listed = [line.split(":")[0] for line in out.splitlines() if line and not line.startswith((" ", "#"))]
    assert listed == list(declared)  # geometric_expansion_k4 is declared there only, not built in
    monkeypatch.chdir(tmp_path)
    assert main(["variants"]) == 0
    out = capsys.readouterr().out
    assert "built in" in out.splitlines()[0] and "geometric_expansion_k4" not in out
    assert main(["variants", "--variant", "geometric", "--add-effect", "speed_damping"]) == 0
    assert "speed_damping: " in capsys.readouterr().out


def test_version_and_help_name_every_command(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"hybridtwin {version('hybridtwin')}"
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    top = parser.format_help()
    for action in commands._choices_actions:  # every subcommand: named, with a help line, and a description
        assert action.dest in top and action.help and action.help in " ".join(top.split())
        description = commands.choices[action.dest].description
        assert description and len(description) > 40, action.dest
        assert action.dest in parser.description
    assert {"simulate", "effects", "variants", "check-data", "rig"} <= set(commands.choices)


def test_the_package_leaves_the_matplotlib_backend_to_the_caller():
    """No matplotlib.use at import: a script's own choice stands (and without a display matplotlib picks Agg)."""
    code = ("import matplotlib; matplotlib.use('svg'); import hybridtwin.plots, hybridtwin.report.report, "
            "hybridtwin.diagnose.diagnosis_report as d, hybridtwin.identify.validation; print(matplotlib.get_backend())")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "svg"


# --- simulate on the config's machine ------------------------------------------------------------------------


def test_simulate_builds_the_variant_on_the_configs_machine(capsys, tmp_path):
    """The stepped rotor with disks of tests/example_machines.py as the config's machine: simulate prints its
    linear unbalance response at the probes (node 8), solved by hand from its matrices (no model, no harmonic
    balance), with the --set values."""
    from example_machines import SENSOR_NODE, STEPPED_YAML, linear_response, stepped_machine

    (tmp_path / "config.yaml").write_text(STEPPED_YAML)
    machine = stepped_machine()
    for rpm in (2000.0, 3900.0, 6000.0):  # below, between and above the first critical speeds (3793, 4064 RPM)
        code, out, err = _run(capsys, "--config", str(tmp_path / "config.yaml"), "--variant", "linear", "--rpm",
                              f"{rpm:g}", "--eccentric-mass-g", "20", "--set", "k_a=3e7", "--harmonics", "2")
        assert code == 0, err
        table = pd.read_csv(io.StringIO(out))
        X = linear_response(machine, rpm, 0.020, k={"a": 3e7})
        expected = X[[machine.dof(f"u{SENSOR_NODE}"), machine.dof(f"v{SENSOR_NODE}")]]
        got = [complex(table.u_re_m[1], table.u_im_m[1]), complex(table.v_re_m[1], table.v_im_m[1])]
        # linear system: the harmonic balance is exact to round-off; %.9e printing bounds it at 1e-9 relative
        np.testing.assert_allclose(got, expected, rtol=2e-9)


def test_on_the_configs_machine_simulate_defaults_to_its_variant_and_effects_lists_its_placed_effects(capsys,
                                                                                                      tmp_path):
    """Without --variant, simulate on a machine of your own builds the config's first variant (the VARM's geometric
    cannot be built there): the same output as with --variant linear. ``hybridtwin effects`` lists what the
    machine adds (linear_bearing@a, unbalance@d1, bearing_anisotropy@b, gyroscopic), as variants can use them;
    on the VARM it lists no placed effects."""
    from example_machines import STEPPED_YAML

    (tmp_path / "config.yaml").write_text(STEPPED_YAML)
    common = ["--config", str(tmp_path / "config.yaml"), "--rpm", "3000", "--eccentric-mass-g", "20"]
    code, default, err = _run(capsys, *common)
    assert code == 0, err
    code, named, err = _run(capsys, *common, "--variant", "linear")
    assert code == 0 and default == named
    code = main(["effects", "--config", str(tmp_path / "config.yaml")])
    out, err = capsys.readouterr()
    assert code == 0, err
    for name in ("linear_bearing@a", "unbalance@d1", "bearing_anisotropy@b", "gyroscopic"):
        assert f"{name}:" in out or f"{name} " in out, name
    code = main(["effects"])
    varm, err = capsys.readouterr()
    assert code == 0 and "@" not in varm


def test_simulate_on_a_longer_varm_shaft(capsys, tmp_path):
    """The VARM's own description in the config (Machine.varm().to_mapping()) prints byte for byte what a config
    without machine: prints; the same machine with a longer shaft gives another response, the one the Python API's model
    on that machine gives."""
    from hybridtwin.model.machine import Machine
    from hybridtwin.solvers.solver import solve
    from hybridtwin.model.variants import builtin_variant

    from hybridtwin.model.variants import BUILTIN_VARIANTS

    args = [*PAPER_ARGS, "--variant", "geometric", "--harmonics", "3"]
    plain = {"variants": {"geometric": BUILTIN_VARIANTS["geometric"]}}
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(_plain(plain)))
    default = _run(capsys, "--config", str(tmp_path / "plain.yaml"), *args)
    varm = plain | {"machine": Machine.varm().to_mapping()}
    (tmp_path / "varm.yaml").write_text(yaml.safe_dump(_plain(varm)))
    same = _run(capsys, "--config", str(tmp_path / "varm.yaml"), *args)
    assert default[0] == same[0] == 0 and default[1] == same[1]
    longer = Machine.varm().to_mapping()
    longer["segments"][0]["length"] = 0.95
    (tmp_path / "longer.yaml").write_text(yaml.safe_dump(_plain(varm | {"machine": longer})))
    code, out, err = _run(capsys, "--config", str(tmp_path / "longer.yaml"), *args)
    assert code == 0, err
    table, before = pd.read_csv(io.StringIO(out)), pd.read_csv(io.StringIO(default[1]))
    assert abs(table.u_re_m[1] - before.u_re_m[1]) > 0.01 * abs(before.u_re_m[1])
    machine = Machine.from_mapping(longer)
    assert machine.L == pytest.approx(0.95) and machine.n == 10
    variant = builtin_variant("geometric", machine)
    values = {"m_e": 0.0148, "k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "q_x": 0.004, "q_y": 0.006}
    result = solve(variant.system(700.0, values), harmonics=3)
    U = result.harmonics[0, :, machine.dof("u1")]
    # the same solver on a model built through the Python API: %.9e printing, 1e-8 relative
    np.testing.assert_allclose(table.u_re_m + 1j * table.u_im_m, U, rtol=1e-8, atol=1e-8 * abs(U).max())


def test_simulate_shows_the_first_probe_pair_and_refuses_a_machine_without_one(capsys, tmp_path):
    """With a second probe plane the output is still the first x, y pair's (node 8): the same table as without
    it; a machine with no node holding both an x and a y probe is refused in one line."""
    from example_machines import STEPPED_YAML

    config = yaml.safe_load(STEPPED_YAML)
    args = ("--variant", "linear", "--rpm", "2000")
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(config))
    config["machine"]["sensors"]["x2"] = {"node": 16, "direction": "x"}
    (tmp_path / "two.yaml").write_text(yaml.safe_dump(config))
    one, two = (_run(capsys, "--config", str(tmp_path / f"{name}.yaml"), *args) for name in ("one", "two"))
    assert one[0] == two[0] == 0 and one[1] == two[1] and one[1].startswith("harmonic,")
    config["machine"]["sensors"] = {"x1": {"node": 8, "direction": "x"}, "y2": {"node": 16, "direction": "y"}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    code, out, err = _run(capsys, "--config", str(tmp_path / "config.yaml"), *args)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "config.yaml: machine 'stepped': sensors" in err and "no node with both an x and a y probe" in err


def _plain(value):
    """Tuples as lists, for yaml.safe_dump."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
