"""Candidate effects (issue 6) against references built here, independently of the package.

The references: system matrices written out by hand from docs/model.md (point masses, supports,
dampers, forcing), scipy's symmetric eigensolver for omega_1, direct complex solves of
(K - (h Omega)^2 M + i h Omega C) U = F, and the one-plane (Jeffcott-like) reduction of a
forward or backward whirl, in which cross-coupling turns into a direct damping or stiffness.
"""

import dataclasses

import numpy as np
import pytest
import scipy.linalg
import yaml

from hybridtwin import solve
from hybridtwin.model.candidates import Candidate, builtin_candidates, candidates_for
from hybridtwin.model.effects import builtin_effects
from hybridtwin.model.model import rpm_to_rad_s
from hybridtwin.model.variants import BASE, BUILTIN_VARIANTS, Variant, load_effects_files
from hybridtwin.solvers.solver import solve_variant

GEOMETRIC = BUILTIN_VARIANTS["geometric"]
# the bundled data's values (rig.DEFAULT_TRUTH), two scenarios with different masses and speeds
VALUES = dict(k_b=2411.3, zeta_s=0.024, zeta_bup=0.016, q_x=0.002, q_y=0.0015, m_e=np.array([0.0259, 0.0148]))
RPM = np.array([450.0, 800.0])
NEW = ["upper_bearing_anisotropy", "cross_coupled_stiffness", "cross_coupled_damping", "moment_stiffness",
       "lower_bearing_compliance", "excitation_2x", "excitation_3x", "speed_damping"]

# the known values of docs/model.md (Table 1 and the nominal supports), written out again
M_BUP, M_BLO, K_LO, ZETA_BLO, R_ME = 0.056, 0.176, 1e4, 0.05, 0.040
K3 = 2 * 2411.3  # a linear upper bearing (expansion_k3 alone): the whole model is linear
LINEAR = dict(k3=K3, zeta_s=0.024, zeta_bup=0.016, q_x=0.0, q_y=0.0, m_e=0.0148)

# The pre-change catalogue (issue 25): the built-in candidates, their tested parameters with (range, limits),
# in order, as candidates.BUILTIN_TESTED gave them before the tested parameters moved onto the effects
# (Effect.switches). Written out once from that table; the catalogue read from the effects must equal it.
PRE_CHANGE_CATALOGUE = {
    "slope_spring": (("k_w", (0.0, 1000.0), None), ("k_z", (0.0, 1000.0), None)),
    "expansion_k2": (("k2", (-1000, 1000), None),),
    "expansion_k4": (("k4", (-1000, 1000), None),),
    "expansion_k5": (("k5", (-1000, 1000), None),),
    "expansion_k6": (("k6", (-1000, 1000), None),),
    "expansion_k7": (("k7", (-14000, 14000), None),),
    "upper_bearing_anisotropy": (("dk_up", (-500.0, 500.0), (-4000.0, 4000.0)),),
    "cross_coupled_stiffness": (("k_xy", (-200.0, 200.0), (-2000.0, 2000.0)),),
    "cross_coupled_damping": (("c_xy", (-5.0, 5.0), (-50.0, 50.0)),),
    "moment_stiffness": (("k_rot", (0.0, 300.0), (0.0, 4140.0)),),
    "lower_bearing_compliance": (("dk_lo", (-2000.0, 2000.0), (-9900.0, 90000.0)),),
    "excitation_2x": (("f2_c", (-0.5, 0.5), (-10.0, 10.0)), ("f2_s", (-0.5, 0.5), (-10.0, 10.0))),
    "excitation_2x_inertial": (("e2_c", (-4.5e-05, 4.5e-05), (-4.5e-04, 4.5e-04)),
                               ("e2_s", (-4.5e-05, 4.5e-05), (-4.5e-04, 4.5e-04))),
    "excitation_3x": (("f3_c", (-0.3, 0.3), (-10.0, 10.0)), ("f3_s", (-0.3, 0.3), (-10.0, 10.0))),
    "speed_damping": (("zeta_v", (0.0, 0.05), (0.0, 1.0)),),
}
BUILTIN = list(PRE_CHANGE_CATALOGUE)


def _with(*names, base=GEOMETRIC):
    return Variant.from_spec("+".join(names) or "base", {**base, "effects": list(base["effects"]) + list(names)})


def _linear(*names):
    return Variant.from_spec("linear", {"effects": BASE + ["expansion_k3", *names]})


def _hand_linear(shaft, rpm, extra=None):
    """M, C, K (K with -Omega^2 M) and the 1X forcing of the linear model, from the spec's formulas."""
    extra = extra or {}
    K, M = shaft.matrices()
    d = shaft.dof
    K, M = K.copy(), M.copy()
    for dof in ("u0", "v0"):
        M[d(dof), d(dof)] += M_BUP
        K[d(dof), d(dof)] += K3
    for dof in ("u10", "v10"):
        M[d(dof), d(dof)] += M_BLO
        K[d(dof), d(dof)] += K_LO
    for dof in ("u5", "v5"):  # z_me = 0.425 m = node 5
        M[d(dof), d(dof)] += LINEAR["m_e"]
    for (row, col), value in extra.items():
        K[d(row), d(col)] += value
    n = shaft.n_plane
    omega_1 = np.sqrt(scipy.linalg.eigh(K[:n, :n], M[:n, :n], eigvals_only=True)[0])
    C = 2 * LINEAR["zeta_s"] * omega_1 * M
    for dof in ("u0", "v0"):
        C[d(dof), d(dof)] += 2 * LINEAR["zeta_bup"] * np.sqrt(K3 * M_BUP)
    for dof in ("u10", "v10"):
        C[d(dof), d(dof)] += 2 * ZETA_BLO * np.sqrt(K_LO * M_BLO)
    Omega = rpm * 2 * np.pi / 60
    F = np.zeros(shaft.n_dof, complex)
    F[d("u5")] = LINEAR["m_e"] * R_ME * Omega**2
    F[d("v5")] = -1j * LINEAR["m_e"] * R_ME * Omega**2
    return M, C, K - Omega**2 * M, F, Omega


def _global_force(system, q):
    """Sum of the local forces on all DOFs, and their derivative, at global displacements q (S, n, N)."""
    S, n, N = q.shape
    F, J = np.zeros((S, n, N)), np.zeros((S, n, n, N))
    for force in system.forces:
        f, j = force.evaluate(q[:, force.dofs], system.rows)
        F[:, force.dofs] += f
        J[:, force.dofs[:, None], force.dofs[None, :]] += j
    return F, J


# --- absent at zero ----------------------------------------------------------------------


@pytest.mark.parametrize("names", [[name] for name in BUILTIN] + [BUILTIN], ids=BUILTIN + ["all-at-once"])
def test_every_builtin_candidate_at_zero_is_the_base_system(names):
    """Each candidate, and all of them in one model (the diagnosis' batched score test), at zero."""
    tested = [p for name in names for p in builtin_candidates()[name].tested]
    base = _with().system(RPM, VALUES)
    zero = _with(*names).system(RPM, {**VALUES, **{p: 0.0 for p in tested}})
    for attr in ("M", "C", "K", "Omega"):
        np.testing.assert_array_equal(getattr(zero, attr), getattr(base, attr), err_msg=attr)
    assert set(zero.forcing) == set(base.forcing)  # not even a zero 2X / 3X harmonic
    for h in base.forcing:
        np.testing.assert_array_equal(zero.forcing[h], base.forcing[h])
    # the local forces: the same on every DOF at arbitrary displacements (a slope term at zero may widen
    # the bearing's DOF set, so compare the assembled force, not the list)
    q = np.random.default_rng(3).normal(scale=3e-3, size=(2, base.n_dof, 7))
    for got, expected in zip(_global_force(zero, q), _global_force(base, q)):
        np.testing.assert_array_equal(got, expected)


def test_new_candidates_describe_themselves_and_do_not_collide():
    effects = builtin_effects()
    for name in NEW:
        candidate = builtin_candidates()[name]
        assert candidate.effect is not None and candidate.meaning and name in BUILTIN
        assert {p.name for p in candidate.effect.parameters} == set(candidate.tested)
        for par in candidate.parameters:
            lo, hi = par.bounds
            assert par.nominal == 0.0 and lo <= 0.0 <= hi < np.inf and hi > 0 and par.unit and par.meaning
            owners = [e.name for e in effects.values() if par.name in {p.name for p in e.parameters}]
            assert owners == [name], f"parameter {par.name} also declared by {owners}"


def test_config_lines_give_a_variant_spec_that_from_spec_accepts():
    for candidate in builtin_candidates().values():
        fragment = yaml.safe_load(candidate.config_lines().replace("..., ", ""))
        assert fragment["effects"] == [candidate.name]
        ranges = fragment["unknown"]
        assert list(ranges) == list(candidate.tested)
        assert all(isinstance(x, (int, float)) for bounds in ranges.values() for x in bounds)  # numbers, not strings
        spec = {**GEOMETRIC, "effects": GEOMETRIC["effects"] + fragment["effects"],
                "unknown": {**GEOMETRIC["unknown"], **ranges}}
        variant = Variant.from_spec(f"geometric_{candidate.name}", spec)
        for par in candidate.parameters:
            assert variant.unknown[par.name] == pytest.approx(par.bounds)


# --- stiffness and damping terms ---------------------------------------------------------


def test_anisotropy_splits_the_node0_support_stiffness_and_c_bup_follows():
    variant, dk = _with("upper_bearing_anisotropy"), 400.0
    values = {**VALUES, "dk_up": dk}
    ctx = variant.model.context(variant.values(values), RPM)
    ctx0 = variant.model.context(variant.values({**values, "dk_up": 0.0}), RPM)
    shaft = variant.model.shaft
    u0, v0 = shaft.dof("u0"), shaft.dof("v0")
    expected = np.zeros((shaft.n_dof, shaft.n_dof))
    expected[u0, u0], expected[v0, v0] = dk, -dk
    np.testing.assert_array_equal(ctx.K_support - ctx0.K_support, np.broadcast_to(expected, ctx.K.shape))
    np.testing.assert_allclose(np.trace(ctx.K_support, axis1=1, axis2=2), np.trace(ctx0.K_support, axis1=1, axis2=2))
    # the documented coupling: c_bup = 2 zeta_bup sqrt(k_up m_bup) per plane, k_up = 2 k_b +- dk_up
    C = variant.system(RPM, values).C
    n = shaft.n_plane
    for s in range(2):
        omega_1 = np.sqrt(scipy.linalg.eigh(ctx.K[s, :n, :n], ctx.M[s, :n, :n], eigvals_only=True)[0])
        direct = C[s] - 2 * 0.024 * omega_1 * ctx.M[s]
        for i, k_up in ((u0, 2 * 2411.3 + dk), (v0, 2 * 2411.3 - dk)):
            assert direct[i, i] == pytest.approx(2 * 0.016 * np.sqrt(k_up * M_BUP), rel=1e-9)


def test_cross_coupled_stiffness_is_the_skew_part_of_K():
    k_xy = 150.0
    variant = _with("cross_coupled_stiffness")
    K = variant.system(RPM, {**VALUES, "k_xy": k_xy}).K
    K0 = _with().system(RPM, VALUES).K
    shaft = variant.model.shaft
    u0, v0 = shaft.dof("u0"), shaft.dof("v0")
    skew = np.zeros((shaft.n_dof, shaft.n_dof))
    skew[u0, v0], skew[v0, u0] = k_xy, -k_xy
    np.testing.assert_allclose(0.5 * (K - np.swapaxes(K, 1, 2)), np.broadcast_to(skew, K.shape), atol=1e-9)
    np.testing.assert_allclose(0.5 * (K + np.swapaxes(K, 1, 2)), K0, rtol=1e-14, atol=1e-9)


@pytest.mark.parametrize("whirl", ["forward", "backward"])
def test_cross_coupling_acts_on_a_whirl_as_direct_damping_and_stiffness(whirl):
    """One-plane reduction: y = -+ i x turns K_xy v into -+ i k_xy u and i Omega C_xy v into +- Omega c_xy u.

    Forward (y = -i x): C_eq = -k_xy / Omega, K_eq = +Omega c_xy at u0; backward the signs flip.
    The reference solves the 22-DOF x plane built by hand; the package solves all 44 DOFs.
    """
    k_xy, c_xy, rpm = 150.0, 3.0, 600.0
    variant = _linear("cross_coupled_stiffness", "cross_coupled_damping")
    system = variant.system(rpm, {**LINEAR, "k_xy": k_xy, "c_xy": c_xy})
    assert not system.forces  # linear
    sign = -1 if whirl == "forward" else 1  # y = sign * i x
    F = system.forcing[1].copy()
    x, y = variant.model.shaft.translational("x"), variant.model.shaft.translational("y")
    F[:, y] = sign * 1j * F[:, x]
    result = solve(dataclasses.replace(system, forcing={1: F}), 1)
    assert result.success.all()
    M, C, K, F_hand, Omega = _hand_linear(variant.model.shaft, rpm)
    n = variant.model.shaft.n_plane
    D = K[:n, :n] + 1j * Omega * C[:n, :n] - Omega**2 * M[:n, :n]
    D[0, 0] += sign * 1j * k_xy - sign * Omega * c_xy  # u0 is DOF 0 of the x plane
    X = np.linalg.solve(D, F_hand[:n])
    np.testing.assert_allclose(result.harmonics[0, 1, :n], X, rtol=1e-9, atol=1e-12 * np.abs(X).max())
    np.testing.assert_allclose(result.harmonics[0, 1, n:], sign * 1j * X, rtol=1e-9, atol=1e-12 * np.abs(X).max())
    # and the coupling matters at this size: the response differs from the uncoupled one by > 1 %
    D0 = K[:n, :n] + 1j * Omega * C[:n, :n] - Omega**2 * M[:n, :n]
    assert np.abs(X - np.linalg.solve(D0, F_hand[:n])).max() > 0.01 * np.abs(X).max()


def test_moment_stiffness_raises_the_first_natural_frequency():
    variant, k_rot = _with("moment_stiffness"), 300.0
    values = variant.values({**VALUES, "k_rot": k_rot})
    ctx = variant.model.context(values, RPM)
    base = _with().model.context(_with().values(VALUES), RPM)
    shaft = variant.model.shaft
    n, du0 = shaft.n_plane, shaft.dof("du0")
    added = np.zeros((shaft.n_dof, shaft.n_dof))
    added[du0, du0] = added[shaft.dof("dv0"), shaft.dof("dv0")] = k_rot
    np.testing.assert_array_equal(ctx.K - base.K, np.broadcast_to(added, ctx.K.shape))
    for s in range(2):
        K = base.K[s, :n, :n].copy()
        K[du0, du0] += k_rot
        reference = np.sqrt(scipy.linalg.eigh(K, base.M[s, :n, :n], eigvals_only=True)[0])
        assert ctx.omega_1[s] == pytest.approx(reference, rel=1e-10)
        assert ctx.omega_1[s] > base.omega_1[s] * 1.01  # 22.3 -> 22.9 Hz, see the range note in effects.py


def test_lower_bearing_compliance_is_a_different_k_in_K_but_not_in_c_blo():
    dk = -1500.0
    variant = _with("lower_bearing_compliance")
    a = variant.system(RPM, {**VALUES, "dk_lo": dk})
    b = _with().system(RPM, {**VALUES, "k": K_LO + dk})  # the same stiffness by another route
    np.testing.assert_allclose(a.K, b.K, rtol=1e-13, atol=1e-9)
    np.testing.assert_array_equal(a.M, b.M)
    # C differs only by the lower damper, which keeps c_blo = 2 zeta_blo sqrt(k m_blo) with the known k
    shaft = variant.model.shaft
    expected = np.zeros((shaft.n_dof, shaft.n_dof))
    for dof in ("u10", "v10"):
        i = shaft.dof(dof)
        expected[i, i] = 2 * ZETA_BLO * (np.sqrt(K_LO * M_BLO) - np.sqrt((K_LO + dk) * M_BLO))
    np.testing.assert_allclose(a.C - b.C, np.broadcast_to(expected, a.C.shape), atol=1e-12)


def test_speed_damping_is_structural_damping_with_a_speed_dependent_ratio():
    """2 zeta_v Omega M = 2 (zeta_v Omega / omega_1) omega_1 M: eq. 31-32 with zeta_s + zeta_v Omega / omega_1."""
    rpm = np.array([350.0, 650.0, 1000.0])
    zeta_v = 0.03
    values = {**VALUES, "m_e": 0.0148}
    C = _with("speed_damping").system(rpm, {**values, "zeta_v": zeta_v}).C
    ctx = _with().model.context(_with().values(values), 0.0)
    n = ctx.shaft.n_plane
    omega_1 = np.sqrt(scipy.linalg.eigh(ctx.K[0, :n, :n], ctx.M[0, :n, :n], eigvals_only=True)[0])
    zeta_s = values["zeta_s"] + zeta_v * rpm_to_rad_s(rpm) / omega_1
    reference = _with().system(rpm, {**values, "zeta_s": zeta_s}).C
    # omega_1 by two eigensolvers (scipy here, the package's Cholesky route there): agree to ~1e-12
    np.testing.assert_allclose(C, reference, rtol=1e-10, atol=1e-14)


# --- 2X and 3X excitation ----------------------------------------------------------------


@pytest.mark.parametrize("h", [2, 3])
def test_harmonic_excitation_forces_harmonic_h_only_with_the_direct_solve_amplitude(h):
    f_c, f_s, rpm = 0.2, -0.1, 550.0
    name = f"excitation_{h}x"
    variant = _linear(name)
    params = {f"f{h}_c": f_c, f"f{h}_s": f_s}
    system = variant.system(rpm, {**LINEAR, **params})
    shaft = variant.model.shaft
    u0, v0 = shaft.dof("u0"), shaft.dof("v0")
    # the convention: f(t) = Re(F_h exp(i h Omega t)) is (f_c, f_s) at t = 0, when the unbalance points to +x,
    # and turns forward (+x -> +y): a quarter period of h Omega later it points to (-f_s, f_c)
    F = system.forcing[h][0]
    np.testing.assert_allclose([F[u0].real, F[v0].real], [f_c, f_s], rtol=1e-15)
    np.testing.assert_allclose([(1j * F[u0]).real, (1j * F[v0]).real], [-f_s, f_c], rtol=1e-15)
    assert np.count_nonzero(F) == 2
    result = solve_variant(variant, rpm, {**LINEAR, **params}, harmonics=5)
    base = solve_variant(variant, rpm, LINEAR, harmonics=5)
    assert result.success.all() and base.success.all()
    others = [k for k in range(6) if k != h]
    np.testing.assert_array_equal(result.harmonics[:, others], base.harmonics[:, others])
    assert np.all(base.harmonics[0, h] == 0)
    M, C, K, _, Omega = _hand_linear(shaft, rpm)
    w = h * Omega
    F_hand = np.zeros(shaft.n_dof, complex)
    F_hand[u0], F_hand[v0] = f_c + 1j * f_s, -1j * (f_c + 1j * f_s)
    U = np.linalg.solve(K - w**2 * M + 1j * w * C, F_hand)
    np.testing.assert_allclose(result.harmonics[0, h], U, rtol=1e-9, atol=1e-12 * np.abs(U).max())
    assert 1e-5 < np.abs(U[shaft.dof("u1")]) < 14e-3  # a measurable response at the sensor


@pytest.mark.parametrize("rpm", [400.0, 900.0])
def test_inertial_2x_law_is_the_constant_force_times_omega_squared(rpm):
    # the Omega^2 law at e = f / Omega^2 forces exactly what the constant law forces with f, at any speed;
    # so their responses are equal there, and the law differs from the constant one by Omega^2 across speeds
    e_c, e_s = 2e-5, -1e-5
    Omega = float(rpm_to_rad_s(rpm))
    inertial = _linear("excitation_2x_inertial").system(rpm, {**LINEAR, "e2_c": e_c, "e2_s": e_s})
    constant = _linear("excitation_2x").system(rpm, {**LINEAR, "f2_c": e_c * Omega**2, "f2_s": e_s * Omega**2})
    np.testing.assert_allclose(inertial.forcing[2], constant.forcing[2], rtol=1e-14)
    shaft = _linear().model.shaft
    assert abs(inertial.forcing[2][0, shaft.dof("u0")] - (e_c + 1j * e_s) * Omega**2) < 1e-15
    with pytest.raises(ValueError, match="law must be"):
        dataclasses.replace(builtin_effects()["excitation_2x"], law="cubic")


def test_absent_excitation_leaves_no_harmonic_so_low_H_still_solves():
    variant = _linear("excitation_3x")
    result = solve_variant(variant, 500.0, {**LINEAR, "f3_c": 0.0, "f3_s": 0.0}, harmonics=1)
    assert result.success.all()
    with pytest.raises(ValueError, match="raise H"):
        solve_variant(variant, 500.0, {**LINEAR, "f3_c": 0.1, "f3_s": 0.0}, harmonics=1)


# --- user candidates ---------------------------------------------------------------------

USER_FILE = '''
from hybridtwin import Effect, Parameter


class FoundationDamping(Effect):
    name = "foundation_damping"
    meaning = "an extra viscous damper under the lower bearing"
    parameters = (Parameter("c_f", "N s/m", (0.0, 5.0), 0.0, "damper at the last node, both planes"),)

    def damping(self, ctx):
        out = ctx.zeros()
        for dof in (f"u{ctx.shaft.n}", f"v{ctx.shaft.n}"):
            i = ctx.dof(dof)
            out[:, i, i] = ctx.p.c_f
        return out


foundation_damping = FoundationDamping()
'''


def test_a_user_candidate_from_an_effects_file(tmp_path):
    path = tmp_path / "my_candidates.py"
    path.write_text(USER_FILE)
    user = load_effects_files([path])
    present = GEOMETRIC["effects"]
    chosen = candidates_for(present, ["excitation_2x", "foundation_damping"], user_effects=user)
    assert [c.name for c in chosen] == ["excitation_2x", "foundation_damping"]
    mine = chosen[1]
    assert mine.tested == ("c_f",) and mine.meaning.startswith("an extra viscous damper")
    fragment = yaml.safe_load(mine.config_lines().replace("..., ", ""))
    spec = {**GEOMETRIC, "effects": GEOMETRIC["effects"] + fragment["effects"],
            "unknown": {**GEOMETRIC["unknown"], **fragment["unknown"]}}
    variant = Variant.from_spec("geometric_foundation", spec, user)
    assert variant.unknown["c_f"] == (0.0, 5.0)
    zero = variant.system(RPM, {**VALUES, "c_f": 0.0})
    base = _with().system(RPM, VALUES)
    np.testing.assert_array_equal(zero.C, base.C)
    on = variant.system(RPM, {**VALUES, "c_f": 2.0})
    i = variant.model.shaft.dof("v10")
    assert on.C[0, i, i] - base.C[0, i, i] == pytest.approx(2.0)
    # without the file the name is unknown; a candidate already in the variant is skipped
    with pytest.raises(ValueError, match="foundation_damping"):
        candidates_for(present, ["foundation_damping"])
    final = BUILTIN_VARIANTS["final"]["effects"]
    assert "slope_spring" not in [c.name for c in candidates_for(final)]
    assert [c.name for c in candidates_for(present)] == BUILTIN
    # a user's effect named like a built-in candidate is the one tested, as it is the one a variant builds with
    # (variants.Variant.from_spec: the user's effects override the built-in ones of the same name)
    clash = {"cross_coupled_stiffness": user["foundation_damping"]}
    tested = candidates_for(present, ["cross_coupled_stiffness"], user_effects=clash)[0]
    assert tested.tested == ("c_f",)
    assert [c.tested for c in candidates_for(present, None, user_effects=clash)
            if c.name == "foundation_damping"] == [("c_f",)]


def test_a_user_coupling_excitation_elsewhere_coexists_with_the_builtin_one():
    from hybridtwin.model.effects import HarmonicExcitation

    coupling = HarmonicExcitation(name="coupling_2x", meaning="2X force of a misaligned coupling at the motor",
                                  harmonic=2, node=10, bounds=(-0.5, 0.5))
    assert [p.name for p in coupling.parameters] == ["f2_c_10", "f2_s_10"]
    spec = {"effects": BASE + ["expansion_k3", "excitation_2x", "coupling_2x"]}
    variant = Variant.from_spec("both", spec, {"coupling_2x": coupling})
    F = variant.system(500.0, {**LINEAR, "f2_c": 0.1, "f2_s_10": 0.2}).forcing[2][0]
    d = variant.model.shaft.dof
    assert F[d("u0")] == 0.1 and F[d("v0")] == -0.1j
    assert F[d("u10")] == 0.2j and F[d("v10")] == 0.2
    assert np.count_nonzero(F) == 4


# --- where a candidate's tested parameters are declared: on the effect (Effect.switches) -----------


def test_the_catalogue_read_from_the_effects_is_the_pre_change_one():
    catalogue = builtin_candidates()
    assert list(catalogue) == BUILTIN  # the same candidates, in the same order
    for name, expected in PRE_CHANGE_CATALOGUE.items():
        candidate = catalogue[name]
        assert candidate.tested == candidate.effect.switches == tuple(p for p, _, _ in expected)
        assert [(p.name, p.bounds, p.limits) for p in candidate.parameters] == list(expected)
    # the other built-in effects declare nothing, so they are no candidates (e.g. expansion_k1, k3, the base)
    undeclared = [e.name for e in builtin_effects().values() if not e.switches]
    assert set(undeclared) & set(BUILTIN) == set() and {"expansion_k1", "expansion_k3", "geometric_spring"} <= set(
        undeclared)


SWITCHED_FILE = '''
from hybridtwin import Effect, Parameter


class PlacedDamper(Effect):
    name = "placed_damper"
    meaning = "a damper of coefficient c_d at a node n_d"
    parameters = (Parameter("c_d", "N s/m", (0.0, 5.0), 0.0, "its coefficient"),
                  Parameter("n_d", "1", (0.0, 10.0), 10.0, "the node it acts at"))


class Switched(PlacedDamper):
    name = "switched_damper"
    switches = ("c_d",)  # n_d only places it: at c_d = 0 it is absent whatever n_d


class Wrong(PlacedDamper):
    name = "wrong_damper"
    switches = ("c_x",)


placed_damper, switched_damper, wrong_damper = PlacedDamper(), Switched(), Wrong()
'''


def test_a_user_effect_declares_its_switches_or_has_all_its_parameters_tested(tmp_path):
    path = tmp_path / "dampers.py"
    path.write_text(SWITCHED_FILE)
    user = load_effects_files([path])
    declared, undeclared = candidates_for([], ["switched_damper", "placed_damper"], user_effects=user)
    assert declared.tested == ("c_d",)  # what it declares
    assert undeclared.tested == ("c_d", "n_d")  # the rule before switches: all its parameters
    assert [p.bounds for p in declared.parameters] == [(0.0, 5.0)]  # the range is the Parameter's
    with pytest.raises(ValueError, match=r"wrong_damper.*\['c_x'\].*switches"):
        candidates_for([], ["wrong_damper"], user_effects=user)


def test_a_harmonic_excitation_switches_on_by_its_own_parameters_wherever_it_acts():
    moved = dataclasses.replace(builtin_effects()["excitation_2x"], node=10, name="excitation_2x_at_10")
    assert moved.switches == ("f2_c_10", "f2_s_10") == tuple(p.name for p in moved.parameters)
    assert Candidate.of(moved).tested == ("f2_c_10", "f2_s_10")


def test_an_effect_says_when_it_is_a_candidate():
    effects = builtin_effects()
    assert "as a diagnosis candidate: switched on by f2_c, f2_s" in effects["excitation_2x"].describe()
    assert "switched on by k2\n" in effects["expansion_k2"].describe()  # before the bearing's formula line
    assert "diagnosis candidate" not in effects["geometric_spring"].describe()
