"""Problems several runs share, said once (issue 37, part 6).

A data set whose records all share one mistake (a wrong unit, a missing column, another probe set) used to get one
error per run, the same sentence 22 times with only the record's name and its figures changed. ``group_problems``
gathers the runs whose messages differ only there (the run's name, its record's file name and the numbers), so
that ``hybridtwin check-data`` and the workflow's check_data rule say each problem once, with the runs it
concerns and the first run's own message as its example; a problem of one run keeps its own line."""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import PurePath

#: a number standing alone (not a digit inside a name such as x1_mm)
_NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?!\w)")
#: runs named in a shared problem's line; the others counted
NAMED_RUNS = 8


@dataclass(frozen=True)
class SharedProblem:
    """One problem and the runs that have it (in the sheet's order); ``message``: the first run's own."""

    runs: tuple[str, ...]
    message: str

    def describe(self, n_runs: int) -> str:
        """'run a: ...' for one run; for several, which runs (every run of the sheet, or their names), then the
        first run's message as the example."""
        first = self.runs[0]
        if len(self.runs) == 1:
            return f"run {first}: {self.message}"
        if len(self.runs) == n_runs:
            who = f"every run of the sheet ({n_runs})"
        else:
            named = ", ".join(self.runs[:NAMED_RUNS])
            more = len(self.runs) - NAMED_RUNS
            who = f"{len(self.runs)} runs ({named}{f' and {more} more' if more > 0 else ''})"
        return f"{who}, the same problem; run {first}: {self.message}"


def _shape(message: str, tokens: Iterable[str]) -> str:
    """The message without what differs from run to run: the run's names and record file names, the numbers."""
    for token in sorted((t for t in tokens if t), key=len, reverse=True):  # a path before the run's name in it
        message = re.sub(rf"(?<![\w.]){re.escape(token)}(?![\w])", "\0", message)
    return _NUMBER.sub("#", message)


def _tokens(run: str, paths: Mapping[str, str]) -> tuple[str, ...]:
    path = str(paths.get(run) or "")
    return (run, path, PurePath(path).name) if path else (run,)


def group_problems(problems: Mapping[str, str], paths: Mapping[str, str] | None = None) -> list[SharedProblem]:
    """``problems`` ({run: message}, in the sheet's order) gathered into the problems they share, in the order of
    their first run. ``paths``: each run's record path (its file name is left out of the comparison too)."""
    paths = paths or {}
    groups: dict[str, list[str]] = {}
    for run, message in problems.items():
        groups.setdefault(_shape(str(message), _tokens(run, paths)), []).append(run)
    return [SharedProblem(tuple(runs), str(problems[runs[0]])) for runs in groups.values()]


def group_messages(messages: Sequence[str], runs: Sequence[str],
                   paths: Mapping[str, str] | None = None) -> list[tuple[str, int]]:
    """Messages not keyed by run (warnings), each kept once with how many times it came: two are the same when they
    differ only in the runs' names, their record file names and the numbers (``runs``, ``paths``: the sheet's)."""
    paths = paths or {}
    tokens = [t for run in runs for t in _tokens(run, paths)]
    seen: dict[str, list] = {}
    for message in messages:
        entry = seen.setdefault(_shape(str(message), tokens), [str(message), 0])
        entry[1] += 1
    return [(message, count) for message, count in seen.values()]
