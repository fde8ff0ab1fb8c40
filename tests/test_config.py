"""The workflow configuration is checked before any job runs (hybridtwin.config.check): the strict schema,
then every name in it; each problem is one line naming the file and line, the key, the bad value and the
allowed names. The bundled config and the overlays the tests use still pass."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from snakemake.utils import update_config

from hybridtwin.config import ConfigError, check

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_workflow import NESTED, SMALL  # noqa: E402  (the workflow tests' base config and overlays)


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A project folder (cwd) with the bundled config and data/default/runs.tsv; returns its path."""
    (tmp_path / "config").mkdir()
    shutil.copy(ROOT / "config" / "config.yaml", tmp_path / "config" / "config.yaml")
    (tmp_path / "data" / "default").mkdir(parents=True)
    shutil.copy(ROOT / "data" / "default" / "runs.tsv", tmp_path / "data" / "default" / "runs.tsv")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _merged(*files: Path, command_line: dict | None = None) -> dict:
    """The config as Snakemake merges it: the files in order (nested keys updated), then --config."""
    config: dict = {}
    for file in files:
        update_config(config, yaml.safe_load(Path(file).read_text()) or {})
    update_config(config, dict(command_line or {}))
    return config


def _problems(overlay: str, project: Path, command_line: dict | None = None) -> list[str]:
    (project / "overlay.yaml").write_text(overlay)
    files = [Path("config/config.yaml"), Path("overlay.yaml")]
    try:
        check(_merged(*files, command_line=command_line), SCHEMA, files, command_line)
    except ConfigError as err:
        assert str(err) == "\n".join(err.problems)
        return err.problems
    return []


def test_bundled_config_passes(project):
    assert _problems("{}\n", project) == []


@pytest.mark.parametrize("overlay", [
    "offline: {spgd_variants: {final: {degree: 2}}}\n",  # test_workflow's overlays on its small config
    NESTED,
    NESTED + "identification: {polish: {nested: false}}\n",
    "offline: {scope: global}\n",
    SMALL.replace("k_w: [0, 1000]", "k_w: [0, 800]"),
])
def test_workflow_tests_configs_pass(project, overlay):
    (project / "config" / "config.yaml").write_text(SMALL)  # test_workflow writes it as the whole config
    (project / "data" / "small").mkdir()
    shutil.copy(ROOT / "data" / "default" / "runs.tsv", project / "data" / "small" / "runs.tsv")
    assert _problems(overlay, project) == []


# (overlay, the words every problem line must hold: key, bad value, the allowed names or a hint)
BAD = {
    "typo at the top": ("identifcation: {trials: 3}\n",
                        ["top level", "unknown key 'identifcation'", "did you mean 'identification'?"]),
    "unknown top-level key": ("colour: blue\n", ["unknown key 'colour'", "allowed: coverage, diagnosis"]),
    "typo in a section": ("offline: {chunk: 3}\n", ["offline", "unknown key 'chunk'", "did you mean 'chunks'?"]),
    "per_run parameter": ("identification: {per_run: [q_x, q_z]}\n",
                          ["identification.per_run", "'q_z'", "unknown of no variant", "q_y"]),
    "per_run parameter of no variant's unknowns": ("identification: {per_run: [zeta_blo]}\n",
                                                  ["identification.per_run", "'zeta_blo'", "unknown of no variant"]),
    "per_run as one name": ("identification: {per_run: q_x}\n", ["identification.per_run", "'q_x'", "array"]),
    "sparse variant of another type": ("diagnosis: {sparse_variant: [final]}\n",
                                       ["diagnosis.sparse_variant", "['final']", "string", "null"]),
    "n_scenarios variant": ("offline: {n_scenarios: {geometrc: 100}}\n",
                            ["offline.n_scenarios", "no variant named 'geometrc'", "did you mean 'geometric'?"]),
    "sparsity variant": ("identification: {sparsity: {expansoin: 0.1}}\n",
                         ["identification.sparsity", "'expansoin'", "variants: expansion, final, geometric"]),
    "spgd_variants variant": ("offline: {spgd_variants: {fianl: {degree: 2}}}\n",
                              ["offline.spgd_variants", "'fianl'", "did you mean 'final'?"]),
    "candidate": ("diagnosis: {candidates: [slope_spring, slope_sprung]}\n",
                  ["diagnosis.candidates", "'slope_sprung'", "did you mean 'slope_spring'?", "speed_damping"]),
    "sparse variant": ("diagnosis: {sparse_variant: expansoin}\n",
                       ["diagnosis.sparse_variant", "'expansoin'", "did you mean 'expansion'?", "null"]),
    "variant effect": ("variants: {geometric: {effects: [unbalance, geometric_sprin]}}\n",
                       ["variants.geometric.effects", "'geometric_sprin'", "did you mean 'geometric_spring'?"]),
    "variant parameter": ("variants: {final: {unknown: {k_zz: [0, 1]}}}\n",
                          ["variants.final.unknown", "'k_zz'", "did you mean 'k_z'?"]),
    "variant key": ("variants: {final: {unknowns: {k_z: [0, 1]}}}\n",
                    ["variants.final", "unknown key 'unknowns'", "did you mean 'unknown'?"]),
    "empty range": ("variants: {final: {unknown: {k_z: [1000, 0]}}}\n", ["variants.final", "k_z", "empty"]),
    "model error column": ("identification: {model_error: median}\n",
                           ["identification.model_error", "'median'", "median_error_pct"]),
    "wrong type in a oneOf": ("diagnosis: {confirm: some}\n", ["diagnosis.confirm", "'some'", "integer >= 0"]),
    "negative sparsity": ("identification: {sparsity: {expansion: -1}}\n",
                          ["identification.sparsity.expansion", "-1", "minimum of 0"]),
    "reversed coverage": ("coverage: {rpm: [900, 300]}\n", ["coverage.rpm", "[900, 300]", "low < high"]),
    "effects file": ("effects_files: [missing.py]\n", ["effects_files", "missing.py", "does not exist"]),
    "runs sheet": ("runs: data/nowhere.tsv\n", ["runs", "data/nowhere.tsv", "does not exist"]),
    "rig truth effect": ("rig: {default: {truth: {effects: [unbalance, slope_sprung]}}}\n",
                         ["rig.default", "slope_sprung"]),
}


@pytest.mark.parametrize("name", BAD)
def test_each_bad_value_is_one_line_naming_file_line_key_and_value(project, name):
    overlay, words = BAD[name]
    problems = _problems(overlay, project)
    assert len(problems) == 1, problems
    line = problems[0]
    assert "\n" not in line
    assert line.startswith("overlay.yaml, line 1: "), line  # every overlay above sets its value on line 1
    for word in words:
        assert word in line, (word, line)


@pytest.mark.parametrize("overlay", [
    "identification: {per_run: [k_w]}\n",  # an unknown of one variant (final) only: per run there
    "identification: {per_run: []}\n",
    "diagnosis: {sparse_variant: null}\n",
    "diagnosis: {sparse_variant: geometric}\n",
])
def test_per_run_and_sparse_variant_accept_what_the_workflow_can_use(project, overlay):
    assert _problems(overlay, project) == []


def test_every_problem_is_reported_with_its_own_line(project):
    overlay = ("identification:\n"
               "  trials: 3\n"
               "  per_run: [q_x, q_z]\n"
               "offline:\n"
               "  n_scenarios: {geometrc: 100}\n"
               "identifcation: {}\n")
    problems = _problems(overlay, project)
    assert len(problems) == 3, problems
    assert any(p.startswith("overlay.yaml, line 6: top level: unknown key 'identifcation'") for p in problems)
    assert any(p.startswith("overlay.yaml, line 3: identification.per_run: 'q_z'") for p in problems)
    assert any(p.startswith("overlay.yaml, line 5: offline.n_scenarios: no variant named 'geometrc'")
               for p in problems)


def test_the_file_that_sets_the_value_is_named(project):
    base = (project / "config" / "config.yaml").read_text().splitlines()
    harmonics_line = base.index("harmonics: 5") + 1
    (project / "config" / "config.yaml").write_text("\n".join(base).replace("harmonics: 5", "harmonics: 0") + "\n")
    assert _problems("{}\n", project) == [
        f"config/config.yaml, line {harmonics_line}: harmonics: 0 is less than the minimum of 1"]
    # an overlay setting it, then --config: the source of highest precedence is named
    assert _problems("harmonics: -1\n", project)[0].startswith("overlay.yaml, line 1: harmonics: -1 ")
    assert _problems("harmonics: -1\n", project, {"harmonics": -2})[0].startswith(
        "--config harmonics=...: harmonics: -2 ")
    # a key set nowhere: the file of the section it is missing from
    (project / "config" / "config.yaml").write_text("harmonics: 5\nruns: data/default/runs.tsv\n")
    assert _problems("{}\n", project) == ["config/config.yaml: top level: missing key 'variants'"]


def test_user_effects_are_known_by_name(project):
    (project / "config" / "tilt.py").write_text(
        "from hybridtwin import Parameter, PolynomialBearing, Term\n"
        "tilt = PolynomialBearing(name='tilt', meaning='tilt stiffness',\n"
        "    parameters=(Parameter('k_t', 'N', (0.0, 500.0), 0.0, 'slope stiffness'),),\n"
        "    terms=(Term(lambda p: p.k_t, (0, 0, 1, 0), \"k_t u'\"),))\n")
    overlay = ("effects_files: [tilt.py]\n"
               "variants: {tilted: {effects: [centrifugal_softening, structural_damping, upper_housing,\n"
               "  lower_bearing, unbalance, shaft_bow, geometric_spring, tilt], unknown: {k_t: [0, 500]}}}\n"
               "diagnosis: {candidates: [tilt, slope_spring]}\n"
               "identification: {per_run: [q_x, k_t]}\n")
    assert _problems(overlay, project) == []
    # without the effects file, each name that needs it is an error
    problems = _problems(overlay.replace("effects_files: [tilt.py]", "effects_files: []"), project)
    assert [p.split(": ")[1] for p in problems] == ["variants.tilted.effects", "diagnosis.candidates"]


def test_snakemake_stops_before_any_job_with_the_one_line_error(tmp_path):
    overlay = tmp_path / "typo.yaml"
    overlay.write_text("identification:\n  per_run: [q_z]\n")
    run = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1", "--configfile", str(overlay)],
                         cwd=ROOT, capture_output=True, text=True)
    output = run.stdout + run.stderr
    assert run.returncode != 0
    assert f"config error: {overlay}, line 2: identification.per_run: 'q_z' is an unknown of no variant" in output
    assert "Traceback" not in output and "Job stats" not in output
