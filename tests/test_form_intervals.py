"""Intervals over the effects the data cannot exclude (hybridtwin.diagnose.form_intervals).

A linear least-squares problem, where the formula is exact: each candidate's interval against a brute-force
profile (every value of the parameter on a fine grid, the candidate's coefficient held to its range by a bounded
least-squares solve, scipy's lsq_linear). Then the physics: the solver-made runs of tests/test_diagnosis.py with a
slope force whose cubic part the fitted variant leaves out, the linearised interval over that candidate against
the extended model's own profile refitted on the full solver, and the truth of the parameter it biases.
"""

import numpy as np
import pandas as pd
import pytest
from scipy import optimize, stats

from hybridtwin.diagnose import form_intervals as fi
from hybridtwin.diagnose import score_test as st


def _linear_case(seed: int = 3):
    """y = A theta + G beta + noise (sigma 1): three shared parameters, one nuisance, two candidates; the second
    candidate's column correlates with theta_1, so the data leave it a stretch of its range that trades with it; the
    first's is orthogonal to the parameters' columns."""
    rng = np.random.default_rng(seed)
    m = 60
    A = 6.0 * rng.standard_normal((m, 4))  # informative enough that every interval lies inside the ranges [-1, 1]
    g1 = 6.0 * rng.standard_normal(m)
    g1 -= A @ np.linalg.lstsq(A, g1, rcond=None)[0]  # orthogonal to every parameter's column: trades with none
    g2 = 0.9 * A[:, 1] + 1.2 * rng.standard_normal(m)  # nearly collinear with theta_1
    theta_true = np.array([0.2, -0.1, 0.3, 0.5])
    y = A @ theta_true + 0.15 * g2 + rng.standard_normal(m)
    theta0 = np.linalg.lstsq(A, y, rcond=None)[0]  # the fit without the candidates
    r = A @ theta0 - y  # weighted residuals (sigma 1), model minus data as d r / d theta = A
    J = np.column_stack([A, g1, g2])
    theta = np.r_[theta0, 0.0, 0.0]  # the candidates at 0 (absent), their ranges [-1, 1] normalised
    entries = [("a", "all"), ("b", "all"), ("c", "all"), ("phase", "r1"), ("g1", "all"), ("g2", "all")]
    free = np.array([True, True, True, True, False, False])
    return J, r, theta, entries, free, {"g1": [4], "g2": [5]}


def _brute_profile(J, r, theta, free, i, cols, delta):
    """The interval of entry i (normalised) by brute force: at each held value, min over the other free entries
    and the candidate's columns (held to [-1, 1]) of the linearised chi^2 (bounded least squares)."""
    base = np.flatnonzero(free)
    others = [k for k in base if k != i] + list(cols)
    lower = np.r_[np.full(len(base) - 1, -np.inf), -1.0 - theta[cols]]
    upper = np.r_[np.full(len(base) - 1, np.inf), 1.0 - theta[cols]]

    def chi2_at(value):
        residual = r + J[:, i] * (value - theta[i])
        step = optimize.lsq_linear(J[:, others], -residual, bounds=(lower, upper), method="bvls").x
        return float(np.sum((residual + J[:, others] @ step) ** 2))

    full = optimize.lsq_linear(J[:, list(base) + list(cols)], -r,
                               bounds=(np.r_[np.full(len(base), -np.inf), lower[len(base) - 1:]],
                                       np.r_[np.full(len(base), np.inf), upper[len(base) - 1:]]), method="bvls")
    reference = 2 * full.cost
    centre = theta[i] + full.x[list(base).index(i)]  # the profile is convex in the held value: one root a side
    level = lambda v: chi2_at(v) - reference - delta  # noqa: E731
    return (optimize.brentq(level, centre - 10.0, centre, xtol=1e-7),
            optimize.brentq(level, centre, centre + 10.0, xtol=1e-7))


def test_each_candidates_interval_is_the_bounded_profile_of_the_linear_problem():
    J, r, theta, entries, free, columns = _linear_case()
    names = {"a": (-1.0, 1.0), "b": (-1.0, 1.0), "c": (-1.0, 1.0)}  # normalised = SI: the ends compare directly
    lower, upper = {k: v[0] for k, v in names.items()}, {k: v[1] for k, v in names.items()}
    dof = J.shape[0] - int(free.sum())
    result = fi.form_intervals(J, r, theta, entries, free, columns, {}, lower, upper, dof)
    chi2_dof = float(r @ r) / dof
    delta = max(1.0, chi2_dof) * stats.chi2.ppf(0.95, 1)
    table = result.table.set_index(["parameter", "candidate"])
    for candidate, cols in {"": [], **columns}.items():
        for i, name in enumerate(["a", "b", "c"]):
            low, high = _brute_profile(J, r, theta, free, i, cols, delta)
            row = table.loc[(name, candidate)]
            # the brute force is exact (bounded least squares, roots to 1e-7); the formula takes beta on a grid of
            # 2.5e-3 of the range, its ends move by at most that times |d p*/d beta| (< 1 here): 3e-3
            assert row["low"] == pytest.approx(low, abs=3e-3) and row["high"] == pytest.approx(high, abs=3e-3), (
                name, candidate, row["low"], low, row["high"], high)
    union = result.union().set_index("parameter")
    own = table.xs("", level="candidate")
    # g2 trades with b: it widens b's interval; g1, orthogonal to every parameter's column, leaves each as it was
    assert "g2" in union.loc["b", "widened_by"]
    assert union.loc["b", "high"] - union.loc["b", "low"] > 1.5 * (own.loc["b", "high"] - own.loc["b", "low"])
    assert not any("g1" in text for text in union["widened_by"])
    for name in "abc":
        assert table.loc[(name, "g1"), "low"] == pytest.approx(own.loc[name, "low"], abs=1e-9)


def test_the_reported_interval_is_kept_and_the_table_reads_back(tmp_path):
    J, r, theta, entries, free, columns = _linear_case()
    ranges = {"a": (-1.0, 1.0), "b": (-1.0, 1.0), "c": (-1.0, 1.0)}
    lower, upper = {k: v[0] for k, v in ranges.items()}, {k: v[1] for k, v in ranges.items()}
    own = {"a": (-5.0, 5.0)}  # a profiled interval wider than the linearised one: reported as such
    result = fi.form_intervals(J, r, theta, entries, free, columns, own, lower, upper, 50)
    union = result.union().set_index("parameter")
    assert (union.loc["a", "own_low"], union.loc["a", "own_high"]) == (-5.0, 5.0)
    assert union.loc["a", "low"] <= -5.0 and union.loc["a", "high"] >= 5.0
    path = tmp_path / "diagnosis_intervals.tsv"
    result.write(path)
    back = fi.FormIntervals.read(path)
    pd.testing.assert_frame_equal(back.table, result.table, check_exact=False, rtol=1e-11)
    pd.testing.assert_frame_equal(back.union(), result.union(), check_exact=False, rtol=1e-11)
    nothing_free = fi.form_intervals(J, r, theta, entries, np.zeros(len(entries), bool), columns, {}, lower, upper, 50)
    assert nothing_free.table.empty and nothing_free.union().empty  # every parameter held: no row, no error
    with pytest.raises(ValueError, match="not a table of intervals"):
        pd.DataFrame({"parameter": ["a"]}).to_csv(tmp_path / "bad.tsv", sep="\t", index=False)
        fi.FormIntervals.read(tmp_path / "bad.tsv")


def _profile_on_the_solver(problem, theta, X, name, delta):
    """The extended model's profile interval of shared parameter ``name`` on the full solver: its optimum (from
    theta and from the candidate at mid-range), then at each held value everything else refitted
    (``levenberg_marquardt(..., fixed=)``, the candidate within its range), the ends where chi^2 rises by delta."""
    from hybridtwin.identify import lm

    L = problem.layout
    entries = L.entries()
    starts = np.vstack([theta, theta])
    starts[1, entries.index((L.parameters[-1], "all"))] = 0.0
    fits = lm.levenberg_marquardt(problem, starts, np.repeat(X[None], 2, 0))
    best = fits.x[int(np.argmin(fits.cost))]
    reference = 2 * float(fits.cost.min())
    i = entries.index((name, "all"))
    fixed = np.zeros(L.n, bool)
    fixed[i] = True

    def rise(value):
        start = best.copy()
        start[i] = value
        return 2 * float(lm.levenberg_marquardt(problem, start[None], X[None], lm.LMOptions(max_iterations=40),
                                                fixed).cost[0]) - reference - delta

    ends = [optimize.brentq(rise, edge, best[i], xtol=1e-5) if rise(edge) > 0 else edge
            for edge in (max(best[i] - 1.0, -1.0), min(best[i] + 1.0, 1.0))]
    k = L.index(name)
    return tuple(L.lower[k] + 0.5 * (np.array(ends) + 1.0) * (L.upper[k] - L.lower[k]))


@pytest.mark.slow
def test_the_linearised_interval_over_a_candidate_is_the_extended_models_profile_on_the_solver():
    """Solver-made runs (tests/test_diagnosis.py's four, H = 3) of the Geometric model with a speed-dependent
    damping too small to be seen (zeta_v = 0.01: not significant), fitted without it: speed damping trades with the
    structural damping zeta_s, so over that candidate zeta_s's interval widens (down to its range's edge), while
    k_b's barely moves. Both against the extended model's own profile on the full solver."""
    from test_diagnosis import TRUTH, _base_fit, _candidates, _data

    data = _data(["speed_damping"], TRUTH | {"zeta_v": 0.01}, seed=1)
    base = _base_fit(data)
    candidates = _candidates(["speed_damping"])
    scores = st.score_tests(base, candidates)
    assert scores.scores[0].p_value > 0.05  # the data do not see it
    result = st.intervals_over_candidates(scores, {})
    table = result.table.set_index(["parameter", "candidate"])
    problem, theta = st.extended_problem(base, candidates)
    delta = max(1.0, scores.base_chi2 / scores.base_dof) * stats.chi2.ppf(0.95, 1)
    own_width = {}
    for name in ("k_b", "zeta_s"):
        low, high = _profile_on_the_solver(problem, theta, base.X, name, delta)
        row = table.loc[(name, "speed_damping")]
        width = high - low
        own_width[name] = table.loc[(name, ""), "high"] - table.loc[(name, ""), "low"]
        # linearised at beta = 0 against the nonlinear profile: measured 0.2 % of the width for k_b and 7 % for
        # zeta_s (the damping's response bends across zeta_v's range); 10 % bounds both
        assert row["low"] == pytest.approx(low, abs=0.1 * width) and row["high"] == pytest.approx(high, abs=0.1 * width)
        if name == "zeta_s":
            assert width > 1.3 * own_width[name] and low == pytest.approx(0.01)  # down to zeta_s's range edge
    union = result.union().set_index("parameter")
    assert "speed_damping" in union.loc["zeta_s", "widened_by"]
