"""One implementation each (issue 37, part 4): the run-up's speed grid and sweep, and the bearing terms.

The offline stage's run-ups (``scenarios.solve_runs``), the fits' (``forward.run_up``, ``forward.run_ups``) and the
rig's (``rig.solve_truth``) take their speeds from ``continuation.ramp`` and sweep through
``continuation.sweep_model``; the VARM's upper-bearing candidates and a machine's candidates at a named bearing put
their parameter into K or C through ``effects.BearingTerm``. The references below are the formulas each place had
before, written out again, so a change to the shared function that alters a grid shows here.
"""

import numpy as np
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
