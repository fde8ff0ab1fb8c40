"""Snapshots: the scenarios' steady states stored as zarr v3 (paper eq. 3, the snapshot matrix).

Each chunk job solves a slice of the scenarios at every run and writes one zarr
group; ``gather`` checks that the chunks hold exactly the sampled scenarios
(none missing, none twice) and writes one store per variant::

    snapshots.zarr/
      harmonics   (R, S, H+1, n) complex128   Q_h of every DOF, NaN where failed
      success     (R, S) bool                 the harmonic-balance solve converged
      stable      (R, S) bool                 converged and stable (every Floquet multiplier inside the unit
                                              circle, ``hybridtwin.solvers.floquet``); unstable points keep their
                                              harmonics, their message says "unstable ..."
      floquet_radius (R, S) float64           the largest |Floquet multiplier| (NaN where not converged)
      solved      (R, S) bool                 the scenario was solved at the run (False: an enrichment scenario
                                              at a run of another eccentric mass; its message ``NOT_SOLVED``)
      message     (R, S) str                  the solver's reason, per run and scenario (for people)
      branch      (R, S) str                  direct / run-up / run-up, jump between ...
      scenario    (S,) int64,  split (S,) str,  parameters (S, d) float64 [SI]
      design      (S,) str                    hypercube (the first design) or enrichment
                                              (``scenarios.sample_enrichment``: solved only at the runs
                                              of one eccentric mass, not solved at the others)
      attrs: variant, runs, rpm and eccentric_mass_g of each run (as solved), parameter names
      manifest.sha256                         sha256 of every other file (``sha256sum -c`` format)

Integrity (``hybridtwin.offline.stores``): every store written here ends with a manifest of its
files' checksums, written last (a store without one is incomplete); ``gather`` verifies
each chunk store against it and reports every bad one by name (``CorruptStoreError``), and
``load`` verifies the gathered store.

Downstream, a point is used only where it is ``steady`` (converged and stable): the POD,
the libraries and the enrichment's sampling leave the unstable ones out and count them;
``failures`` lists them with the failed solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import zarr

from .. import tables
from ..model.effect_base import Array
from .scenarios import NOT_SOLVED, RunSolutions
from .stores import CorruptStoreError, check_store, verify_store, write_manifest


#: the gathered store's arrays with one row per run, chunked one run per chunk
PER_RUN = ("harmonics", "success", "stable", "floquet_radius", "solved", "message", "branch")


#: ``Snapshots.failures``' reason codes
FAILED, UNSTABLE = "failed", "unstable"


class StaleStoreError(ValueError):
    """A snapshot store written before the stability check (no ``stable`` array): rebuild it."""


@dataclass
class Snapshots:
    """All scenarios' steady states at all runs of one variant."""

    variant: str
    runs: list[str]
    rpm: list[float]  # the speed each run was solved at (refined from its record, or nominal)
    eccentric_mass_g: list[float]
    parameters: list[str]
    scenario: Array
    split: Array
    values: Array  # (S, d)
    harmonics: Array  # (R, S, H+1, n)
    success: Array
    message: Array
    branch: Array
    stable: Array  # (R, S) converged and stable
    floquet_radius: Array  # (R, S)
    design: Array | None = None  # (S,) hypercube / enrichment; None: all hypercube (stores from before it)
    #: (R, S) the scenario was solved at the run (enrichment scenarios only at their eccentric mass); None: all
    solved: Array | None = None

    def __post_init__(self) -> None:
        if self.design is None:
            self.design = np.full(self.scenario.shape, "hypercube", dtype=object)
        if self.solved is None:
            self.solved = np.ones(self.success.shape, bool)

    @property
    def steady(self) -> Array:
        """(R, S): a steady state the machine can be in, converged and stable (what downstream stages use)."""
        return self.success & self.stable

    def run_index(self, run: str) -> int:
        if run not in self.runs:
            raise KeyError(f"run {run!r} is not in the snapshots of variant {self.variant} (runs: {self.runs})")
        return self.runs.index(run)

    def failures(self) -> pd.DataFrame:
        """Every (run, scenario) without a steady state, failed or unstable, with its reason: ``reason`` the code
        (``FAILED``: no periodic solution; ``UNSTABLE``: converged, a Floquet multiplier outside the unit circle),
        ``message`` the solver's sentence (not the runs an enrichment scenario was not meant for)."""
        r, s = np.nonzero(~self.steady & self.solved)
        unstable = self.success[r, s] & (np.nan_to_num(self.floquet_radius[r, s], nan=0.0) >= 1.0)
        return pd.DataFrame({"run": np.asarray(self.runs)[r], "scenario": self.scenario[s],
                             "split": self.split[s], "message": self.message[r, s],
                             "reason": np.where(unstable, UNSTABLE, FAILED)})


def failure_summary(failures: pd.DataFrame) -> pd.DataFrame:
    """``Snapshots.failures`` in counts (the report's view of failures.tsv, which lists every point): per run,
    split and reason the number of scenarios, and the solver's sentence for the first of them (its numbers are that
    scenario's), in the runs' order of first appearance."""
    columns = list(tables.FAILURE_SUMMARY.columns)
    if failures.empty:
        return pd.DataFrame(columns=columns)
    grouped = failures.groupby(["run", "split", "reason"], sort=False)
    out = grouped.agg(n_scenarios=("scenario", "size"), first_scenario=("scenario", "first"),
                      first_message=("message", "first")).reset_index()
    return out[columns]


def write_chunk(path: str | Path, variant: str, scenarios: pd.DataFrame, parameters: Sequence[str],
                solutions: RunSolutions, design: str = "hypercube") -> None:
    """One chunk job's result: its scenarios at every run (``design``: hypercube or enrichment)."""
    group = zarr.open_group(str(path), mode="w")
    group.attrs.update({"variant": variant, "runs": solutions.runs, "rpm": solutions.rpm,
                        "eccentric_mass_g": solutions.eccentric_mass_g, "parameters": list(parameters)})
    _write(group, "scenario", scenarios["scenario"].to_numpy(np.int64))
    _write(group, "split", scenarios["split"].to_numpy(str))
    _write(group, "design", np.full(len(scenarios), design))
    _write(group, "parameters", scenarios[list(parameters)].to_numpy(float))
    _write(group, "harmonics", solutions.harmonics)
    _write(group, "success", solutions.success)
    _write(group, "stable", solutions.stable)
    _write(group, "floquet_radius", solutions.floquet_radius)
    _write(group, "solved", solutions.solved.astype(bool))
    _write(group, "message", solutions.message.astype(str))
    _write(group, "branch", solutions.branch.astype(str))
    write_manifest(path)


def _write(group: zarr.Group, name: str, data: Array, chunks: tuple[int, ...] | None = None) -> None:
    """One array; text as variable-length UTF-8 strings, zarr v3's specified string type (numpy's fixed-length
    unicode has no v3 specification: zarr warns that other readers may not read it)."""
    data = np.asarray(data)
    if data.dtype.kind == "U":
        data = data.astype(np.dtypes.StringDType())
    group.create_array(name, data=data, chunks=chunks or "auto")


def _solved(group: zarr.Group, sel: slice = slice(None)) -> Array:
    """The store's ``solved`` array (rows ``sel``). A store written before it (no such array) is still read: there
    an enrichment scenario's message at the runs it was not solved for began with ``NOT_SOLVED``, and that prefix
    is read as the code (the one place a message is read: only for those older stores)."""
    if "solved" in group:
        return np.asarray(group["solved"][sel], bool)
    return _solved_from_messages(_text(group["message"][sel]))


def _solved_from_messages(message: Array) -> Array:
    """Stores from before the ``solved`` array: not solved where the message began with ``NOT_SOLVED``."""
    return ~np.char.startswith(np.asarray(message).astype(str), NOT_SOLVED)


def _text(array: Array) -> Array:
    """A text array as numpy str, whether stored variable-length (``_write``) or fixed-length (older stores)."""
    array = np.asarray(array)
    return array if array.dtype.kind == "U" else array.astype(object).astype(str)


def gather(chunk_paths: Sequence[str | Path], expected: pd.DataFrame, out: str | Path) -> Snapshots:
    """Join the chunk stores into one store at ``out`` (``read_chunks``, then ``save``)."""
    snapshots = read_chunks(chunk_paths, expected)
    save(snapshots, out)
    return snapshots


def read_chunks(chunk_paths: Sequence[str | Path], expected: pd.DataFrame) -> Snapshots:
    """The chunk stores joined, in scenario order; the scenarios must be exactly those of ``expected``.

    Every chunk store is first verified against its manifest: a missing, changed or unlisted
    file, or no manifest at all, raises ``CorruptStoreError`` naming each bad chunk (all of
    them, so one rerun rebuilds them all); a chunk store from before the stability check
    raises ``StaleStoreError``.
    """
    if not chunk_paths:
        raise ValueError("no chunk stores to gather")
    bad = {str(p): found for p in chunk_paths if (found := verify_store(p))}
    if bad:
        raise CorruptStoreError(bad, "chunk store")
    parts = [zarr.open_group(str(p), mode="r") for p in chunk_paths]
    for path, g in zip(chunk_paths, parts):
        _require_stability(g, path)
    scenario = np.concatenate([g["scenario"][:] for g in parts])
    wanted = expected["scenario"].to_numpy(np.int64)
    missing = np.setdiff1d(wanted, scenario)
    twice = pd.Series(scenario).value_counts()
    if missing.size or (twice > 1).any() or np.setdiff1d(scenario, wanted).size:
        raise ValueError(
            f"chunk stores {[str(p) for p in chunk_paths]} do not hold exactly the sampled scenarios: "
            f"missing {missing[:10].tolist()}, duplicated {twice[twice > 1].index[:10].tolist()}, "
            f"unexpected {np.setdiff1d(scenario, wanted)[:10].tolist()}"
        )
    plan = {k: parts[0].attrs[k] for k in ("runs", "rpm", "eccentric_mass_g")}
    for path, g in zip(chunk_paths, parts):
        other = {k: g.attrs[k] for k in plan}
        if other != plan:
            raise ValueError(f"chunk store {path} was solved for another run plan ({other} vs {plan})")
    order = np.argsort(scenario)
    stack = {name: np.concatenate([g[name][:] for g in parts], axis=axis)
             for name, axis in (("harmonics", 1), ("success", 1), ("stable", 1), ("floquet_radius", 1),
                                ("parameters", 0))}
    stack |= {name: np.concatenate([_text(g[name][:]) for g in parts], axis=axis)
              for name, axis in (("message", 1), ("branch", 1), ("split", 0))}
    stack["solved"] = np.concatenate([_solved(g) for g in parts], axis=1)
    # chunk stores from before the enrichment have no design array: all hypercube
    stack["design"] = np.concatenate([_text(g["design"][:]) if "design" in g
                                      else np.full(g["scenario"].shape, "hypercube") for g in parts]).astype(object)
    return Snapshots(
        variant=parts[0].attrs["variant"], runs=list(plan["runs"]), rpm=list(plan["rpm"]),
        eccentric_mass_g=list(plan["eccentric_mass_g"]), parameters=list(parts[0].attrs["parameters"]),
        scenario=scenario[order], split=stack["split"][order], values=stack["parameters"][order],
        harmonics=stack["harmonics"][:, order], success=stack["success"][:, order],
        message=stack["message"][:, order], branch=stack["branch"][:, order], stable=stack["stable"][:, order],
        floquet_radius=stack["floquet_radius"][:, order], design=stack["design"][order],
        solved=stack["solved"][:, order],
    )


def _run_files(r: int):
    """The files ``load(path, run)`` reads: all but the other runs' chunks of the per-run arrays (``save``
    chunks them one run per chunk: keys <array>/c/<run>/...)."""
    def select(name: str) -> bool:
        parts = name.split("/")
        return not (len(parts) > 2 and parts[0] in PER_RUN and parts[1] == "c") or parts[2] == str(r)
    return select


def _require_stability(group: zarr.Group, path: str | Path) -> None:
    """A store written before the stability check has no ``stable`` array: its unstable points cannot be told."""
    if "stable" not in group:
        raise StaleStoreError(f"{path}: no stability flags (written before the Floquet check of every steady "
                              "state): delete it and run the workflow again to rebuild it")


def save(snapshots: Snapshots, path: str | Path) -> None:
    """Write the gathered store, chunked by run (what the per-run library jobs read)."""
    group = zarr.open_group(str(path), mode="w")
    group.attrs.update({"variant": snapshots.variant, "runs": snapshots.runs, "rpm": snapshots.rpm,
                        "eccentric_mass_g": snapshots.eccentric_mass_g, "parameters": snapshots.parameters})
    R, S = snapshots.success.shape
    _write(group, "harmonics", snapshots.harmonics, (1, S) + snapshots.harmonics.shape[2:])
    for name in ("success", "stable", "solved"):
        _write(group, name, getattr(snapshots, name).astype(bool), (1, S))
    _write(group, "floquet_radius", snapshots.floquet_radius, (1, S))
    for name in ("message", "branch"):
        _write(group, name, getattr(snapshots, name).astype(str), (1, S))
    _write(group, "scenario", snapshots.scenario)
    _write(group, "split", snapshots.split.astype(str))
    _write(group, "design", snapshots.design.astype(str))
    _write(group, "parameters", snapshots.values)
    write_manifest(path)


def operating_point(path: str | Path, run: str) -> tuple[float, float]:
    """A run's speed as solved [RPM] and eccentric mass [g], from the store's attributes (no array is read)."""
    check_store(path, "snapshot store", select=lambda name: name == "zarr.json")
    attrs = zarr.open_group(str(path), mode="r").attrs
    runs = list(attrs["runs"])
    if run not in runs:
        raise KeyError(f"run {run!r} is not in {path} (runs: {runs})")
    return float(attrs["rpm"][runs.index(run)]), float(attrs["eccentric_mass_g"][runs.index(run)])


def load(path: str | Path, run: str | None = None) -> Snapshots:
    """Read a gathered store, all runs or only ``run`` (reads that run's chunks only).

    The store is verified against its manifest first (``CorruptStoreError``; with ``run``, only the files
    that are read: the other runs' chunks are not); a store from before the stability check raises
    ``StaleStoreError``.
    """
    check_store(path, "snapshot store", select=lambda name: name == "zarr.json")
    group = zarr.open_group(str(path), mode="r")
    runs = list(group.attrs["runs"])
    sel, select = slice(None), None
    if run is not None:
        if run not in runs:
            raise KeyError(f"run {run!r} is not in {path} (runs: {runs})")
        sel, select = slice(runs.index(run), runs.index(run) + 1), _run_files(runs.index(run))
    check_store(path, "snapshot store", select)
    _require_stability(group, path)
    return Snapshots(
        variant=group.attrs["variant"], runs=runs[sel], rpm=list(group.attrs["rpm"])[sel],
        eccentric_mass_g=list(group.attrs["eccentric_mass_g"])[sel], parameters=list(group.attrs["parameters"]),
        scenario=group["scenario"][:], split=_text(group["split"][:]).astype(object), values=group["parameters"][:],
        harmonics=group["harmonics"][sel], success=group["success"][sel], message=_text(group["message"][sel]),
        branch=_text(group["branch"][sel]), stable=group["stable"][sel], floquet_radius=group["floquet_radius"][sel],
        design=_text(group["design"][:]).astype(object) if "design" in group else None, solved=_solved(group, sel),
    )
