"""The quick example (examples/quick/README.md): a project of its own that shows the whole loop in minutes on seven
of the bundled runs. What can drift without its run being redone is checked here: its records are the bundled ones,
its config is valid and plans, and its improved variant is the diagnosis's recommendation as the code prints it.
(Its run itself, and the figures its README quotes, are measured there: a workflow run is minutes, not a test's.)"""

import filecmp
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml

from hybridtwin.diagnose.recommendation import variant_spec
from hybridtwin.model.candidates import builtin_candidates
from hybridtwin.model.variants import Variant

ROOT = Path(__file__).resolve().parents[1]
QUICK = ROOT / "examples" / "quick"


def test_its_records_are_the_bundled_ones():
    sheet = pd.read_csv(QUICK / "runs.tsv", sep="\t")
    bundled = pd.read_csv(ROOT / "data" / "default" / "runs.tsv", sep="\t").set_index("run")
    assert len(sheet) == 7 and set(sheet["role"]) == {"fit", "validate"}
    for _, row in sheet.iterrows():
        original = bundled.loc[row["run"]]
        assert (row["rpm"], row["eccentric_mass_g"], row["role"]) == \
            (original["rpm"], original["eccentric_mass_g"], original["role"])
        assert filecmp.cmp(QUICK / row["path"], ROOT / "data" / "default" / original["path"], shallow=False)


def test_its_improved_variant_is_the_recommendation_as_printed():
    """geometric + expansion_k4 in its default range, the bow shared by the config: variant_spec's entry, the one
    diagnosis.md prints, equal to the pasted one (a change of the recommendation's form shows here)."""
    config = yaml.safe_load((QUICK / "config" / "config.yaml").read_text())
    base = Variant.from_spec("geometric", config["variants"]["geometric"])
    printed = variant_spec(base, builtin_candidates()["expansion_k4"])
    assert config["variants"]["geometric_expansion_k4"] == printed


def test_it_plans_from_the_repository_root():
    """`snakemake -n --directory examples/quick` (the README's command, dry): the config passes the strict schema
    and both variants are planned, with fits on the full solver (no library jobs)."""
    done = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "2", "--directory", str(QUICK),
                           "--forceall", "--quiet", "rules"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    plan = done.stdout + done.stderr
    assert "identify_joint" in plan and "diagnose" in plan and "spgd_library" not in plan
