"""The dependency floors CI installs (issue 37, part 7): .ci/floors.py pins exactly the floors pyproject.toml
declares, so that the floors check (.ci/run) cannot drift from what the package says it needs."""

import importlib.util
import re
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
        assert pin == f"{name}=={floor.split(',<')[0]}"  # an upper bound after the floor is not pinned
    assert pins[-1].startswith("pytest==")
    assert "numpy==2.0" in pins


@pytest.mark.parametrize("written", ["scipy>=1.13; python_version >= '3.11'", "scipy~=1.13", "scipy==1.13",
                                     "scipy<2", "scipy>=1.13,!=1.14"])
def test_a_dependency_not_written_as_a_floor_is_refused(tmp_path, written):
    text = (ROOT / "pyproject.toml").read_text().replace('"scipy>=1.13"', f'"{written}"')
    assert text != (ROOT / "pyproject.toml").read_text()
    (tmp_path / "pyproject.toml").write_text(text)
    with pytest.raises(SystemExit, match=f"dependency {re.escape(repr(written))} is not written 'name>=floor'"):
        floors.pins(tmp_path / "pyproject.toml")


def test_a_floor_with_an_upper_bound_pins_the_floor(tmp_path):
    """plotly>=X,<7 (ROSS 2.3.0 needs plotly below 7): CI installs plotly==X, the bound only keeps newer ones out."""
    text = (ROOT / "pyproject.toml").read_text().replace('"scipy>=1.13"', '"scipy >= 1.13, < 2"')
    (tmp_path / "pyproject.toml").write_text(text)
    assert "scipy==1.13" in floors.pins(tmp_path / "pyproject.toml")
    assert any(pin.startswith("plotly==") for pin in floors.pins())
