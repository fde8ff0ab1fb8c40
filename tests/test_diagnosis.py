"""The diagnosis (issue 6) on synthetic runs made by the full solver with a known hidden effect.

Four runs (two unbalance masses, 500-850 RPM), H = 3, the measured sigma of the bundled data (8e-7 m per
real/imaginary part), shared bow: small enough to fit and refit with the full solver in seconds, and the same
code paths as the workflow's diagnose rule.
"""

import re
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from hybridtwin.diagnose import conclusion as conc
from hybridtwin.diagnose import elimination as elim
from hybridtwin.diagnose import recommendation as rec
from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.diagnose import diagnosis_report as dgr
from hybridtwin.identify import forward as fwd
from hybridtwin.identify.arrow_problem import Layout
from hybridtwin.identify import identification as idn
from hybridtwin.identify import lm
from hybridtwin.model import variants
from hybridtwin.diagnose import refit as rf
from hybridtwin.diagnose import score_test as st
from hybridtwin.identify import uncertainty as unc
from hybridtwin.model.candidates import Candidate, builtin_candidates
from hybridtwin.model.effect_base import Parameter, PolynomialBearing, Term
from hybridtwin.identify.protocol import ProtocolOptions
from hybridtwin.identify.run_fits import theta_from_nested
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant
from hybridtwin.settings import diagnosis_settings

#: the diagnosis options of a config that sets none: the schema's defaults (hybridtwin.settings)
OPTIONS = diagnosis_settings({}).options()

H = 3
SIGMA = 8e-7  # m, the bundled records' harmonic sigma (results/data/harmonics.tsv: 6-10e-7)
RUNS = [("r500_m25p9", 500.0, 25.9), ("r650_m25p9", 650.0, 25.9), ("r750_m14p8", 750.0, 14.8),
        ("r850_m14p8", 850.0, 14.8)]
GEOMETRIC = BUILTIN_VARIANTS["geometric"]  # the paper's Geometric model, as in config/config.yaml
TRUTH = {"k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "q_x": 0.002, "q_y": 0.0015}


def _data(extra_effects: list[str], values: dict[str, float], seed: int) -> list[idn.RunData]:
    """Measured harmonics of the four runs: the truth (geometric + extra effects) by the solver, plus noise."""
    spec = {"effects": GEOMETRIC["effects"] + extra_effects, "unknown": {k: (-1e9, 1e9) for k in values}}
    truth = Variant.from_spec("truth", spec)
    rng = np.random.default_rng(seed)
    names = list(values)
    x = np.zeros((1, len(names)))  # the middle of the (-1e9, 1e9) ranges is 0: shift to the values below
    out = []
    for run, rpm, mass in RUNS:
        model = fwd.SolverModel(truth, run, rpm, mass, names, np.array([values[n] for n in names]) - 1.0,
                                np.array([values[n] for n in names]) + 1.0, H)
        M = model.evaluate(x, jacobian=False)[0][0]
        assert np.isfinite(M).all()
        noise = SIGMA * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
        out.append(idn.RunData(run, rpm, mass, "fit", M + noise, np.full(M.shape, SIGMA)))
    return out


def _base_fit(data: list[idn.RunData], spec: dict = GEOMETRIC, per_run=()) -> st.BaseFit:
    """The variant fitted with the full solver (shared bow, or ``per_run``): random starts plus the nominal one."""
    variant = Variant.from_spec("geometric", spec)
    lower, upper = zip(*variant.unknown.values())
    models = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, list(variant.unknown), np.array(lower),
                              np.array(upper), H) for d in data]
    options = ProtocolOptions(trials=3, monte_carlo=0, seed=2, lm=lm.LMOptions(max_iterations=60))
    fit = idn.identify(models, data, per_run, options)
    assert fit.success or fit.status == lm.STALLED
    return st.BaseFit(variant, fit.layout, fit.theta, fit.data, H)


CANDIDATES = ["slope_spring", "expansion_k4", "expansion_k2", "cross_coupled_stiffness", "speed_damping",
              "excitation_2x"]


def _diagnose(base, candidates, options=None):
    """``dg.diagnose`` with the default options (``OPTIONS``) unless given."""
    return dg.diagnose(base, candidates, OPTIONS if options is None else options)


def _candidates(names=CANDIDATES) -> list[Candidate]:
    available = builtin_candidates()
    return [available[n] for n in names]


@pytest.fixture(scope="module")
def slope_data():
    return _data(["slope_spring"], TRUTH | {"k_w": 324.2, "k_z": 301.1}, seed=1)


@pytest.fixture(scope="module")
def slope_base(slope_data):
    return _base_fit(slope_data)


def test_score_statistic_equals_the_linearised_chi2_drop(slope_base):
    """S = ||r_p||^2 - min ||r_p + G_p b||^2 equals the drop of the full linearised least squares with the
    base entries and the candidate together (lstsq on [J, G] vs [J] alone: no projection), to rounding."""
    candidates = _candidates(["expansion_k2", "cross_coupled_stiffness"])  # two-signed ranges: no constraint
    scores = st.score_tests(slope_base, candidates)
    problem, theta = st.extended_problem(slope_base, candidates)
    ev = problem.evaluate(theta[None], slope_base.X[None], jacobian=True)
    r, J = ev.r[0].reshape(-1), problem.dense_jacobian(ev)
    entries = problem.layout.entries()
    base_cols = [i for i, (p, _) in enumerate(entries) if p not in ("k2", "k_xy")]
    # a base entry at a range edge is held, as in the score test
    free = [i for i in base_cols if entries[i][0] == "phase" or abs(theta[i]) < 1 - unc.BOUND_TOLERANCE]

    def drop(cols):
        without = np.linalg.lstsq(J[:, free], -r, rcond=None)[0]
        with_c = np.linalg.lstsq(J[:, free + cols], -r, rcond=None)[0]
        return np.sum((r + J[:, free] @ without) ** 2) - np.sum((r + J[:, free + cols] @ with_c) ** 2)

    for score, name in zip(scores.scores, ("k2", "k_xy")):
        expected = drop([entries.index((name, "all"))])
        assert score.statistic == pytest.approx(expected, rel=1e-6, abs=1e-6)  # same algebra, rounding only


def test_hidden_slope_force_is_ranked_first_and_confirmed(slope_base):
    result = _diagnose(slope_base, _candidates())
    table = result.table
    assert result.summary["misfit"]  # the geometric model misses the slope force: the misfit is real
    assert table.loc[0, "effect"] in ("slope_spring", "expansion_k4")  # the slope force (k4 u' is its linear part)
    assert table.loc[0, "verdict"].startswith("add")
    assert table.loc[0, "verdict_code"] == dg.CandidateVerdict.ADD  # the code beside the sentence (issue 37)
    assert result.conclusion.startswith("add")
    # after adding it, chi^2/dof is at the noise floor: within 3 sigma of chi^2(dof)/dof (dof ~ 30)
    dof = result.confirmations[table.loc[0, "effect"]].dof
    assert table.loc[0, "confirmed_chi2_dof"] < 1 + 3 * np.sqrt(2 / dof)
    assert table.loc[0, "delta_bic"] < -10
    # the recommended variant is a valid config entry that adds the effect
    assert f"geometric_{table.loc[0, 'effect']}" in result.recommendation
    recommended = result.summary["recommended_variant"]
    assert recommended["spec"]["effects"][-1] == table.loc[0, "effect"]
    assert Variant.from_spec(recommended["name"], recommended["spec"]).unknown_names[-1] in table.loc[0, "parameters"]
    markdown = dgr.markdown(result)
    assert result.conclusion in markdown and "| rank |" in markdown
    # candidates not refitted have no confirmed chi^2/dof or Delta BIC: blank cells, never "nan"
    assert table["confirmed_chi2_dof"].isna().any() and "nan" not in markdown
    assert f"{len(result.summary['runs'])} fit runs, " in markdown
    dgr.plot(result)


def test_the_diagnosis_stands_when_its_intervals_over_the_candidates_cannot_be_had(slope_base, monkeypatch,
                                                                                   tmp_path):
    """The intervals over the candidates are an addition at the end of the diagnosis: where the solver fails next
    to the final fit (score_tests' RuntimeError), the verdict, the path and the outputs are written as before, the
    intervals table empty and the failure in the summary; with them, the final model's shared parameters are
    listed (here the path's last fit: geometric + the slope force's linear term)."""
    with_them = _diagnose(slope_base, _candidates(["expansion_k4", "expansion_k2"]))
    union = with_them.intervals.union()
    assert {"k_b", "zeta_s"} <= set(union["parameter"]) and (union["low"] <= union["own_low"]).all()

    def fail(*args, **kwargs):
        raise RuntimeError("the full solver failed at the base optimum")

    monkeypatch.setattr(dg, "final_intervals", fail)
    result = _diagnose(slope_base, _candidates(["expansion_k4", "expansion_k2"]))
    assert result.status == with_them.status and [s.effect for s in result.path] == [s.effect for s in with_them.path]
    assert result.intervals.table.empty and result.summary["intervals_over_candidates"] == []
    assert "solver failed" in result.summary["intervals_over_candidates_failed"]
    dgr.write(result, tmp_path / "d.tsv", tmp_path / "d.md", tmp_path / "d.yaml")
    result.intervals.write(tmp_path / "i.tsv")
    assert "Intervals over the effects" not in (tmp_path / "d.md").read_text()


def test_estimate_of_the_linear_slope_term_matches_the_truth(slope_base):
    """k4 u' alone stands for k_w u' + k_z u'^3 with small slopes: k4 near k_w = 324.2 N (within 10 %: the
    cubic part, 301.1 (u')^3 with u' ~ 0.02, adds ~0.04 % of the linear force, the rest is noise)."""
    scores = st.score_tests(slope_base, _candidates(["expansion_k4"]))
    cf = rf.confirm(slope_base, scores.scores[0], scores)
    k4 = cf.estimates.set_index("parameter").loc["k4"]
    assert k4["value"] == pytest.approx(324.2, rel=0.1)
    assert k4["ci_low"] > 0  # the interval excludes zero: the effect is there


def test_no_false_alarm_without_a_hidden_effect():
    base = _base_fit(_data([], TRUTH, seed=3))
    result = _diagnose(base, _candidates())
    assert not result.summary["misfit"]
    assert result.conclusion.startswith("no missing effect")
    assert not any(v.startswith("add") for v in result.table["verdict"])
    assert result.recommendation == ""


def test_indistinguishable_candidates_are_called_confounded(slope_base):
    """A user's effect with the very same physics as expansion_k4 (a force k_t u') cannot be told apart."""
    tilt = PolynomialBearing(name="tilt_force", meaning="force on the shaft tilt (a user's duplicate of k4 u')",
                             parameters=(Parameter("k_t", "N", (-1000.0, 1000.0), 0.0, "tilt stiffness"),),
                             terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), "k_t u'"),))
    candidates = _candidates(["expansion_k4", "expansion_k2"]) + [Candidate(tilt, ("k_t",))]
    result = _diagnose(slope_base, candidates)
    verdicts = dict(zip(result.table["effect"], result.table["verdict"]))
    assert "confounded" in verdicts["expansion_k4"] and "confounded" in verdicts["tilt_force"]
    assert "cannot tell them apart" in result.conclusion


def test_the_same_local_sensitivities_are_not_confounded_when_the_refits_differ(slope_base):
    """A user's effect whose derivative at zero is expansion_k4's (a force k_t u') but which also stiffens the
    bearing like k_t^2 / 20 u (nothing at first order): the score test sees the same sensitivities (nested both
    ways), but at k_t ~ 324 N its extra 5 kN/m of stiffness cannot fit, so the refits differ by far more than
    confounded_bic and the data can tell them apart: not "confounded", expansion_k4 the one to add."""
    twin = PolynomialBearing(name="stiffening_tilt", meaning="k_t u' plus a stiffness k_t^2 / 20 (a user's effect)",
                             parameters=(Parameter("k_t", "N", (-1000.0, 1000.0), 0.0, "tilt stiffness"),),
                             terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), "k_t u'"),
                                    Term(lambda p: p.k_t * p.k_t / 20.0, (1, 0, 0, 0), "k_t^2 / 20 u")))
    candidates = _candidates(["expansion_k4"]) + [Candidate(twin, ("k_t",))]
    scores = st.score_tests(slope_base, candidates)
    by_name = {s.candidate.name: s for s in scores.scores}
    assert st.nested(by_name["stiffening_tilt"].projected, by_name["expansion_k4"].projected)  # locally the same
    result = _diagnose(slope_base, candidates)
    verdicts = dict(zip(result.table["effect"], result.table["verdict"]))
    assert verdicts["expansion_k4"].startswith("add") and "confounded" not in verdicts["expansion_k4"]
    assert "confounded" not in verdicts["stiffening_tilt"] and "cannot tell them apart" not in result.conclusion


def test_unexplained_discrepancy_when_no_candidate_fits():
    """A hidden 3X excitation while only linear 1X-type candidates are offered: say so, name none."""
    data = _data(["excitation_3x"], TRUTH | {"f3_c": 0.3, "f3_s": -0.2}, seed=4)
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["cross_coupled_stiffness", "speed_damping", "expansion_k2"]))
    assert result.summary["misfit"]
    assert result.conclusion.startswith("unexplained discrepancy")
    assert not any(v.startswith("add: explains the discrepancy") for v in result.table["verdict"])
    # the residual's fingerprint tells the user where the missing physics sits: 3X, which the model lacks
    fp = result.fingerprint
    assert fp.dominant == 3 and fp.harmonic_share[3] > 0.9
    assert "What the residual looks like" in result.conclusion and "3X" in result.summary["fingerprint"]
    assert "3X" in dgr.markdown(result)


def test_nested_subspaces():
    rng = np.random.default_rng(0)
    b = rng.standard_normal((50, 2))
    assert st.nested(b[:, :1] * 3.0, b)
    assert st.nested(b @ np.array([[1.0], [2.0]]), b)
    assert not st.nested(rng.standard_normal((50, 1)), b)
    assert not st.nested(b, b[:, :1])


def test_a_candidate_whose_range_excludes_zero_is_refused(slope_base):
    bad = Candidate(builtin_candidates()["expansion_k2"].effect, ("k2",))
    effect = replace(bad.effect, parameters=(Parameter("k2", "N/m", (10.0, 20.0), 15.0, "no zero"),
                                             bad.effect.parameters[1]))
    with pytest.raises(ValueError, match="excludes 0"):
        st.extend(slope_base.variant, [Candidate(effect, ("k2",))])


def test_sparse_route_reads_which_terms_an_l1_fit_kept():
    """The paper's route side by side: active = interval excludes zero, or pushed to a range edge away from 0."""
    import pandas as pd

    spec = {"effects": GEOMETRIC["effects"][:-1] + ["expansion_k3", "expansion_k4", "expansion_k6"],
            "unknown": {"k3": [0, 7000], "k4": [-1000, 1000], "k6": [-1000, 1000], "q_x": [0.001, 0.01]}}
    variant = Variant.from_spec("expansion", spec)
    table = pd.DataFrame({
        "parameter": ["k3", "k4", "k6", "q_x", "phase"], "run": ["all", "all", "all", "r1", "r1"],
        "kind": ["shared", "shared", "shared", "per_run", "nuisance"], "unit": ["N/m", "N", "N", "m", "rad"],
        "value": [5460.0, 399.0, -1000.0 + 1e-9, 0.003, 0.1], "ci_low": [5397.0, -5.0, np.nan, 0.002, 0.0],
        "ci_high": [5523.0, 800.0, np.nan, 0.004, 0.2], "at_bound": [False, False, True, False, False]})
    route = dgr.sparse_route(table, variant).set_index("parameter")
    assert list(route.index) == ["k3", "k4", "k6"]  # q_x cannot be switched off, phases are nuisances
    assert route.loc["k3", "active"] and not route.loc["k4", "active"] and route.loc["k6", "active"]
    assert route.loc["k4", "effect"] == "expansion_k4"


def test_parent_variant_is_the_one_extended_by_exactly_one_effect():
    base = ["centrifugal_softening", "unbalance", "geometric_spring"]
    specs = {"geometric": {"effects": base, "unknown": {"k_b": [0, 1]}},
                "geometric_slope_spring": {"effects": base + ["slope_spring"], "unknown": {"k_b": [0, 1], "k_w": [0, 1]}},
                "two_more": {"effects": base + ["slope_spring", "speed_damping"],
                             "unknown": {"k_b": [0, 1], "k_w": [0, 1], "zeta_v": [0, 1]}},
                "other": {"effects": ["unbalance", "radial_spring", "slope_spring"], "unknown": {"k_b": [0, 1]}}}
    assert variants.parent_variant(specs, "geometric_slope_spring") == ("geometric", "slope_spring")
    assert variants.parent_variant(specs, "two_more") == ("geometric_slope_spring", "speed_damping")
    assert variants.parent_variant(specs, "geometric") is None
    assert variants.parent_variant(specs, "other") is None


def test_theta_from_table_normalises_with_the_new_layout():
    import pandas as pd

    layout = Layout.build(["k_b", "k_w"], [2000.0, 0.0], [3500.0, 1000.0], ["r1"], ["k_w"])
    refits = pd.DataFrame({"effect": ["slope_spring"] * 3 + ["other"],
                           "parameter": ["k_b", "k_w", "phase", "k_b"], "run": ["all", "r1", "r1", "all"],
                           "value": [2750.0, 250.0, 0.3, 3000.0]})
    slope, other = (refits[refits["effect"] == e] for e in ("slope_spring", "other"))
    np.testing.assert_allclose(idn.theta_from_table(slope, layout), [0.0, -0.5, 0.3])
    assert idn.theta_from_table(other, layout) is None  # does not cover every entry


def test_theta_from_nested_maps_the_shared_values_and_copies_the_runs():
    """A Geometric fit as an Expansion start: k1 = k_b, k3 = 2 k_b, k7 = -4 k_b, the other k_i zero (eq. 22-24),
    the bow and phases copied run by run, anything else from the fallback table."""
    import pandas as pd

    from hybridtwin.model.variants import builtin_variant

    geometric, expansion = builtin_variant("geometric"), builtin_variant("expansion")
    names = list(expansion.unknown)
    lower, upper = expansion.bounds(names)
    layout = Layout.build(names, lower, upper, ["r1", "r2"], ["q_x", "q_y"])
    fit = pd.DataFrame({"parameter": ["k_b", "zeta_s", "q_x", "q_y", "phase", "q_x", "q_y", "phase"],
                        "run": ["all", "all", "r1", "r1", "r1", "r2", "r2", "r2"],
                        "value": [3000.0, 0.02, 0.002, 0.003, 0.1, 0.004, 0.005, -0.2]})
    fallback = pd.DataFrame({"parameter": ["k2"], "run": ["all"], "value": [123.0]})  # overridden by the map
    theta, mismatch = theta_from_nested(fit, geometric, expansion, layout, fallback)
    assert mismatch < 1e-12
    si = dict(zip(layout.entries(), layout.to_si(theta)))
    expected = {("k1", "all"): 3000.0, ("k2", "all"): 0.0, ("k3", "all"): 6000.0, ("k7", "all"): -12000.0,
                ("k4", "all"): 0.0, ("q_x", "r2"): 0.004, ("q_y", "r1"): 0.003, ("phase", "r2"): -0.2}
    for entry, value in expected.items():
        assert si[entry] == pytest.approx(value, abs=1e-9)
    missing = fit[fit["parameter"] != "phase"]  # phases neither in the fit nor the fallback: no start
    assert theta_from_nested(missing, geometric, expansion, layout, fallback)[0] is None


def test_no_effect_shares_stay_finite(slope_base):
    """On data at the noise floor the predicted share of the excess chi^2 must not divide by ~0 (it printed
    3.2e14 % once): the excess is floored at one standard deviation of chi^2(dof)."""
    base = _base_fit(_data([], TRUTH, seed=3))
    result = _diagnose(base, _candidates(["cross_coupled_stiffness", "expansion_k2"]))
    drop = result.table["predicted_error_drop_pct"]
    # S ~ chi^2(1) under "absent": a few units over sqrt(2 dof) ~ 7 gives tens of percent, never 1e14
    assert np.isfinite(drop).all() and drop.max() < 1e3


def test_an_estimate_beyond_the_range_is_found_by_widening_it():
    """Lower bearing 30 % softer (dk_lo = -3000 N/m) than the candidate's range (+-2000) allows: the refit widens
    the range towards -2000's side until the estimate is inside, and the truth lies in its interval."""
    data = _data(["lower_bearing_compliance"], TRUTH | {"dk_lo": -3000.0}, seed=6)
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["lower_bearing_compliance", "cross_coupled_stiffness"]))
    assert result.table.loc[0, "effect"] == "lower_bearing_compliance"
    assert result.conclusion.startswith("add lower_bearing_compliance")
    cf = result.confirmations["lower_bearing_compliance"]
    assert cf.widened and cf.widened[0][0] == "dk_lo" and cf.ranges["dk_lo"][0] < -2000.0
    row = cf.estimates.set_index("parameter").loc["dk_lo"]
    assert not row["at_bound"] and row["ci_low"] < -3000.0 < row["ci_high"]
    assert "range widened" in result.table.loc[0, "estimate"]
    # the recommended variant carries the widened range
    assert result.summary["recommended_variant"]["spec"]["unknown"]["dk_lo"][0] < -2000.0


def test_two_hidden_effects_are_both_found_by_forward_selection():
    """The slope force and a 2X force hidden together: the path adds both and ends at the noise floor."""
    data = _data(["slope_spring", "excitation_2x"], TRUTH | {"k_w": 324.2, "k_z": 301.1, "f2_c": 0.1,
                                                             "f2_s": -0.05}, seed=7)
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["slope_spring", "excitation_2x", "cross_coupled_stiffness"]))
    path = result.path_table()
    assert set(path["effect"]) == {"slope_spring", "excitation_2x"}
    assert result.conclusion.startswith("add ") and "together they explain" in result.conclusion
    final = result.path[-1].confirmation
    assert final.chi2 / final.dof < 1 + 3 * np.sqrt(2 / final.dof)  # within 3 sigma of the noise floor
    spec = result.summary["recommended_variant"]["spec"]
    assert {"slope_spring", "excitation_2x"} <= set(spec["effects"])
    Variant.from_spec(result.summary["recommended_variant"]["name"], spec)  # a valid config entry
    assert "## Forward selection" in dgr.markdown(result)


def test_the_data_tell_which_law_the_2x_force_follows():
    """A 2X force growing like Omega^2 (e2 = 3e-5 kg m: 0.08-0.24 N over 500-850 RPM): the Omega^2 law fits,
    the constant-amplitude law is ranked below it by the refits' Delta BIC."""
    data = _data(["excitation_2x_inertial"], TRUTH | {"e2_c": 3e-5, "e2_s": -1.5e-5}, seed=8)
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["excitation_2x", "excitation_2x_inertial"]))
    assert result.table.loc[0, "effect"] == "excitation_2x_inertial"
    assert result.table.loc[0, "verdict"].startswith("add")
    bic = result.table.set_index("effect")["delta_bic"]
    assert bic["excitation_2x_inertial"] < bic["excitation_2x"] - 10  # "very strong" evidence between the laws


@pytest.mark.slow  # ~30 s CPU: a diagnosis with one step after the first
def test_a_misfit_of_form_buys_no_second_effect():
    """A 2X force growing like Omega^2 (e2 = 6e-6 kg m) and only the constant-amplitude law among the candidates:
    the constant law is added first and leaves a misfit of form (chi^2/dof ~12: the laws differ by a factor 2.9
    over 500-850 RPM). At the stated sigmas the next step took expansion_k2 for the part of that misfit it absorbs
    (Delta BIC -64, chi^2/dof 11.9 -> 10.4); judged at the remaining misfit (diagnosis, "the stop rule") it is not
    an effect, and the path stops at the right one, its misfit reported."""
    data = _data(["excitation_2x_inertial"], TRUTH | {"e2_c": 6e-6, "e2_s": -3e-6}, seed=8)
    result = _diagnose(_base_fit(data), _candidates(["excitation_2x", "slope_spring", "cross_coupled_stiffness",
                                                     "speed_damping", "expansion_k2"]))
    assert list(result.path_table()["effect"]) == ["excitation_2x"]
    final = result.path[-1].confirmation
    assert final.chi2 / final.dof > 3.0  # the premise: a misfit of form remains, far above the noise


@pytest.mark.slow  # ~25 s CPU: a diagnosis of two hidden effects
def test_a_weak_effect_below_sigmas_stated_too_large_is_still_found():
    """Sigmas stated 10 % too large (the right model then gives chi^2/dof ~0.83, as records whose floor is 0.85-0.9),
    a strong 2X force and a weak cross coupling (k_xy = 6 N/m: its chi^2 share, ~0.6 per dof at the stated sigmas,
    lies below the old stop at chi^2/dof 1.2 and above the data's own scale). The strong effect leaves chi^2/dof
    ~1.13: at the stated sigmas the path stopped there ("add excitation_2x"); judged at the data's scale it goes on
    and finds the weak one, inside its interval."""
    data = _data(["excitation_2x", "cross_coupled_stiffness"], TRUTH | {"f2_c": 0.1, "f2_s": -0.05, "k_xy": 6.0},
                 seed=11)
    data = [replace(d, sigma=1.1 * d.sigma) for d in data]
    result = _diagnose(_base_fit(data), _candidates(["excitation_2x", "cross_coupled_stiffness", "slope_spring",
                                                     "speed_damping"]))
    path = result.path_table()
    assert list(path["effect"]) == ["excitation_2x", "cross_coupled_stiffness"]
    assert 1.0 < path["chi2_dof_before"].iloc[1] < OPTIONS["misfit_ratio"]  # the premise: within the old stop
    assert result.summary["path"][1]["judged_at"] == pytest.approx(path["chi2_dof_before"].iloc[1], rel=0.05)
    k_xy = result.estimates().set_index("parameter").loc["k_xy"]
    assert k_xy["ci_low"] < 6.0 < k_xy["ci_high"]


def test_a_base_fit_in_another_basin_is_left_by_the_profile():
    """Lower bearing 60 % softer (dk_lo = -6000 N/m): the base compensates with its own parameters, the refit
    from the base optimum leans the wrong way (its widenings go towards stiffer) and stays at chi^2/dof ~1e6;
    the profile (dk_lo held on a grid across the default range widened both ways, the rest fitted at each point,
    then the best points freed) reaches the truth's basin."""
    data = _data(["lower_bearing_compliance"], TRUTH | {"dk_lo": -6000.0}, seed=7)
    base = _base_fit(data)
    scores = st.score_tests(base, _candidates(["lower_bearing_compliance"]))
    assert scores.base_chi2 / scores.base_dof > 1e4  # the premise: a base fit far from any valid linearisation
    cf = rf.confirm(base, scores.scores[0], scores, starts=7)
    assert cf.widened[0][2][1] > 2000.0  # the premise: the first widening went towards stiffer, away from the truth
    # chi^2/dof of a right model is 1 +- sqrt(2/dof) ~ 0.3 here (4 runs, H = 3: ~40 dof): 2 is far from the
    # 1e6 of the wrong basin and allows the noise
    assert cf.chi2 / cf.dof < 2.0
    row = cf.estimates.set_index("parameter").loc["dk_lo"]
    assert row["ci_low"] < -6000.0 < row["ci_high"]


def test_the_path_stops_when_no_quick_refit_comes_near_the_noise():
    """The forward selection's stop rule (diagnosis._out_of_reach): with chi^2 1000 on 100 dof, the drop to
    chi^2/dof = misfit_ratio (1.2) is 880; a best quick refit removing half of 880 / REACH stops the path and
    names that candidate (not the weaker one), one removing 880 / REACH lets it go on, and no refit never stops.
    Nor does a short step where a candidate among the ``thorough`` best by score stopped its quick refit at a range
    edge it could widen (its truth may lie beyond: the lower bearing 60 % softer on run-ups); one ranked below them
    does not keep the path going."""
    from types import SimpleNamespace

    def score(name, log_p):
        return SimpleNamespace(candidate=SimpleNamespace(name=name), log_p=log_p, statistic=-log_p)

    def refit(chi2, widenable=False):
        return SimpleNamespace(chi2=chi2, widenable=widenable)

    names = ["a", "b", "c", "d", "e"]
    scores = SimpleNamespace(base_chi2=1000.0, base_dof=100, scores=[score(n, -50.0 + i) for i, n in enumerate(names)])
    o = OPTIONS
    needed = 1000.0 - o["misfit_ratio"] * 100
    short, enough = 0.5 * needed / dg.REACH, needed / dg.REACH
    stop = dg._out_of_reach(scores, {"a": refit(1000.0 - short / 2), "b": refit(1000.0 - short)}, o)
    assert stop.startswith(f"the best remaining candidate, b, removes {short:.4g} of chi^2 1000")
    assert f"{needed:.4g} needed" in stop
    assert dg._out_of_reach(scores, {"b": refit(1000.0 - enough)}, o) == ""
    assert dg._out_of_reach(scores, {}, o) == ""
    assert o["thorough"] < len(names)
    within = names[o["thorough"] - 1]  # the last of the thorough best by score
    beyond = names[o["thorough"]]
    quick = {n: refit(1000.0 - short) for n in names}
    assert dg._out_of_reach(scores, quick | {within: refit(1000.0 - short / 4, widenable=True)}, o) == ""
    assert dg._out_of_reach(scores, quick | {beyond: refit(1000.0 - short / 4, widenable=True)}, o) != ""


def test_a_refit_whose_optimum_is_unstable_is_never_confirmed():
    """A refit with a huge likelihood ratio is confirmed, unless its optimum's steady state is unstable at some run
    (Floquet check, refit.confirm): then it is not, whatever its chi^2; not checked (None) or stable ([]) pass."""
    from types import SimpleNamespace

    o = OPTIONS
    cf = SimpleNamespace(lr_p_value=1e-30, delta_bic=-1e4, unstable_runs=None)
    assert conc.is_confirmed(cf, o, 1e-3)
    assert conc.is_confirmed(replace_ns(cf, unstable_runs=[]), o, 1e-3)
    assert not conc.is_confirmed(replace_ns(cf, unstable_runs=["r1000_m0p0"]), o, 1e-3)


def replace_ns(ns, **changes):
    from types import SimpleNamespace

    return SimpleNamespace(**(vars(ns) | changes))


def test_backward_elimination_drops_a_stand_in_made_redundant_by_a_later_effect(slope_base):
    """A path that took a stand-in first: cross-coupled stiffness (absent from the truth, which hides the slope
    force) refitted at the base, then expansion_k4 (the slope force's linear term) at base + stand-in, which
    fits to the noise. Backward elimination refits base + expansion_k4 from the final optimum: the stand-in is
    not needed (its removal costs less than the confirmation threshold), so it is dropped, and the path's last
    row is the refit without it, still at the noise (3 sigma of chi^2(dof)) with k4 where the full path had it."""
    scores = st.score_tests(slope_base, _candidates(["cross_coupled_stiffness", "expansion_k4"]))
    by_name = {s.candidate.name: s for s in scores.scores}
    stand_in = rf.confirm(slope_base, by_name["cross_coupled_stiffness"], scores, starts=0, widen=0, far=False)
    extended = st.BaseFit(st.extend(slope_base.variant, [stand_in.candidate], stand_in.ranges), stand_in.fit.layout,
                          stand_in.fit.theta, slope_base.data, slope_base.harmonics)
    step_scores = st.score_tests(extended, _candidates(["expansion_k4"]))
    k4 = rf.confirm(extended, step_scores.scores[0], step_scores, starts=0, widen=0, far=False)
    assert k4.chi2 / k4.dof < 1 + 3 * np.sqrt(2 / k4.dof)
    path = [conc.Step("cross_coupled_stiffness", 0.0, stand_in.chi2 / stand_in.dof, stand_in.delta_bic, 0.0, stand_in),
            conc.Step("expansion_k4", 0.0, k4.chi2 / k4.dof, k4.delta_bic, 0.0, k4)]
    placeholder = {s.candidate.name: (dg.CandidateVerdict.NOT_SIGNIFICANT, "") for s in scores.scores}
    result = conc.Diagnosis(conc._table(scores, {}, placeholder, []), "", "")
    kept = elim.backward_elimination(slope_base, path, scores, OPTIONS, result)
    assert [step.effect for step in kept] == ["expansion_k4"]
    final = kept[-1].confirmation
    assert final.chi2 / final.dof < 1 + 3 * np.sqrt(2 / final.dof)
    assert set(final.fit.layout.parameters) == set(slope_base.layout.parameters) | {"k4"}  # no k_xy left
    eliminated = result.summary["eliminated"]
    assert [e["effect"] for e in eliminated] == ["cross_coupled_stiffness"] and eliminated[0]["delta_bic"] > -10
    verdict = result.table.set_index("effect").loc["cross_coupled_stiffness", "verdict"]
    assert verdict.startswith("dropped by backward elimination: not needed once expansion_k4 is in")
    assert (result.table.set_index("effect").loc["cross_coupled_stiffness", "verdict_code"]
            == dg.CandidateVerdict.DROPPED)
    k4_full = k4.estimates.set_index("parameter").loc["k4"]
    k4_kept = final.estimates.set_index("parameter").loc["k4"]
    assert abs(k4_kept.value - k4_full.value) < 2 * (k4_full.ci_high - k4_full.ci_low) / 3.92 + 1e-9


def _one_step_path(base: st.BaseFit, name: str) -> tuple[list, st.Scores, conc.Diagnosis]:
    """The path of a diagnosis that took ``name`` and fits the noise: one thorough-enough refit at ``base``."""
    scores = st.score_tests(base, _candidates([name]))
    cf = rf.confirm(base, scores.scores[0], scores, starts=0, widen=0, far=False)
    path = [conc.Step(name, scores.base_chi2 / scores.base_dof, cf.chi2 / cf.dof, cf.delta_bic, 1.0, cf)]
    table = conc._table(scores, {}, {name: (dg.CandidateVerdict.NOT_SIGNIFICANT, "")}, [])
    return path, scores, conc.Diagnosis(table, "", "")


def test_the_sharing_check_shares_a_bow_the_data_do_not_need_per_run(slope_data):
    """Data with one bow for all runs, a base with the bow per run (the workflow's default) and the slope force
    found: the per-run bows buy nothing the shared one does not (likelihood ratio ~ chi^2(6) under "shared"), so
    the check shares them: the path's last step is the shared fit (no per-run entry, chi^2 within 3 sigma of
    chi^2(dof)), its k4 the truth's k_w within 10 % as with the shared base (the cubic part is small, see
    test_estimate_of_the_linear_slope_term_matches_the_truth), and the recommended variant says per_run: []."""
    base = _base_fit(slope_data, per_run=("q_x", "q_y"))
    path, scores, result = _one_step_path(base, "expansion_k4")
    assert path[-1].confirmation.fit.layout.local == ("q_x", "q_y")
    shared = elim.sharing_check(base, path, scores, OPTIONS, result)
    sharing = result.summary["sharing"]
    assert sharing["shared"] and sharing["lr_dof"] == 2 * (len(RUNS) - 1)
    assert sharing["chi2_shared"] >= sharing["chi2_per_run"] - 1e-6 * sharing["chi2_per_run"]  # nested fits
    final = shared[-1].confirmation
    assert final.fit.layout.local == () and final.chi2 == pytest.approx(sharing["chi2_shared"])
    assert final.chi2 / final.dof < 1 + 3 * np.sqrt(2 / final.dof)
    assert final.estimates.set_index("parameter").loc["k4", "value"] == pytest.approx(324.2, rel=0.1)
    # the step's share of the base's excess is the effect's, as the base was fitted (per run): the shared fit has
    # 2 (runs - 1) more dof and a higher chi^2, which is not a negative share
    assert shared[-1].share == path[-1].share
    result.path = shared
    conc.conclude_path(result, base, scores, OPTIONS)
    assert "need not be estimated per run" in result.conclusion
    assert "-" not in re.search(r"\((-?\d+) % of the excess", result.conclusion).group(1)
    spec = result.summary["recommended_variant"]["spec"]
    assert spec["per_run"] == [] and "per_run: []" in result.recommendation
    assert "per run (q_x, q_y)" in dgr._sharing_markdown(sharing) and "`per_run: []`" in dgr._sharing_markdown(sharing)
    Variant.from_spec(result.summary["recommended_variant"]["name"], spec)  # a valid config entry


def test_the_shared_fit_widens_a_range_its_estimate_runs_into(slope_data):
    """The per-run fit can end with a new effect's range too narrow for the shared fit (its bows traded off
    against the effect): the shared fit is started across the range and widened as a refit is. Here k4's range
    is cut to [0, 100] N, a third of the truth's k_w = 324.2 N: the shared fit must widen it past the truth and
    end inside it, at k_w within 10 % (test_estimate_of_the_linear_slope_term_matches_the_truth), and fit to the
    noise (chi^2 within 3 sigma of chi^2(dof))."""
    base = _base_fit(slope_data, per_run=("q_x", "q_y"))
    path, scores, _ = _one_step_path(base, "expansion_k4")
    k4 = path[-1].confirmation
    cf = rf.shared(base, [k4.candidate], {"k4": (0.0, 100.0)}, k4.fit, scores.base_chi2, scores.n_data)
    assert cf.ranges["k4"][1] > 324.2 and cf.widened and cf.widened[0][1] == (0.0, 100.0)
    estimate = cf.estimates.set_index("parameter").loc["k4"]
    assert not estimate["at_bound"] and estimate["value"] == pytest.approx(324.2, rel=0.1)
    assert cf.chi2 / cf.dof < 1 + 3 * np.sqrt(2 / cf.dof)


def test_the_sharing_check_keeps_a_bow_that_differs_between_runs():
    """The same, but the truth's bow differs between the two unbalance masses (q_x 0.002 at 25.9 g, 0.004 at
    14.8 g: a bow that the rig's mounting changed): one shared bow cannot fit both, the per-run values are
    needed and stay (the path unchanged, the recommended variant without per_run)."""
    truth = TRUTH | {"k_w": 324.2, "k_z": 301.1}
    heavy = _data(["slope_spring"], truth, seed=1)[:2]
    light = _data(["slope_spring"], truth | {"q_x": 0.004}, seed=2)[2:]
    base = _base_fit(heavy + light, per_run=("q_x", "q_y"))
    path, scores, result = _one_step_path(base, "expansion_k4")
    kept = elim.sharing_check(base, path, scores, OPTIONS, result)
    assert not result.summary["sharing"]["shared"] and result.summary["sharing"]["lr"] > 100
    assert kept[-1].confirmation is path[-1].confirmation


def test_a_recommended_variant_name_is_valid_in_the_config():
    """Effects placed at a bearing are named ``effect@bearing``; the recommended variant's name must pass the
    schema's pattern for variant names (read from the schema itself)."""
    import re
    from pathlib import Path

    import yaml

    schema = yaml.safe_load((Path(__file__).resolve().parents[1] / "src/hybridtwin/config.schema.yaml").read_text())
    pattern = schema["properties"]["variants"]["propertyNames"]["pattern"]
    name = rec.joined_variant_name(["linear", "bearing_anisotropy@b", "cross_coupled_stiffness"])
    assert name == "linear_bearing_anisotropy_at_b_cross_coupled_stiffness" and re.fullmatch(pattern, name)
    # an effect of the user's file may be named with other characters (oil-film_b): still a valid variant name
    name = rec.joined_variant_name(["linear", "oil-film_b", "k.2"])
    assert name == "linear_oil_film_b_k_2" and re.fullmatch(pattern, name)


def test_the_recommended_variants_yaml_reads_back_as_numbers():
    """The "What to do" lines are pasted under ``variants:``: every range end and fixed value must read back as the
    number it was (to the 6 digits printed), large and small ones too. Python's ``f"{3e7:g}"`` is "3e+07", which
    YAML 1.1 (PyYAML, Snakemake's loader) reads as a string, and the config check then rejected the pasted
    variant; the schema's own type check is applied here."""
    from pathlib import Path

    import jsonschema
    import yaml

    spec = {"description": "linear + bearing_anisotropy@b: stiffness along x minus the mean at bearing b",
            "effects": ["linear_bearing@a", "bearing_anisotropy@b"],
            "unknown": {"k_a": [1.5e7, 3e7], "dk_b": [-2e6, 2e6], "c_a": [400.0, 1600.0], "zeta": [0.01, 0.05],
                        "tiny": [1e-5, 2.5e-4], "k": [0.0, 1000.0]},
            "fixed": {"q": 1e-5, "big": -1.23456e12}}
    read = yaml.safe_load("variants:\n" + rec.variant_lines("v", spec))["variants"]["v"]
    for section in ("unknown", "fixed"):
        for name, value in spec[section].items():
            assert not isinstance(read[section][name], str), (section, name, read[section][name])
            np.testing.assert_allclose(read[section][name], value, rtol=5e-6)
    schema = yaml.safe_load((Path(__file__).resolve().parents[1] / "src/hybridtwin/config.schema.yaml").read_text())
    variant_schema = schema["properties"]["variants"]["additionalProperties"]
    jsonschema.validate(read, {**variant_schema, "definitions": schema.get("definitions", {}),
                               "$defs": schema.get("$defs", {})})
    assert [rec.yaml_number(x) for x in (3e7, -2e6, 2000.0, 0.05, 1e-5)] == ["3.0e+07", "-2.0e+06", "2000", "0.05",
                                                                          "1.0e-05"]


@pytest.mark.parametrize("value, low, high", [(1200005.31, 1199927.44, 1200083.19), (324.0, 323.4, 324.6),
                                              (-5998.0, -5999.5, -5996.5), (0.197, 0.192, 0.202)])
def test_an_estimates_text_shows_its_interval(value, low, high):
    """The printed interval's ends differ from each other and from the value (a narrow interval around a large
    value printed to 4 digits read "1.2e+06 [1.2e+06, 1.2e+06]"), with 4 significant digits at least."""
    d = conc._digits(value, high - low)
    texts = [f"{x:.{d}g}" for x in (low, value, high)]
    assert len(set(texts)) == 3 and d >= 4


def test_a_plan_too_thin_to_decide_says_so_instead_of_no_missing_effect():
    """One fit run (12 numbers for 5 parameters and a phase) holding the hidden slope force: the base fit absorbs
    it (its chi^2 is within the noise), and no candidate is significant: the conclusion must not read as a clean
    bill ("no missing effect"), but say these runs cannot rule one out, and why (the degrees of freedom; a
    parameter the fit leaves undetermined, from the parameter table's flags)."""
    values = TRUTH | {"k_w": 324.2, "k_z": 301.1}
    data = _data(["slope_spring"], values, seed=5)[:1]
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["slope_spring", "expansion_k4"]))
    assert not result.summary["misfit"] and result.summary["base_dof"] < conc.MIN_DOF
    assert result.conclusion.startswith("no missing effect found, but these fit runs cannot rule one out")
    assert f"only {result.summary['base_dof']} degrees of freedom" in result.conclusion
    assert "only 1 fit run;" in result.conclusion
    # four runs at 500-850 RPM: enough to decide, no such caveat (test_no_false_alarm_without_a_hidden_effect)
    four = _base_fit(_data([], TRUTH, seed=3))
    assert conc._thin_plan(four, st.score_tests(four, _candidates(["expansion_k4"]))) == []
    table = pd.DataFrame({"parameter": ["k_b", "zeta_s", "q_x", "q_x", "phase"], "run": ["all", "all", "a", "b", "a"],
                          "kind": ["shared", "shared", "per_run", "per_run", "nuisance"],
                          "identifiable": [False, True, True, True, False],
                          "at_bound": [False, True, "False", "True", False]})
    assert st.undetermined_parameters(table) == ("k_b (not identifiable)", "zeta_s (at a range edge)",
                                                 "q_x (at a range edge)")


def _stand_in_then_k4(base: st.BaseFit) -> tuple[st.Scores, dict, list]:
    """A forward path that took a stand-in first (as in test_backward_elimination_drops_a_stand_in_made_redundant_by
    _a_later_effect): cross-coupled stiffness refitted at ``base``, then expansion_k4 at base + stand-in."""
    scores = st.score_tests(base, _candidates(["cross_coupled_stiffness", "expansion_k4"]))
    by_name = {s.candidate.name: s for s in scores.scores}
    stand_in = rf.confirm(base, by_name["cross_coupled_stiffness"], scores, starts=0, widen=0, far=False)
    extended = st.BaseFit(st.extend(base.variant, [stand_in.candidate], stand_in.ranges), stand_in.fit.layout,
                          stand_in.fit.theta, base.data, base.harmonics)
    k4 = rf.confirm(extended, st.score_tests(extended, _candidates(["expansion_k4"])).scores[0],
                    st.score_tests(extended, _candidates(["expansion_k4"])), starts=0, widen=0, far=False)
    excess = conc.score_excess(scores)
    path = [conc.Step("cross_coupled_stiffness", scores.base_chi2 / scores.base_dof, stand_in.chi2 / stand_in.dof,
                    stand_in.delta_bic, (scores.base_chi2 - stand_in.chi2) / excess, stand_in),
            conc.Step("expansion_k4", stand_in.chi2 / stand_in.dof, k4.chi2 / k4.dof, k4.delta_bic,
                    (scores.base_chi2 - k4.chi2) / excess, k4)]
    return scores, {"cross_coupled_stiffness": stand_in}, path


@pytest.fixture(scope="module")
def every_path(slope_data, slope_base):
    """A Diagnosis from each way the diagnosis can end, by its own code (``diagnose``, or its tail
    ``diagnosis._finish`` on a path built here where the full loop would not take that path on these data)."""
    out = {}
    scores, confirmations, path = _stand_in_then_k4(slope_base)
    alpha = OPTIONS["alpha"] / len(scores.scores)
    data = _data(["slope_spring", "excitation_2x"], TRUTH | {"k_w": 324.2, "k_z": 301.1, "f2_c": 0.1, "f2_s": -0.05},
                 seed=7)  # as test_two_hidden_effects_are_both_found_by_forward_selection
    out["forward"] = _diagnose(_base_fit(data), _candidates(["slope_spring", "excitation_2x"]))
    first = conc.conclude_first_step(slope_base, scores, confirmations, OPTIONS, alpha)
    out["backward elimination"] = dg._finish(first, slope_base, scores, list(path), OPTIONS)
    tilt = PolynomialBearing(name="tilt_force", meaning="force on the shaft tilt (a user's duplicate of k4 u')",
                             parameters=(Parameter("k_t", "N", (-1000.0, 1000.0), 0.0, "tilt stiffness"),),
                             terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), "k_t u'"),))
    out["confounded"] = _diagnose(slope_base, _candidates(["expansion_k4"]) + [Candidate(tilt, ("k_t",))])
    per_run = _base_fit(slope_data, per_run=("q_x", "q_y"))
    one, scores, result = _one_step_path(per_run, "expansion_k4")
    result = conc.conclude_first_step(per_run, scores, {"expansion_k4": one[0].confirmation}, OPTIONS, OPTIONS["alpha"])
    out["sharing"] = dg._finish(result, per_run, scores, one, OPTIONS)
    data = _data(["excitation_3x"], TRUTH | {"f3_c": 0.3, "f3_s": -0.2}, seed=4)
    out["unexplained"] = _diagnose(_base_fit(data), _candidates(["cross_coupled_stiffness", "speed_damping"]))
    return out


def _not_plain(value, where="summary") -> list[str]:
    """Where ``value`` holds anything but dict (str keys), list, str, int, float, bool or None (exact types)."""
    if isinstance(value, dict):
        return [f"{where}: key {k!r}" for k in value if type(k) is not str] + \
            [w for k, v in value.items() for w in _not_plain(v, f"{where}.{k}")]
    if type(value) is list:
        return [w for i, v in enumerate(value) for w in _not_plain(v, f"{where}[{i}]")]
    return [] if value is None or type(value) in (str, int, float, bool) else [f"{where}: {type(value).__name__}"]


def _same(a, b) -> bool:
    """Equal, NaN equal to NaN (a summary read back from YAML)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return True
    return a == b and type(a) is type(b)


PATHS = ["forward", "backward elimination", "confounded", "sharing", "unexplained"]


@pytest.mark.slow  # the module fixture every_path runs five diagnoses: ~35 s CPU
@pytest.mark.parametrize("path", PATHS)
def test_every_path_builds_its_summary_from_plain_types(every_path, path):
    """Each way the diagnosis ends (it did end each way: checked first) leaves a summary of plain Python types at
    the source, before any writer: on the backward-elimination path a numpy float (Delta BIC of keeping the dropped
    effect) reached yaml.safe_dump and the workflow died writing diagnosis.yaml."""
    result = every_path[path]
    s = result.summary
    took = {"forward": len(result.path) == 2 and not s.get("eliminated"),
            "backward elimination": [e["effect"] for e in s.get("eliminated", [])] == ["cross_coupled_stiffness"],
            "confounded": bool(s["confounded"]) and "cannot tell them apart" in result.conclusion,
            "sharing": bool(s.get("sharing", {}).get("shared")),
            "unexplained": result.conclusion.startswith("unexplained")}
    assert took[path], (path, result.conclusion)
    assert _not_plain(s) == []


@pytest.mark.slow  # the module fixture every_path runs five diagnoses: ~35 s CPU
@pytest.mark.parametrize("path", PATHS)
def test_every_diagnosis_output_reads_back(every_path, path, tmp_path):
    """diagnosis.yaml, .tsv and .md as the workflow writes them (diagnosis_report.write), read back: the YAML
    equals the summary (plain types, NaN as NaN), the TSV the table (numbers to the 6 digits written: relative
    5e-6 at most, 1e-5 allowed), the Markdown holds the conclusion and no nan or numpy repr."""
    result = every_path[path]
    files = [tmp_path / name for name in ("diagnosis.tsv", "diagnosis.md", "diagnosis.yaml")]
    dgr.write(result, *files)
    read = dgr.read_diagnosis_summary(files[2])  # the writer's inverse (what report_summary reads)
    assert _same(read, result.summary)
    table = pd.read_csv(files[0], sep="\t")
    assert list(table.columns) == list(result.table.columns)
    for column in result.table:
        if pd.api.types.is_numeric_dtype(result.table[column]) and not pd.api.types.is_bool_dtype(result.table[column]):
            np.testing.assert_allclose(table[column], result.table[column].astype(float), rtol=1e-5, equal_nan=True)
        else:
            written = table[column].astype(object).where(table[column].notna(), "")
            assert written.astype(str).tolist() == result.table[column].astype(str).tolist()
    markdown = files[1].read_text()
    assert result.conclusion in markdown and "nan" not in markdown and "np." not in markdown


@pytest.mark.slow  # the module fixture every_path runs five diagnoses: ~35 s CPU
def test_the_writer_converts_a_stray_numpy_number_and_names_what_it_cannot(every_path, tmp_path):
    """The writer's safety net: a numpy number left in the summary is written as a number; an object that is no
    number is refused with the file and the key."""
    import yaml

    result = every_path["unexplained"]
    files = [tmp_path / name for name in ("d.tsv", "d.md", "d.yaml")]
    saved = dict(result.summary)
    try:
        result.summary["stray"] = {"x": np.float64(6.106), "n": np.int64(3), "pair": (np.float32(0.5), 1)}
        dgr.write(result, *files)
        assert yaml.safe_load(files[2].read_text())["stray"] == {"x": 6.106, "n": 3, "pair": [0.5, 1]}
        result.summary["stray"] = {"x": object()}
        with pytest.raises(ValueError, match=r"d\.yaml.*summary\.stray\.x is a object"):
            dgr.write(result, *files)
    finally:
        result.summary.clear()
        result.summary.update(saved)


# issue 36's cases on time-integrated rig records (a truth beyond its candidate's range; two effects of another
# form than their candidates'): tests/test_diagnosis_rig.py


def test_a_negligible_step_needs_both_a_tiny_estimate_and_a_tiny_share():
    """diagnosis_status.negligible_step: a cross-coupled damping of 0.02 N s/m (0.4 % of its +-5 range) whose
    chi^2 drop is 5e-7 of the base's excess is negligible (the issue's third step); the same drop with 1 N s/m
    (20 % of the range: a real damping) is not, nor 0.02 N s/m removing 1 % of the excess."""
    from types import SimpleNamespace

    from hybridtwin.diagnose import diagnosis_status as ds

    c_xy = _candidates(["cross_coupled_damping"])[0]

    def step(value, drop, excess=1.2e8):
        cf = SimpleNamespace(candidate=c_xy, chi2=1e4 - drop,
                             estimates=pd.DataFrame({"parameter": ["c_xy"], "value": [value]}))
        return ds.negligible_step(cf, 1e4, excess)

    found = step(0.02, 57.0)
    assert found["effect"] == "cross_coupled_damping"
    assert found["estimate_fraction_of_range"] == pytest.approx(0.02 / 5.0)
    assert found["share_of_excess"] == pytest.approx(57.0 / 1.2e8)
    assert step(-0.02, 57.0) is not None  # the size is a magnitude
    assert step(1.0, 57.0) is None  # a real damping, however little it removes
    assert step(0.02, 1200.0, excess=1.2e5) is None  # 1 % of the excess: not negligible, however small


def test_a_status_is_a_code_and_the_conclusion_opens_from_it():
    from hybridtwin.diagnose.diagnosis_status import OPENINGS, Status, opening

    assert set(OPENINGS) == set(Status)  # every code has its sentence
    text = opening(Status.ADD_NEARLY, effects="a and b", they="together they", share="99.96 %", after="1.41")
    assert text.startswith("add a and b: together they carry the discrepancy (99.96 % of the excess chi^2)")
    assert "not among the candidates" not in text and Status("add_nearly") is Status.ADD_NEARLY


@pytest.mark.slow  # ~15 s CPU: a diagnosis of two hidden effects
def test_the_forward_selection_does_not_take_a_negligible_step(monkeypatch):
    """The rule's wiring in the forward selection, with its thresholds loosened so that any step counts as
    negligible (the rule itself: test_a_negligible_step_needs_both_a_tiny_estimate_and_a_tiny_share): on the data
    of test_two_hidden_effects_are_both_found_by_forward_selection, step 2 is then not taken; the path keeps step
    1 alone, the summary says which step was refused and why, and that candidate's verdict says it."""
    from hybridtwin.diagnose import diagnosis_status as ds

    monkeypatch.setattr(ds, "NEGLIGIBLE_FRACTION", np.inf)
    monkeypatch.setattr(ds, "NEGLIGIBLE_SHARE", np.inf)
    data = _data(["slope_spring", "excitation_2x"], TRUTH | {"k_w": 324.2, "k_z": 301.1, "f2_c": 0.1,
                                                             "f2_s": -0.05}, seed=7)
    result = _diagnose(_base_fit(data), _candidates(["slope_spring", "excitation_2x"]))
    assert len(result.path) == 1
    refused = result.summary["negligible_step"]
    assert refused["effect"] in {"slope_spring", "excitation_2x"} - {result.path[0].effect}
    assert refused["chi2_after"] < refused["chi2_before"]
    verdict = result.table.set_index("effect").loc[refused["effect"], "verdict"]
    assert verdict.startswith("not added at step 2: negligible")
    assert result.table.set_index("effect").loc[refused["effect"], "verdict_code"] == dg.CandidateVerdict.NEGLIGIBLE
    assert result.status is ds.Status.UNEXPLAINED  # step 1 alone leaves a misfit it cannot call small


def test_intervals_grow_with_the_misfit_and_the_report_says_when_they_may_be_optimistic():
    """uncertainty.analyse_uncertainty scales the covariance by chi^2/dof when that exceeds 1 (never below 1):
    on a linear problem the standard errors are sqrt(diag((J^T J)^-1)) (the independent reference, to rounding)
    times sqrt(max(1, chi^2/dof)). diagnosis_status.interval_note flags a significant chi^2 (at alpha) as a misfit
    that can make them optimistic, and the report's paragraph appears only then."""
    from types import SimpleNamespace

    from hybridtwin.diagnose.diagnosis_status import interval_note

    rng = np.random.default_rng(3)
    J = rng.standard_normal((40, 2))
    layout = SimpleNamespace(n=2, entries=lambda: [("a", "all"), ("b", "all")], is_phase=np.zeros(2, bool),
                             scale=lambda: np.ones(2), bounds=lambda: (np.full(2, -1.0), np.full(2, 1.0)))
    reference = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    for chi2_dof in (0.5, 1.0, 4.0):
        r = rng.standard_normal(40)
        r *= np.sqrt(chi2_dof * 38 / (r @ r))  # chi^2 / (40 - 2) = chi2_dof
        u = unc.analyse_uncertainty(J, r, np.zeros(2), layout)
        np.testing.assert_allclose(u.stderr, reference * np.sqrt(max(1.0, chi2_dof)), rtol=1e-9)
    misfit, noise = interval_note(300.0, 40, 0.01), interval_note(45.0, 40, 0.01)
    assert misfit["optimistic"] and misfit["scaled_by"] == pytest.approx(np.sqrt(7.5))
    assert not noise["optimistic"] and noise["scaled_by"] == pytest.approx(np.sqrt(45 / 40))
    assert "may be optimistic" in dgr._intervals_markdown(misfit) and dgr._intervals_markdown(noise) == ""


def test_what_to_do_names_the_project_it_was_run_in():
    """The recommendation names the config, command and ledger of the project: the root's by default, a project's
    run with --directory DIR (the workflow's project_place, common.smk) DIR's (issue 39: it named the root's)."""
    spec = {"description": "a test", "effects": ["unbalance"], "unknown": {"k_b": [2000, 3500]}}
    root = rec.what_to_do("v", spec, OPTIONS)
    assert "in config/config.yaml, then run `snakemake --cores 2` " in root and "results/ledger.tsv:" in root
    place = {"config": "examples/quick/config/config.yaml", "command": "snakemake --cores 2 --directory examples/quick",
             "ledger": "examples/quick/results/ledger.tsv"}
    text = rec.what_to_do("v", spec, OPTIONS | {"project": place})
    assert all(f"{value}" in text for value in place.values()) and "in config/config.yaml" not in text
    assert "  v:\n" in text  # the variant to paste follows


def test_what_to_do_sizes_the_new_variants_libraries_like_its_parents():
    """Where the config sizes the parent's libraries under `offline: n_scenarios:` (issue 39, item 4), the
    recommendation says what to add there for the new variant (the parent's share of its default: the README's quick
    overlay, geometric 500 -> geometric_expansion_k4 900), so that pasting it builds the variant as intended; nothing
    about scenarios where the parent has no entry (the default for both) or where there are no libraries (scope
    none, the fits on the full solver)."""
    parent = variants.builtin_variant("geometric")
    spec = rec.variant_spec(parent, builtin_candidates()["expansion_k4"])
    sized = OPTIONS | {"offline": {"scope": "run", "n_scenarios": {"geometric": 500}}}
    text = rec.what_to_do("geometric_expansion_k4", spec, sized, parent)
    assert "`offline: n_scenarios:`" in text and "`geometric_expansion_k4: 900`" in text
    assert "beside geometric: 500" in text and "default, 1800, which it takes otherwise" in text
    assert rec.scenarios_entry(spec, parent, sized | {"offline": {"scope": "global", "n_scenarios": {"geometric": 2000}}}
                               ) == 3600
    plain_text = rec.what_to_do("geometric_expansion_k4", spec, OPTIONS, parent)
    assert "n_scenarios" not in plain_text
    assert plain_text == rec.what_to_do("geometric_expansion_k4", spec, OPTIONS)
    for o in (sized | {"offline": {"scope": "none", "n_scenarios": {"geometric": 500}}},
              sized | {"offline": {"scope": "run", "n_scenarios": {"expansion": 500}}}):
        assert rec.what_to_do("geometric_expansion_k4", spec, o, parent) == plain_text
    # in diagnosis.md the lines to paste stay one fenced YAML block at the end, after the sentence
    columns = ["rank", "effect", "statistic", "p_value", "predicted_error_drop_pct", "confirmed_chi2_dof", "delta_bic",
               "estimate", "verdict"]
    summary = {"variant": "geometric", "runs": ["r1", "r2"], "n_data": 8, "base_chi2_dof": 40.0,
               "base_gof_p_value": 0.0, "candidates": [], "refitted": []}
    md = dgr.markdown(conc.Diagnosis(pd.DataFrame(columns=columns), "add expansion_k4", text, summary))
    assert md.count("```yaml\n  geometric_expansion_k4:\n") == 1 and "900`" in md.split("```yaml")[0]
