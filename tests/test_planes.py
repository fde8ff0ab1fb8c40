"""Records with more than one sensor plane (issue 24): channels named after the machine's sensors, read, order
analysed, checked and fitted; and the VARM's one x, y pair unchanged.

The VARM reference (planes_varm_reference.json) was computed with the code before this change (commit e4645ba,
its src/ exported with ``git archive e4645ba src``) by this file's own ``varm_reference``:

    PYTHONPATH=<that src> python tests/test_planes.py tests/planes_varm_reference.json

It holds, for two bundled runs (data/default), every metre-valued column of the preprocessed row and the
residuals and Jacobian of the full-solver identification problem (geometric variant, bow per run) at a fixed
point: the whole path from a record to the identification's residual vector.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = Path(__file__).with_name("planes_varm_reference.json")
TWO_PLANES = {"x1": {"node": 8, "direction": "x"}, "y1": {"node": 8, "direction": "y"},
              "x2": {"node": 16, "direction": "x"}, "y2": {"node": 16, "direction": "y"}}


def varm_reference() -> dict:
    """The VARM path's numbers (module docstring), with the APIs the code had before and has after the change."""
    import pandas as pd

    import hybridtwin.identify.forward as fwd
    import hybridtwin.identify.identification as idn
    from hybridtwin.identify.arrow_problem import ArrowProblem, Layout
    from hybridtwin.data.measurements import read_runs
    from hybridtwin.data.preprocessing import preprocess_run
    from hybridtwin.model.variants import builtin_variant

    runs = read_runs(ROOT / "data" / "default" / "runs.tsv", require_mass=True)
    rows = [runs[runs["run"] == r].iloc[0].to_dict() for r in ("r600_m25p9", "r750_m14p8")]
    table = pd.concat([preprocess_run(row, 3, 14e-3)[0] for row in rows], ignore_index=True)
    variant = builtin_variant("geometric")
    names = list(variant.unknown)
    lower, upper = (np.array([variant.unknown[n][i] for n in names]) for i in (0, 1))
    data = [idn.run_data(table, r["run"]) for r in rows]
    models = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, names, lower, upper, 3) for d in data]
    layout = Layout.for_data(names, lower, upper, data, per_run=("q_x", "q_y"))
    problem = ArrowProblem(models, layout, np.stack([idn.total_sigma(d) for d in data]))
    theta = np.linspace(-0.5, 0.5, layout.n)[None]
    ev = problem.evaluate(theta, np.stack([d.X for d in data])[None], jacobian=True)
    return {"columns": {f"{table['run'].iloc[i]}:{c}": float(table[c].iloc[i]) for i in range(len(rows))
                        for c in table.columns if c.endswith("_m") or c == "rpm_true"},
            "residual": ev.r[0].ravel().tolist(), "jacobian_shared": ev.Js[0].ravel().tolist(),
            "jacobian_local": ev.Jl[0].ravel().tolist()}


#: How far the VARM path may move across machines (issue 42), measured by running ``varm_reference`` under each
#: OpenBLAS kernel this machine runs (OPENBLAS_CORETYPE=Haswell, Zen, Prescott) against the reference, written on a
#: SkylakeX kernel: the record's columns (least squares on the samples) <= 8.7e-10 relative; the residuals <= 3.4e-10
#: and the Jacobian's local block <= 2.9e-10 of their largest entry (the harmonic-balance solution is converged to
#: ||r|| <= 1e-10 ||x||, solver.solve's tol, and the kernels move its last iterate within that); the shared block
#: <= 3.3e-8 of its largest (derivatives of that solution through the near-resonant continuation). Each tolerance
#: keeps a margin of ~30 over its measured spread; a change of the path itself (a unit, a sign, a harmonic, a
#: convention, a bow in another place) moves these numbers by 1e-4 to 1.
KERNEL_SPREAD = {"columns": 3e-8, "residual": 1e-8, "jacobian_local": 1e-8, "jacobian_shared": 1e-6}


def test_the_varm_path_is_unchanged():
    """Records of x_mm, y_mm at node 1: the preprocessed row and the identification's residuals and Jacobian are
    those of the code before the change, to the spread that BLAS kernels of other CPUs give (KERNEL_SPREAD)."""
    reference = json.loads(REFERENCE.read_text())
    now = varm_reference()
    assert list(now["columns"]) == list(reference["columns"])  # same columns, same order
    for key in ("residual", "jacobian_shared", "jacobian_local"):
        scale = KERNEL_SPREAD[key] * np.abs(reference[key]).max()
        np.testing.assert_allclose(now[key], reference[key], rtol=0, atol=scale, err_msg=key)
    got, want = np.array(list(now["columns"].values())), np.array(list(reference["columns"].values()))
    np.testing.assert_allclose(got, want, rtol=KERNEL_SPREAD["columns"], atol=0, equal_nan=True)


def _machine(sensors=TWO_PLANES):
    sys.path.insert(0, str(Path(__file__).parent))
    from example_machines import stepped_config

    from hybridtwin.config import machine

    config = stepped_config()
    config["machine"]["sensors"] = dict(sensors)
    config["variants"] = {"linear": {"effects": ["linear_bearing@a", "linear_bearing@b", "gyroscopic",
                                                 "unbalance@d1"],
                                     "unknown": {"k_b": [7.5e6, 1.5e7], "c_b": [250, 1000]}}}
    return config, machine(config)


def _write(path: Path, header: str, rows: int = 400) -> Path:
    t = np.arange(rows) / 2000.0
    columns = header.split(",")
    data = [t] + [0.1 * np.cos(2 * np.pi * 50 * t + k) for k in range(len(columns) - 1)]
    np.savetxt(path, np.column_stack(data), delimiter=",", header=header, comments="", fmt="%.6f")
    return path


def test_a_record_holds_a_channel_per_sensor_named_after_it(tmp_path):
    import pytest

    from hybridtwin.data.measurements import DataError
    from hybridtwin.data.records import read_record

    _, machine = _machine()
    record = read_record(_write(tmp_path / "a.csv", "time_s,x1_mm,y1_mm,x2_m,y2_mm"), machine)
    assert record.names == ("x1", "y1", "x2", "y2") and record.pairs == ((0, 1), (2, 3))
    assert record.units == {"x1": "mm", "y1": "mm", "x2": "m", "y2": "mm"} and record.unit == "mm/mm/m/mm"
    # mm converted to m, m kept: the same cosine written in each column
    np.testing.assert_allclose(record.channel("x1"), 1e-3 * 0.1 * np.cos(2 * np.pi * 50 * record.time_s), atol=1e-9)
    np.testing.assert_allclose(record.channel("x2"), 0.1 * np.cos(2 * np.pi * 50 * record.time_s + 2), atol=1e-6)
    # the columns follow the sensors, not the file's order
    shuffled = read_record(_write(tmp_path / "b.csv", "time_s,y2_mm,x1_mm,x2_mm,y1_mm"), machine)
    assert shuffled.names == ("x1", "y1", "x2", "y2")
    with pytest.raises(DataError) as err:  # a missing channel: the file, the channel, the machine's sensors
        read_record(_write(tmp_path / "c.csv", "time_s,x1_mm,y1_mm,x2_mm"), machine)
    message = str(err.value)
    assert message.startswith(str(tmp_path / "c.csv")) and "missing column y2_mm (or y2_m)" in message
    assert "sensors x1, y1, x2, y2" in message
    with pytest.raises(DataError, match=r"unexpected column\(s\) \['x3_mm'\].*sensors x1, y1, x2, y2"):
        read_record(_write(tmp_path / "d.csv", "time_s,x1_mm,y1_mm,x2_mm,y2_mm,x3_mm"), machine)
    with pytest.raises(DataError, match="missing column x1_mm"):  # the VARM's x, y are not this machine's channels
        read_record(_write(tmp_path / "e.csv", "time_s,x_mm,y_mm"), machine)
    with pytest.raises(DataError, match=r"machine of your own\? .*check-data --config FILE"):  # read as the VARM's
        read_record(tmp_path / "a.csv")
    # the config form the workflow's rules pass (params.sensors: the machine section's sensors) reads the same
    config_form = read_record(tmp_path / "a.csv", _machine()[0]["machine"]["sensors"])
    assert config_form.names == record.names and config_form.pairs == record.pairs
    assert all(np.array_equal(config_form.channel(c), record.channel(c)) for c in record.names)


def test_order_analysis_gives_each_channel_its_harmonics_with_one_speed_and_one_phase_origin(tmp_path):
    """Four channels of known 1X and 2X (phases differing per channel) and noise: each channel's harmonics
    recovered to within 5 of their sigmas (a 5-sigma bound on a Gaussian estimate), one speed for the run."""
    import pandas as pd
    import pytest

    from hybridtwin.data.measurements import DataWarning
    from hybridtwin.data.records import Record
    from hybridtwin.data.preprocessing import analyse_record, harmonic_column, run_row, table_channels

    rng = np.random.default_rng(5)
    rpm, fs = 3000.0, 2000.0
    t = np.arange(int(2.0 * fs)) / fs
    omega = rpm * np.pi / 30
    truth = {"x1": (1e-4, 2e-5j), "y1": (-1e-4j, 1e-5), "x2": (3e-5 + 1e-5j, 0.0), "y2": (2e-5, -4e-6j)}
    channels = {name: sum((X * np.exp(1j * h * omega * t)).real for h, X in enumerate(harm, start=1))
                + 1e-5 * (k + 1) + 1e-6 * rng.standard_normal(t.size) for k, (name, harm) in enumerate(truth.items())}
    pairs = ((0, 1), (2, 3))
    analysis = analyse_record(Record(Path("r.csv"), t, channels, None, "m", pairs=pairs), rpm, 2, 1e-3)
    assert analysis.usable and analysis.orders.harmonics.shape == (4, 3)
    # the phase origin is a revolution boundary (no keyphasor): the truth's phases shift by h Omega t_origin
    shift = np.exp(1j * np.arange(1, 3) * omega * analysis.origin.time_s)
    for i, (name, harm) in enumerate(truth.items()):
        expected = np.array(harm) * shift
        error = np.abs(analysis.orders.harmonics[i, 1:] - expected)
        assert (error < 5 * np.sqrt(2) * analysis.orders.sigma[i, 1:]).all(), name
        assert abs(analysis.orders.harmonics[i, 0].real - 1e-5 * (i + 1)) < 1e-7  # its own DC offset
    # one plane whirling backward while another whirls forward can be real (between the split critical speeds of an
    # anisotropic support): a warning, the run stays in the fit, whichever plane the machine lists first; every
    # plane backward is a finding (the record's x and y swapped), the run is kept out
    orbit = {"x2": 4e-5 * np.cos(omega * t), "y2": -4e-5 * np.sin(omega * t)}  # a backward whirl at d2
    d2_backward = dict(channels, **{k: v + 1e-6 * rng.standard_normal(t.size) for k, v in orbit.items()})
    for order in (pairs, pairs[::-1]):
        with pytest.warns(DataWarning, match="orbit of x2, y2 whirls backward .* while the orbit of x1, y1 whirls "
                                             "forward: real between"):
            ok = analyse_record(Record(Path("b.csv"), t, d2_backward, None, "m", pairs=order), rpm, 2, 1e-3)
        assert ok.usable, ok.note
    with pytest.warns(DataWarning, match="the 1X orbit of x1, y1 whirls backward .* x1 and y1 swapped"):
        one = analyse_record(Record(Path("c.csv"), t, dict(channels, x1=channels["y1"], y1=channels["x1"]),
                                    None, "m", pairs=pairs), rpm, 2, 1e-3)
    assert one.usable  # the other plane whirls forward: no single run can tell
    every = dict(channels, x1=channels["y1"], y1=channels["x1"], x2=channels["y2"], y2=channels["x2"])
    with pytest.warns(DataWarning) as caught:
        swapped = analyse_record(Record(Path("d.csv"), t, every, None, "m", pairs=pairs), rpm, 2, 1e-3)
    messages = [str(w.message) for w in caught]
    assert all(any(f"the 1X orbit of {p} whirls backward" in m for m in messages) for p in ("x1, y1", "x2, y2"))
    assert not swapped.usable and "x1 and y1 swapped?" in swapped.note and "x2 and y2 swapped?" in swapped.note
    row = pd.DataFrame([run_row(analysis, 2)])
    assert table_channels(row) == ("x1", "y1", "x2", "y2")
    assert harmonic_column("x1", 2, "re") == "x1_2_re_m" and harmonic_column("x", 2, "re") == "x2_re_m"
    assert {"noise_x2_m", "offset_y2_m", "y2_2_sigma_m"} <= set(row.columns)
    # the fits read a run's channels by the model's sensor names, in the model's order, whatever the table's order
    from hybridtwin.data.measured import run_data

    row = row.assign(run="r1", rpm=rpm, eccentric_mass_g=20.0)
    data = run_data(row, "r1")
    assert data.channels == ("x1", "y1", "x2", "y2")
    other = run_data(row, "r1", channels=("x2", "y2", "x1", "y1"))
    assert other.channels == ("x2", "y2", "x1", "y1")
    np.testing.assert_array_equal(other.X, data.X[:, [2, 3, 0, 1]])
    np.testing.assert_array_equal(other.sigma, data.sigma[:, [2, 3, 0, 1]])
    with pytest.raises(ValueError, match="channels are x1, y1, x2, y2, the model's sensors x, y"):
        run_data(row, "r1", channels=("x", "y"))


def test_two_planes_see_the_overhung_disks_bearing_that_one_plane_barely_sees(tmp_path, capsys):
    """The stepped rotor with probes at d1 (node 8) and d2 (node 16): the virtual rig writes x1, y1, x2, y2;
    check-data reads them by the config's machine; the full-solver fit of bearing b (k_b, c_b) recovers the truth
    within its 95 % intervals from either set of probes, and the second plane narrows them many times: d1's
    probes sit near a node of the overhung disk's mode (examples/stepped_rotor/README.md), which bearing b
    carries. Measured: standard errors 18-20 times smaller with both planes; asserted: more than 5 times."""
    import copy
    from dataclasses import replace

    import pandas as pd
    import yaml

    import hybridtwin.identify.forward as fwd
    import hybridtwin.identify.identification as idn
    from hybridtwin.identify import lm
    from hybridtwin.cli import main
    from hybridtwin.config import variant as config_variant
    from hybridtwin.data.measurements import read_runs
    from hybridtwin.data.preprocessing import preprocess_run
    from hybridtwin.identify.protocol import ProtocolOptions
    from hybridtwin.rig.rig import RigSpec, generate

    config, machine = _machine()
    truth = {"k_b": 1.1e7, "c_b": 450.0}
    plan = pd.DataFrame({"run": ["r3700", "r3900", "r4100", "r4300"], "rpm": [3700.0, 3900.0, 4100.0, 4300.0],
                         "eccentric_mass_g": [20.0] * 4, "role": ["fit"] * 4})
    spec = RigSpec.from_mapping({"seed": 3, "harmonics": 1,
                                 "truth": {"effects": config["variants"]["linear"]["effects"], "values": truth},
                                 "imperfections": {"duration_s": 2.0, "noise_mm": 0.0005, "offset_mm": 0.2,
                                                   "keyphasor": True, "sensor_range_mm": 1.0}}, machine=machine)
    generate(plan, spec, tmp_path / "data")
    header = (tmp_path / "data" / "records" / "r3700.csv").read_text().splitlines()[0]
    assert header == "time_s,x1_mm,y1_mm,x2_mm,y2_mm,keyphasor"
    # check-data with the config: a line per run, noise and offset per channel
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    code = main(["check-data", str(tmp_path / "data" / "runs.tsv"), "--config", str(tmp_path / "config.yaml"),
                 "--harmonics", "1", "--sensor-range-mm", "1"])
    out = capsys.readouterr().out
    assert code == 0 and all(f"noise_{c}_mm" in out and f"{c}_1X_mm" in out for c in ("x1", "y1", "x2", "y2"))
    runs = read_runs(tmp_path / "data" / "runs.tsv", require_mass=True)
    table = pd.concat([preprocess_run(row, 1, 1e-3, sensors=machine)[0] for _, row in runs.iterrows()],
                      ignore_index=True)
    fits = {}
    for label, keep in (("two", slice(None)), ("one", slice(0, 2))):
        own = copy.deepcopy(config)
        if label == "one":  # the machine with the first plane's probes only, and the data of those
            own["machine"]["sensors"] = {k: v for k, v in TWO_PLANES.items() if k in ("x1", "y1")}
        variant = config_variant(own, "linear")
        data = [idn.run_data(table, run) for run in runs["run"]]
        assert data[0].channels == ("x1", "y1", "x2", "y2") and data[0].X.shape == (1, 4)
        data = [replace(d, X=d.X[:, keep], sigma=d.sigma[:, keep], channels=d.channels[keep]) for d in data]
        names = list(variant.unknown)
        lower, upper = (np.array([variant.unknown[n][i] for n in names]) for i in (0, 1))
        models = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, names, lower, upper, 1) for d in data]
        fit = idn.identify(models, data, (), ProtocolOptions(trials=3, monte_carlo=0, seed=1,
                                                             lm=lm.LMOptions(max_iterations=60)))
        assert fit.problem.n_data == len(data) * 2 * data[0].X.shape[1]  # every channel's Re and Im
        fits[label] = fit.table().set_index("parameter")
        # the noise is what the rig put in: chi^2/dof near 1 (2 sigma of a chi^2 with ~10-30 dof: below 2)
        assert fit.chi2_dof < 2.0
    for name, value in truth.items():
        for label in ("two", "one"):
            row = fits[label].loc[name]
            assert row.ci_low <= value <= row.ci_high, (label, name, row.value, row.ci_low, row.ci_high)
        assert fits["two"].loc[name, "stderr"] < fits["one"].loc[name, "stderr"] / 5, name


def test_predictions_comparisons_figures_and_fingerprint_follow_the_channels(tmp_path):
    """Four channels x1, y1, x2, y2 (not in alphabetical order) through the validation predictions' file, the
    report's harmonics table and run figure, and the diagnosis fingerprint: the files give the same numbers back
    in the sensors' order, the figure names the channels it shows, and the fingerprint's whirl is that of the first
    pair (channels 0, 1): the same as a fingerprint of those two channels alone."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hybridtwin.report import report
    from hybridtwin.report import report_plots
    from hybridtwin.identify import validation as val
    from hybridtwin.diagnose.fingerprint import fingerprint

    rng = np.random.default_rng(1)
    channels = ("x1", "y1", "x2", "y2")
    H = 2
    Z = rng.standard_normal((H, 4)) + 1j * rng.standard_normal((H, 4))
    prediction = val.PredictedRun("v1", "solver", 0.3, 1e-4 * Z, channels)
    val.write_predictions(tmp_path / "p.tsv", [prediction])
    back = val.read_predictions(tmp_path / "p.tsv")[0]
    assert back.channels == channels and np.array_equal(back.harmonics, prediction.harmonics)

    comparison = report.RunComparison("v1", "validate", 4000.0, 20.0, 1e-4 * Z, 0.9e-4 * Z, np.full((H, 4), 1e-6),
                                      2 * Z.size - 1, "solver", channels)
    table = report.comparison_table([comparison])
    assert list(table["channel"][:4]) == list(channels)
    again = report.read_comparisons(table)[0]
    assert again.channels == channels and np.array_equal(again.measured, comparison.measured)
    assert again.chi2 == comparison.chi2  # every channel counts
    figure = report_plots.plot_run(comparison, "linear")
    orbits = [ax for ax in figure.axes if ax.get_title().startswith("orbit")]
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in orbits] == [("x1 [mm]", "y1 [mm]"), ("x2 [mm]", "y2 [mm]")]
    assert "not drawn" not in figure._suptitle.get_text()  # every channel has its row
    plt.close(figure)
    odd = report.RunComparison("v1", "validate", 4000.0, 20.0, 1e-4 * Z[:, :3], 0.9e-4 * Z[:, :3],
                               np.full((H, 3), 1e-6), 11, "solver", channels[:3])
    figure = report_plots.plot_run(odd, "linear")
    assert "not drawn: channel x2 (no pair)" in figure._suptitle.get_text()
    plt.close(figure)

    import pandas as pd

    from hybridtwin.report.response_plots import plot_cascade

    f = np.linspace(0.0, 300.0, 50)
    spectra = {"v1": pd.DataFrame({"frequency_hz": f, "order": f / 66.7,
                                   **{f"{c}_amplitude_m": 1e-6 * (1 + k + f) for k, c in enumerate(channels)}})}
    cascade = plot_cascade(spectra, pd.DataFrame({"run": ["v1"], "rpm": [4000.0], "eccentric_mass_g": [20.0]}))
    titles = [ax.get_title() for ax in cascade.axes if ax.get_title()]
    assert [t.split(":")[0] for t in titles] == list(channels)  # a panel per channel, in the sensors' order
    plt.close(cascade)

    R = 5
    X = 1e-4 * (rng.standard_normal((R, H + 1, 4)) + 1j * rng.standard_normal((R, H + 1, 4)))
    M = X + 1e-6 * (rng.standard_normal(X.shape) + 1j * rng.standard_normal(X.shape))
    M[:, :, 1] += 3e-6 * 1j * M[:, :, 0] / np.abs(M[:, :, 0])  # a residual that whirls in the first plane
    rpm = np.linspace(3000, 4000, R)
    four = fingerprint(X, M, 1e-6, rpm, np.full(R, 20.0))
    two = fingerprint(X[:, :, :2], M[:, :, :2], 1e-6, rpm, np.full(R, 20.0))
    np.testing.assert_array_equal(four.forward, two.forward)  # the whirl: channels 0, 1 only
    assert four.chi2 > two.chi2 and four.dof == 2 * two.dof  # the chi^2: every channel


def test_the_run_figure_draws_an_orbit_for_each_plane_the_machine_declares_and_no_other(tmp_path):
    """A plane with an x and a y probe, and two probes without a partner (an x at one node, a y at another): the
    machine keeps them x1, y1, xa, yb. Consecutive channels would draw xa against yb as if they were one plane's
    orbit; with the machine's pairs (``sensor_pair_names`` of the config's sensors, as the report_runs rule passes
    them) the figure has the one orbit x1, y1 and its title names xa and yb as not drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hybridtwin.report import report
    from hybridtwin.report import report_plots

    sensors = {"yb": {"node": 4, "direction": "y"}, "x1": {"node": 9, "direction": "x"},
               "xa": {"node": 2, "direction": "x"}, "y1": {"node": 9, "direction": "y"}}
    pairs = report_plots.sensor_pair_names(sensors)
    assert pairs == [("x1", "y1")]
    assert report_plots.sensor_pair_names(None) is None  # the VARM: its x, y
    rng = np.random.default_rng(3)
    H, channels = 2, ("x1", "y1", "xa", "yb")  # the machine's order (tests/test_machine.py: sensors_by_name)
    Z = 1e-4 * (rng.standard_normal((H, 4)) + 1j * rng.standard_normal((H, 4)))
    comparison = report.RunComparison("r1", "fit", 3000.0, 10.0, Z, 0.9 * Z, np.full((H, 4), 1e-6), 15, "solver",
                                      channels)
    figure = report_plots.plot_run(comparison, "linear", pairs)
    orbits = [ax for ax in figure.axes if ax.get_title().startswith("orbit")]
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in orbits] == [("x1 [mm]", "y1 [mm]")]
    assert "not drawn: channels xa, yb (no pair)" in figure._suptitle.get_text()
    plt.close(figure)
    # the pair's numbers are its own channels' (by name, whatever the column order)
    swapped = report_plots.probe_pairs(comparison, [("y1", "x1")])[0]
    np.testing.assert_array_equal(swapped.measured, Z[:, [1, 0]])
    with pytest.raises(ValueError, match="run r1: channel.s. x2 not among its channels"):
        report_plots.probe_pairs(comparison, [("x2", "y1")])


def test_a_library_and_its_surrogate_give_every_sensor_in_declared_order():
    """A library with four sensor DOFs (two planes, declared out of DOF order): Library.sensor is its own field at
    those DOFs in that order, and the identification's SensorSurrogate (h >= 1, normalised parameters) the same
    numbers; exact algebra on the same amplitudes, so round-off only (1e-12 relative)."""
    from hybridtwin.identify.forward import SensorSurrogate
    from hybridtwin.offline.library import Library
    from hybridtwin.offline.spgd import SparsePGD

    rng = np.random.default_rng(7)

    def truth(X):
        p1, p2, p3 = X.T
        return np.column_stack([(1 + p1 * p1) * (2 - p2), p1 + 0.3 * p2 * p3, p3 * p3 - p2])

    X, X_val = rng.uniform(-1, 1, (300, 3)), rng.uniform(-1, 1, (100, 3))
    model = SparsePGD(degree=3, max_terms=6).fit(X, truth(X), X_val, truth(X_val))
    n_harmonics, n_dof = 3, 44
    modes = np.linalg.qr(rng.standard_normal((2 * n_harmonics * n_dof, 3)))[0]
    dofs = [24, 2, 27, 5]  # v1, u1, v4, u4: any order, any planes
    lower, upper = np.zeros(3), np.array([1.0, 2.0, 4.0])
    library = Library("r1", ["a", "b", "c"], lower, upper, modes, np.ones(3), model, n_harmonics, n_dof, dofs)
    values = rng.uniform(lower, upper, (50, 3))
    sensor = library.sensor(values)
    assert sensor.shape == (50, n_harmonics, 4)
    np.testing.assert_allclose(sensor, library.field(values)[:, :, dofs], rtol=1e-12, atol=1e-14)
    surrogate = SensorSurrogate(library)
    M, dM = surrogate.evaluate(2 * (values - lower) / (upper - lower) - 1)
    assert surrogate.C == 4 and M.shape == (50, n_harmonics - 1, 4) and dM.shape == (50, n_harmonics - 1, 4, 3)
    np.testing.assert_allclose(M, sensor[:, 1:], rtol=1e-12, atol=1e-14)
    # the Jacobian per channel: central differences of the surrogate (a polynomial of degree 3: truncation of
    # order step^2 ~ 1e-12, round-off ~ 1e-16 / 1e-6 = 1e-10 of the response's size)
    x0, step = 2 * (values[:1] - lower) / (upper - lower) - 1, 1e-6
    for j in range(3):
        e = np.zeros((1, 3))
        e[0, j] = step
        numeric = (surrogate.evaluate(x0 + e, False)[0] - surrogate.evaluate(x0 - e, False)[0]) / (2 * step)
        np.testing.assert_allclose(dM[0, ..., j], numeric[0], rtol=1e-6, atol=1e-8 * np.abs(M[0]).max())


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps(varm_reference()))
