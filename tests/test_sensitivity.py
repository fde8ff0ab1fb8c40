"""Sensitivities of the periodic steady state (solver.sensitivity) against independent references.

- Central finite differences of the full solve (a different algorithm: every perturbed point is
  solved again by Newton to 1e-14, while ``sensitivity`` solves one linear system at the
  unperturbed solution), for every kind of parameter: linear stiffness, damping ratios through
  omega_1, bow and 2X forcing, the eccentric mass (mass matrix and forcing), nonlinear bearing
  coefficients, speed-dependent damping, a moment stiffness on the slope DOFs.
- A closed form: a linear system (no local forces), where dQ_h/dp = -D_h^-1 (dD_h/dp Q_h - dF_h/dp)
  is written out by hand from the entries the effect touches.
- Scenario independence: a batch gives each scenario the result it gets alone.
Complex-step differentiation is not possible here: the dynamic stiffness D_h is already complex.
"""

from __future__ import annotations

import numpy as np
import pytest

from hybridtwin import solve
from hybridtwin.solvers.solver import sensitivity
from hybridtwin.model.variants import Variant, builtin_variant

FINAL = builtin_variant("final")
#: every candidate-effect kind on top of the Final model (slope force: the local force acts on slopes too)
EXTRA = ["upper_bearing_anisotropy", "cross_coupled_stiffness", "excitation_2x", "lower_bearing_compliance",
         "speed_damping", "moment_stiffness"]
VALUES = {"dk_up": 30.0, "k_xy": 20.0, "f2_c": 0.05, "f2_s": -0.02, "dk_lo": -500.0, "zeta_v": 0.01,
          "k_rot": 10.0}
#: (parameter, scale of its range): steps are 1e-4 of the scale (see ``_steps``)
SCALES = {"k_b": 1500.0, "k_w": 1000.0, "k_z": 1000.0, "zeta_s": 0.04, "zeta_bup": 0.05, "q_x": 0.009,
          "q_y": 0.009, "dk_up": 1000.0, "k_xy": 400.0, "f2_c": 1.0, "dk_lo": 4000.0, "zeta_v": 0.05,
          "k_rot": 300.0, "m_e": 0.04, "l_i": 0.05}


def _extended() -> Variant:
    spec = {"effects": [e.name for e in FINAL.model.effects] + EXTRA, "unknown": dict(FINAL.unknown)}
    return Variant.from_spec("final_plus", spec)


def _steps(names):
    # 1e-4 of a parameter's range: large enough that the assembly's round-off (general eigenproblem
    # of the first mode, ~1e-12 relative) stays below 1e-8 of the difference, small enough that the
    # O(step^2) error of parameters entering through omega_1 / Phi_1 is ~1e-8 (measured: agreement
    # with the re-solved differences to 2e-8 at this step, 3e-4 at 1e-7 of the value for dk_up)
    return np.array([1e-4 * SCALES[n] for n in names])


def _solved(variant, rpm, values, S=1):
    vals = {k: np.full(S, float(np.asarray(v))) for k, v in variant.values(values).items()}

    def build(v):
        return variant.model.system(v, rpm)

    # run-up from 300 RPM to the speed, the branch the rig reaches (900 RPM is near the fold)
    state = None
    for speed in np.arange(300.0, rpm, 50.0).tolist() + [rpm]:
        state = solve(variant.model.system(vals, speed), 5, initial=None if state is None else state.state,
                      tol=1e-14)
    assert state.success.all()
    return build, vals, state


@pytest.mark.parametrize("rpm", [700.0, 900.0])
def test_sensitivities_match_finite_differences_of_the_solve(rpm):
    variant = _extended()
    build, vals, state = _solved(variant, rpm, VALUES | {"m_e": 0.0148})
    names = list(FINAL.unknown) + ["dk_up", "k_xy", "f2_c", "dk_lo", "zeta_v", "k_rot", "m_e", "l_i"]
    dQ, dx = sensitivity(build, vals, names, state, _steps(names), condensed=True)
    assert dQ.shape == (1, len(names), 6, state.harmonics.shape[2])
    assert dx.shape == (1, len(names)) + state.state.shape[1:]
    for j, name in enumerate(names):
        h = 1e-4 * SCALES[name]
        solved, states = [], []
        for sign in (1.0, -1.0):
            shifted = {k: v.copy() for k, v in vals.items()}
            shifted[name] = shifted[name] + sign * h
            again = solve(build(shifted), 5, initial=state.state, tol=1e-14)
            assert again.success.all()
            solved.append(again.harmonics[0])
            states.append(again.state[0])
        fd = (solved[0] - solved[1]) / (2 * h)
        err = np.abs(fd - dQ[0, j]).max() / np.abs(fd).max()
        # both sides carry O(h^2) and round-off errors of ~1e-8 (see _steps); a wrong term, sign or
        # factor is O(1), a missing coupling (e.g. through the local force) >= 1e-3
        assert err < 1e-6, (rpm, name, err)
        fd_x = (states[0] - states[1]) / (2 * h)  # the condensed state (the continuation's predictor)
        assert np.abs(fd_x - dx[0, j]).max() < 1e-6 * np.abs(fd_x).max(), (rpm, name)


def test_linear_system_closed_form():
    # a linear model (the upper bearing as the Expansion model's linear term k3 u alone) plus the cross-coupled
    # stiffness, whose dD/dk_xy is +1 at (u0, v0), -1 at (v0, u0) (it changes neither omega_1 nor Phi_1 of the
    # x plane, so nothing else), and a 2X force
    spec = {"effects": ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing",
                        "unbalance", "shaft_bow", "expansion_k3", "cross_coupled_stiffness", "excitation_2x"],
            "unknown": {"k_xy": (-200.0, 200.0)}}
    variant = Variant.from_spec("linear", spec)
    rpm = 650.0
    vals = {k: np.atleast_1d(np.asarray(v, float)) for k, v in
            variant.values({"m_e": 0.0259, "k_xy": 40.0, "f2_c": 0.1, "f2_s": 0.05}).items()}
    system = variant.model.system(vals, rpm)
    assert not system.forces  # linear: the closed form below is the whole answer
    state = solve(system, 5)
    dQ = sensitivity(lambda v: variant.model.system(v, rpm), vals, ["k_xy", "f2_s"], state,
                     np.array([0.04, 1e-4]))
    shaft = variant.model.shaft
    E = np.zeros((1, shaft.n_dof, shaft.n_dof))
    E[0, shaft.dof("u0"), shaft.dof("v0")], E[0, shaft.dof("v0"), shaft.dof("u0")] = 1.0, -1.0
    Omega = system.Omega[0]
    for h in range(6):
        D = system.K[0] + 1j * h * Omega * system.C[0] - (h * Omega) ** 2 * system.M[0]
        # k_xy enters K only: dQ = -D^-1 E Q
        expected = -np.linalg.solve(D, E[0] @ state.harmonics[0, h])
        assert np.allclose(dQ[0, 0, h], expected, rtol=0, atol=1e-9 * np.abs(expected).max() + 1e-300)
        # f2_s enters the 2X forcing only: F_2 = i f2_s at u0, f2_s at v0 (HarmonicExcitation)
        dF = np.zeros(shaft.n_dof, complex)
        if h == 2:
            dF[shaft.dof("u0")], dF[shaft.dof("v0")] = 1j, 1.0
        expected = np.linalg.solve(D, dF)
        assert np.allclose(dQ[0, 1, h], expected, rtol=0, atol=1e-9 * max(np.abs(expected).max(), 1e-12))
    assert np.abs(dQ[0, 1, 2]).max() > 0 and np.abs(dQ[0, 1, 1]).max() == 0


def test_batch_gives_each_scenario_its_own_sensitivity():
    variant = _extended()
    rpm = 750.0
    rng = np.random.default_rng(3)
    S = 4
    overrides = VALUES | {"m_e": 0.0148, "k_b": rng.uniform(2100, 3300, S), "zeta_s": rng.uniform(0.015, 0.04, S)}
    vals = {k: np.broadcast_to(np.asarray(v, float), (S,)).copy() for k, v in variant.values(overrides).items()}

    def build(v):
        return variant.model.system(v, rpm)

    state = None
    for speed in np.arange(300.0, rpm, 50.0).tolist() + [rpm]:
        state = solve(variant.model.system(vals, speed), 5, initial=None if state is None else state.state,
                      tol=1e-14)
    names = ["k_b", "zeta_s", "k_w", "q_x"]
    steps = _steps(names)
    batched = sensitivity(build, vals, names, state, steps)
    for s in range(S):
        one = {k: v[s:s + 1] for k, v in vals.items()}
        alone = solve(build(one), 5, initial=state.state[s:s + 1], tol=1e-14)
        single = sensitivity(build, one, names, alone, steps)
        # the same linear algebra on the same numbers, up to the solve's tolerance (1e-14) and round-off
        assert np.allclose(batched[s], single[0], rtol=1e-7, atol=1e-9 * np.abs(single).max())


def test_failed_scenarios_get_nan_and_bad_steps_are_refused():
    variant = FINAL
    vals = {k: np.full(2, float(np.asarray(v))) for k, v in variant.values({"m_e": 0.0148}).items()}
    state = solve(variant.model.system(vals, 500.0), 5)
    state.success[1] = False
    dQ = sensitivity(lambda v: variant.model.system(v, 500.0), vals, ["k_b"], state, [0.15])
    assert np.isfinite(dQ[0]).all() and np.isnan(dQ[1]).all()
    with pytest.raises(ValueError, match="one positive step per parameter"):
        sensitivity(lambda v: variant.model.system(v, 500.0), vals, ["k_b", "k_w"], state, [0.15])
