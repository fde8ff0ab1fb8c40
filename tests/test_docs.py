"""The documentation a clone can read: every relative link of the README and the docs resolves inside the
repository (files, folders and #anchors of Markdown headings), nothing points outside it, and the README's
`hybridtwin ...` command lines run as documented (the cheap ones in full, on the bundled data; every one's
subcommand and options checked against the command line's own help). Seconds."""

from __future__ import annotations

import io
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
HYBRIDTWIN = str(Path(sys.executable).with_name("hybridtwin"))  # the console script of this environment
#: the pages a user reads: the README, the docs, each data set's README, the history
PAGES = sorted({ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "benchmarks" / "README.md",
                *(ROOT / "docs").glob("*.md"), *(ROOT / "data").glob("*/README.md"),
                *(ROOT / "examples").glob("*/README.md")})
#: folders never scanned for pointers outside the repository (environments, results, caches)
IGNORED = {".git", ".venv", "results", ".snakemake", "logs", "__pycache__", ".pytest_cache", ".ruff_cache",
           "node_modules", "records"}
TEXT_SUFFIXES = {".md", ".py", ".smk", ".yaml", ".yml", ".toml", ".rst", ".sh", ".txt", ".cfg", ".json", ".tsv"}

FENCE = re.compile(r"^(```|~~~).*?^\1", re.DOTALL | re.MULTILINE)
CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.DOTALL)
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]*)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE_LINK = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+\"[^\"]*\")?\s*$", re.MULTILINE)
HTML_LINK = re.compile(r"<(?:a|img)\b[^>]*?\b(?:href|src)=\"([^\"]+)\"", re.IGNORECASE)
EXTERNAL = re.compile(r"^(?:[a-z][a-z0-9+.-]*:|//)", re.IGNORECASE)  # http:, https:, mailto:, ...
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$", re.MULTILINE)


def _prose(text: str) -> str:
    """A Markdown page without its code: fenced blocks and code spans (their brackets are not links)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def links(text: str) -> list[str]:
    """Every link target of a Markdown page: inline links and images, reference definitions, HTML a/img."""
    prose = _prose(text)
    return [m.group(1) for pattern in (INLINE_LINK, REFERENCE_LINK, HTML_LINK) for m in pattern.finditer(prose)]


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: inline markup and links reduced to their text, lower case,
    punctuation but '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a Markdown page's headings (duplicates numbered -1, -2, ... as GitHub does)."""
    seen: dict[str, int] = {}
    result = set()
    for m in HEADING.finditer(FENCE.sub("", text)):
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        result.add(base if n == 0 else f"{base}-{n}")
    return result


def broken_links(page: Path, text: str | None = None) -> list[str]:
    """The links of ``page`` (its ``text``, read when not given) that do not resolve inside the repository,
    each with the reason."""
    text = page.read_text() if text is None else text
    problems = []
    for target in links(text):
        if EXTERNAL.match(target):
            continue
        path, _, anchor = target.partition("#")
        if path.startswith("/"):
            problems.append(f"{target}: an absolute path (a clone does not have it)")
            continue
        if not path:  # an anchor of the page itself
            if anchor not in anchors(text):
                problems.append(f"{target}: no heading with this anchor on the page")
            continue
        resolved = (page.parent / path).resolve()
        if not resolved.is_relative_to(ROOT):
            problems.append(f"{target}: outside the repository")
        elif not resolved.exists():
            problems.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved.read_text()):
            problems.append(f"{target}: no heading with the anchor #{anchor} in {resolved.relative_to(ROOT)}")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_inside_the_repository(page):
    problems = broken_links(page)
    assert not problems, f"{page.relative_to(ROOT)}:\n" + "\n".join(problems)


def test_the_pages_a_user_reads_are_all_checked():
    names = {str(p.relative_to(ROOT)) for p in PAGES}
    assert {"README.md", "docs/README.md", "docs/model.md", "docs/measurement-format.md",
            "data/default/README.md"} <= names


def test_the_link_checker_catches_what_it_should():
    """The checker itself, on a page with one link of each kind (a checker that passes everything passes
    the tests above too)."""
    page = ROOT / "docs" / "__probe__.md"  # resolved against docs/, never written
    text = ("# Top\n\n## Scenarios (eq. 1)\n\n[ok](model.md#conventions) [self](#scenarios-eq-1) [no](#nowhere) "
            "[gone](missing.md) [out](../../notes/varm-model.md) [abs](/etc/passwd) [bad](model.md#no-such) "
            "[web](https://example.org/x) `[code](ignored.md)`\n\n```\n[fenced](ignored.md)\n```\n"
            "[ref]: ../README.md\n<img src=\"img/none.png\">\n")
    found = links(text)
    assert "ignored.md" not in found and "https://example.org/x" in found and "../README.md" in found
    assert anchors(text) == {"top", "scenarios-eq-1"}
    problems = broken_links(page, text)
    reasons = {p.split(":")[0]: p for p in problems}
    assert set(reasons) == {"#nowhere", "missing.md", "../../notes/varm-model.md", "/etc/passwd", "model.md#no-such",
                            "img/none.png"}
    assert "outside the repository" in reasons["../../notes/varm-model.md"]
    assert "absolute path" in reasons["/etc/passwd"]


def _project_files():
    """The project's files: what git tracks or would track (its .gitignore leaves out the venvs CI makes, e.g.
    a developer's, and generated results); outside a git checkout (an unpacked sdist), every file but
    the IGNORED folders."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                                cwd=ROOT, capture_output=True, check=True).stdout.decode().split("\0")
        return [ROOT / name for name in listed if name]
    except (OSError, subprocess.CalledProcessError):
        return list(ROOT.rglob("*"))


def _text_files():
    for path in _project_files():
        parts = path.relative_to(ROOT).parts
        if any(part in IGNORED or part.endswith(".egg-info") for part in parts) or not path.is_file():
            continue
        if path.suffix in TEXT_SUFFIXES or path.name in ("Snakefile", "run"):
            yield path


def test_nothing_in_the_project_points_outside_the_repository():
    """No relative path that climbs out of the repository (notes kept beside a developer's clone are not in a
    user's), and no absolute path on a developer's machine."""
    climbing = re.compile(r"(?:\.\./)+[\w.-]+(?:/[\w.-]+)*")
    machine = re.compile(r"(?<![\w.])/(?:work|home|root|Users)/")
    found = []
    for path in _text_files():
        if path == Path(__file__).resolve():
            continue
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            escapes = [m for m in climbing.findall(line) if not (path.parent / m).resolve().is_relative_to(ROOT)]
            if escapes or machine.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:120]}")
    assert not found, "\n".join(found)


# --- the README's command lines ------------------------------------------------------------------------

#: the user guide: the README and the pages its command line, data and workflow sections moved to (issue 55)
GUIDE_PAGES = [ROOT / "README.md", *(ROOT / "docs" / name for name in (
    "commands.md", "own-machine.md", "workflow.md", "results.md", "loop.md", "runups.md", "cluster.md"))]
README = "\n".join(page.read_text() for page in GUIDE_PAGES)


def readme_commands(text: str = README) -> list[list[str]]:
    """The `hybridtwin ...` command lines of the README: lines of its code blocks (continuations joined,
    comments dropped) and code spans, split as a shell would."""
    lines = []
    for block in FENCE.finditer(text):
        body = re.sub(r"\\\n\s*", " ", block.group(0))
        lines += [line.split(" #")[0].strip() for line in body.splitlines()]
    lines += [m.group(2).strip() for m in CODE_SPAN.finditer(FENCE.sub("", text))]
    commands = []
    for line in lines:
        for part in re.split(r"&&|;|\|", line):
            part = part.strip()
            if part.startswith("hybridtwin ") and "..." not in part:
                commands.append(shlex.split(part))
    return commands


def _help(subcommand: str) -> str:
    run = subprocess.run([HYBRIDTWIN, subcommand, "--help"], capture_output=True,
                         text=True, check=False, cwd=ROOT)
    assert run.returncode == 0, f"hybridtwin {subcommand} --help: {run.stderr[-500:]}"
    return run.stdout


def test_the_readme_shows_the_command_line():
    subcommands = {command[1] for command in readme_commands() if len(command) > 1}
    assert {"simulate", "effects", "variants", "check-data", "rig"} <= subcommands
    top = {command[1] for command in readme_commands((ROOT / "README.md").read_text()) if len(command) > 1}
    assert {"check-data", "assess"} <= top  # the README itself: check your records, judge a new one


def quoted_figures(text: str) -> list[str]:
    """The measured times a page quotes: each number written before "s of CPU", "minutes" or "s of wall time"."""
    return re.findall(r"(\d+(?:\.\d+)?)(?=\s+(?:s of CPU|minutes|s of wall time))", _prose(text))


def test_a_time_the_readme_quotes_is_the_benchmarks_latest():
    """Every time the README quotes (a number before "s of CPU", "minutes" or "s of wall time") is in
    benchmarks/README.md, where each figure stands with its command and commit (issue 55): the README never carries
    a figure of its own that could drift. The main job's time is not quoted at all: the README names the section."""
    readme = (ROOT / "README.md").read_text()
    benchmarks = (ROOT / "benchmarks" / "README.md").read_text()
    missing = [number for number in quoted_figures(readme)
               if not re.search(rf"(?<![\d.]){re.escape(number)}(?![\d])", benchmarks)]
    assert not missing, f"README quotes times benchmarks/README.md does not have: {missing}"
    assert 'benchmarks/README.md, section "The main job"' in readme and "the-main-job" in anchors(benchmarks)
    # the check itself finds a quoted time
    assert quoted_figures("in 4.5 minutes of wall time (272 s of wall time), 467 s of CPU") == ["4.5", "272", "467"]


@pytest.mark.parametrize("command", readme_commands(), ids=shlex.join)
def test_every_readme_command_uses_an_existing_subcommand_and_options(command):
    """Each option a README command line uses is one its subcommand's help lists."""
    helptext = _help(command[1])
    used = [word.split("=")[0] for word in command[2:] if word.startswith("--")]
    missing = [option for option in used if not re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", helptext)]
    assert not missing, f"{shlex.join(command)}: hybridtwin {command[1]} has no option {missing}"


#: README commands run in full: seconds each (one steady state, listings, the bundled data's check)
CHEAP = {"simulate", "effects", "variants", "check-data"}
#: the README's placeholders for a user's own files, and the bundled file of the same kind each runs with
PLACEHOLDERS = {"path/to/runs.tsv": "data/default/runs.tsv"}
#: options whose value is a file the command writes: redirected into a temporary folder
WRITES = {"--output", "--time-series", "--out"}


def _runnable(command: list[str], tmp_path: Path) -> list[str]:
    """The command with its written files moved to ``tmp_path`` and the README's own example file there."""
    result = []
    for i, word in enumerate(command):
        result.append(str(tmp_path / Path(word).name) if i and command[i - 1] in WRITES
                      else PLACEHOLDERS.get(word, word))
    return result


def readme_effects_file() -> str | None:
    """The README's example effects file: its Python block that defines an effect."""
    return next((block for block in re.findall(r"```python\n(.*?)```", README, re.DOTALL)
                 if re.search(r"^\w+ = \w*(Effect|Bearing)\(", block, re.MULTILINE)), None)


@pytest.mark.parametrize("command", [c for c in readme_commands() if c[1] in CHEAP], ids=shlex.join)
def test_cheap_readme_commands_run_as_documented(command, tmp_path):
    command = _runnable(command, tmp_path)
    for i, word in enumerate(command[:-1]):
        if word == "--effects-file" and not (ROOT / command[i + 1]).exists():
            effects = readme_effects_file()
            assert effects, f"{shlex.join(command)}: the README defines no {command[i + 1]}"
            command[i + 1] = str(tmp_path / Path(command[i + 1]).name)
            Path(command[i + 1]).write_text(effects)
    run = subprocess.run([HYBRIDTWIN, *command[1:]], capture_output=True, text=True,
                         check=False, cwd=ROOT)
    assert run.returncode == 0, f"{shlex.join(command)}:\n{run.stderr[-1500:]}"
    assert "Traceback" not in run.stderr
    if command[1] == "simulate" and not {"--output", "--help", "--polar"} & set(command):
        table = pd.read_csv(io.StringIO(run.stdout))
        assert len(table) >= 2 and table.notna().all().all()  # harmonics 0..H, every value a number
