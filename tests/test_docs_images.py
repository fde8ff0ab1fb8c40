"""The README's and docs' figures (docs/img) come from one command (issue 37 part 5, issue 39 item 6):
``hybridtwin docs-images`` copies those a run of the main job makes; those a benchmark makes are listed with their
command in benchmarks/README.md. Every docs/img image a page shows is one or the other, and the command runs on a
small fixture run."""

import re
from pathlib import Path

import pytest

from hybridtwin.cli import main
from hybridtwin.cli.docs_images import FROM_BENCHMARKS, FROM_RUN

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _shown() -> set[str]:
    """The docs/img images the pages show (Markdown image links, relative to their page)."""
    shown = set()
    for page in PAGES:
        for target in re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", page.read_text()):
            path = (page.parent / target).resolve()
            if path.parent == ROOT / "docs" / "img":
                shown.add(path.name)
    return shown


def test_every_image_a_page_shows_is_made_by_the_command_or_a_listed_benchmark():
    shown = _shown()
    assert {"summary.png", "geometric_run.png", "design.png", "online_trend.png", "online_alarms.png"} <= shown
    assert shown <= set(FROM_RUN) | set(FROM_BENCHMARKS), shown - set(FROM_RUN) - set(FROM_BENCHMARKS)
    assert not set(FROM_RUN) & set(FROM_BENCHMARKS)
    assert all((ROOT / "docs" / "img" / name).is_file() for name in shown)
    listing = (ROOT / "benchmarks" / "README.md").read_text()
    for name, command in FROM_BENCHMARKS.items():  # each benchmark's figure with its command
        script = re.search(r"benchmarks/\w+\.py", command).group(0)
        assert f"`docs/img/{name}` | `" in listing and script in listing and (ROOT / script).is_file()
    for text in ((ROOT / "README.md").read_text(), (ROOT / "docs" / "README.md").read_text()):
        assert "hybridtwin docs-images" in text


def test_the_command_copies_a_runs_figures(tmp_path, capsys):
    """On a fixture run (a results/ holding only the figures' sources): each copied byte for byte; a run without
    them is an error naming the missing file, nothing copied."""
    results = tmp_path / "run" / "results"
    for i, path in enumerate(FROM_RUN.values()):
        source = results / Path(path).relative_to("results")
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes([i]) * 16)
    out = tmp_path / "img"
    assert main(["docs-images", "--results", str(results), "--out", str(out)]) == 0
    for name, path in FROM_RUN.items():
        assert (out / name).read_bytes() == (results / Path(path).relative_to("results")).read_bytes()
    assert sorted(p.name for p in out.iterdir()) == sorted(FROM_RUN)
    assert "online_trend.png: made by a benchmark" in capsys.readouterr().out
    (results / "summary.png").unlink()
    assert main(["docs-images", "--results", str(results), "--out", str(tmp_path / "none")]) == 2
    assert "summary.png: missing" in capsys.readouterr().err and not (tmp_path / "none").exists()
