"""The workflow's habits (issue 37, part 5): its Snakefile and rule files formatted by snakefmt, and `snakemake
--lint` without a complaint but the one taken on knowingly (SOFTWARE_STACK). In the suite (not only in .ci/run) so
that the README's test command covers them; snakefmt comes with the `test` extra, and its check is skipped, saying
so, where it is not installed."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_workflow_is_formatted_by_snakefmt():
    """`snakefmt --check` (its settings in pyproject.toml, [tool.snakefmt]) would change no file."""
    if importlib.util.find_spec("snakefmt") is None:
        pytest.skip("snakefmt is not installed (it comes with pip install -e '.[test]')")
    files = ["Snakefile", "workflow/rules"]
    done = subprocess.run([sys.executable, "-m", "snakefmt", "--check", *files], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, (
        f"snakefmt would reformat (run `snakefmt {' '.join(files)}`):\n{done.stdout}{done.stderr}")


#: the one lint taken on knowingly: the rules name no conda environment or container. The workflow runs in the
#: environment the package is installed in (pip, pyproject.toml: what CI installs and tests, its floors included);
#: a conda environment file could not be tested here (no conda on CI), so there is none (issue 37, part 7).
SOFTWARE_STACK = "Specify a conda environment or container for each rule."


def _lints(text: str) -> dict[str, list[str]]:
    """{lint title: rules} from `snakemake --lint`'s text: "Lints for rule NAME (...)", then "    * TITLE:" lines."""
    found: dict[str, list[str]] = {}
    rule = None
    for line in text.splitlines():
        if line.startswith("Lints for "):
            rule = line[len("Lints for "):].split(" (")[0]
        elif line.startswith("    * ") and rule is not None:
            found.setdefault(line[len("    * "):].rstrip(":"), []).append(rule)
    return found


def test_snakemake_lint_finds_nothing_but_the_software_stack():
    """`snakemake --lint` exits 1 on any lint (a rule without log, an absolute path, a long run: block...); the
    only one it may find is SOFTWARE_STACK (above, why), and then at every rule alike."""
    done = subprocess.run([sys.executable, "-m", "snakemake", "--lint"], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    said = done.stdout + done.stderr
    lints = _lints(said)
    assert set(lints) <= {SOFTWARE_STACK}, f"snakemake --lint:\n{said}"
    assert done.returncode == (1 if lints else 0), said


def test_the_lint_reader_sees_a_lint():
    """_lints reads snakemake's text as it is printed (so that the test above cannot pass by reading nothing)."""
    text = ("Lints for rule pod (line 4, workflow/rules/pod.smk):\n"
            "    * Specify a conda environment or container for each rule.:\n"
            "      This way, the used software for each specific step is documented, and the\n"
            "Lints for rule all (line 1, Snakefile):\n    * Do not use absolute path in input directive /x.:\n")
    assert _lints(text) == {SOFTWARE_STACK: ["rule pod"],
                            "Do not use absolute path in input directive /x.": ["rule all"]}
