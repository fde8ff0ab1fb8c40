"""The dependency floors CI installs (issue 37, part 7): .ci/floors.py pins exactly the floors pyproject.toml
declares, so that the floors check (.ci/run) cannot drift from what the package says it needs."""

import importlib.util
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("floors", ROOT / ".ci" / "floors.py")
floors = importlib.util.module_from_spec(spec)
spec.loader.exec_module(floors)


def test_every_declared_floor_is_pinned_exactly():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = floors.pins()
    declared = [r.replace(" ", "") for r in project["dependencies"]]
    assert len(pins) == len(declared) + 1  # and pytest's, from the test extra
    for requirement, pin in zip(declared, pins):
        name, floor = requirement.split(">=")
        assert pin == f"{name}=={floor}"
    assert pins[-1].startswith("pytest==")
    assert "numpy==2.0" in pins


def test_a_dependency_not_written_as_a_floor_is_refused(tmp_path):
    text = (ROOT / "pyproject.toml").read_text().replace('"scipy>=1.13"', '"scipy>=1.13,<2"')
    assert text != (ROOT / "pyproject.toml").read_text()
    (tmp_path / "pyproject.toml").write_text(text)
    with pytest.raises(SystemExit, match="dependency 'scipy>=1.13,<2' is not written 'name>=floor'"):
        floors.pins(tmp_path / "pyproject.toml")
