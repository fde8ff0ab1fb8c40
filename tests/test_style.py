"""The workflow's habits (issue 37, part 5): its Snakefile and rule files formatted by snakefmt, and `snakemake
--lint` without a complaint. In the suite (not only in .ci/run) so that the README's test command covers them;
snakefmt comes with the `test` extra, and its check is skipped, saying so, where it is not installed."""

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


def test_snakemake_lint_is_clean():
    """`snakemake --lint` exits 1 on any lint (a rule without log or software environment, an absolute path, a
    long run: block...); here it finds none."""
    done = subprocess.run([sys.executable, "-m", "snakemake", "--lint"], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, f"snakemake --lint:\n{done.stdout}{done.stderr}"
    assert "Lints for" not in done.stdout + done.stderr


def test_the_conda_environment_is_the_package_pip_installed():
    """workflow/envs/hybridtwin.yaml (for --software-deployment-method conda) names no dependency of its own: Python
    and the repository's package installed by pip, so its dependencies are pyproject.toml's, which CI installs and
    tests (the floors too); conda itself is not on CI, so this is what can be checked of the file."""
    import yaml

    env = yaml.safe_load((ROOT / "workflow/envs/hybridtwin.yaml").read_text())
    pip = [d for d in env["dependencies"] if isinstance(d, dict)]
    assert [d for d in env["dependencies"] if isinstance(d, str)] == ["python>=3.11", "pip"]
    assert len(pip) == 1 and len(pip[0]["pip"]) == 1 and pip[0]["pip"][0].startswith("-e ")
    folder = pip[0]["pip"][0][3:].strip()  # relative to the file's folder: the repository's root, with pyproject.toml
    assert (ROOT / "workflow/envs" / folder).resolve() == ROOT and (ROOT / "pyproject.toml").is_file()
