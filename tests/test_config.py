"""The workflow configuration is checked before any job runs (hybridtwin.config.check): the strict schema,
then every name in it; each problem is one line naming the file and line, the key, the bad value and the
allowed names. The bundled config and the overlays the tests use still pass."""

import copy
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from snakemake.utils import update_config

from hybridtwin.config import ConfigError, check

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "src" / "hybridtwin" / "config.schema.yaml"
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


def _merged_text(*texts: str) -> dict:
    """The config that YAML texts make when Snakemake merges them in order."""
    config: dict = {}
    for text in texts:
        update_config(config, yaml.safe_load(text) or {})
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
    "unknown top-level key": ("colour: blue\n", ["unknown key 'colour'", "allowed: coverage, design, diagnosis"]),
    "typo in a section": ("offline: {chunk: 3}\n", ["offline", "unknown key 'chunk'", "did you mean 'chunks'?"]),
    "per_run parameter": ("identification: {per_run: [q_x, q_z]}\n",
                          ["identification.per_run", "'q_z'", "unknown of no variant", "q_y"]),
    "per_run parameter of no variant's unknowns": ("identification: {per_run: [zeta_blo]}\n",
                                                  ["identification.per_run", "'zeta_blo'", "unknown of no variant"]),
    "variant's own per_run": ("variants: {final: {per_run: [q_x, q_z]}}\n",
                              ["variants.final.per_run", "'q_z'", "not an unknown of variant 'final'", "q_y"]),
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


def test_the_main_config_holds_no_rig_and_a_bad_rig_entry_names_config_rig_yaml(project):
    """config/config.yaml lists only what acts on the main job (issue 50): the virtual rig's data sets live in
    config/rig.yaml, which the Snakefile loads after it (validated with it); a bad entry there is one line naming
    config/rig.yaml, the entry's line and the key."""
    assert "rig" not in yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    assert 'RIG_CONFIG = "config/rig.yaml"' in (ROOT / "Snakefile").read_text()
    text = (ROOT / "config" / "rig.yaml").read_text()
    assert list(yaml.safe_load(text)) == ["rig"]
    files = [Path("config/config.yaml"), Path("config/rig.yaml")]
    (project / files[1]).write_text(text)
    check(_merged(*files), SCHEMA, files, None)  # the bundled pair passes
    bad = text.replace("slope_spring]", "slope_sprung]")
    (project / files[1]).write_text(bad)
    with pytest.raises(ConfigError) as err:
        check(_merged(*files), SCHEMA, files, None)
    line = bad.splitlines().index("  default:") + 1  # the entry the problem is reported on (rig.default)
    assert len(err.value.problems) == 1, err.value.problems
    assert err.value.problems[0].startswith(f"config/rig.yaml, line {line}: "), err.value.problems
    assert "rig.default" in err.value.problems[0] and "slope_sprung" in err.value.problems[0]


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
    "variants: {final: {per_run: []}}\n",  # a diagnosis's recommendation: the bow shared in this variant
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


# --- defaults in one place: the schema's default: entries, read by hybridtwin.settings ----------------------

def _library_defaults() -> dict:
    """Every default the library fills in, by config section: the schema's (hybridtwin.settings.defaults)."""
    from hybridtwin.settings import defaults

    return defaults()


def _schema() -> dict:
    return yaml.safe_load(SCHEMA.read_text())


def _declared(schema: dict, path: tuple = ()) -> dict:
    """{path: default} of every property along the schema's nested ``properties`` from the top."""
    found = {}
    for key, sub in schema.get("properties", {}).items():
        if "default" in sub:
            found[path + (key,)] = sub["default"]
        found |= _declared(sub, path + (key,))
    return found


def _same(a, b) -> bool:
    """Equal and of the same type, recursively (1 is not 1.0 or True: a filled-in default that differs in type
    from the library's would change a job's params, so rerun it)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _all_default_nodes(node, path: tuple = ()) -> list[tuple]:
    """The path (schema keys) of every schema node that declares a default."""
    found = []
    if isinstance(node, dict):
        if "default" in node:
            found.append(path)
        for key, value in node.items():
            if key != "default":
                found += _all_default_nodes(value, path + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            found += _all_default_nodes(value, path + (i,))
    return found


def _minimal() -> dict:
    return {"runs": "runs.tsv", "harmonics": 5, "variants": {"v": {"effects": ["unbalance"]}}}


def test_the_schema_is_the_packages_and_the_only_place_of_defaults():
    """The schema ships with the package (found wherever it is installed) and the workflow validates against that
    same file; no module of the package keeps a DEFAULTS dict of a config section (every default is the schema's);
    the schema declares no default for a required key, nor under $defs or a mapping of names (a validator filling
    them in would fill every offline.spgd_variants entry)."""
    import ast

    from hybridtwin import settings

    assert settings.SCHEMA_FILE.resolve() == SCHEMA.resolve() and SCHEMA.is_file()
    assert not (ROOT / "workflow" / "schemas" / "config.schema.yaml").exists()  # one file, not two
    assert 'hybridtwin = ["config.schema.yaml"]' in (ROOT / "pyproject.toml").read_text()  # package data
    kept = []
    for path in sorted((ROOT / "src" / "hybridtwin").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, ast.AnnAssign) else []
            kept += [f"{path.name}: {t.id}" for t in targets if isinstance(t, ast.Name) and t.id.endswith("DEFAULTS")]
    assert kept == []
    schema = _schema()
    declared = _declared(schema)
    assert not set(declared) & {(key,) for key in schema["required"]}
    nowhere_else = [p for p in _all_default_nodes(schema) if tuple(k for k in p if k != "properties") not in declared]
    assert nowhere_else == []


def test_the_schema_is_applied_once():
    """The Snakefile's check validates the config against the schema; nothing in the workflow validates it again
    (Snakemake's validate would also write the defaults into the config: the settings objects hold them)."""
    sources = [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]
    assert [str(p.name) for p in sources if "config.schema.yaml" in p.read_text()] == []
    assert [str(p.name) for p in sources if "validate(config" in p.read_text()] == []
    assert "check_or_exit(" in (ROOT / "Snakefile").read_text()
    assert "SETTINGS = Settings.from_config(config)" in (ROOT / "workflow" / "rules" / "common.smk").read_text()


def test_every_section_is_the_schemas_defaults_without_a_config():
    """A config that sets no option: every section's values are the schema's defaults, type included (what a
    validator filling them in would write), in every nesting (identification.polish, offline.enrichment...)."""
    from dataclasses import fields

    from hybridtwin.settings import Settings, defaults

    built = Settings.from_config(_minimal() | {"online": {"variant": "v", "records": "runs.tsv"}})
    schema_defaults = defaults()
    for section, value in (("offline", built.offline.options()), ("design", built.design.as_dict()),
                           ("diagnosis", built.diagnosis.as_dict()), ("online", built.online.as_dict()),
                           ("identification", built.identification.as_dict())):
        expected = schema_defaults[section]
        if section == "identification":
            assert value.pop("variant_per_run") == {}
        if section == "online":
            assert {k: value.pop(k) for k in ("variant", "records")} == {"variant": "v", "records": "runs.tsv"}
        assert _same(value, expected), (section, value, expected)  # keys in any order, values and types alike
    assert _same(built.transient.as_dict(), defaults("report")["transient"])
    # every field of a section has a schema default but the required ones (online: variant, records)
    declared = _declared(_schema())
    for section, obj in (("offline", built.offline), ("design", built.design), ("diagnosis", built.diagnosis)):
        assert [f.name for f in fields(obj) if (section, f.name) not in declared
                and f.name != "enrichment"] == [], section
    assert built.offline.enrichment.as_dict() == defaults("offline")["enrichment"]
    assert Settings.from_config(_minimal()).online is None  # no online: section, no twin online


def test_a_wrong_type_or_an_unknown_key_is_named():
    """The schema checks every value first (hybridtwin.config.check); a config that skipped it and has a value of
    the wrong type, or a key no setting has, stops with the key named."""
    from hybridtwin.settings import Settings, SettingsError

    cases = {"offline.chunks": {"offline": {"chunks": "4"}},
             "offline.enrichment.chunks": {"offline": {"enrichment": {"chunks": 2.5}}},
             "identification.polish.joint": {"identification": {"polish": {"joint": "yes"}}},
             "diagnosis.alpha": {"diagnosis": {"alpha": "0.01"}},
             "design.runs": {"design": {"runs": True}},
             "report.transient.frame": {"report": {"transient": {"frame": 1}}},
             "offline.chunk": {"offline": {"chunk": 4}},
             "offline.spgd_variants": {"offline": {"spgd_variants": {"nope": {"degree": 8}}}}}
    for key, section in cases.items():
        with pytest.raises(SettingsError, match=rf"config {key}\b"):
            Settings.from_config(_minimal() | section)
    Settings.from_config(_minimal() | {"offline": {"sensor_range_mm": 14}})  # an int is a number (as written)


def test_the_sections_are_frozen_and_travel_to_a_job():
    """Each section is a frozen object; it pickles as it is (a rule's params, into a job's process)."""
    import dataclasses
    import pickle

    from hybridtwin.settings import Settings

    built = Settings.from_config(yaml.safe_load((ROOT / "config" / "config.yaml").read_text()))
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.offline.chunks = 8
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.identification.polish.joint = False
    assert pickle.loads(pickle.dumps(built)) == built


def test_the_defaults_are_a_valid_config():
    """The schema's defaults, written out as a config, pass the schema (a default the schema forbids, e.g. out of
    range, would be a default no user could write)."""
    from jsonschema import Draft202012Validator

    config = {**_minimal(), **copy.deepcopy(_library_defaults())}
    config["online"] |= {"variant": "v", "records": "runs.tsv"}  # the section's required keys (no default)
    assert [error.message for error in Draft202012Validator(_schema()).iter_errors(config)] == []


@pytest.mark.parametrize("overlay", [
    "",
    "offline: {spgd: {max_terms: 20}, spgd_variants: {final: {degree: 2}}, enrichment: {chunks: 3}}\n",
    "identification: {polish: {joint: false}, joint: {trials: 7}}\ndiagnosis: {alpha: 0.05}\n",
    "identification: {}\ndiagnosis: {}\noffline: {}\n",
])
def test_snakemake_filling_in_the_schema_defaults_changes_no_option(overlay):
    """The settings are the same whether a config leaves the defaults out or has them written in (as Snakemake's
    validate writes them into every section the config gives; the workflow no longer calls it, but a user's config
    may spell every default out): what each rule reads (its params) is the same either way."""
    from snakemake.utils import validate

    from hybridtwin import config as cfg
    from hybridtwin.settings import Settings

    config = _merged_text(SMALL, overlay)
    config["runs"] = str(ROOT / "data" / "default" / "runs.tsv")
    filled = copy.deepcopy(config)
    validate(filled, str(SCHEMA))
    assert filled != config or overlay == ""  # defaults were filled in where the sections are given

    def options(c: dict) -> dict:
        built = Settings.from_config(c)
        out = {"settings": built, "offline": cfg.offline(c), "diagnosis": built.diagnosis.options(),
               "effects": cfg.user_effects(c)}
        for name in c["variants"]:
            out[name] = (cfg.offline_for(c, name), built.identification.for_variant(name),
                         [built.identification.rule(name, rule) for rule in ("run", "joint", "validation")])
        return out

    assert repr(options(filled)) == repr(options(config))  # repr: the params Snakemake compares


def test_the_bundled_config_writes_out_the_defaults():
    """config/config.yaml sets its offline, identification and diagnosis options to the schema's defaults: the
    workflow and the Python API (which fills in the defaults) run alike."""
    bundled = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    library = _library_defaults()
    for section in ("offline", "identification", "diagnosis", "design"):
        for key, value in bundled[section].items():
            default = library[section][key]
            if key in ("spgd", "joint", "polish", "enrichment"):  # the keys it sets of a nested section
                assert value == {k: default.get(k) for k in value}, (section, key, value, default)
            else:
                assert value == default, (section, key, value, default)


def test_the_offline_spgd_defaults_are_the_sparse_pgds():
    """offline.spgd's defaults but the degree candidates are hybridtwin.offline.spgd.SparsePGD's own (the workflow's
    libraries and an sPGD built in Python fit alike)."""
    import inspect

    from hybridtwin.offline.spgd import SparsePGD
    from hybridtwin.settings import defaults

    signature = inspect.signature(SparsePGD).parameters
    for key, value in defaults("offline")["spgd"].items():
        if key != "degree":
            assert _same(value, signature[key].default), (key, value, signature[key].default)


def test_a_variants_own_per_run_overrides_the_identification_default_for_it_alone():
    """variants.NAME.per_run (what a diagnosis recommends when the data do not need the bow per run) is the joint
    fit's per_run for that variant; the others keep identification.per_run."""
    from hybridtwin.settings import IdentificationSettings

    config = {"identification": {"per_run": ["q_x", "q_y"]},
              "variants": {"geometric": {"effects": ["unbalance"]},
                           "geometric_lbc": {"effects": ["unbalance"], "per_run": []}}}
    identification = IdentificationSettings.from_config(config)
    assert identification.rule("geometric_lbc", "joint")["per_run"] == []
    assert identification.rule("geometric", "joint")["per_run"] == ["q_x", "q_y"]


def _workflow_overlay(heading: str) -> str:
    """The yaml block under ``heading`` in docs/workflow.md (the overlays moved there from the README, issue 55)."""
    import re

    page = (ROOT / "docs" / "workflow.md").read_text()
    found = re.search(rf"^### {re.escape(heading)}\n.*?```yaml\n(.*?)```", page, re.DOTALL | re.MULTILINE)
    assert found, f"docs/workflow.md: no yaml block under '### {heading}'"
    return found.group(1)


def test_the_readmes_quick_look_overlay_is_valid_and_does_what_it_says(project):
    """The guide's overlay for a smaller library design (its yaml block in docs/workflow.md, under "The paper's
    libraries, and a smaller design"; the README's until issue 55) passes the checks, keeps the libraries (the
    default), halves every bundled variant's design (its comment says so), switches the enrichment off and keeps one
    sPGD degree; the options it does not name keep their values (Snakemake merges nested keys)."""
    from hybridtwin.config import n_scenarios, offline, variant

    block = _workflow_overlay("The paper's libraries, and a smaller design")
    assert _problems(block, project) == []
    base = _merged(Path("config/config.yaml"))
    quick = _merged(Path("config/config.yaml"), Path("overlay.yaml"))
    assert set(quick["offline"]["n_scenarios"]) == set(base["variants"])
    for name in base["variants"]:
        assert 2 * n_scenarios(quick, variant(quick, name)) == n_scenarios(base, variant(base, name)), name
    assert offline(quick)["scope"] == "run" and offline(base)["scope"] == "run"
    assert offline(quick)["enrichment"]["n_scenarios"] == 0
    assert offline(quick)["enrichment"]["chunks"] == offline(base)["enrichment"]["chunks"]
    assert offline(quick)["spgd"]["degree"] == 8 and offline(base)["spgd"]["degree"] != 8
    assert {k: v for k, v in offline(quick)["spgd"].items() if k != "degree"} == {
        k: v for k, v in offline(base)["spgd"].items() if k != "degree"}


def test_the_shortcut_for_small_machines_overlay_is_valid_and_does_what_it_says(project):
    """The guide's shortcut (docs/workflow.md, "The shortcut for small machines") passes the checks and switches the
    libraries off (the bundled config's default is the paper's library per run) and nothing else: every other option,
    offline or not, keeps its value."""
    from hybridtwin.config import offline

    block = _workflow_overlay("The shortcut for small machines")
    assert _problems(block, project) == []
    base = _merged(Path("config/config.yaml"))
    small = _merged(Path("config/config.yaml"), Path("overlay.yaml"))
    assert offline(base)["scope"] == "run" and offline(small)["scope"] == "none"
    assert {k: v for k, v in offline(small).items() if k != "scope"} == {
        k: v for k, v in offline(base).items() if k != "scope"}
    assert {k: v for k, v in small.items() if k != "offline"} == {k: v for k, v in base.items() if k != "offline"}


def test_no_literal_harmonics_default_in_a_signature():
    """The harmonics a function or a dataclass takes when not told are named constants (issue 37, "no literal
    defaults in signatures"): the analysis's solver.DEFAULT_HARMONICS (the config's ``harmonics`` is required, it
    has no schema default) and transient.RESOLVED_HARMONICS (the time integration's and the rig truth's; ``rig:
    NAME: harmonics`` has no schema default either), their values as before."""
    import ast
    import inspect

    from hybridtwin.rig.rig import RigSpec, solve_truth
    from hybridtwin.solvers import solver, sweep, transient

    literal = []
    for path in sorted((ROOT / "src" / "hybridtwin").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.posonlyargs + node.args.args
                pairs = list(zip(args[len(args) - len(node.args.defaults):], node.args.defaults))
                pairs += [(a, d) for a, d in zip(node.args.kwonlyargs, node.args.kw_defaults) if d is not None]
                literal += [f"{path.name}:{node.lineno} {node.name}" for a, d in pairs
                            if a.arg == "harmonics" and isinstance(d, ast.Constant) and d.value not in (None, 1)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) \
                    and node.target.id == "harmonics" and isinstance(node.value, ast.Constant):
                literal.append(f"{path.name}:{node.lineno} field harmonics")
    assert literal == []  # (harmonics=1: the linear response's single harmonic, not a choice of H)
    assert (solver.DEFAULT_HARMONICS, transient.RESOLVED_HARMONICS) == (5, 7)
    for function in (sweep.start_state, sweep.integrate_sweep, transient.settle, transient.run_up_harmonics,
                     solve_truth):
        assert inspect.signature(function).parameters["harmonics"].default == transient.RESOLVED_HARMONICS
    assert RigSpec().harmonics == transient.RESOLVED_HARMONICS


def test_the_level_of_a_test_is_written_once():
    """alpha = 0.01 lives in one place in the code (identify.uncertainty.ALPHA, issue 52); the schema's defaults of
    the config's diagnosis.alpha and online.alpha are YAML and cannot import it, so they are checked against it, and
    no module writes the number again as a default."""
    import ast

    from hybridtwin.identify.uncertainty import ALPHA
    from hybridtwin.settings import defaults

    assert defaults("diagnosis")["alpha"] == ALPHA and defaults("online")["alpha"] == ALPHA
    package = Path(__file__).resolve().parents[1] / "src" / "hybridtwin"
    again = []
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([t.id for t in node.targets if isinstance(t, ast.Name)] if isinstance(node, ast.Assign) else
                     [a.arg for a in node.args.args[-len(node.args.defaults):]] if isinstance(node, ast.FunctionDef)
                     and node.args.defaults else [])
            values = ([node.value] if isinstance(node, ast.Assign) else
                      node.args.defaults if isinstance(node, ast.FunctionDef) else [])
            again += [f"{path.name}:{node.lineno}" for name, value in zip(names, values)
                      if "alpha" in name.lower() and isinstance(value, ast.Constant) and value.value == ALPHA
                      and not (path.name == "uncertainty.py" and name == "ALPHA")]
    assert not again, again
