"""One mistake, one message (issue 37, part 6).

A mistyped value of the machine used to be followed by one misleading line per effect placed at it ("no candidate
effect named 'bearing_anisotropy@b'" six times after "machine.bearings.b: unknown key 'kk'"); a bearing renamed in
machine.bearings by one line per use of its old name; and `hybridtwin check-data` said a problem every record
shares once per run. Here the root cause is the only message, naming the file, line and key, and a shared data
problem is said once, with the runs it concerns."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from hybridtwin.cli import main
from hybridtwin.config import ConfigError, check
from hybridtwin.data.shared_problems import group_messages, group_problems

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_bad_inputs import GOOD, RPM, signals  # noqa: E402  (the bad-input tests' data set)
from test_workflow import SNAKEMAKE  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "stepped_rotor"
SCHEMA = ROOT / "src" / "hybridtwin" / "config.schema.yaml"


@pytest.fixture
def example(tmp_path, monkeypatch):
    """The stepped rotor example's config and runs sheet in a project folder (cwd); returns the config."""
    (tmp_path / "config").mkdir()
    shutil.copy(EXAMPLE / "config" / "config.yaml", tmp_path / "config" / "config.yaml")
    shutil.copy(EXAMPLE / "runs.tsv", tmp_path / "runs.tsv")
    monkeypatch.chdir(tmp_path)
    return yaml.safe_load((tmp_path / "config" / "config.yaml").read_text())


def _problems(text: str) -> list[str]:
    Path("config/config.yaml").write_text(text)
    try:
        check(yaml.safe_load(text), SCHEMA, [Path("config/config.yaml")], config_dir="config")
    except ConfigError as err:
        return err.problems
    return []


BEARINGS = "bearings: {a: {node: 2, k: 2.0e+7, c: 800}, b: {node: 13, k: 1.0e+7, c: 500}}"
SENSOR = "x1: {node: 8, direction: x}"


@pytest.mark.parametrize("old, new, expected", [
    (BEARINGS, BEARINGS.replace("k: 1.0e+7", "kk: 1.0e+7"),
     "config/config.yaml, line 19: machine.bearings.b: unknown key 'kk' (did you mean 'k'?"),
    (SENSOR, SENSOR.replace("direction: x", "direction: z"),
     "config/config.yaml, line 21: machine.sensors.x1.direction: 'z' is not allowed (allowed: x, y)"),
    (BEARINGS, BEARINGS.replace("node: 13", "node: 30"),
     "config/config.yaml, line 10: machine: machine 'stepped': bearing 'b' at node 30: nodes are the integers 0..17"),
])
def test_a_mistyped_machine_value_is_the_only_error(example, old, new, expected):
    """Before: the root cause, then six 'no candidate effect named ...@a/@b' lines for diagnosis.candidates."""
    text = (EXAMPLE / "config" / "config.yaml").read_text()
    assert text.count(old) == 1
    problems = _problems(text.replace(old, new))
    assert len(problems) == 1, problems
    assert problems[0].startswith(expected), problems
    assert "candidate" not in problems[0]


def test_a_renamed_bearing_is_one_error_naming_every_use(example):
    """Bearing b renamed bb: its old name is used eight times (both variants, the diagnosis candidates, the rig's
    truth); one error says the machine has no place 'b', suggests 'bb' and names where it is used."""
    text = (EXAMPLE / "config" / "config.yaml").read_text()
    problems = _problems(text.replace(BEARINGS, BEARINGS.replace("b: {node: 13", "bb: {node: 13")))
    assert len(problems) == 1, problems
    message = problems[0]
    assert message.startswith("config/config.yaml, line 35: variants.linear.effects: 8 effects are placed at 'b' "
                              "(bearing_anisotropy@b, cross_coupled_damping@b, cross_coupled_stiffness@b, "
                              "linear_bearing@b), which the machine does not have (did you mean 'bb'?"), message
    assert message.endswith("named in variants.linear.effects, variants.anisotropic_b.effects, diagnosis.candidates, "
                            "rig.stepped.truth.effects"), message


def test_a_bearing_without_its_coefficients_is_one_error_at_the_bearing(example):
    """Bearing b without k: the eight effects sized to it (variants, candidates, the rig's truth) are one error, at
    machine.bearings.b (the line to fix), naming them and where they are used."""
    text = (EXAMPLE / "config" / "config.yaml").read_text()
    problems = _problems(text.replace(BEARINGS, BEARINGS.replace("b: {node: 13, k: 1.0e+7, c: 500}",
                                                                 "b: {node: 13, c: 500}")))
    assert len(problems) == 1, problems
    assert problems[0].startswith("config/config.yaml, line 19: machine.bearings.b: bearing 'b' is declared without "
                                  "its nominal k (and c) in machine.bearings (e.g. b: {node: 13, k: 2.0e+06, c: 300})"
                                  ", which 8 effects placed at it need (bearing_anisotropy@b, cross_coupled_damping@b,"
                                  " cross_coupled_stiffness@b, linear_bearing@b); named in variants.linear.effects, "
                                  "variants.anisotropic_b.effects, diagnosis.candidates, rig.stepped.truth.effects"), \
        problems


def test_one_mistyped_placement_keeps_its_own_message(example):
    """A place named once (a typo in one effect name, not a renamed bearing) is said as before, at that name."""
    text = (EXAMPLE / "config" / "config.yaml").read_text()
    old = "effects: [linear_bearing@a, linear_bearing@b, gyroscopic, unbalance@d1]"
    assert text.count(old) == 1
    problems = _problems(text.replace(old, old.replace("linear_bearing@b", "linear_bearing@c")))
    assert len(problems) == 1, problems
    assert "variants.linear.effects: no effect named 'linear_bearing@c' (did you mean 'linear_bearing@a'?" \
        in problems[0] or "variants.linear.effects: no effect named 'linear_bearing@c' (did you mean " \
        "'linear_bearing@b'?" in problems[0], problems


def test_snakemake_says_a_machine_typo_in_one_line(tmp_path):
    """The real thing: `snakemake -n` in a copy of the example with a mistyped key prints one config error."""
    shutil.copytree(EXAMPLE / "config", tmp_path / "config")
    shutil.copy(EXAMPLE / "runs.tsv", tmp_path / "runs.tsv")
    config = tmp_path / "config" / "config.yaml"
    config.write_text(config.read_text().replace(BEARINGS, BEARINGS.replace("k: 1.0e+7", "kk: 1.0e+7")))
    done = subprocess.run([*SNAKEMAKE, "-n", "-s", str(ROOT / "Snakefile"), "--directory", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    said = done.stdout + done.stderr
    assert done.returncode != 0
    errors = [line for line in said.splitlines() if "error" in line.lower()]
    assert errors == ["config error: config/config.yaml, line 19: machine.bearings.b: unknown key 'kk' (did you "
                      "mean 'k'? allowed: c, k, node, table)"], said


# --- check-data: a problem every record shares, said once ---------------------------------


def _data_set(folder: Path, headers: dict[str, str]) -> Path:
    """The bad-input tests' three runs (a, c fit, b validate), each record written with its header (two names:
    the y channel left out)."""
    for seed, (run, rpm) in enumerate(RPM.items()):
        t, x, y, _ = signals(rpm, seed=seed)
        names = headers.get(run, "time_s,x_mm,y_mm").split(",")
        table = pd.DataFrame(dict(zip(names, (t, x, y))))
        (folder / "records").mkdir(parents=True, exist_ok=True)
        table.to_csv(folder / "records" / f"{run}.csv", index=False, float_format="%.7g")
    sheet = folder / "runs.tsv"
    sheet.write_text(GOOD)
    return sheet


def _errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("hybridtwin check-data: error: ")]


def test_check_data_says_a_problem_every_run_shares_once(tmp_path, capsys):
    sheet = _data_set(tmp_path, {run: "time_s,x_mm" for run in RPM})
    assert main(["check-data", str(sheet)]) == 1
    errors = _errors(capsys.readouterr().err)
    assert len(errors) == 2, errors  # the shared problem, then: no usable fit run
    assert errors[0].startswith("hybridtwin check-data: error: every run of the sheet (3), the same problem; run a: ")
    assert f"{tmp_path / 'records' / 'a.csv'}: line 1 (header): missing column y_mm" in errors[0]
    assert errors[1].startswith(f"hybridtwin check-data: error: no usable fit run in {sheet}")


def test_check_data_names_the_runs_that_share_a_problem_and_keeps_different_ones_apart(tmp_path, capsys):
    """Runs a and b in metres that are millimetres (their values differ: the same problem all the same), run c
    without its y column: two errors, the first naming a and b (then: no usable fit run)."""
    sheet = _data_set(tmp_path, {"a": "time_s,x_m,y_m", "b": "time_s,x_m,y_m", "c": "time_s,x_mm"})
    assert main(["check-data", str(sheet)]) == 1
    err = capsys.readouterr().err
    errors = _errors(err)
    assert len(errors) == 3 and "no usable fit run" in errors[2], errors
    assert errors[0].startswith("hybridtwin check-data: error: 2 runs (a, b), the same problem; run a: "), errors
    assert err.count("they look like millimetres (name the column x_mm)") == 1, err  # run a's, said once
    assert errors[1].startswith("hybridtwin check-data: error: run c: ") and "missing column y_mm" in errors[1]


def test_grouping_leaves_out_only_names_and_figures():
    problems = {"r1": "records/r1.csv: column x_m: values up to 0.72 m", "r2": "records/r2.csv: column x_m: values "
                "up to 1.5 m", "r3": "records/r3.csv: missing column x1_mm", "r4": "records/r4.csv: missing column "
                "x2_mm"}
    groups = group_problems(problems)
    assert [g.runs for g in groups] == [("r1", "r2"), ("r3",), ("r4",)]  # x1_mm and x2_mm are different columns
    assert groups[0].message == problems["r1"]
    assert groups[0].describe(4) == "2 runs (r1, r2), the same problem; run r1: " + problems["r1"]
    assert group_problems({"a": "x", "b": "x"})[0].describe(2) == "every run of the sheet (2), the same problem; " \
        "run a: x"
    assert group_messages(["slow.csv: noise 0.1 mm", "fast.csv: noise 0.3 mm", "other"], ["s", "f"],
                          {"s": "data/slow.csv", "f": "data/fast.csv"}) == [("slow.csv: noise 0.1 mm", 2), ("other", 1)]
