"""The virtual rig: reproducible, honest about uniqueness, stability and the sensor range, and the bundled data
set is exactly what the configured truth generates."""

import filecmp
import re
import warnings
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from numeric_files import same_record  # noqa: E402

from hybridtwin.cli import main
from hybridtwin.model.machine import Machine
from hybridtwin.data.measurements import DataWarning, read_runs
from hybridtwin.data.records import detect_saturation, read_record
from hybridtwin.rig.rig import (
    DEFAULT_TRUTH, Imperfections, RigError, RigSpec, RigWarning, Truth, generate, harmonics_of, read_plan,
    write_steady_records,
)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT / "data" / "default"
GEOMETRIC = ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "unbalance",
             "shaft_bow", "geometric_spring"]


def plan(*runs):
    """A run plan from (run, rpm, eccentric_mass_g) triples."""
    return pd.DataFrame({"run": [r[0] for r in runs], "rpm": [float(r[1]) for r in runs],
                         "eccentric_mass_g": [float(r[2]) for r in runs], "role": "fit"})


SMALL = plan(("a", 400, 25.9), ("b", 800, 14.8), ("c", 950, 0.0))
SHORT = Imperfections(duration_s=1.0)


def files(folder):
    return sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())


def test_same_seed_same_files_and_runs_independent_of_the_plan(tmp_path):
    spec = RigSpec(imperfections=SHORT, seed=3, harmonics=5)
    two_runs = SMALL.iloc[:2]
    generate(two_runs, spec, tmp_path / "one")
    generate(two_runs, spec, tmp_path / "two")
    assert files(tmp_path / "one") == files(tmp_path / "two")
    for name in files(tmp_path / "one"):
        assert filecmp.cmp(tmp_path / "one" / name, tmp_path / "two" / name, shallow=False), name
    generate(two_runs, RigSpec(imperfections=SHORT, seed=4, harmonics=5), tmp_path / "other")
    assert not filecmp.cmp(tmp_path / "one" / "records" / "a.csv", tmp_path / "other" / "records" / "a.csv",
                           shallow=False)
    # each run's draws come from (seed, run id): dropping other runs from the plan leaves its record unchanged
    generate(two_runs.iloc[[1]], spec, tmp_path / "alone")
    assert filecmp.cmp(tmp_path / "one" / "records" / "b.csv", tmp_path / "alone" / "records" / "b.csv",
                       shallow=False)


def test_records_and_answer_key(tmp_path):
    spec = RigSpec(imperfections=Imperfections(duration_s=1.5, noise_mm=(0.03, 0.17), offset_mm=0.4), seed=8,
                   harmonics=5)
    truth = generate(SMALL, spec, tmp_path)
    sheet = read_runs(tmp_path / "runs.tsv")  # a valid runs sheet pointing at records that exist
    assert sheet["run"].tolist() == ["a", "b", "c"] and sheet["path"].tolist()[0] == "records/a.csv"
    record = read_record(sheet["record"].iloc[0])
    assert record.n_samples == 3000 and record.sample_rate_hz == pytest.approx(2000.0) and record.keyphasor is None
    assert truth["unique"].all() and truth["inside_range"].all() and (truth["clipped_samples"] == 0).all()
    assert truth["stable"].all() and truth["floquet_radius"].between(0.0, 1.0, inclusive="neither").all()
    assert truth["noise_x_m"].between(0.03e-3, 0.17e-3).all() and truth["offset_y_m"].abs().max() <= 0.4e-3
    assert (abs(truth["rpm_true"] / truth["rpm"] - 1) < 5e-3).all() and (truth["rpm_true"] != truth["rpm"]).all()
    key = yaml.safe_load((tmp_path / "truth.yaml").read_text())
    assert key["seed"] == 8 and key["truth"]["effects"][-1] == "slope_spring"
    assert key["truth"]["values"]["k_w"] == 324.2 and key["imperfections"]["noise_mm"] == [0.03, 0.17]
    # the record is the truth's steady state: its mean is the drawn offset (the truth has no 0X), to 4 sigma
    row = truth.iloc[0]
    assert abs(record.x_m.mean() - row["offset_x_m"]) < 4 * row["noise_x_m"] / np.sqrt(record.n_samples) + 2e-6


def test_records_written_again_from_the_answer_key_are_the_records(tmp_path):
    """rig.write_steady_records from truth.tsv as written (no solve) gives the records generate wrote, to one unit
    of their last written digit (numeric_files.same_record): truth.tsv keeps 10 significant digits, 1e-10 relative
    of a response of at most a few mm is < 1e-6 mm, far below the records' 1e-4 mm digit."""
    spec = RigSpec(imperfections=Imperfections(duration_s=1.0, keyphasor=True), seed=5, harmonics=5)
    generate(SMALL, spec, tmp_path / "solved")
    key = pd.read_csv(tmp_path / "solved" / "truth.tsv", sep="\t")
    again = write_steady_records(key, spec, tmp_path / "again")
    assert again["clipped_samples"].tolist() == key["clipped_samples"].tolist()
    for run in SMALL["run"]:
        same_record(tmp_path / "again" / "records" / f"{run}.csv", tmp_path / "solved" / "records" / f"{run}.csv")
    np.testing.assert_allclose(harmonics_of(key, 5)[:, 1], harmonics_of(again, 5)[:, 1], rtol=0)


def test_keyphasor_marks_the_unbalance_on_plus_x_once_per_turn(tmp_path):
    spec = RigSpec(imperfections=Imperfections(duration_s=1.0, keyphasor=True), seed=2, harmonics=3)
    truth = generate(SMALL.iloc[[1]], spec, tmp_path)
    record = read_record(tmp_path / "records" / "b.csv")
    marks = record.time_s[record.keyphasor]
    omega = 2 * np.pi * truth["rpm_true"].iloc[0] / 60
    np.testing.assert_allclose(np.diff(marks), 2 * np.pi / omega, atol=record.dt_s)  # one per revolution
    angle = omega * marks + truth["phase_origin_rad"].iloc[0]  # rotor angle at the marks
    assert np.abs(np.angle(np.exp(1j * angle))).max() <= omega * record.dt_s / 2 + 1e-9  # nearest sample to 0
    assert len(marks) == pytest.approx(omega / (2 * np.pi), abs=1)


def test_response_beyond_the_sensor_range_is_clipped_flagged_and_detected(tmp_path):
    truth_model = Truth.from_spec({"effects": DEFAULT_TRUTH["effects"],
                                   "values": {**DEFAULT_TRUTH["values"], "q_x": 0.005, "q_y": 0.005}})
    spec = RigSpec(truth_model, Imperfections(duration_s=1.0, speed_error=0.0), seed=1, harmonics=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RigWarning)
        truth = generate(plan(("c", 975, 0.0)), spec, tmp_path)  # 0 g near the resonance: ~24 mm
    messages = [str(w.message) for w in caught]
    assert any(re.match(r"run c: the response reaches 2\d\.\d+ mm .* \d+ sample\(s\) clipped", m) for m in messages)
    assert not truth["inside_range"].iloc[0] and truth["clipped_samples"].iloc[0] > 100
    # that large an orbit is also unstable (|mu| = 2.0): flagged as well, the record written all the same
    assert not truth["stable"].iloc[0] and any(m.startswith("run c: the truth's steady state at 975.00 RPM is "
                                                            "unstable") for m in messages)
    record = read_record(tmp_path / "records" / "c.csv")
    assert np.abs(record.x_m).max() == pytest.approx(14e-3, abs=1e-12)  # flat tops at the range
    with pytest.warns(DataWarning, match="is clipped at"):
        found = detect_saturation(record)
    assert {f.channel for f in found} == {"x", "y"} and {f.kind for f in found} == {"clipped"}


def test_non_unique_steady_state_is_reported(tmp_path):
    # a lightly damped Geometric machine softens (the u v^2 term) near 900 RPM: run-up and run-down differ
    truth_model = Truth.from_spec({"effects": GEOMETRIC, "values": {"k_b": 2411.3, "zeta_s": 0.01, "zeta_bup": 0.0,
                                                                    "q_x": 0.006, "q_y": 0.006}})
    spec = RigSpec(truth_model, Imperfections(duration_s=1.0, speed_error=0.0, clip=False), seed=1, harmonics=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RigWarning)
        truth = generate(plan(("d", 900, 0.0)), spec, tmp_path)
    assert not truth["unique"].iloc[0] and truth["updown_difference_rel"].iloc[0] > 0.5
    messages = [str(w.message) for w in caught]
    assert any("not unique" in m and "follows the run-up branch" in m for m in messages)
    assert any("not clipped (clip off)" in m for m in messages)  # 19 mm, reported but left unclipped


def test_an_unstable_steady_state_is_flagged_in_the_answer_key_and_on_the_console(tmp_path, capsys):
    """The geometric machine lightly damped with 14.8 g: its run-up branch is unstable at 866 RPM (|mu| = 2.28,
    checked by time integration in tests/test_stability.py); at 700 RPM it is stable. The record is written (the
    harmonic-balance state exists) but the run is flagged: column stable, its radius, a warning naming the run."""
    truth_model = Truth.from_spec({"effects": GEOMETRIC, "values": {"zeta_s": 0.01, "zeta_bup": 0.0}})
    spec = RigSpec(truth_model, Imperfections(duration_s=0.5, speed_error=0.0, clip=False), seed=1, harmonics=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RigWarning)
        truth = generate(plan(("s", 700, 14.8), ("u", 866, 14.8)), spec, tmp_path)
    assert truth["stable"].tolist() == [True, False]
    assert truth["floquet_radius"].iloc[0] < 1.0 and 2.0 < truth["floquet_radius"].iloc[1] < 2.6
    unstable = [str(w.message) for w in caught if "unstable" in str(w.message)]
    assert len(unstable) == 1 and unstable[0].startswith("run u: the truth's steady state at 866.00 RPM is unstable")
    assert "|mu| = 2." in unstable[0]
    key = pd.read_csv(tmp_path / "truth.tsv", sep="\t")  # the answer key keeps the flag
    assert key["stable"].tolist() == [True, False] and (key["floquet_radius"] > 0).all()
    assert read_runs(tmp_path / "runs.tsv")["run"].tolist() == ["s", "u"]  # the sheet is the usual one
    # the command line prints the flag per run and the warning on the console
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\nu\t866\t14.8\n")
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump({"truth": {"effects": GEOMETRIC,
                                                                  "values": {"zeta_s": 0.01, "zeta_bup": 0.0}},
                                                        "imperfections": {"duration_s": 0.5, "speed_error": 0.0,
                                                                          "clip": False}, "harmonics": 5}))
    assert main(["rig", "--plan", str(tmp_path / "plan.tsv"), "--spec", str(tmp_path / "spec.yaml"),
                 "--out", str(tmp_path / "cli")]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines()[0].split()[:6] == ["run", "rpm", "eccentric_mass_g", "rpm_true", "unique", "stable"]
    assert out.splitlines()[1].split()[5] == "False"
    assert "hybridtwin rig: warning: run u: the truth's steady state at 866.00 RPM is unstable" in err


@pytest.mark.parametrize("spec, message", [
    ({"truth": {"effects": ["unbalance", "no_such_effect"]}}, "no effect named 'no_such_effect'"),
    ({"truth": {"values": {"m_e": 0.01}}}, "m_e comes from each run's eccentric_mass_g"),
    ({"imperfections": {"noise": 0.1}}, r"imperfections: unknown key\(s\) \['noise'\]"),
    ({"imperfections": {"noise_mm": [0.2, 0.1]}}, "noise_mm must be"),
    ({"imperfections": {"unit": "inch"}}, "unit must be 'mm' or 'm'"),
    ({"colour": "red"}, r"rig: unknown key\(s\) \['colour'\]"),
])
def test_bad_rig_specs_are_rejected_with_the_reason(spec, message):
    with pytest.raises(RigError, match=message):
        RigSpec.from_mapping(spec)


def test_plan_needs_every_mass(tmp_path):
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\na\t400\t\n")
    with pytest.raises(RigError, match=r"plan.tsv: the rig needs every run's eccentric mass; empty for \['a'\]"):
        read_plan(tmp_path / "plan.tsv")


def test_cli_rig_with_options(tmp_path, capsys):
    (tmp_path / "plan.tsv").write_text("run\trpm\teccentric_mass_g\trole\nk1\t700\t19.5\tvalidate\n")
    code = main(["rig", "--plan", str(tmp_path / "plan.tsv"), "--out", str(tmp_path / "out"), "--seed", "5",
                 "--duration-s", "0.5", "--keyphasor", "--unit", "m", "--noise-mm", "0.03", "0.17",
                 "--set", "q_x=0.003", "--harmonics", "3"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "k1" in out and "True" in out and "wrote 1 record(s)" in err
    header = (tmp_path / "out" / "records" / "k1.csv").read_text().splitlines()[0]
    assert header == "time_s,x_m,y_m,keyphasor"
    key = yaml.safe_load((tmp_path / "out" / "truth.yaml").read_text())
    assert key["truth"]["values"]["q_x"] == 0.003 and key["imperfections"]["keyphasor"] is True
    assert main(["rig", "--plan", str(tmp_path / "nowhere.tsv"), "--out", str(tmp_path / "x")]) == 1
    assert "nowhere.tsv: file does not exist" in capsys.readouterr().err


def test_bundled_data_set_is_what_the_configured_truth_generates(tmp_path):
    """data/default is reproduced from config/rig.yaml's rig: default entry (README claim): the sheet and the
    answer key's YAML byte for byte, every record to one unit of its last written digit (another CPU's BLAS
    kernel may flip one, issue 42: numeric_files.same_record); the truth table's full-precision steady states to 1e-9
    relative, its solver messages aside (their last printed digits follow the numpy/BLAS build: bit-identity
    across library versions is not promised, and 1e-9 is far below the records' 1e-4 mm rounding, which
    stays byte-identical)."""
    config = yaml.safe_load((ROOT / "config" / "rig.yaml").read_text())
    entry = config["rig"]["default"]
    truth = generate(read_plan(ROOT / entry["plan"]), RigSpec.from_mapping(entry), tmp_path)
    for name in ["runs.tsv", "truth.yaml"]:
        assert filecmp.cmp(DEFAULT_DATA / name, tmp_path / name, shallow=False), name
    for run in truth["run"]:
        same_record(tmp_path / "records" / f"{run}.csv", DEFAULT_DATA / "records" / f"{run}.csv")
    # the solver's message quotes its final residual, round-off (~1e-17), which is left out
    bundled, again = (pd.read_csv(folder / "truth.tsv", sep="\t").drop(columns="message")
                      for folder in (DEFAULT_DATA, tmp_path))
    pd.testing.assert_frame_equal(bundled, again, check_exact=False, rtol=1e-9, atol=1e-15)
    # the data set's documented properties: the paper's 19 + 3 runs, unique steady states, inside +-14 mm
    assert len(truth) == 22 and (truth["role"] == "validate").sum() == 3
    assert truth["unique"].all() and truth["inside_range"].all() and (truth["clipped_samples"] == 0).all()
    assert truth["stable"].all() and truth["floquet_radius"].max() < 0.82  # measured 0.56 - 0.81
    assert truth["updown_difference_rel"].max() < 1e-10
    assert 1e3 * truth[["peak_x_m", "peak_y_m"]].to_numpy().max() < 14 - 0.5 - 4 * 0.05  # range - offset - noise
    assert sum(p.stat().st_size for p in DEFAULT_DATA.rglob("*")) < 10e6  # small enough for git


# --- the rig on the config's machine ------------------------------------------------------------------------


def _machine_rig(tmp_path, config: dict, truth: dict, plan_rows, name: str) -> int:
    """``hybridtwin rig --config`` with ``config`` and a short spec of ``truth``: its exit status."""
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump({"seed": 2, "harmonics": 3, "truth": truth,
                                                        "imperfections": {"duration_s": 0.2}}, sort_keys=False))
    plan_rows.to_csv(tmp_path / "plan.tsv", sep="\t", index=False)
    code = main(["rig", "--config", str(tmp_path / "config.yaml"), "--spec", str(tmp_path / "spec.yaml"),
                 "--plan", str(tmp_path / "plan.tsv"), "--out", str(tmp_path / name)])
    return code


def test_rig_builds_the_truth_on_the_configs_machine(tmp_path, capsys):
    """The stepped rotor with disks of tests/example_machines.py, given as the config's machine: the answer key's
    sensor harmonics are its linear unbalance response at the probes (node 8), solved by hand from its matrices
    (no model, no harmonic balance), at each run's true speed and mass, and the answer key records the machine."""
    from example_machines import SENSOR_NODE, linear_response, stepped_config, stepped_machine

    runs = plan(("slow", 2000, 20.0), ("near", 3500, 10.0), ("fast", 5000, 5.0))
    truth = {"effects": ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"],
             "values": {"k_a": 2.5e7, "c_b": 700.0}}
    config = stepped_config()
    assert _machine_rig(tmp_path, config, truth, runs, "out") == 0, capsys.readouterr().err
    table = pd.read_csv(tmp_path / "out" / "truth.tsv", sep="\t")
    machine = stepped_machine()
    for row in table.itertuples():
        X = linear_response(machine, row.rpm_true, row.eccentric_mass_g * 1e-3, k={"a": 2.5e7}, c={"b": 700.0})
        expected = X[[machine.dof(f"u{SENSOR_NODE}"), machine.dof(f"v{SENSOR_NODE}")]]
        # the channels are named after the machine's sensors x1, y1 (harmonic h: x1_<h>_re_m, ...)
        got = np.array([complex(row.x1_1_re_m, row.x1_1_im_m), complex(row.y1_1_re_m, row.y1_1_im_m)])
        # harmonic balance of a linear system: one Newton step, exact to round-off (1e-9 relative asserted)
        np.testing.assert_allclose(got, expected, rtol=1e-9)
        assert abs(complex(row.x1_2_re_m, row.x1_2_im_m)) < 1e-12 * abs(expected[0])  # linear: 1X only
    key = yaml.safe_load((tmp_path / "out" / "truth.yaml").read_text())
    assert key["machine"] == machine.to_mapping() == Machine.from_mapping(config["machine"]).to_mapping()
    assert key["truth"]["effects"] == truth["effects"]


def test_rig_on_the_default_machine_is_unchanged(tmp_path, capsys):
    """A config without machine: (the VARM) gives the files the rig gives without any config, byte for byte, and
    an answer key without a machine entry; a longer VARM shaft in the config gives another response."""
    runs = plan(("a", 600, 14.8), ("b", 800, 14.8))
    truth = {k: DEFAULT_TRUTH[k] for k in ("effects", "values")}
    assert _machine_rig(tmp_path, {"harmonics": 5}, truth, runs, "config") == 0, capsys.readouterr().err
    spec = RigSpec.from_mapping({"seed": 2, "harmonics": 3, "truth": truth, "imperfections": {"duration_s": 0.2}})
    generate(runs, spec, tmp_path / "library")
    for name in files(tmp_path / "library"):
        assert filecmp.cmp(tmp_path / "config" / name, tmp_path / "library" / name, shallow=False), name
    assert "machine" not in yaml.safe_load((tmp_path / "config" / "truth.yaml").read_text())
    longer = Machine.varm().to_mapping()
    longer["segments"][0]["length"] = 0.95
    assert _machine_rig(tmp_path, {"machine": longer}, truth, runs, "longer") == 0, capsys.readouterr().err
    base, other = (pd.read_csv(tmp_path / name / "truth.tsv", sep="\t") for name in ("config", "longer"))
    assert (np.abs(other["x1_re_m"] - base["x1_re_m"]) > 1e-3 * np.abs(base["x1_re_m"])).all()


def test_rig_refuses_a_machine_it_cannot_record(tmp_path, capsys):
    """Without the truth's effects (the default truth is the VARM's) or without any x, y probe pair at one node
    (a record's orbit): one line. Probes at two planes are recorded (test_planes.py)."""
    from example_machines import stepped_config, stepped_machine

    with pytest.raises(RigError, match="truth: machine 'stepped' needs the truth's effects"):
        Truth.from_spec({"values": {}}, machine=stepped_machine())
    config = stepped_config()
    config["machine"]["sensors"] = {"x1": {"node": 8, "direction": "x"}, "y2": {"node": 16, "direction": "y"}}
    code = _machine_rig(tmp_path, config, {"effects": ["linear_bearing@a", "linear_bearing@b"]},
                        plan(("a", 1000, 1.0)), "out")
    err = capsys.readouterr().err
    assert code == 1 and "no node with both an x and a y probe" in err and len(err.strip().splitlines()) == 1


def test_rig_rule_script_passes_the_machine(tmp_path):
    """scripts/rig.py (the rig rule) builds the truth on params.machine: the records equal the command's."""
    import logging
    import runpy
    from types import SimpleNamespace

    from example_machines import stepped_config

    config = stepped_config()
    entry = {"seed": 2, "harmonics": 3, "imperfections": {"duration_s": 0.2},
             "truth": {"effects": ["linear_bearing@a", "linear_bearing@b", "gyroscopic", "unbalance@d1"]}}
    runs = plan(("a", 2500, 12.0))
    runs.to_csv(tmp_path / "plan.tsv", sep="\t", index=False)
    out = tmp_path / "rule"
    out.mkdir()
    fake = SimpleNamespace(params=SimpleNamespace(spec=entry, machine=config["machine"], effects_files=[]),
                           input=SimpleNamespace(plan=str(tmp_path / "plan.tsv")),
                           output=SimpleNamespace(sheet=str(out / "runs.tsv")), log=[str(tmp_path / "rig.log")])
    try:
        runpy.run_path(str(ROOT / "scripts" / "rig.py"), init_globals={"snakemake": fake})
    finally:
        logging.captureWarnings(False)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(entry))
    assert main(["rig", "--config", str(tmp_path / "config.yaml"), "--spec", str(tmp_path / "spec.yaml"),
                 "--plan", str(tmp_path / "plan.tsv"), "--out", str(tmp_path / "command")]) == 0
    assert filecmp.cmp(out / "records" / "a.csv", tmp_path / "command" / "records" / "a.csv", shallow=False)
    assert yaml.safe_load((out / "truth.yaml").read_text())["machine"]["name"] == "stepped"
