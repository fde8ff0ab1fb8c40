"""Contracts between stages (issue 37, part 2): no decision taken on an English sentence.

Code that acts on a verdict, a status or a failure reads a code (an enum value, a code column), never the sentence
written for people: changing a word must not change behaviour. ``test_no_branch_on_prose`` reads the source (ast)
of the package, the rule scripts and the workflow's Python and refuses a test of a prose-named value (message,
verdict, conclusion, note, ...) against text: ``.startswith``/``.endswith``/``.contains``, ``"..." in message``,
``note == "ok"``. The other tests check each decision that was converted reads its code.
"""

import ast
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "src" / "hybridtwin", ROOT / "scripts", ROOT / "workflow"]
#: names whose values are sentences for people (a code column is named otherwise: status, reason, verdict_code,
#: explanation, outcome, flags)
PROSE = {"message", "messages", "verdict", "verdicts", "conclusion", "note", "notes", "explanation_note",
         "recommendation", "summary_text"}
#: the one place left, with why: snapshot stores written before their ``solved`` code array marked an enrichment
#: scenario not solved at a run only by the NOT_SOLVED prefix of its message; such stores are still read (only there)
ALLOWED = {("src/hybridtwin/offline/snapshots.py", "_solved_from_messages")}


def _names(node: ast.AST, prose: set[str] = PROSE) -> set[str]:
    """The prose-looking names an expression reads: variables, attributes, subscripts by a string key."""
    out = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name):
            out.add(sub.id)
        elif isinstance(sub, ast.Attribute):
            out.add(sub.attr)
        elif isinstance(sub, ast.Subscript) and isinstance(sub.slice, ast.Constant) and isinstance(
                sub.slice.value, str):
            out.add(sub.slice.value)
    return out & prose


def _is_text(node: ast.AST) -> bool:
    return isinstance(node, (ast.Constant, ast.JoinedStr)) and (not isinstance(node, ast.Constant)
                                                                or isinstance(node.value, str))


def _branches(tree: ast.AST) -> list[tuple[int, str, str]]:
    """(line, enclosing function, the expression) of every test of prose against text in ``tree``."""
    found = []
    # a loop variable over prose is prose too (``for v in table["verdict"]``)
    prose = set(PROSE)
    for node in ast.walk(tree):
        if isinstance(node, (ast.comprehension, ast.For)) and _names(node.iter):
            prose |= {n.id for n in ast.walk(node.target) if isinstance(n, ast.Name)}

    def reads(node: ast.AST) -> set[str]:
        return _names(node, prose)

    def visit(node: ast.AST, function: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function
            if isinstance(child, ast.Call) and isinstance(child.func, ast.Attribute) and child.func.attr in (
                    "startswith", "endswith", "contains", "match"):
                receiver = target = child.func.value
                if ast.unparse(receiver) in ("np.char", "numpy.char", "char") and child.args:
                    target = child.args[0]  # np.char.startswith(message, ...)
                if reads(target):
                    found.append((child.lineno, name, ast.unparse(child)))
            elif isinstance(child, ast.Compare):
                sides = [child.left, *child.comparators]
                for op, left, right in zip(child.ops, sides, sides[1:]):
                    if isinstance(op, (ast.In, ast.NotIn)) and _is_text(left) and reads(right):
                        found.append((child.lineno, name, ast.unparse(child)))
                    elif isinstance(op, (ast.Eq, ast.NotEq)) and (
                            _is_text(right) and reads(left) or _is_text(left) and reads(right)):
                        found.append((child.lineno, name, ast.unparse(child)))
            visit(child, name)

    visit(tree, "")
    return found


def _python_files():
    for base in SOURCES:
        yield from sorted(base.rglob("*.py"))


def test_no_branch_on_prose():
    problems = []
    for path in _python_files():
        rel = path.relative_to(ROOT).as_posix()
        for line, function, text in _branches(ast.parse(path.read_text(), str(path))):
            if (rel, function) not in ALLOWED:
                problems.append(f"{rel}:{line} ({function}): {text}")
    assert not problems, "decisions on sentences (read a code instead):\n" + "\n".join(problems)


def test_the_check_finds_what_it_is_for():
    """The check itself: each shape of a branch on prose is found, a code column is not."""
    src = '''
def f(fit, failures, note, t, row):
    a = fit.message.startswith("unstable")
    b = failures["message"].str.startswith("unstable")
    c = ["x" for v in t["verdict"] if "confounded" in v]
    d = note == "ok"
    e = np.char.startswith(fit.message, "not solved")
    ok = failures["reason"] == "unstable" or row.status == "used" or row.explanation in {"bow_law"}
'''
    found = _branches(ast.parse(src))
    assert [line for line, _, _ in found] == [3, 4, 5, 6, 7], found


def test_diagnosis_verdict_codes():
    """Every verdict code has its sentence and a colour; the figure's colours follow the code column (the sentence
    of each code as it was, e.g. "add: explains ..." green, "... (confounded with X)" on the best orange)."""
    from hybridtwin.diagnose.diagnosis_status import CandidateVerdict, verdict_colour, verdict_text

    for code in CandidateVerdict:
        assert verdict_text(code, pct=50, tied="", others="a", with_="", share="99 %", best="b", bic=1.0,
                            best_bic=0.5, inside="c", runs="r1", step=2, fraction=0.1, drop=1e-5, verb="is", lr=1.0)
    assert verdict_text(CandidateVerdict.ADD) == "add: explains the discrepancy"
    assert verdict_text(CandidateVerdict.ADD_PART, pct=62.4, tied=" (confounded with x)") == (
        "add: explains 62 % of the excess chi^2; a discrepancy remains (confounded with x)")
    assert verdict_text(CandidateVerdict.CONFOUNDED, best="k", bic=-12.34, best_bic=-13.0) == (
        "confounded with k: these data cannot tell them apart (Delta BIC -12.3 vs -13.0)")
    colours = {code: verdict_colour(code.value) for code in CandidateVerdict}
    assert {c for c, colour in colours.items() if colour == "tab:green"} == {
        CandidateVerdict.ADD, CandidateVerdict.ADD_PART, CandidateVerdict.ADD_WITH, CandidateVerdict.ADD_NEARLY}
    assert {c for c, colour in colours.items() if colour == "tab:red"} == {CandidateVerdict.CONFIRMED_WEAKER,
                                                                          CandidateVerdict.SIGNIFICANT}
    assert colours[CandidateVerdict.EXPLAINS_ONLY_TIED] == "tab:orange"
    assert colours[CandidateVerdict.EXPLAINS_ONLY] == "tab:gray"
    # the old rule on the sentences, for every sentence: the code's colour is the one the sentence had
    for code in CandidateVerdict:
        tied = " (confounded with z)" if code is CandidateVerdict.EXPLAINS_ONLY_TIED else ""
        v = verdict_text(code, pct=40, tied=tied,
                         others="a", with_="", share="99 %", best="b", bic=1.0, best_bic=0.5, inside="c", runs="r1",
                         step=2, fraction=0.1, drop=1e-5, verb="is", lr=1.0)
        old = ("tab:green" if v.startswith("add") else "tab:orange" if "confounded" in v or "part of" in v
               or "contains" in v else "tab:red" if "significant," in v or "confirmed," in v else "tab:gray")
        assert verdict_colour(code.value) == old, (code, v)


def test_snapshot_failures_reason():
    """failures.tsv's reason: "unstable" exactly where the solver's message says so (a converged point with a
    Floquet multiplier outside the unit circle), "failed" where no periodic solution was found."""
    from hybridtwin.offline.snapshots import FAILED, UNSTABLE, Snapshots

    success = np.array([[True, True, False, True]])
    radius = np.array([[0.5, 1.2, np.nan, np.nan]])
    message = np.array([["converged", "unstable periodic solution: ...", "no periodic solution found", "converged"]],
                       object)
    snaps = Snapshots("v", ["r"], [1000.0], [0.0], ["k"], np.arange(4), np.array(["train"] * 4, object),
                      np.zeros((4, 1)), np.zeros((1, 4, 2, 2)), success, message, np.full((1, 4), "direct", object),
                      success & (np.nan_to_num(radius, nan=np.inf) < 1), radius)
    failures = snaps.failures()
    assert failures["scenario"].tolist() == [1, 2, 3]
    assert failures["reason"].tolist() == [UNSTABLE, FAILED, FAILED]
    assert ((failures["reason"] == UNSTABLE) == failures["message"].str.startswith("unstable")).all()


def test_band_outcome_codes():
    """A band's saturated and usable columns follow its outcome code, not its note's wording."""
    from hybridtwin.data import transient

    row = transient.band_row(None, ["x"], 1, "anything at all", 1000.0, "m", 1e-4, transient.BAND_CLIPPED)
    assert row["saturated"] and not row["usable"]
    row = transient.band_row(None, ["x"], 1, "clipped: 3 samples", 1000.0, "m", 1e-4, transient.BAND_NOT_REACHED)
    assert not row["saturated"] and not row["usable"]


@pytest.mark.parametrize("first", [True, False])
def test_stability_prefix_once(first, monkeypatch):
    """check_stability says "unstable steady state" once per fit, by the fit's unstable_runs, whatever its message
    already says."""
    from hybridtwin.identify import forward

    class Check:
        unstable_runs = ["r2"]

        def note(self):
            return "r2 is unstable"

    class Uncertainty:
        notes: list = []

    class Fit:
        message = "unstable steady state is a phrase" if first else "converged"
        unstable_runs = ()
        uncertainty = Uncertainty()

    fit = Fit()
    fit.uncertainty.notes = []
    monkeypatch.setattr(forward, "floquet_radii", lambda models, xs: [None])
    monkeypatch.setattr(forward, "StabilityCheck", lambda runs, radii: Check())
    model = object.__new__(forward.SolverModel)
    fit.problem = type("P", (), {"models": [model]})()
    fit.theta = np.zeros(1)
    fit.layout = type("L", (), {"runs": ["r2"], "n_runs": 1, "run_parameters": lambda self, t, k: [t[0]]})()
    with pytest.warns(forward.StabilityWarning):
        forward.check_stability(fit)
    before = fit.message
    assert before.startswith("unstable steady state at run(s) r2; ") and fit.unstable_runs == ("r2",)
    with pytest.warns(forward.StabilityWarning):
        forward.check_stability(fit)
    assert fit.message == before  # not said twice


def test_table_has_verdict_code_column():
    """diagnosis.tsv carries verdict_code beside verdict (written by diagnosis_report.write)."""
    import inspect

    from hybridtwin.diagnose import conclusion, diagnosis

    assert '"verdict_code"' in inspect.getsource(conclusion._table)
    assert pd.Series([v.value for v in diagnosis.CandidateVerdict]).is_unique


# --- one contract per table between rules: each writer's output read back by its reader ---------------------------


def _round_trip(write, read, table, tmp_path, name):
    """read(write(t)) is a fixed point after the first pass (the writer's digits), dtypes included."""
    first = tmp_path / f"{name}_1.tsv"
    write(table, first)
    once = read(first)
    second = tmp_path / f"{name}_2.tsv"
    write(once, second)
    twice = read(second)
    pd.testing.assert_frame_equal(once, twice, check_dtype=True)
    third = tmp_path / f"{name}_3.tsv"
    write(twice, third)
    assert second.read_text() == third.read_text()
    return once


def test_harmonics_table_round_trip(tmp_path):
    from hybridtwin.data import measured

    table = pd.DataFrame({"run": ["001", "r2"], "rpm": [1000.0, 1200.5], "rpm_true": [1000.25, np.nan],
                          "usable": [True, False], "keyphasor": [True, False], "flat": [False, False],
                          "note": ["ok", "flat: no signal"], "x1_re_m": [1.23456789012e-6, -2e-7]})
    out = _round_trip(measured.write_harmonics, measured.read_harmonics, table, tmp_path, "harmonics")
    assert out["run"].tolist() == ["001", "r2"]
    assert out["usable"].dtype == bool and out["keyphasor"].tolist() == [True, False]
    np.testing.assert_allclose(out["x1_re_m"], table["x1_re_m"], rtol=1e-9)
    assert measured.kept_out(out)["run"].tolist() == ["r2"]
    # the true/false columns, read one way: text, numbers or bools; empty is false
    assert measured.flags(pd.Series([True, "False", "true", "1", 0, np.nan, "", " TRUE "])).tolist() == [
        True, False, True, True, False, False, False, True]


def test_parameter_table_round_trip(tmp_path):
    from hybridtwin.identify import identification as idn

    table = pd.DataFrame({"parameter": ["k_b", "q_x", "phase"], "run": ["all", "001", "001"],
                          "kind": ["shared", "per_run", "nuisance"], "unit": ["N/m", "1", ""],
                          "value": [1.5e6, 2.25e-5, 0.1], "stderr": [1e3, np.nan, 0.01],
                          "at_bound": [False, True, False], "identifiable": [True, True, True],
                          "lower": [1e5, -1e-4, -np.pi], "upper": [1e7, 1e-4, np.pi], "source": ["solver"] * 3})
    out = _round_trip(idn.write_parameters, idn.read_parameters, table, tmp_path, "parameters")
    assert out["run"].tolist() == ["all", "001", "001"] and out["unit"].tolist() == ["N/m", "1", ""]
    assert out["value"].dtype == float and out["at_bound"].dtype == bool


def test_validation_table_round_trip(tmp_path):
    from hybridtwin.identify import validation_refit as vr

    rows = [{"run": "007", "rpm": 900.0, "eccentric_mass_g": 25.9, "model": "solver", "error_rel": 0.125,
             "chi2_per_residual": 3.5, "note": "ok", "beyond_noise": True, "explanation": "not_pinned",
             "explanation_note": "the fit runs do not pin k_b; this run does", "pinned": "k_b,zeta"},
            {"run": "008", "rpm": 950.0, "eccentric_mass_g": 25.9, "model": "none", "note": "flat",
             "explanation": "not_checked"}]
    out = _round_trip(vr.write_validation, vr.read_validation, pd.DataFrame(rows), tmp_path, "validation")
    assert list(out.columns[:7]) == vr.VALIDATION_TABLE[:7] and set(vr.VALIDATION_TABLE) <= set(out.columns)
    assert out["run"].tolist() == ["007", "008"] and out["pinned"].tolist() == ["k_b,zeta", ""]
    assert out["beyond_noise"].tolist() == [True, False] and np.isnan(out.loc[1, "error_rel"])


def test_error_ledger_comparison_and_library_tables_round_trip(tmp_path):
    from hybridtwin.offline import library
    from hybridtwin.report import report

    errors = pd.DataFrame({"run": ["001", "r2"], "rpm": [1000.0, 1100.0], "eccentric_mass_g": [25.9, 0.0],
                           "role": ["fit", "validate"], "source": ["solver", "solver"], "chi2": [40.5, 120.0],
                           "dof": [32.0, 32.0], "chi2_dof": [1.265625, 3.75], "p_value": [0.14, 1e-12],
                           "beyond_noise": [False, True], "error_pct": [1.5, 7.25], "signal_m": [1e-4, 2e-4]},
                          columns=report.ERROR_COLUMNS)
    out = _round_trip(report.write_errors, report.read_errors, errors, tmp_path, "errors")
    assert out["beyond_noise"].dtype == bool and out["run"].tolist() == ["001", "r2"]
    empty = _round_trip(report.write_errors, report.read_errors, errors.iloc[:0], tmp_path, "no_errors")
    assert empty["beyond_noise"].dtype == bool and empty.empty
    ledger = pd.DataFrame([{c: 1.5 for c in report.LEDGER_COLUMNS} | {
        "variant": "geometric", "description": "the base", "source": "solver", "worst_run": "001",
        "worst_validation_run": ""}])
    out = _round_trip(report.write_ledger, report.read_ledger, ledger, tmp_path, "ledger")
    assert out.loc[0, "worst_run"] == "001" and out["chi2_dof"].dtype == float
    X = np.array([[1e-5 + 2e-6j, -3e-6 + 1e-6j], [2e-7 - 1e-7j, 1e-7j]])
    comparison = report.RunComparison("001", "fit", 1000.0, 25.9, X, 0.9 * X, np.full((2, 2), 1e-7), 6.0, "solver",
                                      ("x", "y"))
    path = tmp_path / "comparisons.tsv"
    report.write_comparisons([comparison], path)
    back = report.load_comparisons(path)
    again = tmp_path / "comparisons_2.tsv"
    report.write_comparisons(back, again)
    assert path.read_text() == again.read_text() and back[0].run == "001" and back[0].channels == ("x", "y")
    np.testing.assert_allclose(back[0].measured, X, rtol=1e-8)
    table = pd.DataFrame({"run": ["001", "all runs"], "n_test": [10, 20], "median_error_pct": [0.5, 0.75]})
    out = _round_trip(library.write_library_validation, library.read_library_validation, table, tmp_path, "libval")
    assert out["run"].tolist() == ["001", "all runs"]


def test_scenario_and_design_tables_round_trip(tmp_path):
    from hybridtwin.identify import design
    from hybridtwin.offline import scenarios

    table = pd.DataFrame({"scenario": [0, 1, 2], "split": ["train", "validation", "test"],
                          "k_b": [2345.678901234567, 2100.0, 3400.5], "zeta_bup": [0.012345678901234, 0.02, 0.03]})
    out = _round_trip(scenarios.write_scenarios, scenarios.read_scenarios, table, tmp_path, "scenarios")
    np.testing.assert_allclose(out["k_b"], table["k_b"], rtol=1e-11)
    full = _round_trip(lambda t, p: scenarios.write_scenarios(t, p, float_format=None), scenarios.read_scenarios,
                       table, tmp_path, "enrichment")
    pd.testing.assert_frame_equal(full, table)  # every digit (the enrichment's table)
    chosen = pd.DataFrame([[1, 1000.0, 7.6, True, 3.2, 9.8, 3.2], [2, 975.0, 0.0, False, 1.1, 10.9, 1.12]],
                          columns=design.CHOSEN_COLUMNS)
    intervals = pd.DataFrame([["zeta_bup", "1", 0.0138, 0.0119, 0.0157, "linear", 0.0, 0.05, 1.9e-3, 1.7e-4, 11.0,
                               True]], columns=design.INTERVAL_COLUMNS)
    candidates = pd.DataFrame([[1000.0, 7.6, True, False, "too large", 1.2, 0.5, 0.1]],
                              columns=design.CANDIDATE_COLUMNS)
    result = type("Design", (), {"chosen": chosen, "intervals": intervals, "candidates": candidates})()
    paths = [tmp_path / f"{n}.tsv" for n in ("chosen", "intervals", "candidates")]
    design.write_design(result, *paths)
    back = [design.read_design_table(p) for p in paths]
    again = type("Design", (), dict(zip(("chosen", "intervals", "candidates"), back)))()
    paths2 = [tmp_path / f"{n}_2.tsv" for n in ("chosen", "intervals", "candidates")]
    design.write_design(again, *paths2)
    for first, second, b in zip(paths, paths2, back):
        assert first.read_text() == second.read_text()
        pd.testing.assert_frame_equal(b, design.read_design_table(second))
    assert back[0]["keyphasor"].dtype == bool and back[1]["unit"].tolist() == ["1"]
    assert back[2]["feasible"].tolist() == [False] and back[2]["keyphasor"].tolist() == [True]


def test_preprocessing_tables_round_trip(tmp_path):
    """A spectrum, speed or runout table (preprocessing.write_tsv) read back by read_tsv; one written without
    columns (a record without a slow-roll runout) reads as None."""
    from hybridtwin.data import preprocessing

    table = pd.DataFrame({"frequency_hz": [0.0, 1.25], "x_m": [1.23456789012e-6, 3e-9], "channel": ["x", "y"]})
    out = _round_trip(preprocessing.write_tsv, preprocessing.read_tsv, table, tmp_path, "spectrum")
    np.testing.assert_allclose(out["x_m"], table["x_m"], rtol=1e-9)
    preprocessing.write_tsv(pd.DataFrame(), tmp_path / "runout.tsv")
    assert preprocessing.read_tsv(tmp_path / "runout.tsv") is None


def _equal(a, b) -> bool:
    """Mappings, lists and numbers equal, NaN equal to NaN, a float never equal to an int or a bool (YAML keeps
    each type)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return isinstance(b, list) and len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and np.isnan(a):
        return isinstance(b, float) and np.isnan(b)
    return type(a) is type(b) and a == b


def test_joint_fit_summary_round_trip(tmp_path):
    """identification/summary.yaml: run_fits.write_fit_summary, read back by read_fit_summary as the same mapping (its
    order, types and NaN included), what ledger, report_harmonics and twin_card read."""
    from hybridtwin.identify.run_fits import read_fit_summary, write_fit_summary

    final = {"runs": ["001", "r2"], "shared": ["k_b"], "per_run": ["q_x"], "keyphasor_runs": [], "n_data": 56,
             "dof": 49, "chi2": 51.25, "chi2_dof": 1.0459183673469388, "loss": float("nan"), "status": 2,
             "message": "`ftol` termination: 1e-12", "notes": ["k_b: at its range edge"], "sparsity": 0.125}
    summary = {"library": dict(final, chi2=60.5), "solver": {"failed": "no periodic solution", "seconds": 1.5},
               "profile": {"loose": ["zeta"], "seconds": 3.0}, "final": final}
    write_fit_summary(summary, tmp_path / "summary.yaml")
    read = read_fit_summary(tmp_path / "summary.yaml")
    assert _equal(summary, read) and read["final"]["chi2_dof"] == final["chi2_dof"]
    write_fit_summary(read, tmp_path / "again.yaml")
    assert (tmp_path / "again.yaml").read_text() == (tmp_path / "summary.yaml").read_text()
    assert not _equal(summary, dict(summary, final=dict(final, dof=49.0)))  # the check tells a type apart


def test_diagnosis_summary_round_trip(tmp_path):
    """diagnosis.yaml: diagnosis_report.write_diagnosis_summary, read back by read_diagnosis_summary (what
    report_summary reads)."""
    from hybridtwin.diagnose.diagnosis_report import read_diagnosis_summary, write_diagnosis_summary

    summary = {"variant": "linear", "status": "add", "conclusion": "add expansion_k4: explains the discrepancy",
               "misfit": True, "base_chi2_dof": 1234.5, "confounded": [], "delta_bic": float("nan"),
               "path": [{"effect": "expansion_k4", "chi2_dof": 1.02, "step": 1}],
               "recommended_variant": {"name": "linear_expansion_k4", "spec": {"effects": ["expansion_k4"],
                                                                              "unknown": {"k4": [0.0, 1e9]}}}}
    write_diagnosis_summary(summary, tmp_path / "diagnosis.yaml")
    read = read_diagnosis_summary(tmp_path / "diagnosis.yaml")
    assert _equal(summary, read)
    write_diagnosis_summary(read, tmp_path / "again.yaml")
    assert (tmp_path / "again.yaml").read_text() == (tmp_path / "diagnosis.yaml").read_text()


def test_twin_card_round_trip(tmp_path):
    """twin.yaml: online.twin.make_card and write_card, read back by read_card as the same mapping."""
    from hybridtwin.online.twin import make_card, read_card, write_card

    model = {"variants": {"linear": {"effects": ["unbalance"], "unknown": {"k_b": (1e5, 1e7)}}}, "machine": None,
             "effects_files": ["effects/extra.yaml"]}
    runs = pd.DataFrame({"run": ["001", "r2"], "rpm": [1000.5, 1200.0], "eccentric_mass_g": [0.0, 25.9]})
    card = make_card("linear", model, 3, True, ["expansion_k4"], 2.0, runs, {"chi2_dof": 1.25, "dof": 40})
    write_card(card, tmp_path / "twin.yaml")
    read = read_card(tmp_path / "twin.yaml")
    assert _equal(card, read)
    assert read["model"]["variants"]["linear"]["unknown"]["k_b"] == [1e5, 1e7]  # a tuple comes back a list


def test_rule_scripts_read_yaml_through_their_readers():
    """No rule script loads or dumps YAML by hand: the joint fit's summary, the diagnosis's and the twin's card go
    through their owners' writers and readers (run_fits, diagnosis_report, online.twin)."""
    problems = []
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and ast.unparse(node.func).split(".")[0] == "yaml":
                problems.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
            if isinstance(node, (ast.Import, ast.ImportFrom)) and (
                    getattr(node, "module", None) == "yaml" or any(a.name == "yaml" for a in node.names)):
                problems.append(f"{path.name}:{node.lineno}: imports yaml")
    assert not problems, "YAML read or written by hand (use its reader and writer):\n" + "\n".join(problems)


def test_rule_scripts_read_tables_through_their_readers():
    """No rule script parses a table between rules by hand: the parameter, harmonics, validation, error, ledger,
    comparison and library-validation tables go through their owners' readers (the tables listed here)."""
    owned = {"parameters", "per_run", "sparse", "harmonics", "runs", "bands", "validation", "library_validation",
             "ledger", "errors", "validation_errors", "table", "refits", "nested", "scenarios", "enrichment",
             "spectra", "speed", "runout"}
    problems = []
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and ast.unparse(node.func) in ("pd.read_csv", "pandas.read_csv"):
                source = ast.unparse(node.args[0]) if node.args else ""
                inputs = {n.attr for n in ast.walk(node.args[0]) if isinstance(n, ast.Attribute)} \
                    if node.args else set()
                if "smk.input" in source and inputs & owned:
                    problems.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert not problems, "tables read by hand (use the table's reader):\n" + "\n".join(problems)


# --- the table layer (issue 52): every table between rules declared once, written and read by one pair ---------

def _sample(table) -> pd.DataFrame:
    """A frame of ``table``'s layout with awkward values: text with an empty cell and words pandas would read as
    missing, numbers at the ends of the float range, a NaN, an integer column, a flag."""
    columns = list(table.columns) if table.columns is not None else [*table.text, *table.flags, "value_m", "count"]
    rng = np.random.default_rng(52)
    data = {}
    for i, c in enumerate(columns):
        if c in table.text:
            data[c] = ["a b", "" if table.na_text else "c", "NA" if table.na_text else "d"]
        elif c in table.flags or c in ("selected", "used", "drifts", "flagged", "best", "recommended_in_config"):
            data[c] = [True, False, True]
        elif c in ("harmonic", "count", "mode", "trial", "iteration", "window", "round"):
            data[c] = [1, 2, 3]
        else:
            data[c] = [rng.normal() * 10.0 ** rng.integers(-12, 6), 1.0 / 3.0, np.nan if i % 2 else 2.5e-9]
    frame = pd.DataFrame(data)
    if table.index:
        frame.index = ["p", "q[r1]", "r"]
    return frame


@pytest.mark.parametrize("name", sorted(__import__("hybridtwin.tables", fromlist=["TABLES"]).TABLES))
def test_every_table_is_read_back_as_written(name, tmp_path):
    """Every table of the registry: ``read`` is ``write``'s inverse. Writing what was read gives the same bytes
    (the file is the contract), the text cells come back as written, the numbers to the table's float format (half
    a unit in its last digit: %.6g 5e-6 relative, %.9g 5e-9, %.9e and %.10g 5e-10, %.12g 5e-12; 0 for every digit,
    %.17g, pandas' shortest repr and ``shortest_repr``)."""
    from hybridtwin import tables

    table = tables.TABLES[name]
    frame = _sample(table)
    table.write(frame, tmp_path / "a.tsv")
    read = table.read(tmp_path / "a.tsv")
    table.write(read, tmp_path / "b.tsv")
    assert (tmp_path / "a.tsv").read_bytes() == (tmp_path / "b.tsv").read_bytes()
    assert list(read.columns) == list(frame.columns)
    for c in frame:
        if c in table.text:
            assert read[c].tolist() == frame[c].tolist(), c
        elif frame[c].dtype == bool:
            assert read[c].astype(bool).tolist() == frame[c].tolist(), c
        else:
            rtol = {None: 0.0, tables.EXACT: 0.0, tables.shortest_repr: 0.0, tables.SHORT: 5e-6, tables.FIT: 5e-9, tables.METRES: 5e-10,
                    tables.SHEET: 5e-10, tables.REFIT: 5e-12}[table.float_format]
            np.testing.assert_allclose(read[c].to_numpy(float), frame[c].to_numpy(float), rtol=rtol, err_msg=c)
    if table.columns is not None:
        with pytest.raises(tables.TableError):
            table.write(frame.iloc[:, ::-1], tmp_path / "c.tsv")


def test_no_script_writes_or_reads_a_table_itself():
    """The rule scripts write and read tables through the layer (``hybridtwin.tables`` or a stage's own reader),
    never by hand: no ``to_csv``, ``read_csv``, ``read_table`` or ``savetxt`` call in scripts/ (ast)."""
    found = []
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in (
                    "to_csv", "read_csv", "read_table", "savetxt", "loadtxt"):
                found.append(f"{path.name}:{node.lineno} {node.func.attr}")
    assert not found, found


def test_the_long_harmonics_and_their_wide_view():
    """The long harmonic table (run, harmonic, channel, re_m, im_m, sigma_m) and the wide view of harmonics.tsv
    are one table: the preprocessing's columns (record_columns.harmonic_columns, written through the long form and
    its wide view) are the numbers given, under the names written out here, the amplitude as abs() of the complex
    value (bit for bit: abs of a complex and hypot are the same libm call); the long form of the wide table gives
    back the numbers given, and its wide view the wide table; a channel whose name ends in a digit too."""
    from hybridtwin import tables
    from hybridtwin.data.record_columns import harmonic_columns

    rng = np.random.default_rng(5)
    names, H = ["x", "y2"], 3
    stems = {"x": "x", "y2": "y2_"}  # x1_re_m for channel x, y2_1_re_m for channel y2
    rows, given = [], {}
    for run in ("r1", "r2"):
        X, sigma = 1e-5 * (rng.normal(size=(2, H + 1)) + 1j * rng.normal(size=(2, H + 1))), rng.uniform(size=(2, H + 1))
        given[run] = X, sigma
        row = {"run": run, "rpm": 900.0} | harmonic_columns(names, H, X, sigma, np.ones(2))
        expected = {}
        for i, c in enumerate(names):
            for h in range(1, H + 1):
                stem = f"{stems[c]}{h}"
                expected |= {f"{stem}_re_m": X[i, h].real, f"{stem}_im_m": X[i, h].imag,
                             f"{stem}_amp_m": abs(X[i, h]), f"{stem}_sigma_m": sigma[i, h]}
        assert list(row)[-len(expected):] == list(expected)  # channel by channel, harmonic by harmonic, last
        assert all(row[k] == v for k, v in expected.items()), row
        rows.append(row)
    wide = pd.DataFrame(rows)
    long = tables.long_harmonics(wide, names)
    assert list(long.columns) == list(tables.HARMONICS_LONG.columns) and len(long) == 2 * H * 2
    for entry in long.itertuples():
        X, sigma = given[entry.run]
        i = names.index(entry.channel)
        assert (entry.re_m, entry.im_m, entry.sigma_m) == (X[i, entry.harmonic].real, X[i, entry.harmonic].imag,
                                                           sigma[i, entry.harmonic])
    back = tables.wide_harmonics(long)
    for c in back.columns[1:]:
        np.testing.assert_array_equal(back[c].to_numpy(), wide[c].to_numpy(), err_msg=c)
    assert back["run"].tolist() == ["r1", "r2"]
    # a run without a harmonic another has: NaN there, not a shifted value
    partial = tables.wide_harmonics(long[~((long["run"] == "r1") & (long["harmonic"] == 3))])
    assert np.isnan(partial.loc[0, "x3_re_m"]) and partial.loc[1, "x3_re_m"] == wide.loc[1, "x3_re_m"]
