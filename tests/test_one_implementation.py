"""One implementation each (issue 37, part 4): the run-up's speed grid and sweep, the bearing terms and the drift
analysis.

The offline stage's run-ups (``scenarios.solve_runs``), the fits' (``forward.run_up``, ``forward.run_ups``) and the
rig's (``rig.solve_truth``) take their speeds from ``continuation.ramp`` and sweep through
``continuation.sweep_model``; the VARM's upper-bearing candidates and a machine's candidates at a named bearing put
their parameter into K or C through ``effects.BearingTerm``. The references below are the formulas each place had
before, written out again, so a change to the shared function that alters a grid shows here. The per-run
estimates' drift (the identification's per_run.tsv and .png, the report's drift.tsv and .png) is
``hybridtwin.report.drift``'s alone, its two weighted means one function's.
"""

import ast
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.model import bearing_candidates as bc
from hybridtwin.model import effects
from hybridtwin.solvers.continuation import intermediate_speeds, ramp


def _old_rig_grid(start, speeds, step):
    points = np.unique(np.append(speeds, start))
    if points.size < 2:
        return points
    parts = [np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)[:-1] for a, b in zip(points[:-1], points[1:])]
    return np.concatenate(parts + [points[-1:]])


@pytest.mark.parametrize("seed", range(20))
def test_ramp_is_each_old_grid(seed):
    rng = np.random.default_rng(seed)
    speeds = np.round(rng.uniform(100, 1500, rng.integers(1, 6)), 1)
    start, step = float(rng.choice([300.0, 150.0, 2000.0])), float(rng.choice([25.0, 50.0, 37.5]))
    grid = ramp(start, speeds, step)
    assert np.array_equal(grid, _old_rig_grid(start, speeds, step))  # the rig's
    low = min(start, speeds.min())
    assert np.array_equal(ramp(low, speeds, step),  # forward.run_up's
                          intermediate_speeds(np.unique(np.append(speeds, low)), step))
    r = float(speeds[0])
    assert np.array_equal(ramp(min(start, r), [r], step),  # forward.run_ups', up and down
                          intermediate_speeds(np.unique([min(start, r), r]), step))
    assert np.array_equal(ramp(max(start, r), [r], step)[::-1],
                          intermediate_speeds(np.unique([r, max(start, r)]), step)[::-1])
    assert np.all(np.diff(grid) <= step + 1e-9) and set(speeds) | {start} <= set(grid)


def test_bearing_terms_share_one_implementation():
    """The named-bearing candidates are the VARM's terms at another node: the same pairs and the same methods; the
    VARM's stay where they are (no ``node``: ``Machine.place`` does not offer them at a bearing)."""
    for named, varm in ((bc.BearingAnisotropy, effects.UpperBearingAnisotropy),
                        (bc.BearingCrossCoupledStiffness, effects.CrossCoupledStiffness),
                        (bc.BearingCrossCoupledDamping, effects.CrossCoupledDamping)):
        assert issubclass(named, effects.BearingTerm) and issubclass(varm, effects.BearingTerm)
        assert named.pairs == varm.pairs
        method = "damping" if varm is effects.CrossCoupledDamping else "stiffness"
        assert getattr(named, method) is getattr(varm, method)
        assert not hasattr(varm(), "node")


def test_named_bearing_term_at_node_zero_is_the_varm_term():
    """On the VARM, a term placed by name at its upper bearing's node gives the VARM candidate's matrix."""
    from hybridtwin.model.machine import Machine
    from hybridtwin.model.model import Model

    machine = Machine.varm()

    class AtNodeZero(bc.BearingCrossCoupledStiffness):
        def bearing_node(self, ctx):
            return 0

    named, varm = AtNodeZero("top", 10.0, 20.0), effects.CrossCoupledStiffness()
    systems = []
    for effect in (named, varm):
        model = Model([effect], machine)
        values = {k: p.nominal for k, p in model.parameters.items()} | {effect.parameters[0].name: 7.5}
        systems.append(model.system(values, 0.0))
    assert np.array_equal(systems[0].K, systems[1].K)


ROOT = Path(__file__).resolve().parents[1]
DRIFT = {"drift_table", "plot_per_run", "weighted_mean", "drift_test", "drift_sigma", "drift_usable",
         "drift_statistics", "plot_drift"}


def test_the_drift_analysis_is_one_module_and_both_rules_use_it():
    """The per-run drift's functions are defined in report/drift.py only (they were in identify/validation.py and
    report/report.py + report_plots.py), and both rules' scripts call them there."""
    defined = {}
    for path in sorted((ROOT / "src").rglob("*.py")) + sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name in DRIFT:
                defined.setdefault(node.name, []).append(path.relative_to(ROOT).as_posix())
    assert defined == {name: ["src/hybridtwin/report/drift.py"] for name in DRIFT}
    for script, used in (("identify_joint.py", {"drift_table", "plot_per_run"}),
                         ("report_drift.py", {"drift_statistics", "plot_drift"})):
        tree = ast.parse((ROOT / "scripts" / script).read_text())
        calls = {ast.unparse(n.func) for n in ast.walk(tree) if isinstance(n, ast.Call)}
        modules = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                   and n.module == "hybridtwin.report" for a in n.names if a.name == "drift"}
        assert len(modules) == 1, (script, modules)
        name = next(iter(modules))
        assert {f"{name}.{f}" for f in used} <= calls, (script, calls)


@pytest.mark.parametrize("seed", range(12))
def test_both_weighted_means_are_the_formulas_they_were(seed):
    """weighted_mean is, to the last bit, the per-run table's weighted mean as identify/validation.drift_table had it
    (pandas, leaving out a zero or missing stderr; the plain mean when none is left) and drift_test's as
    report/report.py had it (numpy, every sigma positive)."""
    from hybridtwin.report.drift import drift_test, weighted_mean

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 30))
    value = pd.Series(rng.normal(5.0, 2.0, n) * 10.0 ** rng.integers(-6, 7))
    stderr = pd.Series(rng.uniform(0.01, 1.0, n) * abs(value.mean()))
    stderr[rng.random(n) < 0.2] = 0.0
    stderr[rng.random(n) < 0.2] = np.nan
    w = 1.0 / stderr.where(stderr > 0) ** 2
    table_mean = (w * value).sum() / w.sum() if w.notna().any() else value.mean()
    assert weighted_mean(value, stderr)[0] == table_mean
    assert weighted_mean(value, pd.Series(0.0, index=value.index))[0] == value.mean()
    s = rng.uniform(0.01, 1.0, n)
    v = value.to_numpy()
    ws = 1.0 / s**2
    assert weighted_mean(v, s) == (float((ws * v).sum() / ws.sum()), float(ws.sum()))
    test = drift_test(v, s, np.linspace(400.0, 1000.0, n))
    assert test["weighted_mean"] == float((ws * v).sum() / ws.sum())
    assert test["weighted_mean_stderr"] == float(1.0 / np.sqrt(ws.sum()))
