"""The assembled VARM model against the definitions of docs/model.md.

References are computed here independently of the package (scipy's generalized
eigensolver, the exact four-spring geometry, the formulas written out again).
"""

import numpy as np
import pytest
import scipy.linalg

from hybridtwin import Effect, Parameter, PolynomialBearing, Term
from hybridtwin.model.effects import geometric_spring
from hybridtwin.model.model import rpm_to_rad_s
from hybridtwin.model.variants import Variant, builtin_variant, load_effects_file
from hybridtwin.solvers.solver import solve_variant

PAPER = dict(k_b=2411.3, zeta_s=0.024, zeta_bup=0.016, q_x=0.004, q_y=0.006, m_e=0.0148)


@pytest.fixture(scope="module")
def geometric():
    return builtin_variant("geometric")


def _x_plane(variant, values):
    ctx = variant.model.context(variant.values(values), 0.0)
    n = variant.model.shaft.n_plane
    return ctx, ctx.K[0, :n, :n], ctx.M[0, :n, :n]


def test_first_natural_frequency_matches_scipy_and_spec(geometric):
    # docs/model.md: f_1 about 21.6 Hz at k_b = 2331.5 N/m (with the 14.8 g run's m_e);
    # 21.3-23.9 Hz over the k_b range (bare rotor, m_e = 0).
    for k_b, m_e, expected_hz in ((2331.5, 0.0148, 21.6), (2000.0, 0.0, 21.3), (3500.0, 0.0, 23.9)):
        ctx, K, M = _x_plane(geometric, {"k_b": k_b, "m_e": m_e})
        reference = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[0])
        # same pencil, different algorithm: agreement to round-off (1e-10 relative)
        assert ctx.omega_1[0] == pytest.approx(reference, rel=1e-10)
        # the spec quotes one decimal in Hz: +-0.05 Hz
        assert ctx.omega_1[0] / (2 * np.pi) == pytest.approx(expected_hz, abs=0.05)


def test_first_mode_shape_is_translational_and_scaled_to_plus_one(geometric):
    ctx, K, M = _x_plane(geometric, PAPER)
    _, vectors = scipy.linalg.eigh(K, M)
    phi = vectors[0::2, 0]  # translational entries
    phi = phi / phi[np.argmax(np.abs(phi))]
    np.testing.assert_allclose(ctx.Phi_1[0], phi, atol=1e-10)
    assert ctx.Phi_1[0].max() == 1.0


def test_damping_matrix_follows_its_definitions(geometric):
    """C = 2 zeta_s omega_1 M + c_bup (node 0) + c_blo (node 10), eq. 31-32."""
    values = geometric.values(PAPER)
    system = geometric.model.system(values, 700)
    ctx, K, M = _x_plane(geometric, PAPER)
    omega_1 = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[0])
    expected = 2 * PAPER["zeta_s"] * omega_1 * ctx.M[0]
    shaft = geometric.model.shaft
    c_bup = 2 * PAPER["zeta_bup"] * np.sqrt(2 * PAPER["k_b"] * 0.056)
    c_blo = 2 * 0.05 * np.sqrt(1e4 * 0.176)
    for dof, c in (("u0", c_bup), ("v0", c_bup), ("u10", c_blo), ("v10", c_blo)):
        expected[shaft.dof(dof), shaft.dof(dof)] += c
    np.testing.assert_allclose(system.C[0], expected, rtol=1e-10, atol=1e-12)


def test_expansion_bearing_damping_uses_k3():
    expansion = builtin_variant("expansion")
    values = {"k3": 5428.5, "zeta_bup": 0.02}
    system = expansion.system(500, values)
    bare = expansion.system(500, {**values, "zeta_bup": 0.0})
    u0 = expansion.model.shaft.dof("u0")
    c_bup = system.C[0, u0, u0] - bare.C[0, u0, u0]
    assert c_bup == pytest.approx(2 * 0.02 * np.sqrt(5428.5 * 0.056), rel=1e-12)


def test_stiffness_has_centrifugal_term_and_linear_bearings(geometric):
    rpm = 650.0
    system = geometric.system(rpm, PAPER)
    ctx, _, _ = _x_plane(geometric, PAPER)
    Omega = rpm_to_rad_s(rpm)
    K_shaft, _ = geometric.model.shaft.matrices()
    expected = K_shaft - Omega**2 * ctx.M[0]
    shaft = geometric.model.shaft
    for dof, k in (("u0", 2 * PAPER["k_b"]), ("v0", 2 * PAPER["k_b"]), ("u10", 1e4), ("v10", 1e4)):
        expected[shaft.dof(dof), shaft.dof(dof)] += k
    np.testing.assert_allclose(system.K[0], expected, rtol=1e-12, atol=1e-9)


def test_forcing_is_unbalance_plus_bow_with_the_stated_phase(geometric):
    """f_x = Omega^2 (m_e r_me e_me + m_el q_x Phi_1) cos(Omega t), f_y the same with sin (eq. 30)."""
    rpm = 800.0
    system = geometric.system(rpm, PAPER)
    ctx, _, _ = _x_plane(geometric, PAPER)
    shaft, Omega = geometric.model.shaft, rpm_to_rad_s(rpm)
    fx = Omega**2 * 0.0281 * PAPER["q_x"] * ctx.Phi_1[0]
    fy = Omega**2 * 0.0281 * PAPER["q_y"] * ctx.Phi_1[0]
    fx[5] += Omega**2 * PAPER["m_e"] * 0.040
    fy[5] += Omega**2 * PAPER["m_e"] * 0.040
    assert set(system.forcing) == {1}
    F = system.forcing[1][0]
    # cos(Omega t) = Re(e^{i Omega t}) and sin(Omega t) = Re(-i e^{i Omega t})
    np.testing.assert_allclose(F[shaft.translational("x")], fx, rtol=1e-12)
    np.testing.assert_allclose(F[shaft.translational("y")], -1j * fy, rtol=1e-12)
    slopes = np.setdiff1d(np.arange(shaft.n_dof), np.r_[shaft.translational("x"), shaft.translational("y")])
    assert np.all(F[slopes] == 0)


def _four_springs(u, v, k_b, l_i):
    """Exact force of four Hooke springs (unstretched length l_i) anchored at 0, 90, 180, 270 degrees."""
    F = np.zeros(2)
    for theta in np.deg2rad([0, 90, 180, 270]):
        d = np.array([u, v]) - l_i * np.array([np.cos(theta), np.sin(theta)])
        length = np.linalg.norm(d)
        F += -k_b * (length - l_i) * d / length
    return F


def test_geometric_spring_is_the_third_order_expansion_of_four_springs(geometric):
    """Eq. 22 (linear part in K, cubic part as the local force) vs the exact spring geometry."""
    effect = geometric_spring()
    k_b, l_i = 2331.5, 0.0508
    values = geometric.values({"k_b": k_b})
    p = {k: np.atleast_1d(v) for k, v in values.items()}
    from hybridtwin import Params

    errors = []
    for s in (8e-3, 4e-3, 2e-3):
        u, v = 0.7 * s, -0.45 * s
        F_nl, _ = effect.force(np.array([[[u], [v]]]), Params(p))
        F = F_nl[0, :, 0] - 2 * k_b * np.array([u, v])
        exact = _four_springs(u, v, k_b, l_i)
        errors.append(np.abs(F - exact).max())
        # the cubic terms matter: without them the error would be ~ k_b s^3 / l_i^2
        assert errors[-1] < 0.05 * k_b * s**3 / l_i**2
    # the remainder of a third-order expansion is O(s^5): halving s divides it by ~32 (allow 25..40)
    for coarse, fine in zip(errors[:-1], errors[1:]):
        assert 25 < coarse / fine < 40


def test_polynomial_jacobian_matches_finite_differences():
    """Every expansion term (quadratic, cross, slope, cubic) has an exact derivative."""
    expansion = builtin_variant("expansion")
    values = {k: np.atleast_1d(v) for k, v in expansion.values({"k2": -300.0, "k5": 200.0, "k4": 100.0}).items()}
    from hybridtwin import Params

    rng = np.random.default_rng(1)
    q = rng.normal(scale=3e-3, size=(1, 4, 5))
    for effect in expansion.model.effects:
        if not effect.is_nonlinear:
            continue
        n = len(effect.dofs)
        local = q[:, :n]
        _, J = effect.force(local, Params(values))
        step = 1e-7  # central differences on O(1e-3) inputs: truncation ~1e-14, round-off ~1e-9 relative
        for j in range(n):
            dq = np.zeros_like(local)
            dq[:, j] = step
            fd = (effect.force(local + dq, Params(values))[0] - effect.force(local - dq, Params(values))[0]) / (2 * step)
            np.testing.assert_allclose(J[:, :, j], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max() + 1e-12)


def test_variant_errors_name_the_problem():
    spec = {"effects": ["structural_damping", "no_such_effect"], "unknown": {"zeta_s": [0.01, 0.05]}}
    with pytest.raises(ValueError, match="no effect named 'no_such_effect'"):
        Variant.from_spec("bad", spec)
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['k_b'\]"):
        Variant.from_spec("bad", {"effects": ["structural_damping"], "unknown": {"k_b": [1, 2]}})
    with pytest.raises(ValueError, match="range of zeta_s"):
        Variant.from_spec("bad", {"effects": ["structural_damping"], "unknown": {"zeta_s": [0.05, 0.01]}})
    with pytest.raises(ValueError, match="has no parameter"):
        builtin_variant("geometric").values({"kb": 1.0})


class _Conflicting(Effect):
    name = "conflicting"
    meaning = "declares k_b with another unit"
    parameters = (Parameter("k_b", "N", (0, 1), 0.5, "clash"),)


def test_parameters_shared_by_effects_must_agree():
    from hybridtwin import Model

    with pytest.raises(ValueError, match="declared differently"):
        Model([geometric_spring(), _Conflicting()])


USER_EFFECT = '''
from hybridtwin import Parameter, PolynomialBearing, Term

tilt_spring = PolynomialBearing(
    name="tilt_spring",
    meaning="moment stiffness against shaft tilt at the upper bearing",
    parameters=(Parameter("k_t", "N", (0.0, 500.0), 0.0, "linear slope stiffness"),),
    terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), "k_t u'"),),
)
'''


def test_user_effect_from_own_file_changes_the_response(tmp_path):
    path = tmp_path / "my_effects.py"
    path.write_text(USER_EFFECT)
    user = load_effects_file(path)
    assert list(user) == ["tilt_spring"]
    spec = {"effects": builtin_variant("geometric").model.effects, "unknown": {}}
    names = [e.name for e in spec["effects"]] + ["tilt_spring"]
    variant = Variant.from_spec("geometric_tilt", {"effects": names}, user)
    base = solve_variant(builtin_variant("geometric"), 600, PAPER)
    zero = solve_variant(variant, 600, {**PAPER, "k_t": 0.0})
    tilted = solve_variant(variant, 600, {**PAPER, "k_t": 300.0})
    np.testing.assert_allclose(zero.harmonics, base.harmonics, rtol=1e-12, atol=1e-18)
    assert np.abs(tilted.harmonics[0, 1] - base.harmonics[0, 1]).max() > 1e-3 * np.abs(base.harmonics[0, 1]).max()
    # the linear slope term is a non-symmetric stiffness K[u0, du0] = k_t
    shaft = variant.model.shaft
    K = variant.system(600, {**PAPER, "k_t": 300.0}).K[0] - variant.system(600, {**PAPER, "k_t": 0.0}).K[0]
    assert K[shaft.dof("u0"), shaft.dof("du0")] == pytest.approx(300.0)
    assert K[shaft.dof("du0"), shaft.dof("u0")] == 0.0


def test_effects_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "broken.py"
    bad.write_text("raise RuntimeError('oops')\n")
    with pytest.raises(RuntimeError, match="broken.py"):
        load_effects_file(bad)
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    with pytest.raises(ValueError, match="defines no Effect"):
        load_effects_file(empty)
    with pytest.raises(FileNotFoundError, match="missing.py"):
        load_effects_file(tmp_path / "missing.py")


def test_builtin_effects_describe_themselves():
    for name in ("geometric", "expansion", "final"):
        variant = builtin_variant(name)
        for effect in variant.model.effects:
            assert effect.name and effect.meaning
            for par in effect.parameters:
                assert par.unit and par.meaning and par.bounds[0] <= par.nominal <= par.bounds[1]
        text = variant.describe()
        assert all(k in text for k in variant.unknown)


def test_solve_runs_keeps_an_unknown_eccentric_mass():
    """m_e given per scenario (the sixth unknown) is not overwritten by the run's mass."""
    import pandas as pd

    from hybridtwin.offline.scenarios import solve_runs

    variant = builtin_variant("geometric")
    runs = pd.DataFrame({"run": ["a"], "rpm": [500.0], "eccentric_mass_g": [25.9]})
    given = solve_runs(variant, runs, {"m_e": np.array([0.0259, 0.010])}, 3)
    from_sheet = solve_runs(variant, runs, {}, 3)
    # the same mass by either route gives the same steady state; another mass another one
    np.testing.assert_allclose(given.harmonics[0, 0], from_sheet.harmonics[0, 0], rtol=1e-12, atol=1e-18)
    assert np.abs(given.harmonics[0, 1, 1] - from_sheet.harmonics[0, 0, 1]).max() > 0.1 * np.abs(
        from_sheet.harmonics[0, 0, 1]).max()


def test_solve_runs_gives_each_mass_the_result_of_its_own_run_up():
    """The run-ups of all the masses are solved in one batched sweep: each run must hold exactly
    (to the bit: the solver treats scenarios independently) what a plan of its mass alone gives."""
    import pandas as pd

    from hybridtwin.offline.scenarios import solve_runs

    variant = builtin_variant("geometric")
    runs = pd.DataFrame({"run": ["a", "b", "c", "d"], "rpm": [400.0, 800.0, 450.0, 900.0],
                         "eccentric_mass_g": [25.9, 0.0, 25.9, 14.8]})
    values = {"k_b": np.array([2100.0, 3400.0]), "q_x": np.array([0.002, 0.009])}
    together = solve_runs(variant, runs, values, 3)
    assert together.success.all()
    for mass, group in runs.groupby("eccentric_mass_g"):
        alone = solve_runs(variant, group, values, 3)
        where = runs.index.get_indexer(group.index)
        np.testing.assert_array_equal(together.harmonics[where], alone.harmonics)
        assert (together.branch[where] == alone.branch).all() and (together.message[where] == alone.message).all()


def test_first_mode_of_a_scenario_does_not_depend_on_its_batch():
    """k_w = 0 leaves K at rest symmetric (Cholesky + eigh), k_w > 0 does not (general eigenproblem).
    In one batch each scenario must still get the mode it gets alone, to the bit; and a speed's
    system from the reused rest stages (``system_at``) must equal the one assembled from scratch."""
    from hybridtwin.model.model import _first_mode

    variant = builtin_variant("final")
    values = variant.values({"k_w": np.array([0.0, 500.0]), "k_z": np.array([0.0, 300.0])})
    rest = variant.model.at_rest(values)
    plane = slice(0, variant.model.shaft.n_plane)
    K = rest.K[:, plane, plane]
    assert np.array_equal(K[0], K[0].T) and not np.allclose(K[1], K[1].T)  # one of each kind
    together = _first_mode(K, rest.M[:, plane, plane])
    for s in range(2):
        alone = _first_mode(K[s:s + 1], rest.M[s:s + 1, plane, plane])
        assert together[0][s] == alone[0][0] and np.array_equal(together[1][s], alone[1][0])
    for s in range(2):
        reused = variant.model.system_at(rest.rows(np.array([s])), 650.0)
        fresh = variant.model.system({k: np.atleast_1d(v)[s:s + 1] if np.size(v) > 1 else v
                                      for k, v in values.items()}, 650.0)
        for name in ("M", "C", "K", "Omega"):
            np.testing.assert_array_equal(getattr(reused, name), getattr(fresh, name))
        np.testing.assert_array_equal(reused.forcing[1], fresh.forcing[1])


def _bearing_forces(variant, values, q):
    """Linear stiffness matrix at rest and the summed local nonlinear bearing forces at states q (4, N)
    = (u, v, u', v') of the upper bearing node, from the effects' own hooks."""
    from hybridtwin import Params

    full = variant.values(values)
    K = variant.model.context(full, 0.0).K[0]
    p = Params({k: np.atleast_1d(v) for k, v in full.items()})
    F = np.zeros((2, q.shape[1]))
    for effect in variant.model.effects:
        if isinstance(effect, PolynomialBearing) and effect.is_nonlinear:
            F += effect.force(q[None, : len(effect.dofs)], p)[0][0, :2]
    return K, F


@pytest.mark.parametrize("parent, values, expected", [
    ("geometric", {"k_b": 2980.96, "zeta_s": 0.0155, "q_x": 0.002, "q_y": 0.003},
     {"k1": 2980.96, "k2": 0.0, "k3": 2 * 2980.96, "k4": 0.0, "k5": 0.0, "k6": 0.0, "k7": -4 * 2980.96}),
    ("final", {"k_b": 2411.3, "k_w": 324.2, "k_z": 301.1, "q_x": 0.002, "q_y": 0.003},
     {"k1": 2411.3, "k2": 0.0, "k3": 2 * 2411.3, "k4": 324.2, "k5": 0.0, "k6": 301.1, "k7": 0.0}),
])
def test_simpler_models_embed_exactly_in_the_expansion_model(parent, values, expected):
    """docs/model.md: the Geometric model is the Expansion model at k1 = k_b, k3 = 2 k_b, k7 = -4 k_b
    (eq. 22-24); the Final one (eq. 38-39) at k1 = k_b, k3 = 2 k_b, k4 = k_w, k6 = k_z. The mapped values
    must also give the same stiffness matrix and nonlinear bearing force as the simpler model's effects."""
    from hybridtwin.model.variants import contains, embed

    small, expansion = builtin_variant(parent), builtin_variant("expansion")
    assert contains(expansion, small) and not contains(small, expansion)
    mapped, mismatch = embed(small, expansion, values)
    assert mismatch < 1e-12  # an exact linear match: only round-off remains
    for name, value in expected.items():
        assert mapped[name] == pytest.approx(value, rel=1e-9, abs=1e-6)  # abs: zero terms, N/m scale ~1e3
    assert (mapped["q_x"], mapped["q_y"]) == (0.002, 0.003)  # copied by name
    q = np.random.default_rng(3).normal(scale=[[4e-3], [3e-3], [0.05], [0.04]], size=(4, 20))
    K_small, F_small = _bearing_forces(small, values, q)
    K_big, F_big = _bearing_forces(expansion, mapped, q)
    np.testing.assert_allclose(K_big, K_small, rtol=1e-12, atol=1e-9 * np.abs(K_small).max())
    np.testing.assert_allclose(F_big, F_small, rtol=1e-9, atol=1e-12 * np.abs(F_small).max())


def test_embedding_reports_what_cannot_be_matched():
    """A term the smaller model lacks (k4: a slope force) or a range too narrow leaves a mismatch > 0."""
    from hybridtwin.model.variants import Variant, embed

    geometric, expansion = builtin_variant("geometric"), builtin_variant("expansion")
    values = {"k1": 2400.0, "k2": 0.0, "k3": 4800.0, "k4": 300.0, "k5": 0.0, "k6": 0.0, "k7": -9600.0}
    _, mismatch = embed(expansion, geometric, values)
    assert mismatch > 0.1  # the slope row cannot be matched at all: its scaled residual is 1
    narrow = Variant("narrow", expansion.model, {**expansion.unknown, "k7": (-5000.0, 5000.0)}, expansion.fixed)
    mapped, mismatch = embed(geometric, narrow, {"k_b": 2400.0})
    assert mapped["k7"] == pytest.approx(-5000.0) and mismatch > 0.01


def test_nested_parents_are_the_simplest_contained_variants():
    """Expansion contains Geometric, Final and Geometric + expansion_k4; only the first two contain no other variant
    (their fits wait for no other), so the Expansion polish starts from them."""
    from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant, contains, nested_parents

    specs = dict(BUILTIN_VARIANTS)
    specs["geometric_expansion_k4"] = {**specs["geometric"],
                                       "effects": specs["geometric"]["effects"] + ["expansion_k4"],
                                       "unknown": {**specs["geometric"]["unknown"], "k4": (-1000.0, 1000.0)}}
    variants = {name: Variant.from_spec(name, spec) for name, spec in specs.items()}
    assert nested_parents(variants, "expansion") == ["geometric", "final"]
    assert nested_parents(variants, "geometric_expansion_k4") == ["geometric"]
    assert nested_parents(variants, "geometric") == [] and nested_parents(variants, "final") == []
    slope = Variant.from_spec("slope", {
        **specs["geometric"], "effects": specs["geometric"]["effects"] + ["slope_spring"],
        "unknown": {**specs["geometric"]["unknown"], "k_w": (0.0, 1000.0), "k_z": (0.0, 1000.0)}})
    # every Final monomial is there, but u v^2 comes with -4 k_b / l_i^2: Final is not a special case
    assert not contains(slope, variants["final"]) and contains(slope, variants["geometric"])


def test_the_first_mode_of_repeated_pencils_is_each_ones_own():
    """Pencils repeated in a batch (runs' copies, a perturbed damping) are solved once: each scenario's mode is
    bit for bit the one it has alone, symmetric and non-symmetric stiffness alike (against a batch of one)."""
    from hybridtwin.model.model import _first_mode

    rng = np.random.default_rng(0)
    n = 12
    A, B = rng.normal(size=(2, 4, n, n))
    K = A @ np.swapaxes(A, 1, 2) + n * np.eye(n)
    M = B @ np.swapaxes(B, 1, 2) + n * np.eye(n)
    K[3] += 0.01 * rng.normal(size=(n, n))  # a cross-coupled, non-symmetric one
    pick = rng.integers(0, 4, 50)
    omega, phi = _first_mode(K[pick], M[pick])
    for s, i in enumerate(pick):
        alone = _first_mode(K[i:i + 1], M[i:i + 1])
        np.testing.assert_array_equal(omega[s], alone[0][0])
        np.testing.assert_array_equal(phi[s], alone[1][0])


def test_a_linear_model_is_solved_at_its_run_speeds_alone_to_the_bits_of_a_run_up():
    """A linear model has one steady state per speed: solve_runs solves its masses' speeds without the run-up from
    300 RPM (fewer solves), and each run holds, to the bit, what an independent harmonic-balance solve at that
    speed alone gives (the linear solve: no continuation can change it)."""
    import pandas as pd

    from hybridtwin.model.model import Model
    from hybridtwin.offline import scenarios
    from hybridtwin.solvers import continuation
    from hybridtwin.solvers.solver import solve

    from example_machines import stepped_machine

    machine = stepped_machine()
    effects = machine.effects()
    model = Model([effects[name] for name in ("linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1")],
                  machine)
    assert not any(e.is_nonlinear for e in model.effects)
    variant = Variant("lin", model, {"k_a": (1.5e7, 3.0e7)})
    runs = pd.DataFrame({"run": ["a", "b", "c"], "rpm": [2000.0, 3600.0, 3000.0], "eccentric_mass_g": [20.0, 20.0, 50.0]})
    values = {"k_a": np.array([1.6e7, 2.9e7])}
    calls = []
    original = continuation.solve

    def counting(system, *args, **kwargs):
        calls.append(system.n_scenarios)
        return original(system, *args, **kwargs)

    continuation.solve = counting
    try:
        got = scenarios.solve_runs(variant, runs, values, 1)
    finally:
        continuation.solve = original
    assert got.success.all() and got.stable.all()
    assert len(calls) <= 3  # one batched solve per step: the speeds 2000 and 3600 (and 3000) only, not 68 steps
    for r, (rpm, mass) in enumerate(zip(runs["rpm"], runs["eccentric_mass_g"])):
        alone = solve(model.system(variant.values({**values, "m_e": mass * 1e-3}), rpm), 1)
        np.testing.assert_array_equal(got.harmonics[r], alone.harmonics)
