"""hybridtwin simulate / effects / variants: output contract and clear errors."""

import io
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from hybridtwin.cli import main

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


def test_no_periodic_solution_exits_1_with_the_reason(capsys):
    # a parameter set in the Geometric ranges whose direct solve at 950 RPM finds no periodic solution, far from
    # the edge of that region (Newton ends with residual ~5; every one of 20 sets within +-0.5 % fails too), so
    # that round-off of another BLAS or numpy cannot make it converge (a borderline set at 900 RPM did)
    args = ["--rpm", "950", "--set", "k_b=2225.59573", "--set", "zeta_s=0.01955", "--set", "zeta_bup=0.02026",
            "--set", "q_x=0.0065", "--set", "q_y=0.0026"]
    code, out, err = _run(capsys, *args)
    assert code == 1
    assert out == ""
    assert "failed at 950 RPM" in err and ("did not converge" in err or "stalled" in err)


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
