"""A variant's fixed values tested as candidates (src/hybridtwin/model/fixed_values.py): the shift of a fixed
value is the model with the value changed, absent at 0; and records of the Geometric model with zeta_s = 0.024,
fitted by a variant that fixes it at the paper's 0.0271, are diagnosed as that fixed value being wrong, with the
value the data say, not as an added effect."""

import numpy as np
import pytest
from test_diagnosis import GEOMETRIC, OPTIONS, TRUTH, _base_fit, _candidates, _data

from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.model.fixed_values import fixed_value_candidates
from hybridtwin.model.model import Model
from hybridtwin.model.variants import Variant

#: the Geometric model with its dampings fixed at the paper's values (as the bundled expansion variant fixes them),
#: the rest free; the truth's are 0.024 and 0.016 (test_diagnosis.TRUTH, the bundled rig's)
FIXED_DAMPINGS = {"effects": GEOMETRIC["effects"], "fixed": {"zeta_s": 0.0271, "zeta_bup": 0.0215},
                  "unknown": {k: v for k, v in GEOMETRIC["unknown"].items() if k not in ("zeta_s", "zeta_bup")}}


@pytest.mark.parametrize("parameter, value, shift", [("zeta_s", 0.0271, -0.0031), ("k_b", 2331.5, 80.0),
                                                     ("l_i", 0.0508, 0.004)])
def test_the_shift_of_a_fixed_value_is_the_model_with_the_value_changed(parameter, value, shift):
    """Through its linear terms (zeta_s: the damping, from omega_1), its linear and cubic ones (k_b: stiffness, the
    geometric spring's local force, and c_bup, which reads the support stiffness), a value in the local force only
    (l_i): the system with d_p = shift is that with p = value + shift (to rounding), with d_p = 0 the base's."""
    variant = Variant.from_spec("v", {"effects": GEOMETRIC["effects"], "fixed": {parameter: value}})
    (candidate,) = fixed_value_candidates(variant)
    assert candidate.name == f"fixed_value@{parameter}" and candidate.tested == (f"d_{parameter}",)
    lo, hi = candidate.parameters[0].bounds
    assert lo < 0 < hi and value + lo == pytest.approx(variant.model.parameters[parameter].bounds[0])
    extended = Model(variant.model.effects + [candidate.effect], variant.model.shaft)
    values = variant.values({"m_e": 0.02})
    rpm = 700.0
    base, at_zero = variant.model.system(values, rpm), extended.system(values | {f"d_{parameter}": 0.0}, rpm)
    for a, b in ((base.K, at_zero.K), (base.C, at_zero.C), (base.M, at_zero.M)):
        np.testing.assert_array_equal(a, b)
    changed = variant.model.system(values | {parameter: value + shift}, rpm)
    shifted = extended.system(values | {f"d_{parameter}": shift}, rpm)
    for a, b in ((changed.K, shifted.K), (changed.C, shifted.C), (changed.M, shifted.M)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
    np.testing.assert_allclose(shifted.forcing[1], changed.forcing[1], rtol=1e-12)
    q = np.random.default_rng(0).normal(0, 2e-3, (1, 2, 16))  # the upper bearing's u0, v0 at 16 instants
    total = [sum(f.evaluate(q, np.array([0]))[0] for f in system.forces) for system in (changed, shifted)]
    np.testing.assert_allclose(total[1], total[0], rtol=1e-12, atol=1e-15)


def test_wrong_fixed_dampings_are_named_not_an_effect_standing_in_for_them():
    """The issue's case on four runs: the diagnosis names the fixed dampings (these runs cannot tell which of the
    two: both are said), ahead of the effects that could stand in for them; the value the data say is given, the
    recommendation frees it instead of adding an effect."""
    base = _base_fit(_data([], TRUTH, seed=5), FIXED_DAMPINGS)
    candidates = fixed_value_candidates(base.variant) + _candidates(["speed_damping", "upper_bearing_anisotropy",
                                                                     "lower_bearing_compliance"])
    assert [c.name for c in candidates[:2]] == ["fixed_value@zeta_s", "fixed_value@zeta_bup"]
    result = dg.diagnose(base, candidates, OPTIONS | {"max_effects": 2, "thorough": 1, "starts": 1})
    assert set(result.table.loc[:1, "effect"]) == {"fixed_value@zeta_s", "fixed_value@zeta_bup"}
    assert result.conclusion.startswith("add fixed_value@")
    first = result.table.loc[0, "effect"]
    freed, truth = first.split("@")[1], {"zeta_s": 0.024, "zeta_bup": 0.016}
    fixed = FIXED_DAMPINGS["fixed"][freed]
    assert f"{freed} fixed at {fixed:g}: the data say " in result.conclusion
    row = result.confirmations[first].estimates.set_index("parameter").loc[f"d_{freed}"]
    assert row["value"] < 0  # both fixed values are above the truth's: the data lower it
    # what to do: free it (from fixed: to unknown:, around the fixed value), no effect added
    recommended = result.summary["recommended_variant"]
    assert recommended["name"] == f"geometric_free_{freed}"
    assert recommended["spec"]["effects"] == GEOMETRIC["effects"] and freed not in recommended["spec"]["fixed"]
    low, high = recommended["spec"]["unknown"][freed]
    assert low < truth[freed] < fixed < high
    Variant.from_spec(recommended["name"], recommended["spec"])  # a valid config entry
