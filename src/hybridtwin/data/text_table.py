"""The one text reader every file of a data set goes through (runs sheets, plans, records; docs/measurement-format.md,
docs/data-checks.md), and the errors it raises.

Every file goes through ``read_text_table``, so every reader of
a sheet (``hybridtwin check-data``, the workflow at parse time, every script)
treats a file the same way: UTF-8 with or without a byte-order mark (UTF-16
with a BOM too), CRLF or LF line ends, blank lines (also at the end) skipped
with line numbers kept, cells and headers stripped of white space and of one
pair of enclosing double quotes, known column names matched case-insensitively.
Everything else that is ambiguous is an error, never a guess: a file that is
not text or not UTF-8, the wrong separator, a line with more or fewer cells
than the header, a decimal comma, a unit inside a number, a duplicated column.

Every check names the file, the line (the header is line 1) and the column,
and the problem. Problems that make a file unusable raise ``DataError`` (all
problems of a file at once, not just the first). Problems that leave a run
readable but not fit for a fit (a flat or clipped channel, see also
``hybridtwin.data.plausibility``) are returned as findings and also emitted as a
``DataWarning``, so the caller flags the run and says so; nothing is dropped
silently.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .record_columns import listed

Array = np.ndarray


class DataError(ValueError):
    """Invalid measured data; the message names the file, line or column and the problem."""


class DataWarning(UserWarning):
    """A run that is kept but flagged (not used in a fit); the message says what and why."""


def read_text_table(path: str | Path, sep: str, known: Sequence[str] | None = None) -> tuple[pd.DataFrame, Array]:
    """A delimited text file as (cells as stripped strings, file line number of each row).

    The conventions of the module docstring: encoding, line ends, blank lines,
    white space, quotes; header names in ``known`` (None: all) matched
    case-insensitively and returned in lower case. Raises ``DataError`` for a
    missing, empty, binary or non-UTF-8 file, the wrong separator, duplicated
    or unnamed columns and lines whose number of cells differs from the header's.
    """
    path = Path(path)
    kind = "TSV (tab-separated)" if sep == "\t" else "CSV (comma-separated)"
    if path.is_dir():
        raise DataError(f"{path}: is a folder, not a file")
    if not path.is_file():
        raise DataError(f"{path}: file does not exist")
    lines = decode_text(path, path.read_bytes()).replace("\r\n", "\n").replace("\r", "\n").split("\n")
    rows = [(n, [clean_cell(c) for c in text.split(sep)]) for n, text in enumerate(lines, start=1)]
    rows = [(n, cells) for n, cells in rows if any(cells)]  # blank lines (also "\t\t", ",,") carry nothing
    if not rows:
        raise DataError(f"{path}: file is empty (no header row)")
    (header_line, header), body = rows[0], rows[1:]
    if len(header) == 1:
        used = next((name for s, name in ((",", "commas"), (";", "semicolons"), ("\t", "tabs"), ("|", "bars"))
                     if s != sep and s in lines[header_line - 1]), "spaces" if " " in header[0] else None)
        found = f"its columns are separated by {used}" if used else "it has a single column"
        raise DataError(f"{path}: line {header_line} (header): not {kind}: {found}; save it as {kind}")
    lowered = {c.lower() for c in known} if known is not None else None
    header = [h.lower() if lowered is None or h.lower() in lowered else h for h in header]
    problems = []
    for name in sorted({h for h in header if h and header.count(h) > 1}):
        where = [i + 1 for i, h in enumerate(header) if h == name]
        problems.append(f"line {header_line} (header): column {name!r} appears {len(where)} times "
                        f"(columns {', '.join(map(str, where))})")
    wrong = [(n, len(cells)) for n, cells in body
             if len(cells) < len(header) or (len(cells) > len(header) and any(cells[len(header):]))]
    if wrong:
        hint = "a decimal comma? use a point: 0.25" if sep == "," else "a missing tab, or spaces instead of a tab?"
        problems += listed(f"not {len(header)} cells as in the header ({hint})", [n for n, _ in wrong],
                            [f"{k} cells" for _, k in wrong])
    cells = [c[:len(header)] for _, c in body]
    for i, name in enumerate(header):
        if not name and any(row[i] for row in cells if len(row) > i):
            problems.append(f"line {header_line} (header): column {i + 1} has no name but holds values")
    if problems:
        raise DataError(problems_message(path, problems))
    keep = [i for i, name in enumerate(header) if name]  # an unnamed, empty column: trailing separators
    table = pd.DataFrame([[row[i] for i in keep] for row in cells], columns=[header[i] for i in keep], dtype=str)
    return table, np.array([n for n, _ in body], dtype=int)


def decode_text(path: Path, raw: bytes) -> str:
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            raise DataError(f"{path}: starts as UTF-16 text but does not decode as UTF-16; save it as UTF-8") from None
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]  # the UTF-8 byte-order mark some spreadsheets write
    if raw.startswith(b"PK\x03\x04"):
        raise DataError(f"{path}: is a zip archive (an Excel or OpenDocument workbook?), not a text file; export it "
                        "as text (tab-separated for a runs sheet, comma-separated for a record)")
    if b"\x00" in raw:
        line = raw[:raw.index(b"\x00")].count(b"\n") + 1
        raise DataError(f"{path}: line {line}: binary content (NUL bytes), not a text file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b"\n") + 1
        raise DataError(f"{path}: line {line}: byte 0x{raw[err.start]:02x} is not UTF-8 text (Latin-1 or "
                        "Windows-1252?); save the file as UTF-8") from None


def clean_cell(cell: str) -> str:
    cell = cell.strip()
    if len(cell) >= 2 and cell[0] == cell[-1] == '"':
        cell = cell[1:-1].strip()
    return cell


def require_columns(path: Path, have: Sequence[str], required: Sequence[str], known: Sequence[str],
                     what: str) -> None:
    missing = [c for c in required if c not in have]
    if missing:
        hints = []
        for column in missing:
            close = difflib.get_close_matches(column, [h for h in have if h not in known], n=1, cutoff=0.5)
            hints.append(f"{column!r} (found {close[0]!r}: misnamed?)" if close else repr(column))
        raise DataError(f"{path}: line 1 (header): missing column(s) {', '.join(hints)}; {what}; "
                        f"the header has {list(have)}")


def duplicate_values(values: pd.Series, line: Array) -> list[tuple[str, list[int]]]:
    out = []
    for value, group in pd.Series(line, index=values.to_numpy()).groupby(level=0, sort=False):
        if len(group) > 1:
            out.append((str(value), group.tolist()))
    return out


def problems_message(path: Path, problems: Sequence[str]) -> str:
    if len(problems) == 1:
        return f"{path}: {problems[0]}"
    return f"{path}: {len(problems)} problems:\n" + "\n".join(f"  - {p}" for p in problems)
