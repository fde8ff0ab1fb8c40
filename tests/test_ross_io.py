"""Speed-dependent bearings (``hybridtwin.model.bearing_table``) and ROSS in and out (``hybridtwin.model.ross_io``),
issue 39 item 3: "A ROSS rotor with speed-dependent bearings round-trips through our machine description with the
same natural frequencies".

The tests of the table itself (interpolation, config form, the effect's matrices, bad tables) run always; those
that build ROSS rotors are skipped, with the reason, where ROSS cannot be imported (pip install -e ".[ross]"), as
tests/test_ross.py's. Tolerance against ROSS: 1e-6, as tests/test_ross.py (the same beam theory on the same mesh,
the same bearing coefficients evaluated by the same scipy calls: the two codes agree to round-off, observed 1.4e-11 on
the frequencies, 1.7e-8 on the damping ratios (small numbers, -Re(lambda) / |lambda| carries the eigensolver's
round-off relative to |lambda|) and 9e-11 on the unbalance response; 1e-6 leaves room for LAPACK differences only,
and is far below the effects the test sees: the bearings' change with speed moves the frequencies by percents
(asserted), and ROSS's spline differs from a linear interpolation of the same table by up to 0.8 % between its rows).
"""

import re
import sys

import numpy as np
import pytest
import yaml
from example_machines import stepped_config
from test_machine import _config, project  # noqa: F401 (the fixture: a project folder with the bundled config)
from test_ross import DISKS, E, G, RHO, SEGMENTS, _ours, rs  # noqa: F401 (rs: the fixture importing ROSS)

from hybridtwin.model.bearing_table import COEFFICIENTS, BearingTable, TableBearing
from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import Bearing, MachineSpecError, ShaftSegment
from hybridtwin.model.model import Model, campbell

RTOL = 1e-6  # see the module docstring
FREQUENCY = np.array([0.0, 200.0, 400.0, 700.0, 1000.0])  # the drive-end table's speeds [rad/s], as ROSS takes them
#: anisotropic (kxx != kyy), cross-coupled, and every coefficient varying with speed, not linearly
DRIVE_END = dict(kxx=2e7 * (1 + 0.5 * np.sin(FREQUENCY / 500)), kyy=1.2e7 * (1 + FREQUENCY / 1000) ** 1.5,
                 kxy=2e6 * FREQUENCY / 1000, kyx=-1.5e6 * (FREQUENCY / 1000) ** 2,
                 cxx=800 + 300 * np.cos(FREQUENCY / 400), cyy=500 + 0.2 * FREQUENCY, cxy=40 * FREQUENCY / 1000,
                 cyx=-30 * (FREQUENCY / 1000) ** 2)
TABLE = {"rpm": [0, 1000, 3000], "kxx": [1e7, 2e7, 3e7], "kxy": [0, 1e6, 3e6], "cxx": [100, 200, 300]}


def _rad_s(rpm):
    return np.asarray(rpm, dtype=float) * 2 * np.pi / 60


# --- the table, without ROSS ---------------------------------------------------------------------------------------


def test_linear_table_interpolates_between_rows_and_holds_its_ends():
    table = BearingTable.from_mapping(TABLE)
    rpm = np.array([-100.0, 0.0, 500.0, 1000.0, 2500.0, 3000.0, 9000.0])  # before, on, between, after the rows
    values = table.at(_rad_s(rpm))
    np.testing.assert_allclose(values["kxx"], [1e7, 1e7, 1.5e7, 2e7, 2.75e7, 3e7, 3e7], rtol=1e-14)
    np.testing.assert_allclose(values["kxy"], [0, 0, 5e5, 1e6, 2.5e6, 3e6, 3e6], rtol=1e-14, atol=1e-8)
    np.testing.assert_allclose(values["kyy"], values["kxx"], rtol=0)  # kyy defaults to kxx, cyy to cxx (as ROSS)
    np.testing.assert_allclose(values["cyy"], [100, 100, 150, 200, 275, 300, 300], rtol=1e-14)
    assert not values["kyx"].any() and not values["cxy"].any()  # the others to 0
    K, C = table.matrices(_rad_s([500.0, 2500.0]))  # (S, 2, 2) over (x, y): [[kxx, kxy], [kyx, kyy]]
    np.testing.assert_allclose(K[:, 0, 1], [5e5, 2.5e6], rtol=1e-14)
    np.testing.assert_allclose(C[:, 1, 1], [150, 275], rtol=1e-14)


def test_ross_rule_extrapolates_beyond_the_ends():
    """ROSS 2.3.0's rule: two rows are a line, continued beyond them (the linear rule holds the end value)."""
    spec = {"rpm": [1000, 2000], "kxx": [1e7, 2e7]}
    ross_rule = BearingTable.from_mapping(spec | {"interpolation": "ross"})
    linear = BearingTable.from_mapping(spec)
    np.testing.assert_allclose(ross_rule.at(_rad_s([1500.0, 3000.0]))["kxx"], [1.5e7, 3e7], rtol=1e-12)
    np.testing.assert_allclose(linear.at(_rad_s([1500.0, 3000.0]))["kxx"], [1.5e7, 2e7], rtol=1e-12)


def test_table_in_the_config_round_trips_and_offers_its_effect():
    spec = {"name": "t", "segments": [{"length": 1.0, "d_out": 0.05, "E": 2.11e11, "rho": 7810, "n_elements": 10}],
            "bearings": {"a": {"node": 0, "k": 1e7, "c": 100.0}, "b": {"node": 10, "table": TABLE}}}
    machine = Machine.from_mapping(spec)
    assert Machine.from_mapping(machine.to_mapping()).to_mapping() == machine.to_mapping()
    assert machine.to_mapping()["bearings"]["b"]["table"]["kyy"] == [1e7, 2e7, 3e7]
    effects = machine.effects()
    assert isinstance(effects["bearing_table@b"], TableBearing) and "linear_bearing@b" not in effects
    assert "bearing_table@a" not in effects and effects["linear_bearing@a"].k == 1e7  # the isotropic one as before
    assert not any(name.endswith("@b") and "cross_coupled" in name for name in effects)  # no candidates sized to k
    assert "table of 3 speeds 0..3000 RPM" in machine.describe()


def test_table_bearing_puts_the_coefficients_at_its_node():
    """The effect's K (at rest and with speed) and C at 500 and 2500 RPM: the table's values at the node's (u, v),
    nothing elsewhere; the stiffness at rest is the table's at 0 RPM (seen by the first mode at rest)."""
    machine = Machine("t", [ShaftSegment(1.0, 0.05, 2.11e11, 7810.0, n_elements=4)],
                      bearings=[Bearing("a", 0, k=1e7, c=10.0),
                                Bearing("b", 4, table=BearingTable.from_mapping(TABLE))])
    fx = machine.effects()
    bare = Model([fx["linear_bearing@a"]], machine).system({"k_a": 1e7, "c_a": 10.0}, [500.0, 2500.0])
    model = Model([fx["linear_bearing@a"], fx["bearing_table@b"]], machine)
    system = model.system({"k_a": 1e7, "c_a": 10.0}, [500.0, 2500.0])
    u, v = machine.dof("u4"), machine.dof("v4")
    dK, dC = system.K - bare.K, system.C - bare.C
    np.testing.assert_allclose(dK[:, [u, u, v, v], [u, v, u, v]], [[1.5e7, 5e5, 0, 1.5e7], [2.75e7, 2.5e6, 0, 2.75e7]],
                               rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(dC[:, [u, v], [u, v]], [[150, 150], [275, 275]], rtol=1e-12)
    dK[:, [u, u, v, v], [u, v, u, v]] = 0
    dC[:, [u, u, v, v], [u, v, u, v]] = 0
    assert not dK.any() and not dC.any()
    rest = model.at_rest({"k_a": 1e7, "c_a": 10.0})
    assert rest.K_support[0, u, u] == 1e7 and rest.K_support[0, u, v] == 0.0  # kxx(0 RPM), kxy(0 RPM) = 0
    assert rest.K_support[0, machine.dof("u0"), machine.dof("u0")] == 1e7  # bearing a's k


@pytest.mark.parametrize("table, message", [
    ({"rpm": [0, 1000], "kxx": [1e7]}, "machine.bearings.b.table: kxx: has 1 values, rpm has 2"),
    ({"rpm": [1000, 0], "kxx": [1e7, 2e7]}, "rpm: speeds must be >= 0 and strictly increasing"),
    ({"rpm": [0, 1000], "kxx": [1e7, "2e7"]}, "kxx: must be a list of finite numbers"),
    ({"rpm": [0, 1000], "cxx": [1, 2]}, "missing key(s) ['kxx']"),
    ({"rpm": [0], "kxx": [1e7], "kzz": [1.0]}, "unknown key(s) ['kzz']"),
    ({"rpm": [0], "kxx": [1e7], "interpolation": "cubic"}, "interpolation: must be one of linear, ross"),
])
def test_bad_tables_are_refused_naming_the_key(table, message):
    spec = {"segments": [{"length": 1.0, "d_out": 0.05, "E": 2.11e11, "rho": 7810, "n_elements": 4}],
            "bearings": {"b": {"node": 4, "table": table}}}
    with pytest.raises(MachineSpecError) as err:
        Machine.from_mapping(spec)
    assert message in str(err.value)


def test_a_bearing_with_k_and_a_table_is_refused():
    with pytest.raises(MachineSpecError, match=r"machine.bearings.b: bearing 'b': give either k \(and c\) or a table"):
        Machine.from_mapping({"segments": [{"length": 1.0, "d_out": 0.05, "E": 2.11e11, "rho": 7810}],
                              "bearings": {"b": {"node": 1, "k": 1e7, "table": {"rpm": [0], "kxx": [1e7]}}}})


@pytest.mark.parametrize("change, expected", [
    ({}, None),
    ({"kxy": [0, 2e5]}, "machine.bearings.b.table: kxy: has 2 values, rpm has 3"),
    ({"kzz": [1, 2, 3]}, "kzz"),
])
def test_a_table_in_the_workflow_config(project, change, expected):  # noqa: F811 (the fixture)
    """The stepped rotor's bearing b as a table in config.yaml, its variant on bearing_table@b: the check passes;
    a bad table is one line, at its place in the file."""
    spec = stepped_config()
    spec["machine"]["bearings"]["b"] = {"node": 13, "table": {
        "rpm": [0, 3000, 6000], "kxx": [1e7, 1.2e7, 1.5e7], "kyy": [0.8e7, 1e7, 1.3e7], "kxy": [0, 2e5, 5e5],
        "cxx": [500, 520, 560]} | change}
    spec["variants"]["linear"] = {"effects": ["linear_bearing@a", "bearing_table@b", "gyroscopic", "unbalance@d1"],
                                  "unknown": {"k_a": [1.0e+7, 4.0e+7]}}
    _, problems = _config(project, yaml.safe_dump(spec))
    if expected is None:
        assert problems == []
    else:
        assert len(problems) == 1 and expected in problems[0] and "config.yaml, line" in problems[0], problems


def test_without_ross_the_functions_say_how_to_install_it(monkeypatch):
    from hybridtwin.model import ross_io

    monkeypatch.setitem(sys.modules, "ross", None)  # `import ross` now raises ImportError
    with pytest.raises(ImportError, match=r'pip install -e "\.\[ross\]"'):
        ross_io.machine_to_ross(_ours(True, True)[0])


# --- ROSS in and out -----------------------------------------------------------------------------------------------


def _ross_rotor(rs, extra_mass=0.0):
    """The stepped rotor of test_ross.py in ROSS (Timoshenko), its drive-end bearing speed-dependent, anisotropic
    and cross-coupled (DRIVE_END), its free-end one constant but anisotropic and cross-coupled; ``extra_mass`` [kg]
    on the first disk (our unbalance plane's point mass)."""
    steel = rs.Material(name="Steel_check", rho=RHO, E=E, G_s=G)
    elements = [rs.ShaftElement(L=length / n, idl=0.0, odl=d, material=steel)
                for length, d, n in SEGMENTS for _ in range(n)]
    disks = [rs.DiskElement(n=node, m=m + (extra_mass if i == 0 else 0.0), Id=I_d, Ip=I_p)
             for i, (node, m, I_p, I_d) in enumerate(DISKS)]
    bearings = [rs.BearingElement(n=2, frequency=FREQUENCY, **DRIVE_END, tag="drive_end"),
                rs.BearingElement(n=16, kxx=1e7, kyy=1.3e7, kxy=1e5, cxx=500.0, tag="free end")]
    return rs.Rotor(elements, disks, bearings, tag="stepped")


def test_ross_rotor_with_speed_dependent_bearings_has_our_campbell(rs, tmp_path):
    """ROSS rotor -> machine_from_ross -> our Campbell at 5 speeds (inside and beyond the table) against ROSS's
    run_modal: damped frequencies and damping ratios of the 8 lowest lateral modes, and the whirl where ROSS calls
    it forward or backward (it calls 'mixed' a mode whose nodes whirl both ways; ours is the net sense). Then back
    to ROSS: the same machine again, and ROSS's eigenvalues of it those of the rotor it came from."""
    from hybridtwin.model.ross_io import machine_from_ross, machine_to_ross

    rotor = _ross_rotor(rs)
    rotor.save(tmp_path / "stepped.toml")
    machine = machine_from_ross(tmp_path / "stepped.toml")  # ROSS's file form
    assert machine.to_mapping() | {"name": "stepped"} == machine_from_ross(rotor).to_mapping()  # the file has no tag
    assert machine.shear and machine.rotary_inertia and len(machine.segments) == 3
    drive, free = machine.bearings
    # ROSS 2's frequency is the speed (its spline, ours "ross"); ROSS 3's is the whirl frequency, read synchronously
    # (whirl = speed, as its run_modal and unbalance response evaluate it) by its PCHIP rule
    assert (drive.name, drive.node, drive.table.interpolation, free.name) == ("drive_end", 2, _native(rs), "free_end")
    np.testing.assert_allclose(drive.table.rpm, FREQUENCY * 60 / (2 * np.pi), rtol=1e-13)  # 14 digits
    fx = machine.effects()
    model = Model([fx["bearing_table@drive_end"], fx["bearing_table@free_end"], fx["gyroscopic"]], machine)
    speeds = np.array([0.0, 150.0, 500.0, 900.0, 1200.0])  # rad/s; 1200 beyond the table (ROSS extrapolates)
    table = campbell(model, {}, speeds * 60 / (2 * np.pi), n_modes=8)
    compared = 0
    for speed, rpm in zip(speeds, sorted(set(table.rpm))):
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        whirl = modal.whirl_direction()
        lateral = np.array([w is not None and w != "None" for w in whirl])
        ours = table[table.rpm == rpm]
        np.testing.assert_allclose(ours.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:8], rtol=RTOL)
        np.testing.assert_allclose(ours.damping_ratio.to_numpy(), modal.damping_ratio[lateral][:8], rtol=RTOL,
                                   atol=1e-9)
        if speed > 0:
            theirs = [w.lower() for w in whirl[lateral][:8]]
            clear = [i for i, w in enumerate(theirs) if w in ("forward", "backward")]
            assert [theirs[i] for i in clear] == [ours.whirl.iloc[i] for i in clear]
            compared += len(clear)
    assert compared >= 10
    # and back to ROSS: the same description, and ROSS's own eigenvalues of it the original rotor's
    again = machine_to_ross(machine)
    assert machine_from_ross(again).to_mapping() == machine.to_mapping()
    for speed in (150.0, 1200.0):
        first, second = (r.run_modal(speed, num_modes=40, sparse=False) for r in (rotor, again))
        np.testing.assert_allclose(second.wd[:16], first.wd[:16], rtol=1e-10)
        np.testing.assert_allclose(second.damping_ratio[:16], first.damping_ratio[:16], rtol=1e-6, atol=1e-12)
    # the check sees the bearings' change with speed: constant coefficients (the table's first row) move the
    # frequencies far beyond the tolerance
    frozen = machine_from_ross(rotor)
    rest = {k: float(v[0]) for k, v in DRIVE_END.items()}
    frozen = Machine(frozen.name, frozen.segments, frozen.disks,
                     [Bearing("drive_end", 2, table=BearingTable.constant(**rest)), free], shear=True,
                     rotary_inertia=True)
    fz = frozen.effects()
    still = campbell(Model([fz["bearing_table@drive_end"], fz["bearing_table@free_end"], fz["gyroscopic"]], frozen),
                     {}, speeds * 60 / (2 * np.pi), n_modes=8)
    change = np.abs(table.frequency_hz.to_numpy() / still.frequency_hz.to_numpy() - 1)
    assert change.max() > 1e4 * RTOL, change.max()


@pytest.mark.parametrize("angle_deg", [0.0, 120.0])
def test_unbalance_response_on_speed_dependent_bearings_matches_ross(rs, angle_deg):
    """The same rotor's 1X response to an unbalance on the first disk (ours: the harmonic-balance solver on the model
    of machine_from_ross; ROSS: run_unbalance_response, its bearings at each speed), every node, x and y, through
    the critical speeds and beyond the table (50-1500 rad/s); the unbalance on +x (angle_me 0) and turned by 120
    degrees (ours: the trial-mass angle angle_me; ROSS: its unbalance phase, the same angle in rad)."""
    from hybridtwin.model.machine_parts import UnbalancePlane
    from hybridtwin.model.ross_io import machine_from_ross
    from hybridtwin.solvers.solver import solve

    m_e, r_me, node = 0.002, 0.1, DISKS[0][0]
    machine = machine_from_ross(_ross_rotor(rs), unbalance_planes=[UnbalancePlane("disk", node)])
    fx = machine.effects()
    model = Model([fx["bearing_table@drive_end"], fx["bearing_table@free_end"], fx["gyroscopic"], fx["unbalance@disk"]],
                  machine)
    speeds = np.linspace(50.0, 1500.0, 30)  # rad/s
    angle = np.deg2rad(angle_deg)
    result = solve(model.system({"m_e": m_e, "r_me": r_me, "angle_me": angle}, speeds * 60 / (2 * np.pi)), 1)
    assert result.success.all()
    rotor = _ross_rotor(rs, extra_mass=m_e)  # our plane's point mass m_e, on ROSS's disk
    theirs_all = rotor.run_unbalance_response(node, m_e * r_me, angle, speeds).forced_resp
    for plane, offset in (("x", 0), ("y", 1)):
        ours = result.harmonics[:, 1, machine.translational(plane)]  # (speeds, nodes)
        theirs = theirs_all[offset::rotor.number_dof][: machine.n_nodes].T
        error = np.linalg.norm(ours - theirs, axis=1) / np.linalg.norm(theirs, axis=1)
        assert error.max() < RTOL, (plane, error.max())
    x, y = result.harmonics[:, 1, machine.dof(f"u{node}")], result.harmonics[:, 1, machine.dof(f"v{node}")]
    assert np.abs(np.abs(x) / np.abs(y) - 1).max() > 0.1  # the bearings' anisotropy shows in the orbit


def test_our_stepped_rotor_round_trips_through_ross(rs):
    """Ours -> machine_to_ross -> machine_from_ross: the same config form (ROSS has no unbalance planes or probes:
    given back), for the three beam theories; and ROSS's matrices of the rotor are those our campbell checks."""
    from hybridtwin.model.ross_io import machine_from_ross, machine_to_ross

    for rotary_inertia, shear in [(False, False), (True, False), (True, True)]:
        machine = _ours(rotary_inertia, shear)[0]
        rotor = machine_to_ross(machine)
        assert len(rotor.shaft_elements) == machine.n and rotor.bearing_elements[0].tag == "drive_end"
        back = machine_from_ross(rotor, name=machine.name, unbalance_planes=machine.unbalance_planes,
                                 sensors=machine.sensors)
        assert back.to_mapping() == machine.to_mapping()


def _native(rs):  # noqa: F811 (the module)
    """The rule of ROSS's own tables: ROSS 2.3's spline ("ross"), ROSS 3's PCHIP ("pchip")."""
    return "ross" if int(rs.__version__.split(".")[0]) < 3 else "pchip"


@pytest.mark.parametrize("rule", ["linear", "ross", "pchip", "linear_extrapolated"])
def test_a_table_goes_to_ross_as_ours(rs, tmp_path, rule):  # noqa: F811 (the fixture)
    """A table by any of our rules: ROSS's bearing in memory evaluates it as ours does (between the rows and
    beyond them, where ROSS's own rule would extrapolate otherwise) and it comes back with its rule; the file keeps
    the table and ROSS's own rule only (ROSS 3 keeps its linear: ours linear_extrapolated; else ROSS's native)."""
    from hybridtwin.model.ross_io import machine_from_ross, machine_to_ross

    ours = _ours(True, True)[0]
    rows = {"rpm": [500.0, 1500.0, 2500.0, 4000.0], "kxx": [1e7, 1.5e7, 3e7, 3.2e7], "kyy": [0.8e7, 1.9e7, 2.2e7, 3e7],
            "cxx": [500.0, 450.0, 300.0, 320.0], "cyx": [0.0, -5.0, 7.0, 2.0], "interpolation": rule}
    table = BearingTable.from_mapping(rows)
    machine = Machine(ours.name, ours.segments, ours.disks, [Bearing("drive_end", 2, table=table), ours.bearings[1]],
                      shear=True, rotary_inertia=True)
    rotor = machine_to_ross(machine, tmp_path / "linear.json")
    element = rotor.bearing_elements[0]
    for rpm in (100.0, 1000.0, 3000.0, 5000.0):  # before, inside and after the table
        K, C = table.matrices(_rad_s([rpm]))
        np.testing.assert_allclose(element.K(_rad_s(rpm))[:2, :2], K[0], rtol=1e-14)
        np.testing.assert_allclose(element.C(_rad_s(rpm))[:2, :2], C[0], rtol=1e-14)
    assert machine_from_ross(rotor).bearings[0].table == table
    loaded = machine_from_ross(tmp_path / "linear.json").bearings[0].table
    kept = rule if rule in ("pchip", "linear_extrapolated") and _native(rs) == "pchip" else _native(rs)
    assert loaded.interpolation == kept
    np.testing.assert_allclose(loaded.kyy, table.kyy, rtol=1e-15)


@pytest.mark.parametrize("change, message", [
    ("taper", "ROSS shaft element 'Shaft Element 3' (node 3): tapered (idl 0, idr 0, odl 0.04, odr 0.05 m); our "
              "segments are uniform"),
    ("mixed_shear", "ROSS rotor 'stepped': mixed shear_effects (elements with and without it)"),
    ("link", "ROSS bearing 'drive_end' (node 2): linked to node 20"),
])
def test_rotors_we_cannot_represent_are_refused(rs, change, message):
    from hybridtwin.model.ross_io import machine_from_ross

    steel = rs.Material(name="Steel_check", rho=RHO, E=E, G_s=G)
    elements = [rs.ShaftElement(L=length / n, idl=0.0, odl=d, material=steel, shear_effects=True)
                for length, d, n in SEGMENTS for _ in range(n)]
    if change == "taper":
        elements[3] = rs.ShaftElement(L=0.05, idl=0.0, odl=0.04, odr=0.05, material=steel)
    if change == "mixed_shear":
        elements[5] = rs.ShaftElement(L=0.05, idl=0.0, odl=0.05, material=steel, shear_effects=False)
    bearing = dict(n=2, kxx=1e7, cxx=100.0, tag="drive_end")
    bearing |= {"link": {"n_link": 20}}.get(change, {})
    rotor = rs.Rotor(elements, [], [rs.BearingElement(**bearing), rs.BearingElement(n=16, kxx=1e7, cxx=100.0)],
                     tag="stepped")
    with pytest.raises(ValueError) as err:
        machine_from_ross(rotor)
    assert message in str(err.value)


def test_machines_ross_cannot_represent_are_refused(rs):
    from hybridtwin.model.ross_io import machine_to_ross

    with pytest.raises(ValueError, match="segment 0: gives I or m directly; ROSS computes them"):
        machine_to_ross(Machine.varm())
    ours = _ours(True, True)[0]
    bare = Machine(ours.name, ours.segments, ours.disks, [Bearing("drive_end", 2)], shear=True)
    with pytest.raises(ValueError, match="bearing 'drive_end' has no coefficients"):
        machine_to_ross(bare)


def test_every_coefficient_reaches_ross_in_its_place(rs):
    """machine_to_ross of a one-row (constant) anisotropic table: ROSS's K and C at the node are the table's."""
    from hybridtwin.model.ross_io import machine_to_ross

    values = dict(zip(COEFFICIENTS, [1e7, 2e5, -3e5, 1.4e7, 300.0, 7.0, -9.0, 450.0]))
    ours = _ours(True, True)[0]
    machine = Machine(ours.name, ours.segments, ours.disks,
                      [Bearing("drive_end", 2, table=BearingTable.constant(**values)), ours.bearings[1]], shear=True)
    element = machine_to_ross(machine).bearing_elements[0]
    K, C = element.K(123.0), element.C(123.0)
    assert K[:2, :2].tolist() == [[values["kxx"], values["kxy"]], [values["kyx"], values["kyy"]]]
    assert C[:2, :2].tolist() == [[values["cxx"], values["cxy"]], [values["cyx"], values["cyy"]]]


# --- a ROSS rotor file in the config (issue 53 item 2) -------------------------------------------------------------


def _layered_file(rs, folder):
    """The stepped rotor of ``_ross_rotor`` with a sleeve (two layered elements at nodes 9 and 10), saved with ROSS's
    ``rotor.save`` in ``folder``; the rotor and the file."""
    base = _ross_rotor(rs)
    sleeve = rs.Material(name="Sleeve_check", rho=RHO, E=0.3 * E, G_s=0.3 * G)
    layers = [rs.ShaftElement(L=0.05, idl=0.05, odl=0.07, material=sleeve, n=n) for n in (9, 10)]
    rotor = rs.Rotor(base.shaft_elements + layers, base.disk_elements, base.bearing_elements)
    rotor.save(folder / "stepped.toml")
    return rotor, folder / "stepped.toml"


ROSS_MACHINE = {"ross": "stepped.toml", "name": "stepped_ross", "unbalance_planes": {"disk": 8},
                "sensors": {"x1": {"node": 8, "direction": "x"}, "y1": {"node": 8, "direction": "y"}}}


def test_a_ross_file_in_the_config_is_the_machine(rs, project, capsys):  # noqa: F811 (the fixture)
    """machine: {ross: stepped.toml, ...}: the config's machine is machine_from_ross of the file (relative to the
    config's folder) with our name, plane and probes; the check passes with a variant on its tables and the
    plane; ``hybridtwin machine`` prints what was read (the file, the layer, the tables)."""
    from hybridtwin import config as cfg
    from hybridtwin.cli import main
    from hybridtwin.model.ross_io import machine_from_ross

    folder, _ = project
    rotor, path = _layered_file(rs, folder / "config")
    overlay = {"machine": ROSS_MACHINE, "variants": {"ross_linear": {
        "effects": ["bearing_table@drive_end", "bearing_table@free_end", "gyroscopic", "unbalance@disk"],
        "unknown": {"m_e": [0.001, 0.01]}}}}
    config, problems = _config(project, yaml.safe_dump(overlay))
    assert problems == []
    machine = cfg.machine(config)
    expected = machine_from_ross(path, name="stepped_ross", unbalance_planes=machine.unbalance_planes,
                                 sensors=machine.sensors)
    assert machine.to_mapping() == expected.to_mapping()
    assert [s.node for s in machine.segments if s.node is not None] == [9] and machine.n_nodes == len(rotor.nodes)
    assert cfg.variant(config, "ross_linear").model.shaft.to_mapping() == machine.to_mapping()
    assert main(["machine", "--config", str(folder / "config" / "config.yaml")]) == 0
    out = capsys.readouterr().out
    assert f"machine read from the ROSS rotor file {folder / 'config' / 'stepped.toml'}" in out
    assert "machine stepped_ross: 20 elements, 21 nodes" in out and "layer 3: nodes 9..11" in out
    assert "bearing drive_end at node 2: table of 5 speeds" in out and "sensor y1 at node 8" in out


@pytest.mark.parametrize("change, message", [
    ({"ross": "missing.toml"}, "machine.ross: config/missing.toml: no such file (a ROSS rotor saved with rotor.save"),
    ({"segments": []}, "unknown key(s) ['segments'] (allowed: name, ross, sensors, unbalance_planes)"),
    ({"unbalance_planes": {"disk": 40}}, "unbalance plane 'disk' at node 40: nodes are the integers 0..20"),
])
def test_a_bad_ross_machine_in_the_config_is_one_line(rs, project, change, message):  # noqa: F811 (the fixture)
    folder, _ = project
    _layered_file(rs, folder / "config")
    _, problems = _config(project, yaml.safe_dump({"machine": ROSS_MACHINE | change}))
    assert any(message in p and "config.yaml, line" in p for p in problems), problems


def test_a_ross_file_we_cannot_represent_is_refused_at_its_key(rs, project):  # noqa: F811 (the fixture)
    folder, _ = project
    steel = rs.Material(name="Steel_check", rho=RHO, E=E, G_s=G)
    elements = [rs.ShaftElement(L=0.05, idl=0.0, odl=0.05, odr=0.06 if n == 3 else 0.05, material=steel)
                for n in range(8)]
    rs.Rotor(elements, [], [rs.BearingElement(n=0, kxx=1e7, cxx=10.0), rs.BearingElement(n=8, kxx=1e7, cxx=10.0)]
             ).save(folder / "config" / "stepped.toml")
    _, problems = _config(project, yaml.safe_dump({"machine": ROSS_MACHINE | {"unbalance_planes": {"disk": 4},
                                                                              "sensors": {}}}))
    assert any("machine.ross: config/stepped.toml: ROSS shaft element 'Shaft Element 3' (node 3): tapered" in p
               for p in problems), problems


def test_bearing_mass_coefficients_match_ross(rs):  # noqa: F811 (the fixture)
    """A bearing with speed-dependent, anisotropic, cross-coupled mass coefficients (a seal's added mass): ours in the
    table (mxx .. myy), at rest in the mass and its change with speed in the system's M at each speed; ROSS's M at
    those speeds is ours, and so are the Campbell data (frequencies, damping ratios), to 1e-6 (the tolerance of
    this module; the mass moves the frequencies by far more, asserted)."""
    from hybridtwin.model.ross_io import machine_from_ross

    mass = dict(mxx=20 + 10 * np.sin(FREQUENCY / 300), myy=15 + 0.02 * FREQUENCY, mxy=2 * FREQUENCY / 1000,
                myx=-1.5 * FREQUENCY / 1000)
    base = _ross_rotor(rs)
    drive = rs.BearingElement(n=2, frequency=FREQUENCY, **DRIVE_END, **mass, tag="drive_end")
    rotor = rs.Rotor(base.shaft_elements, base.disk_elements, [drive, base.bearing_elements[1]], tag="stepped")
    machine = machine_from_ross(rotor)
    table = machine.bearings[0].table
    assert table.has_mass and "mxx" in table.to_mapping() and "mxx 20.." in table.describe()
    fx = machine.effects()
    model = Model([fx["bearing_table@drive_end"], fx["bearing_table@free_end"], fx["gyroscopic"]], machine)
    speeds = np.array([0.0, 350.0, 900.0])  # rad/s
    system = model.system({}, speeds * 60 / (2 * np.pi))
    u, v = machine.dof("u2"), machine.dof("v2")
    for s, speed in enumerate(speeds):
        theirs = rotor.M(speed)[np.ix_([12, 13], [12, 13])]  # ROSS's node 2: x, y
        ours = system.M[s][np.ix_([u, v], [u, v])]
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12 * np.abs(theirs).max())  # the spline's 1e-15
    ours = campbell(model, {}, speeds * 60 / (2 * np.pi), n_modes=8)
    plain = campbell(Model([fx["bearing_table@free_end"], fx["gyroscopic"], machine_from_ross(base).effects()[
        "bearing_table@drive_end"]], machine_from_ross(base)), {}, speeds * 60 / (2 * np.pi), n_modes=8)
    for speed, rpm in zip(speeds, sorted(set(ours.rpm))):
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        lateral = np.array([w is not None and w != "None" for w in modal.whirl_direction()])
        at = ours[ours.rpm == rpm]
        np.testing.assert_allclose(at.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:8], rtol=RTOL)
        np.testing.assert_allclose(at.damping_ratio.to_numpy(), modal.damping_ratio[lateral][:8], rtol=RTOL, atol=1e-9)
    change = np.abs(ours.frequency_hz.to_numpy() / plain.frequency_hz.to_numpy() - 1)
    assert change.max() > 1e3 * RTOL, change.max()


def test_a_support_with_a_point_mass_is_refused_naming_it(rs):  # noqa: F811 (the fixture)
    """ROSS's point masses are a support's (on the node a bearing links the shaft to): refused, naming the point mass
    and the reason, before its bearing's link is."""
    from hybridtwin.model.ross_io import machine_from_ross

    base = _ross_rotor(rs)
    pedestal = [base.bearing_elements[0], rs.BearingElement(n=16, n_link=21, kxx=1e7, cxx=500.0, tag="free end"),
                rs.BearingElement(n=21, kxx=1e8, cxx=100.0, tag="pedestal")]  # the free end on a support of 10 kg
    rotor = rs.Rotor(base.shaft_elements, base.disk_elements, pedestal,
                     point_mass_elements=[rs.PointMass(n=21, m=10.0, tag="pm")])
    with pytest.raises(ValueError, match=re.escape("ROSS point mass 'pm' (node 21): a support's mass")):
        machine_from_ross(rotor)
