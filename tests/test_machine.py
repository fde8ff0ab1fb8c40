"""The machine description (src/hybridtwin/model/machine.py): the VARM as the bundled default machine, bit for bit
the model built on the uniform ``Shaft``; stepped shafts, disks, rotary and polar inertia against closed-form
integrals; effects placed at named nodes; sensors; the Campbell data.

The independent check of a stepped rotor with disks and gyroscopic coupling against ROSS is tests/test_ross.py.
"""

import numpy as np
import pytest
import scipy.linalg
import yaml
from example_machines import STEPPED_YAML as MACHINE_YAML  # the stepped rotor's config section, shared

from hybridtwin.model.effects import Unbalance, builtin_effects, candidate_effects
from hybridtwin.model.machine import Bearing, Disk, Machine, Sensor, ShaftSegment, UnbalancePlane  # as docs/model.md
from hybridtwin.model.model import Model, campbell
from hybridtwin.model.sensor import sensor_dofs
from hybridtwin.model.shaft import Shaft
from hybridtwin.solvers.solver import solve
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant, builtin_variant
from hybridtwin.solvers.solver import solve_variant

STEEL = dict(E=211e9, rho=7810.0)


def _stepped(rotary_inertia=False):
    """A stepped shaft (three sections, one hollow), two disks, two bearings inside the span."""
    return Machine(
        "stepped",
        [ShaftSegment(0.2, 0.04, n_elements=4, **STEEL), ShaftSegment(0.5, 0.05, d_in=0.02, n_elements=10, **STEEL),
         ShaftSegment(0.3, 0.035, n_elements=3, **STEEL)],
        disks=[Disk(8, 15.3, 0.12, 0.062, "d1"), Disk(16, 7.4, 0.037, 0.019, "d2")],
        bearings=[Bearing("a", 2, k=2e7, c=800.0), Bearing("b", 13, k=1e7, c=500.0)],
        unbalance_planes=[UnbalancePlane("d1", 8)],
        sensors=[Sensor("x1", 8, "x"), Sensor("y1", 8, "y"), Sensor("x2", 16, "x")],
        rotary_inertia=rotary_inertia,
    )


# --- the VARM, bit for bit ------------------------------------------------------------------------


def test_varm_structure_is_the_uniform_shaft_bit_for_bit():
    varm, shaft = Machine.varm(), Shaft()
    for a, b in zip(varm.matrices(), shaft.matrices()):
        assert np.array_equal(a, b)
    assert (varm.n, varm.n_dof, varm.L) == (shaft.n, shaft.n_dof, shaft.L)
    assert np.array_equal(varm.z, shaft.z)
    for name in ("u0", "dv10", "v3", "du7"):
        assert varm.dof(name) == shaft.dof(name)
    z = np.random.default_rng(0).uniform(0, shaft.L, 2000)  # random: no exact mid-point ties
    assert [varm.node_at(v) for v in z] == [shaft.node_at(v) for v in z]
    assert (varm.node("upper"), varm.node("lower"), varm.node("eccentric_mass")) == (0, 10, 5)
    assert varm.sensor_node == 1 and sensor_dofs(varm) == sensor_dofs(shaft) == [2, 24]


def _systems_equal(a, b):
    for name in ("M", "C", "K", "Omega"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert sorted(a.forcing) == sorted(b.forcing)
    for h in a.forcing:
        assert np.array_equal(a.forcing[h], b.forcing[h])
    assert [f.name for f in a.forces] == [f.name for f in b.forces]


@pytest.mark.parametrize("name", sorted(BUILTIN_VARIANTS))
def test_varm_models_are_bit_for_bit_those_of_the_shaft(name):
    """Every paper variant plus every candidate effect (non-zero), three scenarios at three speeds: the same
    matrices, forcing and nonlinear forces, and the same steady state, on Shaft(), Machine.varm() and the
    default structure."""
    spec = dict(BUILTIN_VARIANTS[name])
    spec["effects"] = spec["effects"] + [e.name for e in candidate_effects()]
    on_shaft = Variant.from_spec(name, spec, shaft=Shaft())
    on_machine = Variant.from_spec(name, spec, shaft=Machine.varm())
    by_default = Variant.from_spec(name, spec)
    assert isinstance(by_default.model.shaft, Machine)
    rng = np.random.default_rng(1)
    overrides = {k: rng.uniform(*on_shaft.model.parameters[k].bounds, 3) for k in on_shaft.unknown}
    overrides |= {"m_e": np.array([0.0148, 0.0259, 0.0]), "dk_up": 100.0, "k_xy": 20.0, "c_xy": 0.5,
                  "k_rot": 30.0, "dk_lo": -300.0, "f2_c": 0.05, "f3_s": -0.02, "e2_c": 4e-6, "zeta_v": 0.01}
    rpm = np.array([400.0, 650.0, 800.0])
    reference = on_shaft.system(rpm, overrides)
    for other in (on_machine, by_default):
        _systems_equal(reference, other.system(rpm, overrides))
    expected = solve(reference, 5)
    for other in (on_machine, by_default):
        result = solve_variant(other, rpm, overrides, harmonics=5)
        assert np.array_equal(result.harmonics, expected.harmonics)
        assert np.array_equal(result.status, expected.status)


def test_unbalance_plane_is_the_z_me_unbalance_on_the_varm():
    varm = Machine.varm()
    base = [e for e in builtin_variant("geometric").model.effects if e.name != "unbalance"]
    plane = Model(base + [varm.effects()["unbalance@eccentric_mass"]], varm)
    z_me = Model(base + [Unbalance()], varm)
    values = {k: p.nominal for k, p in z_me.parameters.items()} | {"m_e": 0.0259}
    _systems_equal(z_me.system(values, [500.0, 900.0]), plane.system(values, [500.0, 900.0]))


# --- stepped shaft, disks, rotary and polar inertia -----------------------------------------------


def test_segments_of_one_section_assemble_as_the_uniform_shaft():
    shaft = Shaft(L=1.2, n=12, E=200e9, I=3e-8, m=4.0)
    split = Machine("split", [ShaftSegment(0.3, 0.03, 200e9, 7800.0, n_elements=3, I=3e-8, m=4.0),
                              ShaftSegment(0.9, 0.03, 200e9, 7800.0, n_elements=9, I=3e-8, m=4.0)])
    K, M = split.matrices()
    K0, M0 = shaft.matrices()
    # element lengths 0.3/3 and 0.9/9 are both 0.1 but can differ in the last bit: round-off only
    np.testing.assert_allclose(K, K0, rtol=1e-12, atol=1e-12 * np.abs(K0).max())
    np.testing.assert_allclose(M, M0, rtol=1e-12, atol=1e-12 * np.abs(M0).max())


def _rigid(machine, kind):
    """Rigid-body motion of the x plane: translation (u = 1) or tilt about z = 0 (u = z, du = 1)."""
    t = np.zeros(machine.n_plane)
    if kind == "translation":
        t[0::2] = 1.0
    else:
        t[0::2], t[1::2] = machine.z, 1.0
    return t


@pytest.mark.parametrize("rotary_inertia", [False, True])
def test_mass_matrix_carries_the_rotor_mass_and_inertia(rotary_inertia):
    """Cubic Hermite elements represent rigid motion exactly, so t^T M t is the rotor's kinetic-energy
    integral written out here in closed form: sum of rho A L + disk masses (translation), and
    sum of rho A (b^3 - a^3) / 3 + m_d z_d^2 + I_d (+ rho I L with rotary inertia) for the tilt."""
    machine = _stepped(rotary_inertia)
    _, M = machine.plane_matrices()
    starts = np.cumsum([0.0] + [s.length for s in machine.segments])
    mass = sum(STEEL["rho"] * np.pi * (s.d_out**2 - s.d_in**2) / 4 * s.length for s in machine.segments)
    mass += sum(d.mass for d in machine.disks)
    t = _rigid(machine, "translation")
    assert t @ M @ t == pytest.approx(mass, rel=1e-12)
    tilt = sum(STEEL["rho"] * np.pi * (s.d_out**2 - s.d_in**2) / 4 * (b**3 - a**3) / 3
               for s, a, b in zip(machine.segments, starts[:-1], starts[1:]))
    tilt += sum(d.mass * machine.z[d.node] ** 2 + d.I_d for d in machine.disks)
    if rotary_inertia:
        tilt += sum(STEEL["rho"] * np.pi * (s.d_out**4 - s.d_in**4) / 64 * s.length for s in machine.segments)
    t = _rigid(machine, "tilt")
    assert t @ M @ t == pytest.approx(tilt, rel=1e-12)


def test_stiffness_uses_the_section_of_each_segment():
    """A cantilever clamped at node 0 under a tip load P: tip deflection P sum of the segments' flexibility
    integrals int (L - z)^2 / (E I(z)) dz (beam theory; cubic elements are exact for point loads)."""
    machine = _stepped()
    K, _ = machine.plane_matrices()
    free = np.arange(2, machine.n_plane)
    f = np.zeros(machine.n_plane)
    f[-2] = 1.0
    q = np.linalg.solve(K[np.ix_(free, free)], f[free])
    L = machine.L
    starts = np.cumsum([0.0] + [s.length for s in machine.segments])
    expected = sum(((L - a) ** 3 - (L - b) ** 3) / 3 / (s.E * np.pi * (s.d_out**4 - s.d_in**4) / 64)
                   for s, a, b in zip(machine.segments, starts[:-1], starts[1:]))
    assert q[-2] == pytest.approx(expected, rel=1e-10)


def test_gyroscopic_matrix_is_the_polar_inertia_coupling_the_slopes():
    """G is skew-symmetric; between rigid tilts of the x and y planes it holds the rotor's polar inertia,
    sum of rho I_p L + disk I_p, with G[du, dv] > 0 (Omega about +z; docs/model.md)."""
    machine = _stepped()
    G = machine.gyroscopic_matrix()
    assert np.array_equal(G, -G.T)
    n = machine.n_plane
    tilt = _rigid(machine, "tilt")
    polar = sum(STEEL["rho"] * np.pi * (s.d_out**4 - s.d_in**4) / 32 * s.length for s in machine.segments)
    polar += sum(d.I_p for d in machine.disks)
    assert tilt @ G[:n, n:] @ tilt == pytest.approx(polar, rel=1e-12)
    assert G[machine.dof("du8"), machine.dof("dv8")] > 0.12  # the disk's 0.12 plus the shaft's share


def test_gyroscopic_stiffening_of_a_spinning_disk():
    """A rigid disk held only by a rotational spring k_t on its tilt (the shaft's other DOFs made
    negligible): I_d w^2 -+ I_p Omega w - k_t = 0, so the forward whirl rises and the backward falls with
    speed, w = (+-I_p Omega + sqrt(I_p^2 Omega^2 + 4 I_d k_t)) / (2 I_d)."""
    I_p, I_d, k_t = 0.2, 0.1, 4.0e4
    # a 10 mm stub of 1 mm diameter, E = 1 kPa: its bending stiffness (4 EI/h = 2e-8 N m) and inertia
    # (1e-11 of the disk's) are negligible; its far node is clamped by stiff springs
    machine = Machine("disk", [ShaftSegment(0.01, 1e-3, 1e3, 7800.0)], disks=[Disk(0, 1.0, I_p, I_d)])

    from hybridtwin.model.effect_base import Effect, Parameter

    class Holder(Effect):
        name, meaning = "holder", "translation held, tilt on a spring k_t"
        parameters = (Parameter("k_t", "N m/rad", (0.0, 1e5), k_t, "tilt spring"),)

        def stiffness(self, ctx):
            out = ctx.zeros()
            for dof, value in (("u0", 1e12), ("v0", 1e12), ("u1", 1e12), ("v1", 1e12), ("du1", 1e12),
                               ("dv1", 1e12), ("du0", k_t), ("dv0", k_t)):
                out[:, ctx.dof(dof), ctx.dof(dof)] = value
            return out

    model = Model([Holder(), machine.effects()["gyroscopic"]], machine)
    table = campbell(model, {"k_t": k_t}, [3000.0], n_modes=2)
    Omega = 3000.0 * 2 * np.pi / 60
    root = np.sqrt(I_p**2 * Omega**2 + 4 * I_d * k_t)
    forward, backward = (I_p * Omega + root) / (2 * I_d), (-I_p * Omega + root) / (2 * I_d)
    got = table.set_index("whirl")["frequency_hz"] * 2 * np.pi
    # the stub's share is below 1e-8: 1e-7 relative
    assert got["forward"] == pytest.approx(forward, rel=1e-7)
    assert got["backward"] == pytest.approx(backward, rel=1e-7)


# --- names, placement, sensors, validation ----------------------------------------------------------


def test_effects_are_placed_at_named_bearings():
    machine = _stepped()
    effects = machine.effects()
    assert {"gyroscopic", "linear_bearing@a", "linear_bearing@b", "lower_bearing@b", "geometric_spring@a",
            "unbalance@d1"} <= set(effects)
    lower = effects["lower_bearing@b"]
    assert lower.node == 13 and builtin_effects()["lower_bearing"].node is None  # the built-in is untouched
    # a placed effect says where it acts, not the VARM's place (its upper or lower bearing, node 0, lowest node)
    for name, effect in effects.items():
        if "@" in name:
            assert not any(words in effect.meaning for words in ("upper bearing", "lower bearing", "node 0",
                                                                   "lowest node")), (name, effect.meaning)
    assert "at node 13" in lower.meaning and "bearing a" in effects["excitation_2x@a"].meaning
    assert "upper bearing" in builtin_effects()["excitation_2x"].meaning  # the built-ins keep theirs
    spring = effects["geometric_spring@a"]
    assert spring.dofs == ("u2", "v2")
    model = Model([effects["linear_bearing@a"], effects["linear_bearing@b"], lower], machine)
    values = {k: p.nominal for k, p in model.parameters.items()}
    K = model.system(values, 0.0).K[0] - machine.matrices()[0]
    expected = np.zeros_like(K)
    for dof, k in (("u2", 2e7), ("v2", 2e7), ("u13", 1e7 + 1e4), ("v13", 1e7 + 1e4)):
        expected[machine.dof(dof), machine.dof(dof)] = k
    np.testing.assert_array_equal(K, expected)
    with pytest.raises(ValueError, match="cannot be placed"):
        machine.place(candidate_effects()[0], "a")
    with pytest.raises(ValueError, match="no bearing, unbalance plane or sensor named 'c'"):
        machine.node("c")


def test_sensors_by_name_node_and_direction():
    machine = _stepped()
    assert machine.sensor_dofs() == [machine.dof("u8"), machine.dof("v8"), machine.dof("u16")]
    assert machine.sensor_planes == [8, 16]
    # every sensor is a channel (sensor_dofs, declared order); the orbit is the first node with an x and a y probe
    assert sensor_dofs(machine) == machine.sensor_dofs()
    assert machine.sensor_node == 8 and machine.sensor_pairs == [(0, 1)]
    assert sensor_dofs(machine, 8) == [machine.dof("u8"), machine.dof("v8")]
    one_plane = Machine("p", machine.segments, sensors=[Sensor("a", 3, "x"), Sensor("b", 3, "y")])
    assert sensor_dofs(one_plane) == [one_plane.dof("u3"), one_plane.dof("v3")]
    # the machine keeps its sensors plane by plane, x then y (planes in order of first appearance), unpaired probes
    # last: the channel order the per-run figure (consecutive pairs) and the whirl check (channels 0, 1) rely on
    two = Machine("p", machine.segments, sensors=[Sensor("y2", 9, "y"), Sensor("x1", 3, "x"), Sensor("z", 5, "x"),
                                                  Sensor("x2", 9, "x"), Sensor("y1", 3, "y")])
    assert [s.name for s in two.sensors] == ["x2", "y2", "x1", "y1", "z"]
    assert two.sensor_node == 9 and two.sensor_pairs == [(0, 1), (2, 3)]
    assert two.sensor_dofs() == [two.dof("u9"), two.dof("v9"), two.dof("u3"), two.dof("v3"), two.dof("u5")]
    # a mapping written with sorted keys (yaml.safe_dump) reads as the same machine
    spec = yaml.safe_load(MACHINE_YAML)["machine"]
    spec["sensors"] = {"x1": {"node": 8, "direction": "x"}, "x2": {"node": 16, "direction": "x"},
                       "y1": {"node": 8, "direction": "y"}, "y2": {"node": 16, "direction": "y"}}
    assert [s.name for s in Machine.from_mapping(spec).sensors] == ["x1", "y1", "x2", "y2"]
    lone = Machine("p", machine.segments, sensors=[Sensor("a", 3, "x"), Sensor("b", 4, "y")])
    with pytest.raises(ValueError, match="no node with both an x and a y probe"):
        lone.sensor_node


@pytest.mark.parametrize("declared", [["x1", "x2", "y1", "y2"], ["y3", "x1", "x2", "y1"]])
def test_records_read_with_the_configs_sensors_have_the_machines_channel_order(tmp_path, declared):
    """The workflow reads records with the config's sensors mapping (rule params), the model's sensor DOFs come
    from the Machine: both must give the channels in the same order, or the fit compares one probe's measurement
    with another's model (a sorted-keys config, x1 x2 y1 y2; a config with probes that have no partner). The
    record's file columns are in yet another order: channels are found by name."""
    from hybridtwin.data.records import read_record, record_channels

    nodes = {"x1": (8, "x"), "y1": (8, "y"), "x2": (16, "x"), "y2": (16, "y"), "y3": (12, "y")}
    spec = yaml.safe_load(MACHINE_YAML)["machine"]
    spec["sensors"] = {name: {"node": nodes[name][0], "direction": nodes[name][1]} for name in declared}
    machine = Machine.from_mapping(spec)
    names, pairs = record_channels(spec["sensors"])
    assert names == tuple(s.name for s in machine.sensors) and list(pairs) == machine.sensor_pairs
    assert names[:2] == ("x1", "y1")  # a plane's x, then its y, first
    t = np.arange(200) / 2000.0
    columns = sorted(declared, reverse=True)
    path = tmp_path / "r.csv"
    path.write_text("time_s," + ",".join(f"{c}_mm" for c in columns) + "\n" + "\n".join(
        f"{x:.6f}," + ",".join(f"{k + 1}" for k, _ in enumerate(columns)) for x in t) + "\n")
    record = read_record(path, spec["sensors"])
    assert list(record.channels) == list(names)
    for k, c in enumerate(columns):  # each channel holds its own column's values
        assert np.all(record.channels[c] == (k + 1) * 1e-3)


def test_sensor_names_in_capitals_read_their_columns_in_any_case(tmp_path):
    """Sensors X1, Y1 (the schema allows capitals): their records' columns X1_mm, Y1_mm (as the rig writes them)
    or x1_mm, y1_mm (headers are read in any case) are their channels, named as the machine names them; two
    sensors whose names differ only in case are an error, since no record could tell their columns apart."""
    from hybridtwin.data.records import read_record

    spec = yaml.safe_load(MACHINE_YAML)["machine"]
    spec["sensors"] = {"X1": {"node": 8, "direction": "x"}, "Y1": {"node": 8, "direction": "y"}}
    t = np.arange(100) / 2000.0
    for header in ("time_s,X1_mm,Y1_mm", "TIME_S,x1_mm,y1_MM"):
        path = tmp_path / "r.csv"
        path.write_text(header + "\n" + "\n".join(f"{x:.6f},1,2" for x in t) + "\n")
        record = read_record(path, spec["sensors"])
        assert list(record.channels) == ["X1", "Y1"], header
        assert np.all(record.channels["X1"] == 1e-3) and np.all(record.channels["Y1"] == 2e-3)
    spec["sensors"]["x1"] = {"node": 4, "direction": "x"}
    with pytest.raises(ValueError, match="'X1', 'x1' differ only in case"):
        Machine.from_mapping(spec)


@pytest.mark.parametrize("kwargs, message", [
    (dict(disks=[Disk(40, 1.0)]), "disk at node 40: nodes are the integers 0..17"),
    (dict(sensors=[Sensor("s", 2.0, "x")]), "sensor 's' at node 2.0: nodes are the integers 0..17"),
    (dict(bearings=[Bearing("a", 1), Bearing("a", 3)]), "the name 'a' is used twice"),
    (dict(bearings=[Bearing("a b", 1)]), "must be a non-empty identifier"),
    (dict(bearings=[Bearing("a", 1, k=-1.0)]), "k and c must be >= 0"),
    (dict(segments=[]), "at least one segment"),
])
def test_invalid_machines_are_refused_in_one_line(kwargs, message):
    spec = dict(name="bad", segments=_stepped().segments) | kwargs
    with pytest.raises(ValueError, match=message) as err:
        Machine(**spec)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kwargs, message", [
    (dict(length=-1.0), "length must be a positive number"),
    (dict(d_in=0.05), "d_in must be in"),
    (dict(n_elements=0), "n_elements must be a positive integer"),
    (dict(I=0.0), "I must be positive"),
])
def test_invalid_segments_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ShaftSegment(**(dict(length=0.1, d_out=0.04, **STEEL) | kwargs))
    with pytest.raises(ValueError, match="direction must be 'x' or 'y'"):
        Sensor("s", 1, "z")


# --- Campbell data --------------------------------------------------------------------------------


def test_campbell_at_rest_is_the_first_mode_of_the_undamped_varm():
    """Without damping the lowest whirl frequency at rest is omega_1 of docs/model.md (scipy's eigh on the
    x-plane pencil); the x and y planes give it twice."""
    variant = builtin_variant("geometric")
    values = variant.values({"zeta_s": 0.0, "zeta_bup": 0.0, "zeta_blo": 0.0, "m_e": 0.0148})
    ctx = variant.model.context(values, 0.0)
    n = variant.model.shaft.n_plane
    omega_1 = np.sqrt(scipy.linalg.eigh(ctx.K[0, :n, :n], ctx.M[0, :n, :n], eigvals_only=True)[0])
    table = campbell(variant.model, {k: float(v) for k, v in values.items()}, [0.0, 600.0], n_modes=4)
    at_rest = table[table.rpm == 0.0]
    # state-space eig against eigh of the same pencil: round-off (1e-9 relative)
    np.testing.assert_allclose(at_rest.frequency_hz.iloc[:2], omega_1 / (2 * np.pi), rtol=1e-9)
    np.testing.assert_allclose(at_rest.damping_ratio.iloc[:2], 0.0, atol=1e-9)
    spinning = table[table.rpm == 600.0]
    # the VARM's centrifugal term -Omega^2 M softens: the lowest frequency falls with speed
    assert spinning.frequency_hz.iloc[0] < at_rest.frequency_hz.iloc[0]
    assert list(table.columns) == ["rpm", "mode", "frequency_hz", "damping_ratio", "whirl", "whirl_index"]


# --- the machine: section of the config -----------------------------------------------------------

@pytest.fixture
def project(tmp_path, monkeypatch):
    """A project folder (cwd) with the bundled config and runs sheet."""
    from pathlib import Path
    import shutil

    root = Path(__file__).resolve().parents[1]
    (tmp_path / "config").mkdir()
    shutil.copy(root / "config" / "config.yaml", tmp_path / "config" / "config.yaml")
    (tmp_path / "data" / "default").mkdir(parents=True)
    shutil.copy(root / "data" / "default" / "runs.tsv", tmp_path / "data" / "default" / "runs.tsv")
    monkeypatch.chdir(tmp_path)
    return tmp_path, root / "src" / "hybridtwin" / "config.schema.yaml"


def _config(project, overlay: str):
    """The bundled config with ``overlay``'s top-level keys and variants added; the ConfigError lines or []."""
    import yaml

    from hybridtwin.config import ConfigError, check

    folder, schema = project
    config = yaml.safe_load((folder / "config" / "config.yaml").read_text())
    extra = yaml.safe_load(overlay)
    config |= {k: v for k, v in extra.items() if k != "variants"}
    config["variants"] |= extra.get("variants", {})
    (folder / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    try:
        check(config, schema, [folder / "config" / "config.yaml"])
    except ConfigError as err:
        return config, err.problems
    return config, []


def test_config_machine_builds_the_same_model_as_the_python_api(project):
    from hybridtwin import config as cfg

    config, problems = _config(project, MACHINE_YAML)
    assert problems == []
    variant = cfg.variant(config, "linear")
    rotor = variant.model.shaft
    reference = _stepped()
    assert isinstance(rotor, Machine) and rotor.n == reference.n == 17
    assert [b.node for b in rotor.bearings] == [2, 13] and rotor.sensor_node == 8
    fx = reference.effects()
    model = Model([fx["linear_bearing@a"], fx["linear_bearing@b"], fx["gyroscopic"], fx["unbalance@d1"]], reference)
    values = variant.values({"m_e": 0.002})
    _systems_equal(model.system(values, [1000.0, 3000.0]), variant.system([1000.0, 3000.0], {"m_e": 0.002}))


def test_config_without_machine_is_the_varm(project):
    from hybridtwin import config as cfg

    config, problems = _config(project, "{}")
    assert problems == [] and "machine" not in config
    variant = cfg.variant(config, "geometric")
    _systems_equal(variant.system([500.0, 900.0], {"m_e": 0.0148}),
                   builtin_variant("geometric", Shaft()).system([500.0, 900.0], {"m_e": 0.0148}))


@pytest.mark.parametrize("edit, expected", [
    (("segments", 0, "E"), "machine.segments: missing key 'E'"),
    (("disks", 0, "node", 40), "machine: machine 'stepped': disk 'd1' at node 40: nodes are the integers 0..17"),
    (("sensors", "x1", "node", 16), "machine.sensors: machine 'stepped': sensors"),
    (("bearings", "a", "nodes", 2), "machine.bearings.a: unknown key 'nodes' (did you mean 'node'?"),
    (("bearings", "a", "k"), "no effect named 'linear_bearing@a': bearing 'a' is declared without its nominal k "
                             "(and c) in machine.bearings (e.g. a: {node: 2, k: 2.0e+06, c: 300})"),
])
def test_bad_machine_sections_are_one_line_each(project, edit, expected):
    import yaml

    spec = yaml.safe_load(MACHINE_YAML)
    target = spec["machine"]
    *path, key = edit[:-1] if len(edit) == 4 else edit
    for step in path:
        target = target[step]
    if len(edit) == 4:
        target[key] = edit[-1]
    else:
        del target[key]
    _, problems = _config(project, yaml.safe_dump(spec))
    assert problems, "the bad section passed"
    assert any(expected in p for p in problems), problems
    assert all("config.yaml, line" in p and "\n" not in p for p in problems)


@pytest.mark.parametrize("spec, message", [
    ({"segments": [{"length": 0.1, "d_out": 0.01, "E": "2e11", "rho": 7800}]},
     "machine.segments[0].E: must be a number, got '2e11'"),
    ({"segments": [{"length": 0.1, "d_out": 0.01, "E": 2e11, "rho": 7800, "n_elements": 2.5}]},
     "machine.segments[0]: shaft segment: n_elements must be a positive integer, got 2.5"),
    ({"segments": {"length": 0.1}}, "machine.segments: must be a list"),
    ({"segments": [], "shaft": 1}, "machine: unknown key(s) ['shaft']"),
    ({"segments": [{"length": 0.1, "d_out": 0.01, "E": 2e11, "rho": 7800}], "sensors": {"s": {"node": 1}}},
     "machine.sensors.s: missing key(s) ['direction']"),
])
def test_machine_from_mapping_names_the_bad_key(spec, message):
    """The Python path (without the schema) says where in the section the problem is, in one line."""
    from hybridtwin.model.machine_parts import MachineSpecError

    with pytest.raises(MachineSpecError) as err:
        Machine.from_mapping(spec)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_machine_from_mapping_of_nothing_is_the_varm():
    for a, b in zip(Machine.from_mapping(None).matrices(), Shaft().matrices()):
        assert np.array_equal(a, b)


# --- Campbell diagram (machine_plots) ----------------------------------------------------------------


def _spinning_disk(I_p, I_d, k_t):
    """The rigid disk on a tilt spring of test_gyroscopic_stiffening_of_a_spinning_disk, as a model."""
    from hybridtwin.model.effect_base import Effect, Parameter

    machine = Machine("disk", [ShaftSegment(0.01, 1e-3, 1e3, 7800.0)], disks=[Disk(0, 1.0, I_p, I_d)])

    class Holder(Effect):
        name, meaning = "holder", "translation held, tilt on a spring k_t"
        parameters = (Parameter("k_t", "N m/rad", (0.0, 1e5), k_t, "tilt spring"),)

        def stiffness(self, ctx):
            out = ctx.zeros()
            for dof, value in (("u0", 1e12), ("v0", 1e12), ("u1", 1e12), ("v1", 1e12), ("du1", 1e12),
                               ("dv1", 1e12), ("du0", k_t), ("dv0", k_t)):
                out[:, ctx.dof(dof), ctx.dof(dof)] = value
            return out

    return Model([Holder(), machine.effects()["gyroscopic"]], machine)


def test_critical_speeds_of_a_spinning_disk():
    """The 1X line crosses I_d w^2 -+ I_p w Omega = k_t at w = Omega: forward at sqrt(k_t / (I_d - I_p)),
    backward at sqrt(k_t / (I_d + I_p))."""
    from hybridtwin.report.machine_plots import critical_speeds

    I_p, I_d, k_t = 0.05, 0.1, 4.0e4
    rpm = np.linspace(0.0, 12000.0, 401)
    table = campbell(_spinning_disk(I_p, I_d, k_t), {"k_t": k_t}, rpm, n_modes=2)
    crossings = critical_speeds(table, 1).set_index("whirl")["rpm"]
    to_rpm = 60 / (2 * np.pi)
    # linear interpolation over 30 RPM steps of smooth branches: error ~ 1e-6 relative, 1e-4 asserted
    assert crossings["forward"] == pytest.approx(np.sqrt(k_t / (I_d - I_p)) * to_rpm, rel=1e-4)
    assert crossings["backward"] == pytest.approx(np.sqrt(k_t / (I_d + I_p)) * to_rpm, rel=1e-4)


def test_campbell_figure_of_the_varm(tmp_path):
    """Undamped, the VARM's centrifugal term gives w^2 = w_1^2 - Omega^2 (K - Omega^2 M against M), so the
    first mode meets 1X at Omega = w_1 / sqrt(2) (docs/model.md, 'Behaviour to expect'); the figure draws the
    table's branches, the 1X-3X lines and each run speed."""
    import matplotlib

    from hybridtwin.report.machine_plots import campbell_figure

    variant = builtin_variant("geometric")
    values = {k: float(v) for k, v in variant.values({"zeta_s": 0.0, "zeta_bup": 0.0, "zeta_blo": 0.0}).items()}
    runs = [350.0, 500.0, 650.0, 800.0, 950.0]
    fig = campbell_figure(variant.model, values, np.linspace(0.0, 1200.0, 121), run_rpm=runs, n_modes=4)
    ctx = variant.model.context(variant.values(values), 0.0)
    expected = ctx.omega_1[0] / np.sqrt(2) * 60 / (2 * np.pi)
    first = fig.critical[fig.critical.branch == 0]
    assert len(first) == 2  # forward and backward branches coincide without gyroscopic coupling
    # 10 RPM steps along sqrt(w_1^2 - Omega^2): interpolation error < 1e-4 relative
    np.testing.assert_allclose(first.rpm, expected, rtol=1e-4)
    ax = fig.axes[0]
    lines = {line.get_gid(): line for line in ax.get_lines()}
    forward = fig.campbell[(fig.campbell.whirl == "forward") & (fig.campbell.branch == 0)].sort_values("rpm")
    np.testing.assert_array_equal(lines["forward:0"].get_ydata(), forward.frequency_hz)
    for h in (1, 2, 3):
        x, y = lines[f"{h}X"].get_data()
        np.testing.assert_allclose(y, h * np.asarray(x) / 60.0)
    assert sorted(float(lines[f"run:{r:g}"].get_xdata()[0]) for r in runs) == runs
    fig.savefig(tmp_path / "campbell.png")
    assert (tmp_path / "campbell.png").stat().st_size > 10_000
    matplotlib.pyplot.close(fig)


def test_campbell_figure_of_a_stepped_rotor_separates_forward_and_backward():
    from hybridtwin.report.machine_plots import campbell_figure

    machine = _stepped()
    fx = machine.effects()
    model = Model([fx["linear_bearing@a"], fx["linear_bearing@b"], fx["gyroscopic"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()}
    fig = campbell_figure(model, values, np.linspace(0.0, 20000.0, 41), run_rpm=[3000.0], n_modes=6)
    table = fig.campbell
    # the branches of the 6 lowest modes at rest, 3 per whirl sense, each followed over all 41 speeds (the
    # third forward one rises past higher backward modes: computed with twice the modes, never cut off)
    assert table.groupby(["whirl", "branch"]).size().to_dict() == {(w, b): 41 for w in ("backward", "forward")
                                                                     for b in range(3)}
    low = table[table.branch == 0].pivot(index="rpm", columns="whirl", values="frequency_hz")
    assert (low["forward"].iloc[1:] > low["backward"].iloc[1:]).all()  # split by the disks' gyroscopic moments
    assert low["forward"].is_monotonic_increasing and low["backward"].is_monotonic_decreasing
    import matplotlib

    matplotlib.pyplot.close(fig)


# --- the config form back (to_mapping), and the rig's truth on the config's machine -------------------------


@pytest.mark.parametrize("machine", [Machine.varm(), _stepped(), _stepped(rotary_inertia=True)],
                         ids=["varm", "stepped", "stepped_rayleigh"])
def test_to_mapping_rebuilds_the_same_machine(machine):
    import yaml

    mapping = yaml.safe_load(yaml.safe_dump(machine.to_mapping(), sort_keys=False))  # through YAML text
    again = Machine.from_mapping(mapping)
    for a, b in zip(again.matrices(), machine.matrices()):
        assert np.array_equal(a, b)
    assert np.array_equal(again.gyroscopic_matrix(), machine.gyroscopic_matrix())
    assert (again.disks, again.bearings, again.unbalance_planes, again.sensors) == \
        (machine.disks, machine.bearings, machine.unbalance_planes, machine.sensors)
    assert again.is_varm == machine.is_varm == (machine.name == "varm")


def test_a_changed_varm_is_not_the_varm():
    mapping = Machine.varm().to_mapping()
    assert Machine.from_mapping(mapping).is_varm
    mapping["segments"][0]["length"] = 0.9
    assert not Machine.from_mapping(mapping).is_varm


def test_config_rig_truth_uses_the_machines_places(project):
    """A rig entry's truth is checked on the config's machine (as the rig rule builds it): its placed effects
    pass, a bearing the machine does not have is one line naming the entry."""
    rig = ("rig:\n  stepped:\n    truth: {effects: [linear_bearing@a, linear_bearing@b, gyroscopic, unbalance@d1], "
           "values: {k_a: 2.5e+7}}\n")
    _, problems = _config(project, MACHINE_YAML + rig)
    assert problems == []
    _, problems = _config(project, MACHINE_YAML + rig.replace("linear_bearing@b,", "linear_bearing@c,"))
    assert len(problems) == 1 and "rig.stepped" in problems[0] and "'linear_bearing@c'" in problems[0]
