"""The candidates a machine of your own is offered (src/hybridtwin/model/bearing_candidates.py,
``Machine.sized_candidates``): at each bearing and unbalance plane of the stepped rotor, sized to its bearings and
shaft; each absent at 0, each term where it says against matrices written out here; and a diagnosis of records with
a wrong known bearing stiffness names that bearing's compliance."""

import numpy as np
import pytest
import scipy.linalg
from diagnosis_helpers import fit_and_diagnose
from example_machines import stepped_machine

from hybridtwin.identify import forward as fwd
from hybridtwin.identify import identification as idn
from hybridtwin.model.candidates import Candidate
from hybridtwin.model.machine import Machine
from hybridtwin.model.model import Model
from hybridtwin.model.variants import Variant

EFFECTS = ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"]
KINDS = ["bearing_anisotropy", "cross_coupled_stiffness", "cross_coupled_damping", "bearing_compliance",
         "moment_stiffness", "bearing_speed_damping"]


def test_a_machine_is_offered_every_family_at_its_own_bearings_and_planes():
    machine = stepped_machine()  # bearings a (node 2, k 2e7, c 800), b (node 13, k 1e7, c 500), plane d1 (node 8)
    sized = machine.sized_candidates()
    assert list(sized) == ([f"{kind}@{b}" for b in "ab" for kind in KINDS]
                           + [f"excitation_{h}x@{p}" for p in ("a", "b", "d1") for h in (2, 3)]
                           + [f"{fault}@{b}" for b in "ab" for fault in ("looseness", "misalignment")] + ["crack@d1", "rub@d1"])
    # ranges from the machine's scale: fractions of each bearing's k, c; the element's 4 E I / h at the bearing
    # (node 2 lies inside segment 0, d = 0.04 m, h = 0.05 m; node 13 inside segment 1, the tube 0.05/0.02 m,
    # h = 0.05 m); the force that moves the rotor 10 um on its supports, 1e-5 (2e7 + 1e7) = 300 N
    tilt = {"a": 4 * 2.11e11 * np.pi * 0.04**4 / 64 / 0.05, "b": 4 * 2.11e11 * np.pi * (0.05**4 - 0.02**4) / 64 / 0.05}
    for b, k, c in (("a", 2e7, 800.0), ("b", 1e7, 500.0)):
        (p,) = sized[f"bearing_compliance@{b}"].parameters
        assert (p.name, p.bounds, p.limits) == (f"dkiso_{b}", (-0.2 * k, 0.2 * k), (-0.99 * k, 9 * k))
        (p,) = sized[f"moment_stiffness@{b}"].parameters
        assert p.name == f"krot_{b}" and p.bounds == pytest.approx((0.0, 0.07 * tilt[b]))
        assert p.limits == pytest.approx((0.0, tilt[b]))
        (p,) = sized[f"bearing_speed_damping@{b}"].parameters
        assert (p.name, p.bounds) == (f"cv_{b}", (-0.4, 0.4))
    for place in ("a", "b", "d1"):
        p2 = sized[f"excitation_2x@{place}"].parameters
        assert [p.name for p in p2] == [f"f2_c_{place}", f"f2_s_{place}"]
        assert p2[0].bounds == pytest.approx((-300.0, 300.0)) and p2[0].limits == pytest.approx((-3000.0, 3000.0))
    # every one declares its switches, and each is in the machine's effects (the config's names), over the VARM's
    # placed built-in of the same name (f2 +-0.5 N, a 2400 N/m bearing's)
    effects = machine.effects()
    assert all(effects[name].parameters == effect.parameters and effect.switches for name, effect in sized.items())
    assert Machine.varm().sized_candidates() == {}  # the VARM: nothing new (its bearings carry no nominal k)


def test_each_new_term_at_zero_is_absent_and_otherwise_where_it_says():
    machine = stepped_machine()
    effects = machine.effects()
    names = ["bearing_compliance@b", "moment_stiffness@a", "bearing_speed_damping@b", "excitation_3x@d1"]
    model = Model([effects[n] for n in EFFECTS + names], machine)
    nominal = {k: p.nominal for k, p in model.parameters.items()} | {"m_e": 0.02}
    on = nominal | {"dkiso_b": -1.5e6, "krot_a": 3e4, "cv_b": 0.3, "f3_c_d1": 20.0, "f3_s_d1": 5.0}
    rpm = 3500.0
    base, zero = Model([effects[n] for n in EFFECTS], machine).system(nominal, rpm), model.system(nominal, rpm)
    for a, b in ((base.K, zero.K), (base.C, zero.C), (base.M, zero.M)):
        np.testing.assert_array_equal(a, b)  # at zero exactly the base
    assert set(zero.forcing) == {1}
    with_ = model.system(on, rpm)
    dK, dC = with_.K[0] - base.K[0], with_.C[0] - base.C[0]
    expected_K = np.zeros_like(dK)
    for dof, value in (("u13", -1.5e6), ("v13", -1.5e6), ("du2", 3e4), ("dv2", 3e4)):
        expected_K[machine.dof(dof), machine.dof(dof)] = value
    np.testing.assert_allclose(dK, expected_K, atol=1e-6)  # K ~ 1e7: a few ulps
    # C[u13] += cv c Omega / omega_1, omega_1 the lowest x-plane frequency at rest (written out: shaft + bearings
    # + the new stiffness terms + the eccentric mass), scipy's symmetric eigensolver
    K, M = machine.plane_matrices()
    for node, k in ((2, 2e7), (13, 1e7 - 1.5e6)):
        K[2 * node, 2 * node] += k
    K[5, 5] += 3e4
    M[16, 16] += 0.02
    omega_1 = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[0])
    expected_C = np.zeros_like(dC)
    for dof in ("u13", "v13"):
        expected_C[machine.dof(dof), machine.dof(dof)] = 0.3 * 500.0 * rpm * np.pi / 30 / omega_1
    np.testing.assert_allclose(dC, expected_C, rtol=1e-9, atol=1e-9)
    F = with_.forcing[3][0]
    assert F[machine.dof("u8")] == 20 + 5j and F[machine.dof("v8")] == -1j * (20 + 5j)
    assert np.count_nonzero(F) == 2


def test_a_wrong_known_bearing_stiffness_is_diagnosed_as_that_bearings_compliance():
    """Records of the stepped rotor (harmonic-balance solver, noise 2e-8 m per part) whose bearing b is 15 % softer
    (k_b 8.5e6) than the variant holds it (1e7, neither fitted nor fixed: its nominal value); the diagnosis among
    the candidates of both bearings names bearing_compliance@b, the truth -1.5e6 N/m within dkiso_b's interval."""
    machine = stepped_machine()
    H, sigma = 1, 2e-8
    runs = [(f"r{int(r)}", r, 20.0) for r in (3000.0, 3800.0, 3950.0, 4100.0, 4800.0)]
    truth = Variant.from_spec("truth", {"effects": EFFECTS, "unknown": {k: [-1e12, 1e12] for k in
                                                                        ("k_a", "c_a", "c_b", "k_b")}}, shaft=machine)
    values = np.array([2.2e7, 900.0, 450.0, 8.5e6])
    rng = np.random.default_rng(1)
    data = []
    for run, rpm, mass in runs:
        model = fwd.SolverModel(truth, run, rpm, mass, ["k_a", "c_a", "c_b", "k_b"], values - 1, values + 1, H)
        X = model.evaluate(np.zeros((1, 4)), jacobian=False)[0][0]
        data.append(idn.RunData(run, rpm, mass, "fit", X + sigma * (rng.standard_normal(X.shape)
                                                                    + 1j * rng.standard_normal(X.shape)),
                                np.full(X.shape, sigma)))
    variant = Variant.from_spec("linear", {"effects": EFFECTS, "unknown": {"k_a": [1e7, 4e7], "c_a": [400, 1600],
                                                                           "c_b": [250, 1000]}}, shaft=machine)
    sized = machine.sized_candidates()
    candidates = [Candidate.of(sized[f"{kind}@b"]) for kind in ("bearing_compliance", "moment_stiffness",
                                                                 "bearing_anisotropy")]
    candidates.append(Candidate.of(sized["bearing_compliance@a"]))
    # the diagnosis with fewer refits than the defaults (the score tests rank moment_stiffness@b first: to first
    # order it looks alike; the refits tell them apart)
    result, _ = fit_and_diagnose(variant, data, candidates, H, {"thorough": 1, "starts": 0, "widen": 0,
                                                                 "max_effects": 1, "quick_iterations": 6,
                                                                 "max_iterations": 20})
    assert result.table.loc[0, "effect"] == "bearing_compliance@b"
    assert result.conclusion.startswith("add bearing_compliance@b: it explains the discrepancy")
    confirmation = result.confirmations["bearing_compliance@b"]
    assert confirmation.chi2 / confirmation.dof < 1 + 3 * np.sqrt(2 / confirmation.dof)  # to the noise: 3 sigma
    estimate = confirmation.estimates.set_index("parameter").loc["dkiso_b"]
    assert estimate["ci_low"] <= -1.5e6 <= estimate["ci_high"]
