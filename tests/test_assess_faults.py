"""Online naming (issue 54, item 6): a record with a fault, judged against a built twin, is a new discrepancy that
says which fault family its residual resembles (``Assessment.resemblance``, ``fingerprint.resembles`` with the faults'
``signatures``). The twin is tests/twin/results/geometric_slope (the VARM, tests/test_assess.py); each record is
made by the project's virtual rig from that twin's truth with one fault added (``faults``: a truth effect, as a file
under ``effects_files`` would give it), at 700 RPM with 14.8 g, keyphasor on, every nuisance of the rig. The VARM
is vertical: its crack breathes under a static side load (1 g along -y, as a magnet's or a fluid's pull would give),
its orbits are nearly circular, so the rub is a ring set 0.8 mm off-centre (touched on one side)."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.model.faults import Crack, Looseness, Misalignment, Rub
from hybridtwin.model.machine import Machine
from hybridtwin.online.assess import Assessment, RecordVerdict, assess
from hybridtwin.online.intake import intake, read_sheet
from hybridtwin.online.twin import load_twin
from hybridtwin.rig.rig import DEFAULT_TRUTH, Imperfections, RigSpec, Truth, generate

TWIN = Path(__file__).resolve().parents[1] / "tests" / "twin" / "results" / "geometric_slope"
VARM = Machine.varm()
ELEMENT = float(VARM.z[1] - VARM.z[0])

#: each fault and its values: the crack in element 4 (mid-span) taking 3e5 N/m of the element's 4.3e5 tip stiffness
#: along xi (a deep crack; psi 0.5 rad); the misaligned coupling's 2X pair of 0.5 N at the upper bearing's element
#: (the response's 2X then 40 times the noise); the rub ring at node 5 (where the 1X orbit is largest, 2.2 mm) of
#: clearance 2.5 mm centred 0.8 mm off the axis along x, contact 500 N/m (a fifth of the upper bearing's), friction
#: 0.1; the upper bearing (node 0, k_b 2411 N/m, its orbit 1.1 mm) loose in a clearance of 0.3 mm
FAULTS = {
    "crack": (Crack(name="crack", node=4, place="c", element_length_m=ELEMENT), {"dk_xi_c": 3e5, "psi_c": 0.5}),
    "misalignment": (Misalignment(name="misalignment", node=0, partner=1), {"f2x_c": 0.5, "f2y_s": 0.5}),
    "rub": (Rub(name="rub", node=5, place="r", centre_m=(8e-4, 0.0)),
            {"delta_r": 2.5e-3, "k_rub_r": 500.0, "mu_r": 0.1}),
    "looseness": (Looseness(name="looseness", node=0, place="u", k_n_m=DEFAULT_TRUTH["values"]["k_b"]),
                  {"delta_loose_u": 3e-4}),
}


@pytest.fixture(scope="module")
def twin():
    return load_twin(TWIN)


def judged(twin, folder: Path, fault: str) -> Assessment:
    effect, values = FAULTS[fault]
    truth = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"] + [effect.name],
                             "values": DEFAULT_TRUTH["values"] | values}, {effect.name: effect})
    plan = pd.DataFrame({"run": [fault], "rpm": [700.0], "eccentric_mass_g": [14.8], "role": "fit"})
    generate(plan, RigSpec(truth, Imperfections(keyphasor=True), seed=11), folder)
    return assess(twin, intake(twin, read_sheet(folder / "runs.tsv")[0]), candidates=False)


@pytest.mark.parametrize("fault, families, shows", [
    # 2X with 3X and a 1X change (its mean loss): a crack, not a coupling (which has no 3X)
    ("crack", ["a breathing crack"], "2X and 3X above the noise with a 1X change"),
    # 2X alone
    ("misalignment", ["a misaligned coupling"], "2X above the noise, the 1X unchanged"),
    # a ring touched on one side clips the orbit: a series 2X, 3X, 4X
    ("rub", ["a rub"], "2X, 3X and 4X above the noise"),
    # 3X from the clearance; its 1X change is absorbed by the twin's best change (k_b lower), so what the 1X did is
    # not in the residual and the record cannot tell a loose bearing from a rub on an ellipse: both are said
    ("looseness", ["a rub", "a loose bearing"], "3X above the noise, the 1X unchanged"),
])
def test_a_record_with_a_fault_is_a_new_discrepancy_that_names_its_family(twin, tmp_path, fault, families, shows):
    result = judged(twin, tmp_path, fault)
    assert result.verdict is RecordVerdict.NEW_DISCREPANCY, result.line()
    named, words = result.resemblance
    assert named == families and words.startswith(shows), (named, words)
    assert f"{words}, like {' or '.join(families)}; no parameter change explains it" in result.line()
    result.write(tmp_path / "assessment")  # the fingerprint read back names the same
    assert Assessment.read(tmp_path / "assessment").resemblance == result.resemblance


def test_the_rigs_two_integrators_agree_on_a_rub(tmp_path):
    """The rig's truth with the off-centre rub through both integrators (``RigSpec.integrator``: harmonic balance,
    now at the rub's 9 harmonics, and Radau settled, tests/test_rig_transient.py), one run at 700 RPM: the harmonics
    0..7 of each probe agree to 1e-4 of the largest, the rub's harmonic balance's own error (5e-5 of the 1X at its 9
    harmonics and 64 samples, tests/test_rub.py) and the settling's (3.4e-6) with a margin; measured 1.4e-5. The
    rub's 2X is 0.7-1.8 % of the 1X: a wrong order or sign would be off by that much."""
    effect, values = FAULTS["rub"]
    truth = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"] + [effect.name],
                             "values": DEFAULT_TRUTH["values"] | values}, {effect.name: effect})
    plan = pd.DataFrame({"run": ["a"], "rpm": [700.0], "eccentric_mass_g": 14.8, "role": ["fit"]})
    imperfections = Imperfections(duration_s=1.0, noise_mm=(0.02, 0.08), keyphasor=True)
    H = 7
    by = {integrator: generate(plan, RigSpec(truth, imperfections=imperfections, seed=7, harmonics=H,
                                             integrator=integrator), tmp_path / integrator)
          for integrator in ("time", "hb")}
    for channel in ("x", "y"):
        Z = {k: np.stack([t[f"{channel}{h}_re_m"] + 1j * t[f"{channel}{h}_im_m"] for h in range(H + 1)], 1)[0]
             for k, t in by.items()}
        scale = np.abs(Z["hb"]).max()
        assert 0.005 * scale < np.abs(Z["hb"][2:5]).max() < 0.05 * scale  # the rub's orders, not zeros agreeing
        assert np.abs(Z["time"] - Z["hb"]).max() < 1e-4 * scale
