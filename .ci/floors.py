"""Print the dependency floors of pyproject.toml as exact pins, one per line, for `pip install -c` (issue 37, part 7).

Every `name>=X` of [project] dependencies becomes `name==X` (a requirement without a floor is left free), and so
does pytest's floor in the test extra (the quick subset runs on it), so that CI installs exactly the lowest
versions the package declares and the pins cannot drift from pyproject.toml. A floor may carry an upper bound
after it, `name>=X,<Y` (plotly's `<7`, which ROSS needs): the floor is still what CI installs. Any other form (a
marker, `~=`, `==`, a bound without a floor) is an error here: the floors check would no longer test what is
declared.

    python .ci/floors.py [pyproject.toml]
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_FLOOR = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:>=\s*([^,;<>=!~\s]+)(?:\s*,\s*<\s*[^,;<>=!~\s]+)?)?\s*$")
#: the test extra's requirements the floors check needs (it runs pytest without xdist)
TEST_NEEDS = ("pytest",)


def pins(pyproject: Path = ROOT / "pyproject.toml") -> list[str]:
    """``name==floor`` for every dependency with a floor, then the test extra's ``TEST_NEEDS``."""
    project = tomllib.loads(pyproject.read_text())["project"]
    test = [r for r in project["optional-dependencies"]["test"] if _name(r, pyproject) in TEST_NEEDS]
    out = []
    for requirement in [*project["dependencies"], *test]:
        name, floor = _parse(requirement, pyproject)
        if floor is not None:
            out.append(f"{name}=={floor}")
    return out


def _name(requirement: str, pyproject: Path) -> str:
    return _parse(requirement, pyproject)[0].lower()


def _parse(requirement: str, pyproject: Path) -> tuple[str, str | None]:
    match = _FLOOR.match(requirement)
    if match is None:
        raise SystemExit(f"{pyproject}: dependency {requirement!r} is not written 'name>=floor' (or "
                         "'name>=floor,<bound', or a bare name): .ci/floors.py cannot pin its floor")
    return match.group(1), match.group(2)


if __name__ == "__main__":
    print("\n".join(pins(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "pyproject.toml")))
