"""Stability of steady states (hybridtwin.solvers.floquet, solver.assess_stability) against independent references.

- Linear: a local *linear* spring entered as the nonlinear force (so the Floquet machinery runs: J(t) is
  constant) and the plain linear system; the reference is the closed form, the eigenvalues lambda of the
  88-state first-order matrix of M, C, K + the spring (numpy), radius exp(max Re lambda T).
- Nonlinear: orbits of the geometric model checked by time integration (hybridtwin.solvers.transient, which shares
  no code with the solver or floquet): a deviation from an unstable orbit grows by the largest multiplier
  per period, one from a stable orbit decays.
- The flag travels: solve_runs -> chunk store -> gathered store -> failures and POD (left out, counted),
  and `hybridtwin simulate` never reports an unstable state as converged.
"""

import numpy as np
import pandas as pd
import pytest

from hybridtwin import cli
from hybridtwin.solvers import floquet
from hybridtwin.offline import snapshots
from hybridtwin.solvers import transient as tr
from hybridtwin.model.model import LocalForce
from hybridtwin.offline.pod import pod_of_runs
from hybridtwin.offline.scenarios import solve_runs
from hybridtwin.offline.snapshots import read_chunks, write_chunk
from hybridtwin.solvers.continuation import solve_sweep
from hybridtwin.solvers.solver import solve
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant

GEOMETRIC = Variant.from_spec("geometric", BUILTIN_VARIANTS["geometric"], {})
BEARING = np.array([0, 22])  # u0, v0: where the geometric spring acts


def _linear_spring(k: float) -> LocalForce:
    """F = -k q at u0 and v0, declared as a local force of degree 1 (its Jacobian -k I at every instant)."""
    def evaluate(q, rows):
        J = np.zeros((q.shape[0], 2, 2, q.shape[2]))
        J[:, 0, 0] = J[:, 1, 1] = -k
        return -k * q, J
    return LocalForce("linear spring", BEARING, evaluate, 1)


def _closed_form_radius(system, extra_k: float = 0.0, at=BEARING) -> np.ndarray:
    """exp(max Re lambda T) per scenario, lambda the eigenvalues of [[0, I], [-M^-1 K, -M^-1 C]] (K + extra_k at
    the bearing DOFs): the Floquet multipliers of a linear time-invariant system are exp(lambda T)."""
    n = system.n_dof
    out = []
    for s in range(system.n_scenarios):
        K = system.K[s].copy()
        K[at, at] += extra_k
        A = np.block([[np.zeros((n, n)), np.eye(n)],
                      [-np.linalg.solve(system.M[s], K), -np.linalg.solve(system.M[s], system.C[s])]])
        out.append(np.exp(np.linalg.eigvals(A).real.max() * 2 * np.pi / system.Omega[s]))
    return np.array(out)


# damping ratios around zero (negative: an energy source) at speeds across the range; zeta_s = 0 leaves the
# lower bearing's damper only (radius 0.9993 at 900 RPM: a decision within 1e-3 of the boundary)
ZETA_S = np.array([0.03, 0.01, 0.0, -0.005, -0.05, 0.03])
ZETA_BUP = np.array([0.02, 0.0, 0.0, 0.0, 0.01, 0.05])
RPM = np.array([400.0, 700.0, 900.0, 700.0, 1100.0, 1200.0])


def test_a_linear_force_gives_the_closed_form_multipliers_and_negative_damping_is_unstable():
    system = GEOMETRIC.model.system(GEOMETRIC.values({"zeta_s": ZETA_S, "zeta_bup": ZETA_BUP}), RPM)
    k = 3000.0  # N/m, of the order of the bearing's own 2 k_b: it moves every mode that has the bearing moving
    system.forces = [_linear_spring(k)]
    result = solve(system, 5)
    reference = _closed_form_radius(system, k)
    assert result.success.all()
    # the Ritz reduction and the 64-step exponential integrator against the exact eigenvalues: measured 3e-8
    # (the integrator is exact for the free modes; J is constant here); 1e-6 leaves room for round-off
    np.testing.assert_allclose(result.floquet_radius, reference, rtol=1e-6)
    np.testing.assert_array_equal(result.stable, reference < 1.0)
    assert list(result.stable) == [True, True, True, False, False, True]  # negative damping -> unstable
    assert 1 - 1e-3 < reference[2] < 1.0  # the near-marginal case is decided right
    assert all(m.startswith("unstable periodic solution") for m in result.message[~result.stable])
    assert all(m.startswith("converged") for m in result.message[result.stable])


def test_a_linear_system_is_judged_by_its_eigenvalues_exactly():
    system = GEOMETRIC.model.system(GEOMETRIC.values({"zeta_s": ZETA_S, "zeta_bup": ZETA_BUP}), RPM)
    system.forces = []
    result = solve(system, 5)
    np.testing.assert_allclose(result.floquet_radius, _closed_form_radius(system), rtol=1e-9)  # same formula
    assert list(result.stable) == [True, True, True, False, False, True]


def test_the_reduced_model_agrees_with_the_full_one_on_nonlinear_orbits():
    """The Ritz reduction (2 m ~ 20-24 states) against the same integrator on all 88 states, over the geometric
    box at four speeds (direct solves: some land on unstable branches)."""
    rng = np.random.default_rng(5)
    lo, hi = GEOMETRIC.bounds(GEOMETRIC.unknown_names)
    values = dict(zip(GEOMETRIC.unknown_names, (lo + rng.random((24, lo.size)) * (hi - lo)).T))
    values["m_e"] = rng.choice([0.0, 0.0148, 0.0259], 24)
    system = GEOMETRIC.model.system(GEOMETRIC.values(values), np.repeat([350.0, 700.0, 900.0, 1200.0], 6))
    result = solve(system, 5, stability=False)
    ok = np.flatnonzero(result.success)
    reduced = floquet.spectral_radius(system.subset(ok), result.harmonics[ok])
    full = floquet.spectral_radius(system.subset(ok), result.harmonics[ok], cutoff_factor=None)
    # measured < 1e-9 on stable orbits, < 5e-5 on strongly unstable ones over 366 orbits of the three variants
    # (the truncated modes move quasi-statically)
    np.testing.assert_allclose(reduced, full, rtol=1e-4)
    assert ((reduced >= 1) == (full >= 1)).all()


def _deviation_per_period(system, harmonics, periods: int, scale_start: float = 1.0) -> np.ndarray:
    """max |q(kT) - q*(0)| over the DOFs at the end of each of ``periods`` periods, integrated from the orbit's
    state at t = 0 (times ``scale_start``: a perturbation along the orbit's own shape, which leaves the stiff
    modes quiet). Radau at 3e-6 x the orbit's size (``transient``'s measured default for settled orbits)."""
    first_order = tr.FirstOrder.from_system(system)
    T = 2 * np.pi / system.Omega[0]
    q0, v0 = tr.harmonic_initial_state(harmonics, system.Omega[0])
    y = np.concatenate([q0, v0]) * scale_start
    atol = tr.state_tolerance(44, tr.DEFAULT_ATOL_RELATIVE * np.abs(harmonics).sum(axis=0).max())
    deviation = []
    for k in range(periods):
        _, Y = tr.run(first_order, y[:44], y[44:], (k * T, (k + 1) * T), np.array([(k + 1) * T]), atol=atol)
        y = Y[-1]
        deviation.append(np.abs(y[:44] - q0).max())
    return np.array(deviation)


def test_an_orbit_found_unstable_leaves_in_a_time_integration_at_the_rate_of_its_largest_multiplier():
    """Geometric model, 14.8 g, little damping, 866 RPM (the run-up branch, 20 mm at the bearing, just below
    the fold): Floquet says |mu| = 2.28. Integrated from the orbit, the harmonic-balance truncation (H = 5) seeds
    a deviation that then grows by that factor per period."""
    values = GEOMETRIC.values({"m_e": 0.0148, "zeta_s": 0.01, "zeta_bup": 0.0})
    speeds = [700.0, 750.0, 800.0, 820.0, 840.0, 850.0, 860.0, 866.0]
    state = solve_sweep(lambda rpm, rows: GEOMETRIC.model.system(values, rpm), speeds, 1, harmonics=5).results[-1]
    assert state.success[0] and not state.stable[0]
    radius = state.floquet_radius[0]
    assert 2.0 < radius < 2.6
    deviation = _deviation_per_period(GEOMETRIC.model.system(values, 866.0), state.harmonics[0], 10)
    growth = deviation[1:] / deviation[:-1]
    assert deviation[-1] > 100 * deviation[0]  # it leaves
    # periods 5-9: the unstable mode dominates (before: the seed's other components; after: nonlinear, the
    # deviation nears the orbit's size); the Floquet radius converges as n_steps^-2, 1e-3 at 64 steps here
    np.testing.assert_allclose(np.median(growth[4:]), radius, rtol=0.03)


def test_an_orbit_found_stable_is_returned_to_after_a_perturbation():
    """Nominal geometric parameters at 700 RPM with 25.9 g: |mu| = 0.73. Started 1 % off the orbit, the time
    integration comes back to it, no period decaying slower than the largest multiplier allows (measured 0.64
    per period: the perturbation excites the bearing-damped modes most)."""
    values = GEOMETRIC.values({"m_e": 0.0259})
    system = GEOMETRIC.model.system(values, 700.0)
    state = solve(system, 7)  # H = 7: the truncation floor far below the perturbation
    assert state.stable[0]
    radius = state.floquet_radius[0]
    assert 0.6 < radius < 0.9
    deviation = _deviation_per_period(system, state.harmonics[0], 10, scale_start=1.01)
    assert deviation[-1] < 0.1 * deviation[0]
    assert np.all(deviation[1:] / deviation[:-1] < 1.05 * radius)


RUNS = pd.DataFrame({"run": ["r500_m25p9", "r700_m25p9"], "rpm": [500.0, 700.0], "eccentric_mass_g": [25.9, 25.9]})


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """12 scenarios at two runs, the last three with negative structural damping (unstable wherever they
    converge), through a chunk store into a gathered store."""
    rng = np.random.default_rng(1)
    lo, hi = GEOMETRIC.bounds(GEOMETRIC.unknown_names)
    table = pd.DataFrame(lo + rng.random((12, lo.size)) * (hi - lo), columns=GEOMETRIC.unknown_names)
    table.loc[9:, "zeta_s"] = -0.02
    table.insert(0, "split", ["train"] * 8 + ["validation", "train", "train", "test"])
    table.insert(0, "scenario", np.arange(12))
    solved = solve_runs(GEOMETRIC, RUNS, {k: table[k].to_numpy() for k in GEOMETRIC.unknown_names}, 5)
    folder = tmp_path_factory.mktemp("mixed")
    write_chunk(folder / "000.zarr", "geometric", table, GEOMETRIC.unknown_names, solved)
    snapshots.save(read_chunks([folder / "000.zarr"], table), folder / "snapshots.zarr")
    return table, solved, folder


def test_unstable_points_are_flagged_by_solve_runs_and_kept_in_the_stores(mixed):
    table, solved, folder = mixed
    negative = (table["zeta_s"] < 0).to_numpy()
    assert solved.success.all()  # harmonic balance converges for every one of them
    np.testing.assert_array_equal(solved.stable, np.broadcast_to(~negative, solved.stable.shape))
    assert (solved.floquet_radius[:, negative] > 1).all() and (solved.floquet_radius[:, ~negative] < 1).all()
    store = snapshots.load(folder / "snapshots.zarr")
    np.testing.assert_array_equal(store.stable, solved.stable)
    np.testing.assert_array_equal(store.floquet_radius, solved.floquet_radius)
    np.testing.assert_array_equal(store.steady, store.success & ~negative[None])
    one = snapshots.load(folder / "snapshots.zarr", RUNS["run"][1])
    np.testing.assert_array_equal(one.stable[0], solved.stable[1])
    failures = store.failures()  # failures.tsv: every point without a steady state, each with its reason
    assert sorted(set(failures["scenario"])) == [9, 10, 11] and len(failures) == 6
    assert failures["message"].str.startswith("unstable periodic solution: largest Floquet multiplier").all()
    # the report's view (failures_summary.tsv): the same points counted per run, split and reason
    summary = snapshots.failure_summary(failures)
    expected = failures.groupby(["run", "split", "reason"]).size()
    assert summary.set_index(["run", "split", "reason"])["n_scenarios"].sort_index().equals(expected.sort_index())
    assert summary["n_scenarios"].sum() == len(failures) and set(summary["first_scenario"]) <= {9, 10, 11}
    assert snapshots.failure_summary(failures.iloc[:0]).empty


def test_the_pod_leaves_unstable_points_out_and_counts_them(mixed):
    table, _, folder = mixed
    # 12 scenarios: enough for a POD, not for a library (the workflow's pod rule asks for that minimum too)
    summary = pod_of_runs(str(folder / "snapshots.zarr"), str(folder / "pod.zarr"), GEOMETRIC.model.shaft, 1.0, 1e-10,
                          for_libraries=False)
    # 10 training scenarios (0-7, 9, 10) of which 2 unstable: 8 snapshots at each run; 3 unstable in all
    assert summary["n_unstable"].tolist() == [3, 3] and summary["n_snapshots"].tolist() == [8, 8]
    from hybridtwin.offline.pod import load_pod

    _, usable = load_pod(str(folder / "pod.zarr"), RUNS["run"][0])
    np.testing.assert_array_equal(usable, (table["zeta_s"] > 0).to_numpy())


def test_stable_results_are_bit_for_bit_those_of_a_solve_without_the_check():
    system = GEOMETRIC.model.system(GEOMETRIC.values({"m_e": 0.0259, "zeta_s": np.array([0.02, -0.3])}), 800.0)
    checked, unchecked = solve(system, 5), solve(system, 5, stability=False)
    for name in ("harmonics", "state", "success", "residual", "iterations"):
        np.testing.assert_array_equal(getattr(checked, name), getattr(unchecked, name))
    assert np.isnan(unchecked.floquet_radius).all() and not unchecked.stable.any()  # not assessed: not "stable"
    assert checked.message[0] == unchecked.message[0] and checked.message[1].startswith("unstable")


def test_simulate_never_reports_an_unstable_state_as_converged(capsys):
    assert cli.main(["simulate", "--rpm", "700", "--set", "zeta_s=-0.5"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""  # no harmonics table for a state the machine does not stay in
    line = [t for t in captured.err.splitlines() if t.startswith("hybridtwin simulate:")]
    assert len(line) == 1 and "unstable at 700 RPM" in line[0] and "Floquet multiplier |mu| = " in line[0]
    assert "converged" not in line[0]
    assert cli.main(["simulate", "--rpm", "700"]) == 0
    assert "converged" in capsys.readouterr().err


# --- a jump past a fold prefers a stable branch ------------------------------------------------------------------

FINAL = Variant.from_spec("final", BUILTIN_VARIANTS["final"], {})
# a stiffening upper bearing lightly damped, 25.9 g: three periodic solutions coexist at 965 RPM, 1X at u0 of
# 59.6 mm (the run-up's, stable), 50.4 mm (|mu| = 1.12: the middle, unstable branch) and 21.3 mm (the run-down's,
# stable); the run-up branch ends at a fold between 970 and 975 RPM
BISTABLE = FINAL.values({"k_b": 2331.5, "zeta_s": 0.01, "zeta_bup": 0.0, "k_z": 1000.0, "k_w": 0.0,
                         "q_x": 0.005, "q_y": 0.005, "m_e": 0.0259})


def _bistable(rpm, rows):
    return FINAL.model.system(BISTABLE, rpm)


def test_a_jump_that_lands_on_an_unstable_branch_goes_on_to_a_stable_one(monkeypatch):
    """With the sweeps' own starts every jump found lands on a stable branch first (the linear response
    converges to the lower branch here), so the starts are reordered: the run-down's state at 960 RPM doubled
    converges to the unstable middle branch at 965 RPM, the linear response to the stable lower one. The jump
    reports the stable one, the solution the run-down reaches by continuation (the reference); with the
    unstable start alone, the unstable landing is kept, flagged."""
    import hybridtwin.solvers.continuation as continuation

    down = solve_sweep(_bistable, np.arange(1000.0, 959.0, -5.0), 1, harmonics=5, direction="down")
    at = dict(zip(down.rpm, down.results))
    reference, x_last = at[965.0], at[960.0].state
    assert reference.stable[0]
    options = {"harmonics": 5, "stability": False}  # as solve_sweep passes them: the jump assesses regardless
    monkeypatch.setattr(continuation, "_JUMP_STARTS", (2.0,))
    unstable = continuation._jump(_bistable, np.array([960.0]), np.array([965.0]), x_last, np.arange(1), "run-up", options)
    assert unstable.success[0] and not unstable.stable[0] and 1.05 < unstable.floquet_radius[0] < 1.2
    assert unstable.message[0].startswith("unstable periodic solution")
    monkeypatch.setattr(continuation, "_JUMP_STARTS", (2.0, None))
    jumped = continuation._jump(_bistable, np.array([960.0]), np.array([965.0]), x_last, np.arange(1), "run-up", options)
    assert jumped.stable[0] and jumped.branch[0] == "run-up, jump between 960 and 965 RPM"
    # the same periodic solution as the run-down's, both converged to 1e-10: agreement to ~1e-9 of the amplitude
    scale = np.abs(reference.harmonics[0]).max()
    assert np.abs(jumped.harmonics[0] - reference.harmonics[0]).max() < 1e-8 * scale
    assert np.abs(unstable.harmonics[0] - reference.harmonics[0]).max() > 0.1 * scale  # a different branch


def test_a_run_up_across_the_fold_reports_the_stability_of_its_landing_without_a_sweep_check():
    """The run-up past the fold (970 -> 975 RPM) jumps to the lower branch, the state the run-down reaches by
    continuation (the reference); the landing's stability is assessed even in a sweep that skips the check
    (the fits' run-ups), the continued steps are left unassessed there."""
    speeds = np.arange(900.0, 991.0, 5.0)
    unchecked = solve_sweep(_bistable, speeds, 1, harmonics=5, stability=False)
    landed = [i for i, r in enumerate(unchecked.results) if "jump" in r.branch[0]]
    assert [unchecked.rpm[i] for i in landed] == [975.0]
    i = landed[0]
    assert unchecked.results[i].stable[0] and 0.9 < unchecked.results[i].floquet_radius[0] < 1.0
    assert np.isnan(unchecked.results[i - 1].floquet_radius[0]) and np.isnan(unchecked.results[i + 1].floquet_radius[0])
    reference = solve_sweep(_bistable, np.arange(1000.0, 974.0, -5.0), 1, harmonics=5, direction="down").results[-1]
    scale = np.abs(reference.harmonics[0]).max()
    assert np.abs(unchecked.results[i].harmonics[0] - reference.harmonics[0]).max() < 1e-8 * scale  # as above


def test_a_linear_machines_radius_from_eigenvalues_equals_the_monodromy_matrix_route():
    """The stepped rotor (gyroscopic coupling: C not symmetric) at 16 speeds and bearing stiffnesses: the radius
    from the first-order form's eigenvalues (``floquet.linear_spectral_radius``, what ``solve`` uses for a system
    without nonlinear forces) equals the general route's (the full modal basis, expm(A T), the monodromy
    matrix's eigenvalues) to round-off: measured 1.6e-11 relative; 1e-9 leaves room for it."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from example_machines import LINEAR_EFFECTS, stepped_machine

    from hybridtwin.solvers import floquet
    from hybridtwin.model.model import Model

    machine = stepped_machine()
    fx = machine.effects()
    model = Model([fx[e] for e in LINEAR_EFFECTS], machine)
    rng = np.random.default_rng(0)
    S = 16
    values = {k: np.full(S, float(v.nominal)) for k, v in model.parameters.items()} | {"m_e": np.full(S, 0.02)}
    values["k_a"] = rng.uniform(1e7, 4e7, S)
    system = model.system(values, rng.uniform(2000.0, 6000.0, S))
    result = solve(system, 1, stability=False)
    general = floquet.spectral_radius(system, result.harmonics, cutoff_factor=None)
    np.testing.assert_allclose(floquet.linear_spectral_radius(system), general, rtol=1e-9)
