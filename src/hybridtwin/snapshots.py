"""Snapshots: the scenarios' steady states stored as zarr v3 (paper eq. 3, the snapshot matrix).

Each chunk job solves a slice of the scenarios at every run and writes one zarr
group; ``gather`` checks that the chunks hold exactly the sampled scenarios
(none missing, none twice) and writes one store per variant::

    snapshots.zarr/
      harmonics   (R, S, H+1, n) complex128   Q_h of every DOF, NaN where failed
      success     (R, S) bool
      message     (R, S) str                  the solver's reason, per run and scenario
      branch      (R, S) str                  direct / run-up / run-up, jump between ...
      scenario    (S,) int64,  split (S,) str,  parameters (S, d) float64 [SI]
      attrs: variant, runs, rpm and eccentric_mass_g of each run (as solved), parameter names
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import zarr

from .effects import Array
from .scenarios import RunSolutions


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

    def run_index(self, run: str) -> int:
        if run not in self.runs:
            raise KeyError(f"run {run!r} is not in the snapshots of variant {self.variant} (runs: {self.runs})")
        return self.runs.index(run)

    def failures(self) -> pd.DataFrame:
        """Every failed (run, scenario) with its reason."""
        r, s = np.nonzero(~self.success)
        return pd.DataFrame({"run": np.asarray(self.runs)[r], "scenario": self.scenario[s],
                             "split": self.split[s], "message": self.message[r, s]})


def write_chunk(path: str | Path, variant: str, scenarios: pd.DataFrame, parameters: Sequence[str],
                solutions: RunSolutions) -> None:
    """One chunk job's result: its scenarios at every run."""
    group = zarr.open_group(str(path), mode="w")
    group.attrs.update({"variant": variant, "runs": solutions.runs, "rpm": solutions.rpm,
                        "eccentric_mass_g": solutions.eccentric_mass_g, "parameters": list(parameters)})
    _write(group, "scenario", scenarios["scenario"].to_numpy(np.int64))
    _write(group, "split", scenarios["split"].to_numpy(str))
    _write(group, "parameters", scenarios[list(parameters)].to_numpy(float))
    _write(group, "harmonics", solutions.harmonics)
    _write(group, "success", solutions.success)
    _write(group, "message", solutions.message.astype(str))
    _write(group, "branch", solutions.branch.astype(str))


def _write(group: zarr.Group, name: str, data: Array, chunks: tuple[int, ...] | None = None) -> None:
    group.create_array(name, data=np.asarray(data), chunks=chunks or "auto")


def gather(chunk_paths: Sequence[str | Path], expected: pd.DataFrame, out: str | Path) -> Snapshots:
    """Join the chunk stores into one; the scenarios must be exactly those of ``expected``."""
    parts = [zarr.open_group(str(p), mode="r") for p in chunk_paths]
    if not parts:
        raise ValueError("no chunk stores to gather")
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
             for name, axis in (("harmonics", 1), ("success", 1), ("message", 1), ("branch", 1),
                                ("split", 0), ("parameters", 0))}
    snapshots = Snapshots(
        variant=parts[0].attrs["variant"], runs=list(plan["runs"]), rpm=list(plan["rpm"]),
        eccentric_mass_g=list(plan["eccentric_mass_g"]), parameters=list(parts[0].attrs["parameters"]),
        scenario=scenario[order], split=stack["split"][order], values=stack["parameters"][order],
        harmonics=stack["harmonics"][:, order], success=stack["success"][:, order],
        message=stack["message"][:, order], branch=stack["branch"][:, order],
    )
    save(snapshots, out)
    return snapshots


def save(snapshots: Snapshots, path: str | Path) -> None:
    """Write the gathered store, chunked by run (what the per-run library jobs read)."""
    group = zarr.open_group(str(path), mode="w")
    group.attrs.update({"variant": snapshots.variant, "runs": snapshots.runs, "rpm": snapshots.rpm,
                        "eccentric_mass_g": snapshots.eccentric_mass_g, "parameters": snapshots.parameters})
    R, S = snapshots.success.shape
    _write(group, "harmonics", snapshots.harmonics, (1, S) + snapshots.harmonics.shape[2:])
    for name in ("success", "message", "branch"):
        _write(group, name, getattr(snapshots, name).astype(bool if name == "success" else str), (1, S))
    _write(group, "scenario", snapshots.scenario)
    _write(group, "split", snapshots.split.astype(str))
    _write(group, "parameters", snapshots.values)


def load(path: str | Path, run: str | None = None) -> Snapshots:
    """Read a gathered store, all runs or only ``run`` (reads that run's chunks only)."""
    group = zarr.open_group(str(path), mode="r")
    runs = list(group.attrs["runs"])
    sel = slice(None)
    if run is not None:
        if run not in runs:
            raise KeyError(f"run {run!r} is not in {path} (runs: {runs})")
        sel = slice(runs.index(run), runs.index(run) + 1)
    return Snapshots(
        variant=group.attrs["variant"], runs=runs[sel], rpm=list(group.attrs["rpm"])[sel],
        eccentric_mass_g=list(group.attrs["eccentric_mass_g"])[sel], parameters=list(group.attrs["parameters"]),
        scenario=group["scenario"][:], split=group["split"][:].astype(object), values=group["parameters"][:],
        harmonics=group["harmonics"][sel], success=group["success"][sel], message=group["message"][sel],
        branch=group["branch"][sel],
    )
