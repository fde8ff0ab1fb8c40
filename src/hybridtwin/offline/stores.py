"""Integrity of the zarr stores the workflow writes and reads: one checksum manifest per store.

zarr reads a missing chunk file as the array's fill value (zeros), and a truncated or
overwritten one either as wrong numbers or as a bare codec error ("Zstd decompression
error") that names no file. A store that lost or damaged a file on the way (a node's
disk, a partial copy, an interrupted write) would thus give plausible-looking zeros.

Every store written by the package (snapshot chunks and the gathered snapshots, the POD
bases, the sPGD libraries, the fits) therefore ends with ``manifest.sha256``: the sha256
of each of its files, in ``sha256sum -c`` format, written last and atomically (a store
without one is incomplete). Every reader verifies the store against it first
(``open_verified`` / ``check_store``) and fails with ``CorruptStoreError``, one line naming
the store and each bad file (missing, changed, unlisted), instead of reading it.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import zarr

MANIFEST = "manifest.sha256"
# files a store may hold besides the manifested ones (Snakemake marks its directory outputs with this one)
_UNLISTED = {MANIFEST, ".snakemake_timestamp"}
_SHOWN = 5  # bad files named per store in an error (all are in ``CorruptStoreError.problems``)


class CorruptStoreError(ValueError):
    """Stores whose files do not match their manifest; ``problems`` maps each store to what is wrong."""

    def __init__(self, problems: dict[str, list[str]], what: str = "store"):
        self.problems = problems
        found = {path: "; ".join(bad[:_SHOWN]) + (f" (and {len(bad) - _SHOWN} more)" if len(bad) > _SHOWN else "")
                 for path, bad in problems.items()}
        if len(found) == 1:
            (path, bad), = found.items()
            head = f"corrupt or incomplete {what} {path}, not read: {bad}"
        else:
            head = f"corrupt or incomplete {what}s, not read: " + " | ".join(f"{p}: {b}" for p, b in found.items())
        super().__init__(head + " (a missing zarr chunk would read as zeros, a damaged one as wrong numbers: "
                         "delete the store and run the job that writes it again)")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _store_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name not in _UNLISTED
                  and not p.name.startswith(f".{MANIFEST}"))


def write_manifest(path: str | Path) -> None:
    """Checksum every file of the store into ``manifest.sha256`` (atomically, as the store's last file)."""
    root = Path(path)
    lines = [f"{_sha256(f)}  {f.relative_to(root).as_posix()}\n" for f in _store_files(root)]
    partial = root / f".{MANIFEST}.partial"
    partial.write_text("".join(lines))
    os.replace(partial, root / MANIFEST)


def verify_store(path: str | Path, require_manifest: bool = True,
                 select: Callable[[str], bool] | None = None) -> list[str]:
    """What is wrong with a store against its manifest: missing, changed or unlisted files ([] if intact).

    Without a manifest the store is reported incomplete, or (``require_manifest=False``) accepted unchecked.
    select: check only the listed files whose name (relative, '/'-separated) it accepts, for a reader
    that reads only those (e.g. one run's chunks); unlisted files are then not looked for.
    """
    root = Path(path)
    if not root.is_dir():
        return ["store missing"]
    manifest = root / MANIFEST
    if not manifest.is_file():
        return ["no manifest.sha256 (incomplete: its job did not finish writing it)"] if require_manifest else []
    listed = {}
    for line in manifest.read_text().splitlines():
        digest, _, name = line.partition("  ")
        listed[name] = digest
    problems = []
    if select is not None:
        listed = {name: digest for name, digest in listed.items() if select(name)}
    for name, digest in listed.items():
        file = root / name
        if not file.is_file():
            problems.append(f"missing {name}")
        elif _sha256(file) != digest:
            problems.append(f"changed {name}")
    if select is None:
        problems += [f"unlisted {name}" for name in sorted({f.relative_to(root).as_posix()
                                                            for f in _store_files(root)} - set(listed))]
    return problems


def check_store(path: str | Path, what: str = "store", select: Callable[[str], bool] | None = None) -> None:
    """Raise ``CorruptStoreError`` naming the store and its bad files unless it matches its manifest
    (``select``: only the files it accepts, see ``verify_store``)."""
    problems = verify_store(path, select=select)
    if problems:
        raise CorruptStoreError({str(path): problems}, what)


def open_verified(path: str | Path, what: str = "store", select: Callable[[str], bool] | None = None):
    """The store's zarr group (read-only), after ``check_store``."""
    check_store(path, what, select)
    return zarr.open_group(str(path), mode="r")
