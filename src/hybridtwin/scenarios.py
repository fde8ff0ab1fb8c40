"""Scenarios: parameter sets to solve at the run plan's operating points (paper eq. 1-2).

- ``sample_scenarios``: a seeded Latin hypercube over a variant's unknown
  ranges (scipy.stats.qmc), split into training, validation (choosing the
  library's size) and test (scoring the library) scenarios.
- ``solve_runs``: every scenario at every run's (rpm, eccentric mass), batched
  over scenarios, the way the rig is driven: per eccentric mass a run-up by
  continuation through that mass's speeds, so that near the resonance each
  point is on the branch a run-up reaches and says which branch that is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .effects import Array
from .sensor import sensor_harmonics
from .solver import SteadyState, solve_sweep
from .variants import Variant

SPLITS = ("train", "validation", "test")


def default_n_scenarios(n_parameters: int) -> int:
    """The paper's sample sizes: 1000 for up to 5 unknowns, 300 per unknown beyond (2700 for 9)."""
    return 1000 if n_parameters <= 5 else 300 * n_parameters


def sample_scenarios(variant: Variant, n: int, seed: int, validation_fraction: float = 0.2,
                     n_test: int = 200) -> pd.DataFrame:
    """Latin-hypercube scenarios over ``variant.unknown``, one row each.

    The first ``n`` rows form one Latin hypercube (the paper's n_s), of which a
    random ``validation_fraction`` is held out to choose the library's size; the
    ``n_test`` rows are a second, independent hypercube used only to score it.
    Columns: scenario, split, then one column per unknown parameter [SI].
    """
    from scipy.stats import qmc  # imported here: scipy.stats costs 0.6 s, and only this rule needs it

    if not variant.unknown:
        raise ValueError(f"variant {variant.name!r} has no unknown parameters to sample")
    if n < 2 or n_test < 0 or not 0 <= validation_fraction < 1:
        raise ValueError(f"need n >= 2, n_test >= 0 and 0 <= validation_fraction < 1 "
                         f"(got {n}, {n_test}, {validation_fraction})")
    names = variant.unknown_names
    lo, hi = variant.bounds(names)
    rng = np.random.default_rng(seed)
    design = qmc.LatinHypercube(d=len(names), seed=rng).random(n)
    test = qmc.LatinHypercube(d=len(names), seed=rng).random(n_test)
    split = np.full(n, "train", dtype=object)
    split[rng.permutation(n)[: int(round(validation_fraction * n))]] = "validation"
    table = pd.DataFrame(qmc.scale(np.vstack([design, test]), lo, hi), columns=names)
    table.insert(0, "split", np.concatenate([split, np.full(n_test, "test", dtype=object)]))
    table.insert(0, "scenario", np.arange(n + n_test))
    return table


@dataclass
class RunSolutions:
    """Steady states of S scenarios at each run: harmonics (R, S, H+1, n) and per-point status."""

    runs: list[str]
    rpm: list[float]  # the speed each run was solved at
    eccentric_mass_g: list[float]
    harmonics: Array
    success: Array  # (R, S)
    message: Array  # (R, S) object
    branch: Array  # (R, S) object


def solve_runs(variant: Variant, runs: pd.DataFrame, values: Mapping[str, Array | float],
               harmonics: int = 5, step_rpm: float = 50.0, start_rpm: float = 300.0) -> RunSolutions:
    """Every scenario of ``values`` at every run (rows with run, rpm, eccentric_mass_g), by run-up.

    values: parameter values, scalars or (S,) arrays (m_e is set from each run).
    Per eccentric mass one batched sweep starts at ``start_rpm`` (or the lowest
    speed if lower) and visits that mass's speeds, with intermediate speeds so
    no step exceeds ``step_rpm`` (solved for continuation only).
    """
    for column in ("run", "rpm", "eccentric_mass_g"):
        if column not in runs:
            raise ValueError(f"the run plan needs a column {column!r} (has {list(runs.columns)})")
    base = variant.values(values)
    S = max([np.size(v) for v in base.values()])
    n_dof = variant.model.shaft.n_dof
    R = len(runs)
    out = RunSolutions(list(runs["run"].astype(str)), runs["rpm"].astype(float).tolist(),
                       runs["eccentric_mass_g"].astype(float).tolist(), np.full((R, S, harmonics + 1, n_dof), np.nan + 0j),
                       np.zeros((R, S), bool), np.empty((R, S), object), np.empty((R, S), object))
    for mass_g, group in runs.groupby("eccentric_mass_g", sort=True):
        scenario_values = {k: np.broadcast_to(v, (S,)) for k, v in base.items()}
        if "m_e" not in values:  # an unknown m_e keeps each scenario's own value
            scenario_values["m_e"] = np.full(S, float(mass_g) * 1e-3)
        speeds = _with_intermediate(np.unique(np.append(group["rpm"].to_numpy(float), start_rpm)), step_rpm)

        def build(rpm: float, rows: Array):
            return variant.model.system({k: v[rows] for k, v in scenario_values.items()}, rpm)

        sweep = solve_sweep(build, speeds, S, harmonics=harmonics, direction="up")
        by_rpm = dict(zip(sweep.rpm, sweep.results))
        for position, rpm in zip(np.flatnonzero(runs.index.isin(group.index)), group["rpm"].to_numpy(float)):
            _store(out, position, by_rpm[rpm])
    return out


def _store(out: RunSolutions, position: int, result: SteadyState) -> None:
    out.harmonics[position] = result.harmonics
    out.success[position] = result.success
    out.message[position] = result.message
    out.branch[position] = result.branch


def solve_operating_points(variant: Variant, points: pd.DataFrame, overrides: Mapping[str, float] | None = None,
                           harmonics: int = 5, **options) -> pd.DataFrame:
    """One parameter set over a run plan: ``points`` plus sensor harmonics and status per run.

    Adds, per harmonic h (1..H), columns U{h}_re_m, U{h}_im_m, V{h}_re_m,
    V{h}_im_m (sensor node, 0-peak), and success, branch, message.
    """
    solutions = solve_runs(variant, points, overrides or {}, harmonics, **options)
    out = points.copy()
    U, V = sensor_harmonics(solutions.harmonics[:, 0], variant.model.shaft)  # (R, H+1) each
    for h in range(1, harmonics + 1):
        for name, values in ((f"U{h}", U[:, h]), (f"V{h}", V[:, h])):
            out[f"{name}_re_m"] = values.real
            out[f"{name}_im_m"] = values.imag
    out["success"] = solutions.success[:, 0]
    out["branch"] = solutions.branch[:, 0]
    out["message"] = solutions.message[:, 0]
    return out


def _with_intermediate(speeds: Array, step: float) -> Array:
    """The sorted speeds plus evenly spaced intermediate ones so no gap exceeds ``step``."""
    if speeds.size < 2:
        return speeds
    parts = [np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)[:-1] for a, b in zip(speeds[:-1], speeds[1:])]
    return np.concatenate(parts + [speeds[-1:]])
