"""The diagnosis's second pass (issue 36) on records of the project's own rig, integrated in time.

The cases of tests/rig_cases (rebuilt by tests/rig_cases/rebuild.py, which says how they are made): four steady
runs (two unbalance masses, 500-850 RPM) whose truth was solved by time integration of the equations of motion
(no harmonic-balance code), written as records with every nuisance of the bundled data's rig (speed error,
noise, offsets, random phase, clipping) and preprocessed as the workflow does (``preprocess_run``, H = 3). The
records are written again here from the kept answer key (``rig.write_steady_records``: the same seeds, the same
records), not integrated again.

The base fits and the diagnosis options are test_diagnosis.py's (Geometric on the full solver, 3 random starts).
"""

import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from test_diagnosis import OPTIONS, _base_fit, _candidates, _diagnose, _not_plain, _same  # noqa: E402

from hybridtwin.data.measurements import read_runs
from hybridtwin.data.preprocessing import preprocess_run
from hybridtwin.rig.rig import read_answer_key, write_steady_records
from hybridtwin.diagnose import conclusion as conc
from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.diagnose import diagnosis_report as dgr
from hybridtwin.diagnose import score_test as st
from hybridtwin.diagnose.diagnosis_status import Status, negligible_step
from hybridtwin.identify import identification as idn
from hybridtwin.model.variants import Variant

CASES = Path(__file__).parent / "rig_cases"
H = 3


def _rig_data(case: str, folder: Path) -> list[idn.RunData]:
    """The case's records written again from its answer key into ``folder``, preprocessed into RunData."""
    key = CASES / case
    spec = read_answer_key(key / "truth.yaml")
    shutil.copy(key / "runs.tsv", folder / "runs.tsv")
    write_steady_records(pd.read_csv(key / "truth.tsv", sep="\t"), spec, folder)
    sheet = read_runs(folder / "runs.tsv")
    table = pd.concat([preprocess_run(row, H)[0] for _, row in sheet.iterrows()], ignore_index=True)
    return [idn.run_data(table, run, H) for run in table["run"]]


@pytest.fixture(scope="module")
def beyond_range(tmp_path_factory):
    return _rig_data("cross_coupled_beyond_range", tmp_path_factory.mktemp("beyond_range"))


def _written_and_read_back(result: conc.Diagnosis, folder: Path) -> None:
    """diagnosis.tsv/.md/.yaml as the workflow writes them (diagnosis_report.write), the YAML read back equal to the
    summary, which holds plain Python types only (a numpy float on the long path killed the workflow there)."""
    assert _not_plain(result.summary) == []
    files = [folder / name for name in ("diagnosis.tsv", "diagnosis.md", "diagnosis.yaml")]
    dgr.write(result, *files)
    assert _same(yaml.safe_load(files[2].read_text()), result.summary)
    assert list(pd.read_csv(files[0], sep="\t").columns) == list(result.table.columns)
    assert result.conclusion in files[1].read_text()


@pytest.mark.slow  # ~40 s CPU: the base fit and a diagnosis with thorough refits that widen
def test_a_truth_beyond_the_range_is_added_at_step_1_on_time_integrated_records(beyond_range, tmp_path):
    """Issue 36, item 2: cross-coupled stiffness k_xy = 500 N/m hidden, 2.5 times its candidate's range edge (+-200;
    at 560 N/m the truth is unstable at 850 RPM). The score test ranks it first, but its quick refit without
    widening stops at the edge, behind a partial stand-in (upper_bearing_anisotropy); with ``thorough: 1`` (the
    stand-ins fill the thorough slots when candidates are many) step 1 used to add the stand-in. Now it is the
    first step, at the noise, its range widened past the truth; the outputs are written and read back."""
    base = _base_fit(beyond_range)
    candidates = _candidates(["cross_coupled_stiffness", "upper_bearing_anisotropy", "cross_coupled_damping",
                              "speed_damping"])
    o = OPTIONS | {"thorough": 1, "max_effects": 1}
    # the premise: ranked first by the score test, its quick refit (no widening) stalled, behind a stand-in's
    scores = st.score_tests(base, candidates)
    chosen, quick = dg._quick_refits(base, scores, o, o["alpha"] / len(candidates))
    assert sorted(chosen, key=st.by_score)[0].candidate.name == "cross_coupled_stiffness"
    assert quick["cross_coupled_stiffness"].at_limit == ["k_xy"]
    assert min(quick.values(), key=lambda cf: cf.delta_bic).candidate.name != "cross_coupled_stiffness"
    result = _diagnose(base, candidates, o)
    assert [step.effect for step in result.path] == ["cross_coupled_stiffness"]
    assert result.status is Status.ADD
    final = result.path[0].confirmation
    assert final.chi2 / final.dof < 1 + 3 * np.sqrt(2 / final.dof)  # at the noise floor (3 sigma of chi^2(dof))
    # widened past the truth, the estimate beyond the initial edge; its interval is not asserted here: on these
    # records it is 506.6 [501.0, 512.3] against 500 (2.4 standard errors, the chi^2 at 0.94 of the noise; the rig's
    # time-integrated truth equals the harmonic balance's to 0.01 um of an 8 mm response, so not the truth's
    # numerics); coverage over many records is benchmarks/interval_coverage_study.py's
    row = final.estimates.set_index("parameter").loc["k_xy"]
    assert final.ranges["k_xy"][1] > 500.0 and row["value"] > 200.0
    _written_and_read_back(result, tmp_path)


@pytest.mark.slow  # ~60 s CPU: the base fit with the bow per run and a diagnosis of three steps
def test_the_long_path_of_the_issue_ends_with_its_outputs_written(beyond_range, tmp_path):
    """Issue 36, item 1, the path that crashed: with the bow per run (the bundled config's), the same records go
    forward selection (a stand-in, then cross_coupled_stiffness with its range widened), backward elimination
    (the stand-in dropped) and the sharing check (the bow shared). The path must be that one (checked first: the
    test means nothing on another), and every output written from plain types and read back.

    Step 1 is a stand-in here although the quick refit that stalls at its edge is promoted (the test above): with
    the bow per run, four runs leave zeta_bup loose, and cross_coupled_stiffness's thorough refit ends at k_xy = 510
    with the model unstable at 850 RPM (Floquet radius 1.013); an unstable optimum is never confirmed. The bow
    shared, the same refit is stable and fits to the noise (the test above)."""
    base = _base_fit(beyond_range, per_run=("q_x", "q_y"))
    candidates = _candidates(["cross_coupled_stiffness", "upper_bearing_anisotropy", "cross_coupled_damping",
                              "speed_damping"])
    result = _diagnose(base, candidates, OPTIONS | {"thorough": 1})
    s = result.summary
    assert [e["effect"] for e in s.get("eliminated", [])] == ["upper_bearing_anisotropy"]
    assert s.get("sharing", {}).get("shared") and [step.effect for step in result.path] == ["cross_coupled_stiffness"]
    assert result.status is Status.ADD
    _written_and_read_back(result, tmp_path)


@pytest.mark.slow  # ~50 s CPU: the base fit and a diagnosis of three steps with thorough refits
def test_two_effects_of_another_form_are_added_and_their_intervals_own_up_to_the_misfit(tmp_path):
    """Issue 36, items 3 and 4: two hidden effects, each of a slightly different form than its candidate: a slope
    force with a strong cubic part (k_w = 324.2 N, k_z = 7e4 N; expansion_k4 is its linear term only) and a 2X
    force (f2 = 0.4 - 0.2j N, beyond excitation_2x's range on one side). The path adds both, removing more than
    99.9 % of the excess chi^2 but leaving chi^2/dof well above the noise (the cubic part): the conclusion adds
    them and reports the small misfit (never "unexplained ... not among the candidates"), no later step is
    negligible, and the 2X force, which its candidate describes exactly, lies inside its intervals, which grow
    with the misfit (by sqrt(chi^2/dof)): without that growth one of them misses the truth on these records."""
    data = _rig_data("two_effects_other_form", tmp_path)
    base = _base_fit(data)
    result = _diagnose(base, _candidates(["expansion_k4", "excitation_2x", "cross_coupled_damping",
                                            "speed_damping"]))
    names = [step.effect for step in result.path]
    assert set(names[:2]) == {"excitation_2x", "expansion_k4"}
    final = result.path[-1].confirmation
    # the premise: a real misfit left (chi^2/dof beyond 5 sigma of chi^2(dof)/dof), nearly all the excess removed
    assert final.chi2 / final.dof > 1 + 5 * np.sqrt(2 / final.dof) and result.path[1].share > 0.999
    excess = max(result.summary["base_chi2"] - result.summary["base_dof"], np.sqrt(2 * result.summary["base_dof"]))
    for before, step in zip(result.path[1:], result.path[2:]):
        assert negligible_step(step.confirmation, before.confirmation.chi2, excess) is None
    assert result.status is Status.ADD_NEARLY and "not among the candidates" not in result.conclusion
    assert "a small misfit remains" in result.conclusion
    Variant.from_spec(result.summary["recommended_variant"]["name"], result.summary["recommended_variant"]["spec"])
    intervals = result.summary["intervals"]
    assert intervals["optimistic"] and intervals["scaled_by"] == pytest.approx(np.sqrt(final.chi2 / final.dof))
    estimates = result.estimates().set_index("parameter")
    truth = {"f2_c": 0.4, "f2_s": -0.2}
    unscaled_miss = []
    for name, value in truth.items():
        row = estimates.loc[name]
        assert row["ci_low"] <= value <= row["ci_high"], (name, row["value"], row["ci_low"], row["ci_high"])
        half = (row["ci_high"] - row["ci_low"]) / 2 / intervals["scaled_by"]
        unscaled_miss.append(abs(row["value"] - value) > half)
    assert any(unscaled_miss)  # the premise: the intervals as they were (not grown) miss a truth here
    _written_and_read_back(result, tmp_path)
