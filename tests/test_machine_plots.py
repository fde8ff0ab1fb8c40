"""Mode shapes and operating deflected shapes (hybridtwin.report.machine_plots) against references computed another way:
the x-plane eigenproblem the model solves for its first mode, the pinned-pinned beam's closed form, the spinning
disk's gyroscopic frequencies, the solver's sensor output and the stepped rotor's response solved by hand.

The Campbell diagram's own tests are in tests/test_machine.py."""

import matplotlib
import numpy as np
import pytest

from example_machines import LINEAR_EFFECTS, SENSOR_NODE, linear_response, stepped_machine
from hybridtwin.model.effect_base import Effect, Parameter
from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import Bearing, Disk, Sensor, ShaftSegment
from hybridtwin.report.machine_plots import (
    deflection, mode_shape_figure, mode_shapes, ods_figure, operating_deflection, undamped_modes,
)
from hybridtwin.model.model import Model
from hybridtwin.model.sensor import sensor_harmonics
from hybridtwin.solvers.solver import solve
from hybridtwin.model.variants import builtin_variant
from hybridtwin.solvers.solver import solve_variant

UNDAMPED = {"zeta_s": 0.0, "zeta_bup": 0.0, "zeta_blo": 0.0}


def _varm_undamped():
    variant = builtin_variant("geometric")
    return variant, {k: float(v) for k, v in variant.values(UNDAMPED | {"m_e": 0.0148}).items()}


def test_varm_first_mode_is_the_models_own_first_mode():
    """At rest the lowest undamped mode is omega_1, Phi_1 of Model.at_rest (scipy's eigh on the x-plane pencil,
    docs/model.md eq. 30), here from the state-space eigenproblem of both planes: a degenerate x/y pair."""
    variant, values = _varm_undamped()
    modes = undamped_modes(variant.model, values, 0.0, n_modes=4)
    rest = variant.model.at_rest(variant.values(values))
    # two eigensolvers on the same pencil: round-off, 1e-9 relative
    np.testing.assert_allclose(modes.frequency_hz[:2], rest.omega_1[0] / (2 * np.pi), rtol=1e-9)
    assert modes.pair[:4].all() and list(modes.whirl[:2]) == ["forward", "backward"]
    z, shapes = mode_shapes(variant.model.shaft, modes, per_element=12)
    at_nodes = shapes[::12, 0]
    assert np.array_equal(z[::12], variant.model.shaft.z)
    # eigenvectors of a well-separated mode from two solvers: 1e-7 asserted (their own accuracy ~1e-12)
    np.testing.assert_allclose(at_nodes / at_nodes[np.argmax(np.abs(at_nodes))], rest.Phi_1[0], atol=1e-7)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_pinned_beam_modes_are_the_closed_form(k):
    """A uniform steel shaft on two very stiff bearings at its ends (pinned-pinned): f_k = (k pi / L)^2
    sqrt(EI / m) / (2 pi), shape sin(k pi z / L), drawn between the nodes by the elements' Hermite functions."""
    L, d = 1.0, 0.02
    machine = Machine("pinned", [ShaftSegment(L, d, E=211e9, rho=7810.0, n_elements=10)],
                      bearings=[Bearing("left", 0, k=1e11), Bearing("right", 10, k=1e11)],
                      sensors=[Sensor("x", 5, "x"), Sensor("y", 5, "y")])
    fx = machine.effects()
    model = Model([fx["linear_bearing@left"], fx["linear_bearing@right"]], machine)
    modes = undamped_modes(model, {p: model.parameters[p].nominal for p in model.parameters}, 0.0, n_modes=8)
    segment = machine.segments[0]
    expected = (k * np.pi / L) ** 2 * np.sqrt(segment.E * segment.section_I / segment.mass_per_length) / (2 * np.pi)
    # 10 consistent-mass cubic elements are a Rayleigh-Ritz approximation: from above, by about
    # (k pi h / L)^4 / 1440 (7e-6, 1e-4, 5.5e-4 for k = 1, 2, 3); the 1e11 N/m bearings lower it by < 1e-6
    error = modes.frequency_hz[2 * (k - 1)] / expected - 1
    assert 0 < error < (k * np.pi / 10) ** 4 / 1000
    assert modes.pair[2 * (k - 1)]
    z, shapes = mode_shapes(machine, modes)
    shape = shapes[:, 2 * (k - 1)]
    exact = np.sin(k * np.pi * z / L)
    exact *= np.sign(exact @ shape) / np.abs(exact).max()
    # Hermite interpolation error h^4 / 384 max|w''''| = (k pi / 10)^4 / 384: 2.5e-5 (k = 1) .. 2e-3 (k = 3)
    assert np.abs(shape - exact).max() < 3e-3 * (k / 3) ** 4 + 1e-5


class TiltSpring(Effect):
    """A rigid disk's node held in translation, its tilt on a spring k_t (the spinning disk of
    tests/test_machine.py)."""

    name, meaning = "tilt_spring", "translation held, tilt on a spring k_t"
    parameters = (Parameter("k_t", "N m/rad", (0.0, 1e5), 4.0e4, "tilt spring"),)

    def stiffness(self, ctx):
        out = ctx.zeros()
        for dof, value in (("u0", 1e12), ("v0", 1e12), ("u1", 1e12), ("v1", 1e12), ("du1", 1e12), ("dv1", 1e12),
                           ("du0", ctx.p.k_t), ("dv0", ctx.p.k_t)):
            out[:, ctx.dof(dof), ctx.dof(dof)] = value
        return out


def test_gyroscopic_modes_of_a_spinning_disk():
    """I_d w^2 -+ I_p Omega w = k_t: forward w = (I_p Omega + sqrt(I_p^2 Omega^2 + 4 I_d k_t)) / (2 I_d), backward
    with -I_p Omega; the gyroscopic coupling is kept in the undamped modes."""
    I_p, I_d, k_t = 0.05, 0.1, 4.0e4
    machine = Machine("disk", [ShaftSegment(0.01, 1e-3, 1e3, 7800.0)], disks=[Disk(0, 1.0, I_p, I_d)])
    model = Model([TiltSpring(), machine.effects()["gyroscopic"]], machine)
    rpm = 3000.0
    Omega = rpm * 2 * np.pi / 60
    root = np.sqrt(I_p**2 * Omega**2 + 4 * I_d * k_t)
    modes = undamped_modes(model, {"k_t": k_t}, rpm, n_modes=2)
    assert list(modes.whirl) == ["backward", "forward"] and not modes.pair.any()
    # the translations' 1e12 springs couple at 1e-8 relative; eig round-off below that
    np.testing.assert_allclose(modes.frequency_hz, np.array([-I_p * Omega + root, I_p * Omega + root])
                               / (2 * I_d) / (2 * np.pi), rtol=1e-7)
    np.testing.assert_allclose(np.abs(modes.whirl_index), 1.0, rtol=1e-9)  # a disk's whirl is circular


def test_campbell_branches_start_at_rest_where_they_go_on_an_anisotropic_support():
    """Bearing b anisotropic (the stepped rotor, dk_b = 1.2e6 N/m): at rest its modes are planar (whirl index of
    round-off size, either sign), so the forward/backward split at 0 RPM was random and the diagram's branches
    jumped between 0 and the next speed. Now each planar mode takes its sense at the nearest speed: the split at 0
    RPM is that at 1 RPM, and every branch's frequency moves by less than 0.1 % from 0 to 1 RPM (a speed change
    of 1 RPM shifts the gyroscopic splitting by a few 1e-4 Hz: continuity)."""
    from hybridtwin.report.machine_plots import branches
    from hybridtwin.model.model import campbell

    machine = stepped_machine()
    fx = machine.effects()
    model = Model([fx[e] for e in LINEAR_EFFECTS + ["bearing_anisotropy@b"]], machine)
    values = {k: float(p.nominal) for k, p in model.parameters.items()} | {"dk_b": 1.2e6}
    table = branches(campbell(model, values, [0.0, 1.0, 50.0], 6))
    at = {rpm: part.set_index(["whirl", "branch"])["frequency_hz"] for rpm, part in table.groupby("rpm")}
    assert (table[table["rpm"] == 0.0]["whirl_index"].abs() < 1e-6).any()  # the case: planar modes at rest
    assert sorted(at[0.0].index) == sorted(at[1.0].index)
    np.testing.assert_allclose(at[0.0].sort_index(), at[1.0].sort_index(), rtol=1e-3)


def test_deflection_of_planar_circular_and_elliptic_whirl():
    """The signed semi-major axis: |U| for a planar or a circular whirl (forward or backward), the larger
    semi-axis of an ellipse; the sign flips where the deflection points against the largest one."""
    U = np.array([1.0, -0.5, 0.2]) * np.exp(0.7j)
    np.testing.assert_allclose(deflection(U, 0 * U), [1.0, -0.5, 0.2])  # planar, any common phase
    np.testing.assert_allclose(deflection(U, -1j * U), [1.0, -0.5, 0.2])  # circular forward
    np.testing.assert_allclose(deflection(U, 1j * U), [1.0, -0.5, 0.2])  # circular backward
    # an ellipse of semi-axes 3 (x) and 1 (y): U = 3, V = -i
    np.testing.assert_allclose(deflection(np.array([3.0, -1.5]), np.array([-1j, 0.5j])), [3.0, -1.5])


def test_mode_shape_figure_of_the_varm_marks_the_machine(tmp_path):
    variant, values = _varm_undamped()
    fig = mode_shape_figure(variant.model, values, 600.0, n_modes=4)
    frequencies = fig.modes.frequency_hz.to_numpy()
    assert len(fig.axes) == 4 and (np.diff(frequencies) > 0).all()  # one panel per distinct mode
    full = undamped_modes(variant.model, values, 600.0, n_modes=8)
    np.testing.assert_array_equal(frequencies, full.frequency_hz[::2][:4])
    ax = fig.axes[0]
    gids = {line.get_gid() for line in ax.get_lines()}
    assert {"bearing:upper", "bearing:lower", "sensor:x", "sensor:y", "unbalance:eccentric_mass", "mode:0"} <= gids
    z, shapes = fig.shapes
    lines = {line.get_gid(): line for line in fig.axes[1].get_lines()}
    np.testing.assert_array_equal(lines["mode:1"].get_ydata(), shapes[:, 1])
    assert shapes[:, 1].min() < -0.5 < 0.5 < shapes[:, 1].max()  # the second mode has a nodal point
    assert "x and y planes alike" in ax.get_title(loc="left")
    fig.savefig(tmp_path / "modes.png")
    assert (tmp_path / "modes.png").stat().st_size > 10_000
    matplotlib.pyplot.close(fig)


def test_operating_deflection_of_the_stepped_rotor():
    """Every node's 1X amplitude of the harmonic balance is the linear response solved by hand; at the probes it
    is the solver's sensor output itself; the figure draws the tables and the measured amplitudes at the
    probes."""
    machine = stepped_machine()
    fx = machine.effects()
    model = Model([fx[e] for e in LINEAR_EFFECTS], machine)
    values = {p: model.parameters[p].nominal for p in model.parameters} | {"m_e": 0.02}
    runs = [(f"{rpm:g} RPM", solve(model.system(values, rpm), harmonics=2)) for rpm in (2000.0, 3900.0)]
    for (label, result), rpm in zip(runs, (2000.0, 3900.0)):
        table = operating_deflection(result, machine)
        nodes = table[table.node >= 0]
        assert nodes.node.tolist() == list(range(machine.n_nodes))
        X = linear_response(machine, rpm, 0.02)
        U, V = X[machine.translational("x")], X[machine.translational("y")]
        # the harmonic balance of a linear system: one solve, round-off (1e-9 relative to the largest)
        scale = np.abs(U).max()
        np.testing.assert_allclose(nodes.x_amplitude_m * np.exp(1j * nodes.x_phase_rad), U, atol=1e-9 * scale)
        np.testing.assert_allclose(nodes.y_amplitude_m * np.exp(1j * nodes.y_phase_rad), V, atol=1e-9 * scale)
        sensor_x, sensor_y = sensor_harmonics(result.harmonics, machine)
        at_probe = nodes[nodes.node == SENSOR_NODE].iloc[0]
        # the node's own entry (the Hermite functions are 1 and 0 there): the same number up to the ulp of abs()
        np.testing.assert_allclose([at_probe.x_amplitude_m, at_probe.y_amplitude_m],
                                   [abs(sensor_x[0, 1]), abs(sensor_y[0, 1])], rtol=1e-15)
    measured = {"2000 RPM": (3.0e-6, 4.0e-6)}
    fig = ods_figure(runs, machine, measured)
    lines = {line.get_gid(): line for line in fig.axes[0].get_lines()}
    np.testing.assert_allclose(lines["x:3900 RPM"].get_ydata(), 1e3 * fig.ods["3900 RPM"].x_amplitude_m)
    np.testing.assert_allclose(lines["measured_x:2000 RPM"].get_xydata(), [[machine.z[SENSOR_NODE], 3.0e-3]])
    np.testing.assert_allclose(lines["measured_y:2000 RPM"].get_xydata(), [[machine.z[SENSOR_NODE], 4.0e-3]])
    assert "measured_x:3900 RPM" not in lines and {"bearing:a", "bearing:b", "sensor:x1"} <= set(lines)
    matplotlib.pyplot.close(fig)


def test_operating_deflection_of_the_varm_at_the_probes_is_the_sensor_output():
    """A nonlinear steady state (the paper's Geometric model): the ODS at node 1 is the solver's sensor output,
    for 1X and 3X (to the last bit of abs and angle)."""
    variant = builtin_variant("geometric")
    result = solve_variant(variant, 700.0, {"m_e": 0.0148, "k_b": 2411.3, "q_x": 0.004}, harmonics=3)
    U, V = sensor_harmonics(result.harmonics, variant.model.shaft)
    for h in (1, 3):
        row = operating_deflection(result, variant.model.shaft, harmonic=h).query("node == 1").iloc[0]
        np.testing.assert_allclose([row.x_amplitude_m, row.x_phase_rad, row.y_amplitude_m, row.y_phase_rad],
                                   [abs(U[0, h]), np.angle(U[0, h]), abs(V[0, h]), np.angle(V[0, h])], rtol=1e-15)


# --- the report's machine figures (scripts/report_machine.py, rule report_machine) ---------------------------


def _parameter_table(rows):
    """A parameters.tsv (Identification.table's columns) holding only the rows (parameter, run, kind, value)."""
    import pandas as pd

    from hybridtwin.identify import identification as idn

    table = pd.DataFrame([dict(zip(("parameter", "run", "kind", "value"), row)) for row in rows])
    for column in idn.TABLE_COLUMNS:
        if column not in table:
            table[column] = "" if column in ("unit", "source") else np.nan
    return table[list(idn.TABLE_COLUMNS)]


@pytest.mark.parametrize("machine", ["varm", "stepped"])
def test_report_machine_script_draws_the_fitted_model(tmp_path, machine):
    """The rule's script: the Campbell table is ``campbell`` of the variant on the config's machine at the table's
    estimates (a per-run parameter's median, the runs' median mass) over 0..1.25 x the fastest run; the mode
    shapes' log lists the undamped modes at the runs' median speed; both figures written."""
    import logging
    import runpy
    from pathlib import Path
    from types import SimpleNamespace

    import pandas as pd

    from example_machines import stepped_config
    from hybridtwin import config as cfg
    from hybridtwin.identify import identification as idn
    from hybridtwin.report.machine_plots import branches, report_speeds
    from hybridtwin.model.model import campbell
    from hybridtwin.model.variants import BUILTIN_VARIANTS

    if machine == "varm":
        model = {"variants": {"geometric": BUILTIN_VARIANTS["geometric"]}, "machine": None, "effects_files": []}
        name, runs = "geometric", {"run": ["a", "b", "c"], "rpm": [400.0, 650.0, 900.0],
                                   "eccentric_mass_g": [14.8, 25.9, 14.8]}
        rows = [("k_b", "all", "shared", 2600.0), ("zeta_s", "a", "per_run", 0.02), ("zeta_s", "b", "per_run", 0.03),
                ("zeta_s", "c", "per_run", 0.05), ("phase", "a", "nuisance", 1.0)]
        expected = {"k_b": 2600.0, "zeta_s": 0.03, "m_e": 0.0148}
    else:
        config = stepped_config()
        model = {"variants": config["variants"], "machine": config["machine"], "effects_files": []}
        name, runs = "linear", {"run": ["a", "b"], "rpm": [2000.0, 3000.0], "eccentric_mass_g": [10.0, 30.0]}
        rows = [("k_a", "all", "shared", 3.0e7), ("c_b", "all", "shared", 300.0), ("phase", "a", "nuisance", 0.1)]
        expected = {"k_a": 3.0e7, "c_b": 300.0, "m_e": 0.020}
    idn.write_parameters(_parameter_table(rows), tmp_path / "parameters.tsv")
    out = {"campbell": tmp_path / "campbell.png", "table": tmp_path / "campbell.tsv", "modes": tmp_path / "modes.png",
           "campbell_html": tmp_path / "campbell.html", "modes_html": tmp_path / "modes.html"}
    fake = SimpleNamespace(input=SimpleNamespace(parameters=str(tmp_path / "parameters.tsv")),
                           output=SimpleNamespace(**{k: str(v) for k, v in out.items()}),
                           params=SimpleNamespace(model=model, runs=runs), wildcards=SimpleNamespace(variant=name),
                           log=[str(tmp_path / "report_machine.log")])
    try:
        runpy.run_path(str(Path(__file__).resolve().parents[1] / "scripts" / "report_machine.py"),
                       init_globals={"snakemake": fake})
    finally:
        logging.captureWarnings(False)
    variant = cfg.variant(model, name)
    values = {k: float(v) for k, v in variant.values(expected).items()}
    reference = branches(campbell(variant.model, values, report_speeds(runs["rpm"]), 12))
    table = pd.read_csv(out["table"], sep="\t")
    assert table.rpm.max() == pytest.approx(1.25 * max(runs["rpm"]))
    merged = table.merge(reference, on=["rpm", "mode"], suffixes=("", "_reference"))
    assert len(merged) == len(table) > 0
    np.testing.assert_allclose(merged.frequency_hz, merged.frequency_hz_reference, rtol=1e-8)  # %.9g written
    modes = undamped_modes(variant.model, values, float(np.median(runs["rpm"])), 8)
    log = (tmp_path / "report_machine.log").read_text()
    assert f"mode 1 at {np.median(runs['rpm']):g} RPM: {modes.frequency_hz[0]:.4g} Hz" in log
    for path in (out["campbell"], out["modes"]):
        assert path.stat().st_size > 10_000
    for path in (out["campbell_html"], out["modes_html"]):  # the interactive figures beside them (plotly.js inside)
        assert "plotly" in path.read_text()[:200_000].lower()
