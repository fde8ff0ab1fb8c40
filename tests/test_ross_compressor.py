"""An industrial rotor as ROSS models it (issue 53 item 1): ROSS's ``compressor_example()`` (56 nodes, 91 shaft
elements, 36 of them layers at a node already holding one, 7 impellers, 2 fluid-film bearings and 12 seals with
speed-dependent, cross-coupled coefficients) through ``ross_io.machine_from_ross`` against ROSS itself: first the
assembled matrices (they localise any convention difference), then the Campbell data (damped frequencies and
logarithmic decrements), the critical speeds and the unbalance response, with ROSS 2.3 (Python 3.11), 3.0 (3.12) and
3.1 (3.13); and every example rotor ROSS ships imports or is refused naming
the element and the reason.

Tolerances. The two codes build the same matrices from the same element formulas (ROSS's Timoshenko beams, Cowper's
coefficient, the same layers added, the same scipy splines of the seals' tables): the matrices agree to round-off
(observed 2.7e-16 of their largest entry), held at 1e-12 (sums taken in another order, nothing more). The frequencies
and decrements come from two eigensolvers of different systems (ROSS's has the axial and torsional DOFs too), observed
equal to 1.1e-11; they are held at 1e-6, which leaves room for LAPACK differences only and is 1000 times tighter than
the issue's 0.1 %. The unbalance response likewise (observed 3.5e-12, held at 1e-6). The layers matter far beyond
that (asserted: they are 31 % of the rotor's mass).

The tests that build ROSS rotors skip, with the reason, where ROSS cannot be imported (pip install -e ".[ross]"); the
layer's own checks (config form, errors) run always.
"""

import dataclasses
import importlib
import inspect
import warnings

import numpy as np
import pytest
from test_ross import rs  # noqa: F401 (the fixture importing ROSS, or skipping)

from hybridtwin.model.machine import Machine
from hybridtwin.model.machine_parts import MachineSpecError, ShaftSegment, UnbalancePlane
from hybridtwin.model.model import Model, campbell

MATRIX_RTOL = 1e-12  # see the module docstring
RTOL = 1e-6
SPEEDS = np.array([0.0, 700.0, 1400.0])  # rad/s: at rest, and across the compressor's running range


@pytest.fixture(scope="module")
def compressor(rs):  # noqa: F811 (the fixture)
    """ROSS's compressor, our machine of it and a model with every bearing and seal table and the gyroscopic terms."""
    from hybridtwin.model.ross_io import machine_from_ross

    rotor = rs.compressor_example()
    machine = machine_from_ross(rotor, unbalance_planes=[UnbalancePlane("impeller_1", rotor.disk_elements[0].n)])
    fx = machine.effects()
    effects = [fx[f"bearing_table@{b.name}"] for b in machine.bearings] + [fx["gyroscopic"]]
    return rotor, machine, effects


def _ross_dofs(machine):
    """Each of our DOFs' index in ROSS's layout (6 per node: x, y, z, alpha, beta, theta) and its sign: our u, v are
    ROSS's x, y; our slope du/dz is ROSS's beta (the rotation about y), dv/dz is -alpha (the rotation about x)."""
    index, sign = np.zeros(machine.n_dof, int), np.ones(machine.n_dof)
    for i in range(machine.n_nodes):
        for name, at, s in (("u", 0, 1), ("v", 1, 1), ("du", 4, 1), ("dv", 3, -1)):
            index[machine.dof(f"{name}{i}")], sign[machine.dof(f"{name}{i}")] = 6 * i + at, s
    return index, sign


def _close(ours, theirs, rtol):
    error = np.abs(ours - theirs).max() / np.abs(theirs).max()
    assert error < rtol, error


def test_compressor_imports_with_its_layers(compressor, rs):  # noqa: F811 (the fixture)
    rotor, machine, _ = compressor
    layers = [s for s in machine.segments if s.node is not None]
    assert machine.n_nodes == len(rotor.nodes) == 56 and len(machine.bearings) == 14 and len(machine.disks) == 7
    assert sum(s.n_elements for s in machine.segments) == len(rotor.shaft_elements) == 91
    assert sum(s.n_elements for s in layers) == 36 and machine.shear and machine.rotary_inertia
    np.testing.assert_allclose(machine.z, rotor.nodes_pos, rtol=1e-12, atol=1e-15)
    seal = next(b for b in machine.bearings if b.name == "Seal_1")
    assert seal.table.interpolation == ("ross" if _major(rs) < 3 else "pchip") and len(seal.table.rpm) == 6 and max(seal.table.kxy) > 0
    assert "layer" in machine.describe()


def test_compressor_matrices_are_ross(compressor):
    """Our M, K (shaft, layers, impellers; bearings and seals at speed), C and G in ROSS's layout equal ROSS's
    assembled ones (``Rotor.M``, ``K``, ``C``, ``G``), lateral DOFs."""
    rotor, machine, effects = compressor
    index, sign = _ross_dofs(machine)

    def theirs(matrix):
        return matrix[np.ix_(index, index)] * np.outer(sign, sign)

    G = machine.gyroscopic_matrix()
    _close(G, theirs(rotor.G()), MATRIX_RTOL)
    model = Model(effects, machine)
    for speed in (0.0, 1100.0):
        system = model.system({}, [speed * 60 / (2 * np.pi)])
        _close(system.M[0], theirs(rotor.M(speed)), MATRIX_RTOL)
        _close(system.K[0], theirs(rotor.K(speed)), MATRIX_RTOL)
        _close(system.C[0] - speed * G, theirs(rotor.C(speed)), MATRIX_RTOL)  # ours: Omega G in the damping
    # the layers are in it, and matter: ROSS's sleeves and hubs (E 6.9 kPa: mass without stiffness) are a third of
    # the rotor's mass (the translational mass 1^T M_uu 1: observed 0.31 of it from the layers)
    bare = Machine(machine.name, machine.chain, machine.disks, machine.bearings, shear=True, rotary_inertia=True)
    u = machine.translational("x")
    mass, mass_bare = (m.matrices()[1][np.ix_(u, u)].sum() for m in (machine, bare))
    np.testing.assert_allclose(mass, rotor.m, rtol=1e-10)  # ROSS's rotor mass: shaft, layers and disks
    assert 1 - mass_bare / mass > 0.2, mass_bare / mass


def test_compressor_campbell_matches_ross(compressor):
    """Damped frequencies, logarithmic decrements and whirl of the 8 lowest lateral modes at rest and at 700 and
    1400 rad/s, against ROSS's run_modal (its lateral modes: those with a whirl direction)."""
    rotor, machine, effects = compressor
    table = campbell(Model(effects, machine), {}, SPEEDS * 60 / (2 * np.pi), n_modes=8)
    for speed, rpm in zip(SPEEDS, sorted(set(table.rpm))):
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        whirl = modal.whirl_direction()
        lateral = np.array([w is not None and w != "None" for w in whirl])
        ours = table[table.rpm == rpm]
        zeta = ours.damping_ratio.to_numpy()
        np.testing.assert_allclose(ours.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:8], rtol=RTOL)
        np.testing.assert_allclose(2 * np.pi * zeta / np.sqrt(1 - zeta**2), modal.log_dec[lateral][:8], rtol=RTOL)
        if speed > 0:  # ROSS calls 'mixed' a mode whose nodes whirl both ways; ours is the net sense
            theirs = [w.lower() for w in whirl[lateral][:8]]
            clear = [i for i, w in enumerate(theirs) if w in ("forward", "backward")]
            assert len(clear) >= 6 and [theirs[i] for i in clear] == [ours.whirl.iloc[i] for i in clear]


def test_compressor_critical_speeds_match_ross(compressor):
    """The 1X critical speeds and their log decrements: ours where the Campbell branches cross 1X
    (``machine_plots.critical_speeds``: linear interpolation between speeds 10 rad/s apart), ROSS's
    ``run_critical_speed`` (Newton on s = w_d(s) per mode, to rtol 1e-9), those in 800-1300 rad/s (the first pair of
    lightly damped modes; ROSS's Newton follows the modes by their order at rest and passes over the heavily damped
    ones crossing 1X lower, log decrement > 6, which ours lists). Held at 1e-3, the issue's 0.1 %: the linear
    interpolation over 10 rad/s of nearly straight branches is far inside it (observed 6e-6)."""
    from hybridtwin.report.machine_plots import critical_speeds

    rotor, machine, effects = compressor
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ROSS warns where its seals' tables extrapolate
        theirs = rotor.run_critical_speed(num_modes=16, rtol=1e-9)
    wd, whirl, log_dec = np.asarray(theirs.wd()), np.asarray(theirs.whirl_direction), np.asarray(theirs.log_dec)
    inside = (wd > 800.0) & (wd < 1300.0)
    assert inside.sum() >= 2, wd
    table = campbell(Model(effects, machine), {}, np.arange(800.0, 1301.0, 10.0) * 60 / (2 * np.pi), n_modes=12)
    ours = critical_speeds(table)
    for w, sense, delta in zip(wd[inside], whirl[inside], log_dec[inside]):
        same = ours[ours.whirl == str(sense).lower()]
        nearest = same.iloc[np.argmin(np.abs(same.rpm.to_numpy() * 2 * np.pi / 60 - w))]
        np.testing.assert_allclose(nearest.rpm * 2 * np.pi / 60, w, rtol=1e-3)
        np.testing.assert_allclose(nearest.log_decrement, delta, rtol=1e-3)


def test_compressor_unbalance_response_matches_ross(compressor, rs):  # noqa: F811 (the fixture)
    """The 1X response of every node to an unbalance on the first impeller, through the first critical speeds,
    x and y, complex (ours: the harmonic-balance solver; ROSS: run_unbalance_response with the plane's point mass on
    its disk)."""
    from hybridtwin.solvers.solver import solve

    rotor, machine, effects = compressor
    m_e, r_me, angle = 0.01, 0.1, np.deg2rad(30.0)
    node = machine.node("impeller_1")
    model = Model(effects + [machine.effects()["unbalance@impeller_1"]], machine)
    speeds = np.linspace(200.0, 1600.0, 15)  # rad/s
    result = solve(model.system({"m_e": m_e, "r_me": r_me, "angle_me": angle}, speeds * 60 / (2 * np.pi)), 1)
    assert result.success.all()
    disks = [d if i else rs.DiskElement(n=d.n, m=d.m + m_e, Id=d.Id, Ip=d.Ip, tag=d.tag)
             for i, d in enumerate(rotor.disk_elements)]
    loaded = rs.Rotor(rotor.shaft_elements, disks, rotor.bearing_elements)
    response = loaded.run_unbalance_response(node, m_e * r_me, angle, speeds).forced_resp
    for plane, offset in (("x", 0), ("y", 1)):
        ours = result.harmonics[:, 1, machine.translational(plane)]
        theirs = response[offset::rotor.number_dof][: machine.n_nodes].T
        error = np.linalg.norm(ours - theirs, axis=1) / np.linalg.norm(theirs, axis=1)
        assert error.max() < RTOL, (plane, error.max())


def test_compressor_round_trips_through_ross(compressor):
    """Ours -> machine_to_ross -> machine_from_ross: the same machine, layers where they were."""
    from hybridtwin.model.ross_io import machine_from_ross, machine_to_ross

    _, machine, _ = compressor
    again = machine_from_ross(machine_to_ross(machine), name=machine.name,
                              unbalance_planes=machine.unbalance_planes)
    assert again.to_mapping() == machine.to_mapping()


#: the examples of ROSS's that we cannot represent, and why (element or rotor, reason: in the message), by ROSS's
#: major version (2.3's rotor_example_with_damping damps its shaft elements, 3's damps the rotor, disks included)
REFUSED = {
    2: {"coaxrotor_example": "a CoAxialRotor (several shafts",
        "two_shaft_rotor_example": "a MultiRotor (several shafts",
        "rotor_amb_example": "ROSS bearing 'Magnetic Bearing 0' (node 12): a MagneticBearingElement (an active magnetic"},
    3: {"coaxrotor_example": "a CoAxialRotor (several shafts",
        "two_shaft_rotor_example": "a MultiRotor (several shafts",
        "rotor_example_amb_complex_controllers": "a MagneticBearingElement (an active magnetic",
        "rotor_example_amb_general_controllers": "a MagneticBearingElement (an active magnetic",
        "rotor_example_amb_simple": "a MagneticBearingElement (an active magnetic",
        "rotor_example_with_damping": "rotor-wide mass-proportional damping (alpha 8.0501 1/s) acts on the disks'"},
}


def _major(rs):  # noqa: F811 (the module)
    return int(rs.__version__.split(".")[0])


def _example_functions(rs):  # noqa: F811 (the module)
    """(module, function name) of every ``*example*`` function in ROSS's source (tests aside) that needs no argument
    and returns what it builds as a rotor (``Rotor(...)``, ``MultiRotor(...)``, ``Rotor.load``/``_from_data`` or a
    variable named rotor): read from the source, not from a list, so a release's new examples are met."""
    import ast
    from pathlib import Path

    root = Path(rs.__file__).parent
    found = []
    for path in sorted(root.rglob("*.py")):
        if "tests" in path.parts or path.name == "conftest.py":
            continue
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if not (isinstance(node, ast.FunctionDef) and "example" in node.name):
                continue
            if len(node.args.args) > len(node.args.defaults):
                continue
            returns = [r.value for r in ast.walk(node) if isinstance(r, ast.Return) and r.value is not None]
            text = ast.unparse(returns[-1]) if returns else ""
            if "Rotor" in text or text.startswith("rotor"):
                module = ".".join(("ross",) + path.relative_to(root).with_suffix("").parts)
                found.append((module.removesuffix(".__init__"), node.name))
    return found


def test_every_example_rotor_of_ross_imports_or_is_refused(rs):  # noqa: F811 (the fixture)
    """Each example rotor of ROSS's (``_example_functions``): it imports, with ROSS's node count, or is refused by a
    ValueError naming the element (or the rotor) and the reason, never another exception. Stochastic rotors
    (``ST_Rotor``, a population of rotors) are not rotors and are passed over."""
    from hybridtwin.model.ross_io import machine_from_ross

    refused, seen = REFUSED[_major(rs)], {}
    for module, function in _example_functions(rs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rotor = getattr(importlib.import_module(module), function)()
        if not isinstance(rotor, rs.Rotor):
            continue
        try:
            machine = machine_from_ross(rotor)
        except ValueError as err:
            seen[function] = str(err)
            assert function in refused and refused[function] in str(err), (function, str(err))
            assert str(err).startswith("ROSS "), str(err)  # names the rotor or the element
            continue
        seen[function] = "imported"
        assert machine.n_nodes == len(rotor.nodes), function
    assert {"rotor_example", "compressor_example", "rotor_example_6dof"} <= {
        k for k, v in seen.items() if v == "imported"}, seen
    assert set(refused) - {"coaxrotor_example"} <= set(seen), seen  # ROSS 3.1 has no coaxial example any more


def test_rotor_wide_damping_matches_ross_and_point_masses_are_refused(rs):  # noqa: F811 (the fixture)
    """ROSS's ``rotor_example()`` without its disks, with rotor-wide proportional damping (alpha M0 + beta K0 of the
    shaft alone: our segments' alpha, beta): our C is ROSS's (MATRIX_RTOL) and the 6 lowest lateral modes' damped
    frequencies and damping ratios at 500 rad/s ROSS's (RTOL). Refused, naming them: rotor-wide alpha with disks
    (alpha M0 damps their mass too) and a point mass (ROSS gives it DOFs of its own: a support's mass)."""
    from hybridtwin.model.ross_io import machine_from_ross

    example = rs.rotor_example()
    pedestal = len(example.nodes)  # ROSS's node of a support: the shaft's last node links to it
    mass = rs.PointMass(n=pedestal, m=4.0, tag="pedestal")
    support = [rs.BearingElement(n=pedestal - 1, n_link=pedestal, kxx=1e7, cxx=0.0, tag="link"),
               rs.BearingElement(n=pedestal, kxx=1e8, cxx=0.0, tag="ground")]
    with pytest.raises(ValueError, match="ROSS point mass 'pedestal' .*: a support's mass"):
        machine_from_ross(rs.Rotor(example.shaft_elements, [], example.bearing_elements + support,
                                   point_mass_elements=[mass]))
    if "alpha" not in inspect.signature(rs.Rotor).parameters:
        return
    rotor = rs.Rotor(example.shaft_elements, [], example.bearing_elements, alpha=3.0, beta=2e-5)
    machine = machine_from_ross(rotor)
    assert {(s.alpha, s.beta) for s in machine.segments} == {(3.0, 2e-5)}
    fx = machine.effects()
    index, sign = _ross_dofs(machine)
    linear = [fx[k] for k in fx if k.startswith(("linear_bearing@", "bearing_table@", "shaft_damping"))]
    model = Model(linear + [fx["gyroscopic"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()}
    _close(Model(linear, machine).system(values, [0.0]).C[0], rotor.C(0.0)[np.ix_(index, index)] * np.outer(sign, sign),
           MATRIX_RTOL)
    table = campbell(model, values, [500.0 * 60 / (2 * np.pi)], n_modes=6)
    modal = rotor.run_modal(500.0, num_modes=40, sparse=False)
    lateral = np.array([w is not None and w != "None" for w in modal.whirl_direction()])
    np.testing.assert_allclose(table.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:6], rtol=RTOL)
    np.testing.assert_allclose(table.damping_ratio.to_numpy(), modal.damping_ratio[lateral][:6], rtol=RTOL)
    with pytest.raises(ValueError, match=r"rotor-wide mass-proportional damping \(alpha 3 1/s\) acts on the disks'"):
        machine_from_ross(rs.Rotor(example.shaft_elements, example.disk_elements, example.bearing_elements, alpha=3.0))


def test_fluid_film_bearings_import_as_their_tables(rs):  # noqa: F811 (the fixture)
    """ROSS's ``rotor_example()`` on two of ROSS's fluid-film bearings (``CylindricalBearing``: the short-bearing
    solution, its eight coefficients computed by ROSS at 5 speeds, cross-coupled, anisotropic): they import as
    their tables (by ROSS's own rule of the version) and the 6 lowest lateral modes' damped frequencies and log
    decrements at 3 speeds, one between the table's rows, are ROSS's (RTOL)."""
    from hybridtwin.model.ross_io import machine_from_ross

    example = rs.rotor_example()
    speeds = rs.Q_([500.0, 1000.0, 1500.0, 2500.0, 4000.0], "RPM")
    film = [rs.CylindricalBearing(n=b.n, speed=speeds, weight=300.0, bearing_length=rs.Q_(30, "mm"),
                                  journal_diameter=rs.Q_(100, "mm"), radial_clearance=rs.Q_(0.1, "mm"),
                                  oil_viscosity=0.1, tag=f"film_{i}")
            for i, b in enumerate(example.bearing_elements)]
    rotor = rs.Rotor(example.shaft_elements, example.disk_elements, film)
    machine = machine_from_ross(rotor)
    table = machine.bearings[0].table
    assert len(table.rpm) == 5 and min(table.kxy) != 0 and table.kxx != table.kyy
    fx = machine.effects()
    model = Model([fx[f"bearing_table@{b.name}"] for b in machine.bearings] + [fx["gyroscopic"]], machine)
    speeds = np.array([100.0, 200.0, 300.0])  # rad/s
    ours = campbell(model, {}, speeds * 60 / (2 * np.pi), n_modes=6)
    for speed, rpm in zip(speeds, sorted(set(ours.rpm))):
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        lateral = np.array([w is not None and w != "None" for w in modal.whirl_direction()])
        at = ours[ours.rpm == rpm]
        zeta = at.damping_ratio.to_numpy()
        np.testing.assert_allclose(at.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:6], rtol=RTOL)
        np.testing.assert_allclose(2 * np.pi * zeta / np.sqrt(1 - zeta**2), modal.log_dec[lateral][:6], rtol=RTOL)


# --- layers without ROSS -------------------------------------------------------------------------------------------


SHAFT = {"length": 0.4, "d_out": 0.05, "E": 2.11e11, "rho": 7810, "n_elements": 8}


def test_a_layer_adds_its_matrices_where_it_lies():
    """A sleeve (a layer over elements 2-3) adds exactly its own elements' matrices there: the machine with it minus
    the machine without it is the sleeve's two elements, assembled at those nodes, and nothing elsewhere."""
    sleeve = ShaftSegment(0.1, 0.08, 2.11e11, 7810.0, d_in=0.05, n_elements=2, node=2)
    plain = Machine("p", [ShaftSegment(**SHAFT)], rotary_inertia=True, shear=True)
    layered = Machine("p", [ShaftSegment(**SHAFT), sleeve], rotary_inertia=True, shear=True)
    alone = Machine("s", [dataclasses.replace(sleeve, node=None)], rotary_inertia=True, shear=True)  # nodes 0..2
    assert (layered.n, layered.n_nodes, layered.L) == (8, 9, plain.L)

    def three(m):  # K, M, G
        return (*m.matrices(), m.gyroscopic_matrix())

    for ours, base, own in zip(three(layered), three(plain), three(alone)):
        added = ours - base
        dofs = [layered.dof(f"{k}{i}") for k in ("u", "du") for i in (2, 3, 4)]
        dofs += [layered.dof(f"{k}{i}") for k in ("v", "dv") for i in (2, 3, 4)]
        local = [alone.dof(f"{k}{i}") for k in ("u", "du") for i in (0, 1, 2)]
        local += [alone.dof(f"{k}{i}") for k in ("v", "dv") for i in (0, 1, 2)]
        scale = 1e-12 * np.abs(ours).max()  # round-off of the difference of two assemblies
        np.testing.assert_allclose(added[np.ix_(dofs, dofs)], own[np.ix_(local, local)], rtol=1e-10, atol=scale)
        assert np.abs(own).max() > 1e3 * scale  # the sleeve is not negligible
        added[np.ix_(dofs, dofs)] = 0
        assert not np.abs(added).max() > scale


def test_layer_config_form_round_trips_and_bad_layers_are_one_line():
    spec = {"name": "l", "segments": [SHAFT, SHAFT | {"d_out": 0.07, "d_in": 0.05, "length": 0.1, "n_elements": 2,
                                                      "node": 3}]}
    machine = Machine.from_mapping(spec)
    assert machine.to_mapping()["segments"][1]["node"] == 3
    assert Machine.from_mapping(machine.to_mapping()).to_mapping() == machine.to_mapping()
    assert "layer 1: nodes 3..5" in machine.describe()
    with pytest.raises(MachineSpecError, match=r"segment 1 \(a layer from node 7, 2 elements\) reaches beyond the "
                                               r"shaft's last node 8"):
        Machine.from_mapping({"segments": [SHAFT, spec["segments"][1] | {"node": 7}]})
    with pytest.raises(MachineSpecError, match=r"its elements are 0.025 m long, the shaft's there 0.05, 0.05 m"):
        Machine.from_mapping({"segments": [SHAFT, spec["segments"][1] | {"length": 0.05}]})
    with pytest.raises(MachineSpecError, match=r"the shaft needs at least one segment \(not a layer"):
        Machine.from_mapping({"segments": [spec["segments"][1]]})


def test_proportional_damping_matches_ross(rs):  # noqa: F811 (the fixture)
    """ROSS's ``rotor_example_with_damping()``, its damping on the shaft elements (alpha M + beta K of each: ROSS 2.3's
    form; ROSS 3 gives it to the rotor, disks included, refused above, so the elements are made again with it): the
    segments carry alpha and beta, with
    the bearings' the effect ``shaft_damping`` makes ROSS's C (``Rotor.C``), and the Campbell data
    (frequencies, damping ratios) of the 6 lowest lateral modes at 0 and 800 rad/s are ROSS's (RTOL); without the
    shaft's damping the damping ratios move far beyond it (asserted)."""
    from hybridtwin.model.ross_io import machine_from_ross

    example = importlib.import_module("ross.rotor_assembly").rotor_example_with_damping()
    shaft = [rs.ShaftElement(L=el.L, idl=el.idl, odl=el.odl, material=el.material, n=el.n, alpha=8.0501, beta=1e-5,
                             shear_effects=el.shear_effects, rotary_inertia=el.rotary_inertia)
             for el in example.shaft_elements]
    rotor = rs.Rotor(shaft, example.disk_elements, example.bearing_elements)
    machine = machine_from_ross(rotor)
    assert {(s.alpha, s.beta) for s in machine.segments} == {(8.0501, 1e-5)}
    fx = machine.effects()
    bearings = [fx[k] for k in fx if k.startswith(("linear_bearing@", "bearing_table@"))]
    index, sign = _ross_dofs(machine)
    model = Model(bearings + [fx["shaft_damping"], fx["gyroscopic"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()}
    ours = Model(bearings + [fx["shaft_damping"]], machine).system(values, [0.0]).C[0]  # shaft and bearings, at rest
    _close(ours, rotor.C(0.0)[np.ix_(index, index)] * np.outer(sign, sign), MATRIX_RTOL)
    speeds = np.array([0.0, 800.0])
    table = campbell(model, values, speeds * 60 / (2 * np.pi), n_modes=6)
    undamped = campbell(Model(bearings + [fx["gyroscopic"]], machine), values, speeds * 60 / (2 * np.pi), n_modes=6)
    for speed, rpm in zip(speeds, sorted(set(table.rpm))):
        modal = rotor.run_modal(speed, num_modes=40, sparse=False)
        lateral = np.array([w is not None and w != "None" for w in modal.whirl_direction()])
        at = table[table.rpm == rpm]
        np.testing.assert_allclose(at.frequency_hz.to_numpy() * 2 * np.pi, modal.wd[lateral][:6], rtol=RTOL)
        np.testing.assert_allclose(at.damping_ratio.to_numpy(), modal.damping_ratio[lateral][:6], rtol=RTOL)
    change = np.abs(table.damping_ratio.to_numpy() / undamped.damping_ratio.to_numpy() - 1)
    assert change.max() > 1e3 * RTOL, change.max()


def test_shaft_damping_is_alpha_m_plus_beta_k_of_the_segments():
    """Without disks and with one segment, the effect ``shaft_damping`` is alpha M + beta K of the shaft's own
    matrices (rotary inertia in M); a layer's damping adds where it lies only; the config form round-trips."""
    from hybridtwin.model.model import Model

    spec = {"segments": [SHAFT | {"alpha": 3.0, "beta": 2e-5}], "rotary_inertia": True, "shear": True}
    machine = Machine.from_mapping(spec)
    K, M = machine.matrices()
    C = Model([machine.effects()["shaft_damping"]], machine).system({}, [1000.0]).C[0]
    np.testing.assert_allclose(C, 3.0 * M + 2e-5 * K, rtol=1e-12, atol=1e-12 * np.abs(C).max())
    assert Machine.from_mapping(machine.to_mapping()).to_mapping() == machine.to_mapping()
    assert "damping alpha 3 1/s, beta 2e-05 s" in machine.describe()
    assert "shaft_damping" not in Machine.from_mapping({"segments": [SHAFT]}).effects()
    sleeve = SHAFT | {"length": 0.1, "n_elements": 2, "node": 2, "d_out": 0.08, "d_in": 0.05, "alpha": 1.0}
    layered = Machine.from_mapping({"segments": [SHAFT, sleeve]})
    C = layered.shaft_damping_matrix()
    touched = np.flatnonzero(np.abs(C).sum(axis=0))
    assert {layered.dof(f"u{i}") for i in (2, 3, 4)} <= set(touched) and layered.dof("u1") not in touched
    with pytest.raises(MachineSpecError, match="alpha \\(proportional damping\\) must be a number >= 0"):
        Machine.from_mapping({"segments": [SHAFT | {"alpha": -1.0}]})
