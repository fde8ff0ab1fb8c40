"""Intervals over a loose parameter (``hybridtwin.identify.profile``): a fit whose parameter sits at its range edge,
where the others' linearised intervals are conditional on that edge and miss the truth.

The reference is closed-form. In the toy model below a and b act only through A = a (1 + b^2): b is not pinned at
all, and a fit started at b = 0 (its lower edge, where dA/db = 0) stays there with a = A. Every (a, b) on the valley
a (1 + b^2) = A fits as well, so over b in [0, 1] the data allow a from A / 2 to A, widened by A's own uncertainty:
the joint region of (a, b) ends where A's chi^2 rises by Delta = chi2_2(0.95) (times chi^2/dof when above 1), i.e.
at A -+ sqrt(Delta) sigma_A. The truth (a = 1.6, b = 0.5, A = 2) lies inside that, not inside the linearised
interval around a = 2.
"""

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from hybridtwin.identify import identification as idn
from hybridtwin.identify import profile as prf
from hybridtwin.identify.protocol import ProtocolOptions
from hybridtwin.identify.uncertainty import INTERVAL_CODES
from test_identification import ToyModel

TRUTH = {"a": 1.6, "b": 0.5, "c": 0.2}


class ValleyModel(ToyModel):
    """M_h = [B, 0.7 B e^{0.4 i h}], B = 1 / (1 + a (1 + b^2) - 0.5 i h (1 + 2 c)), h = 1, 2: exact derivatives in x."""

    lower, upper = np.array([0.5, 0.0, -1.0]), np.array([3.0, 1.0, 1.0])

    def evaluate(self, x, jacobian=True):
        a, b, c, h, half = self.physical(x)
        base = 1.0 / (1.0 + a * (1.0 + b**2) - 0.5j * h * (1.0 + 2.0 * c))
        turn = 0.7 * np.exp(0.4j * h)
        M = np.stack([base, base * turn], axis=-1)
        if not jacobian:
            return M, None
        dbase = np.stack([-(1.0 + b**2) * base**2, -2.0 * a * b * base**2, 1j * h * base**2], axis=-1)
        dM = np.stack([dbase, dbase * turn[..., None]], axis=-2)  # (N, H, C, 3)
        return M, dM * half


def _data(runs=3, noise=1.0, seed=7):
    x = np.array([[2 * (TRUTH[p] - lo) / (hi - lo) - 1 for p, lo, hi in
                   zip(ValleyModel.parameters, ValleyModel.lower, ValleyModel.upper)]])
    M = ValleyModel().evaluate(x, jacobian=False)[0][0]
    rng = np.random.default_rng(seed)
    sigma = np.full(M.shape, 2e-3)
    out = []
    for k in range(runs):
        X = M * np.exp(1j * np.arange(1, 3) * 0.3 * k)[:, None]
        X = X + noise * sigma * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
        out.append(idn.RunData(f"r{k}", 500.0, 10.0, "fit", X, sigma))
    return out


@pytest.fixture(scope="module")
def at_edge():
    """The fit from b = 0 (its lower edge): b stays there, a = A."""
    data = _data()
    start = np.zeros(3 + len(data))  # a and c mid-range, b at -1 (its edge), phases 0
    start[1] = -1.0
    start[3:] = [0.3 * k for k in range(len(data))]
    fit = idn.identify([ValleyModel()] * len(data), data, options=ProtocolOptions(trials=0, monte_carlo=0),
                       extra_starts=start)
    return fit


def test_the_edge_fit_is_the_case_and_its_linearised_interval_misses(at_edge):
    fit = at_edge
    table = fit.table().set_index("parameter")
    assert table.loc["b", "at_bound"] and table.loc["b", "value"] == 0.0
    # the linearised interval of a is conditional on b = 0: around A = 2, it excludes a's truth 1.6
    assert not table.loc["a", "ci_low"] <= TRUTH["a"] <= table.loc["a", "ci_high"]
    assert table.loc["a", "interval"] == "conditional" and table.loc["a", "loose"] == "b"
    assert table.loc["b", "interval"] == "none" and np.isnan(table.loc["b", "ci_low"])


def test_the_profile_widens_a_to_the_closed_form_and_covers_every_truth(at_edge):
    fit = at_edge
    profiled = prf.profile_intervals(fit)
    assert profiled is not None and profiled.loose == ("b",)
    result = prf.with_profile(fit)
    table = result.table()
    shared = table[table["run"] == "all"].set_index("parameter")
    for p, truth in TRUTH.items():
        assert shared.loc[p, "ci_low"] <= truth <= shared.loc[p, "ci_high"], (p, shared.loc[p].to_dict())
        assert shared.loc[p, "interval"] == "profile"
    assert shared.loc["a", "loose"] == "b" and shared.loc["c", "loose"] == "b" and shared.loc["b", "loose"] == ""
    # closed form: a (1 + b^2) within A -+ sqrt(Delta) sigma_A over b in [0, 1], Delta = chi2_2(0.95) s^2 (a's
    # region is that of a and b); sigma_A is a's linearised stderr at b = 0, where a = A
    A, sigma_A = fit.x[0], fit.uncertainty.stderr[0]
    delta = max(1.0, fit.chi2_dof) * stats.chi2.ppf(0.95, 2)
    half = np.sqrt(delta) * sigma_A
    # the search settles within 5 % of Delta in the chi^2 rise (2.5 % of the half-width in sqrt) or within a bracket
    # of 0.004 normalised (0.005 in a); A's chi^2 is nearly quadratic over +-sqrt(Delta) sigma_A (sigma_A ~ 1 %)
    tolerance = 0.025 * half + 0.005
    assert shared.loc["a", "ci_low"] == pytest.approx((A - half) / 2, abs=tolerance)
    assert shared.loc["a", "ci_high"] == pytest.approx(A + half, abs=tolerance)
    # b: the valley is flat, so its own profile spans its whole range (at one degree of freedom)
    assert shared.loc["b", "ci_low"] == 0.0 and shared.loc["b", "ci_high"] == pytest.approx(1.0, abs=1e-9)
    assert profiled.threshold[1] == pytest.approx(max(1.0, fit.chi2_dof) * stats.chi2.ppf(0.95, 1))
    # never narrower than the linearised intervals, and the phases keep theirs, marked as conditional on b
    before = fit.table()
    assert (table["ci_low"] <= before["ci_low"].fillna(np.inf)).all()
    assert (table["ci_high"] >= before["ci_high"].fillna(-np.inf)).all()
    phases = table[table["parameter"] == "phase"]
    assert phases["interval"].eq("conditional").all() and phases["loose"].eq("b").all()
    assert set(table["interval"]) <= set(INTERVAL_CODES)


def test_a_parameter_not_identifiable_gets_its_profile_not_its_linearised_interval():
    """From the middle of the valley b is free but on a null direction of the Jacobian (not identifiable): its
    linearised interval is meaningless (wider than the range); its own interval is its profile, the whole range [0, 1]
    (the valley is flat), and a's covers the closed form's A / 2 .. A as at the edge."""
    data = _data()
    start = np.r_[0.0, 0.0, 0.0, [0.3 * k for k in range(len(data))]]
    fit = idn.identify([ValleyModel()] * len(data), data, options=ProtocolOptions(trials=0, monte_carlo=0),
                       extra_starts=start)
    row = fit.table().set_index("parameter").loc["b"]
    assert not row["at_bound"] and not row["identifiable"]
    shared = prf.with_profile(fit).table()
    shared = shared[shared["run"] == "all"].set_index("parameter")
    assert shared.loc["b", "ci_low"] == pytest.approx(0.0, abs=1e-9)
    assert shared.loc["b", "ci_high"] == pytest.approx(1.0, abs=1e-9)
    A = fit.x[0] * (1 + fit.x[1] ** 2)  # the valley's A at this fit
    assert shared.loc["a", "ci_low"] < A / 2 and shared.loc["a", "ci_high"] > A
    for p, truth in TRUTH.items():
        assert shared.loc[p, "ci_low"] <= truth <= shared.loc[p, "ci_high"], p


def test_a_profiled_table_reads_back_exactly(at_edge, tmp_path):
    table = prf.with_profile(at_edge).table()
    path = tmp_path / "parameters.tsv"
    idn.write_parameters(table, path)
    read = idn.read_parameters(path)
    pd.testing.assert_frame_equal(read, table, check_exact=False, rtol=1e-8)  # 9 significant digits written
    back = idn.Identification.from_table(read, parameters=ValleyModel.parameters)
    pd.testing.assert_frame_equal(back.table(), read, check_exact=True)
    assert read["loose"].tolist().count("") == 1  # b's own row: profiled over nothing else; "" stays ""


def test_nothing_loose_nothing_profiled():
    """Every parameter pinned (test_identification's toy model): no profile, every interval linear."""
    from test_identification import toy_data

    data = [toy_data([0.3, -0.4, 0.5], phase, noise=1.0, seed=seed, run=f"r{seed}") for seed, phase in ((1, 0.4),
                                                                                                           (2, -1.0))]
    fit = idn.identify([ToyModel()] * 2, data, options=ProtocolOptions(trials=4, monte_carlo=0, seed=1))
    assert fit.table()["identifiable"].all() and not fit.table()["at_bound"].any()
    assert prf.profile_intervals(fit) is None
    table = prf.with_profile(fit).table()
    assert table["interval"].eq("linear").all() and table["loose"].eq("").all()
