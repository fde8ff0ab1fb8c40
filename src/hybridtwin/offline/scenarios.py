"""Scenarios: parameter sets to solve at the run plan's operating points (paper eq. 1-2).

- ``sample_scenarios``: a seeded Latin hypercube over a variant's unknown
  ranges (scipy.stats.qmc), split into training, validation (choosing the
  library's size) and test (scoring the library) scenarios.
- ``solve_runs``: every scenario at every run's (rpm, eccentric mass), batched
  over scenarios, the way the rig is driven: per eccentric mass a run-up by
  continuation through that mass's speeds, so that near the resonance each
  point is on the branch a run-up reaches and says which branch that is.
- ``sample_enrichment`` / ``solve_enrichment``: adaptive sampling after the
  first design, more scenarios where the runs near the resonance can be
  measured (most of the box is outside the sensor range there).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import tables
from ..model.effect_base import Array
from ..model.sensor import sensor_harmonics
from ..solvers.continuation import RUN_UP_FROM_RPM, padded_speeds, ramp, sweep_model
from ..solvers.solver import DEFAULT_HARMONICS, SteadyState, flag_unstable, floquet_radius
from ..model.variants import Variant


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
    """Steady states of S scenarios at each run: harmonics (R, S, H+1, n) and per-point status.

    success: the harmonic-balance solve converged; floquet_radius: the largest |Floquet multiplier|
    of a converged point (NaN where none); ``stable``: converged with every multiplier inside the
    unit circle. An unstable point keeps its harmonics, and its message starts with "unstable".
    ``solved``: the scenario was solved at the run (the code; False only for an enrichment scenario at a run of
    another eccentric mass, whose message, for people, is ``NOT_SOLVED``); all True when not given.
    """

    runs: list[str]
    rpm: list[float]  # the speed each run was solved at
    eccentric_mass_g: list[float]
    harmonics: Array
    success: Array  # (R, S)
    message: Array  # (R, S) object
    branch: Array  # (R, S) object
    floquet_radius: Array | None = None  # (R, S)
    solved: Array | None = None  # (R, S) bool

    def __post_init__(self) -> None:
        if self.floquet_radius is None:
            self.floquet_radius = np.full(self.success.shape, np.nan)
        if self.solved is None:
            self.solved = np.ones(self.success.shape, bool)

    @property
    def stable(self) -> Array:
        """(R, S) converged and stable."""
        return self.success & (np.nan_to_num(self.floquet_radius, nan=np.inf) < 1.0)


def solve_runs(variant: Variant, runs: pd.DataFrame, values: Mapping[str, Array | float],
               harmonics: int = DEFAULT_HARMONICS, step_rpm: float = 50.0,
               start_rpm: float = RUN_UP_FROM_RPM) -> RunSolutions:
    """Every scenario of ``values`` at every run (rows with run, rpm, eccentric_mass_g), by run-up.

    values: parameter values, scalars or (S,) arrays (m_e is set from each run).
    Per eccentric mass a run-up starts at ``start_rpm`` (or the lowest speed if
    lower) and visits that mass's speeds, with intermediate speeds so no step
    exceeds ``step_rpm`` (solved for continuation only). The run-ups of all the
    masses are one batched sweep with per-scenario speeds (``solve_sweep``): each
    Newton call serves every mass, and each result is that of a run-up of its own.
    The stability of each point is assessed at the runs' speeds only (``assess_stability``),
    not at the intermediate ones. A linear model (no effect with a nonlinear force) has one steady
    state at each speed, whatever the start: its masses' speeds are solved without the run-up from
    ``start_rpm`` and without intermediate speeds, to the same bits (the harmonic balance is then the
    linear solve; the first speed of each mass is labelled ``direct``).
    """
    for column in ("run", "rpm", "eccentric_mass_g"):
        if column not in runs:
            raise ValueError(f"the run plan needs a column {column!r} (has {list(runs.columns)})")
    base = variant.values(values)
    S = max([np.size(v) for v in base.values()])
    out = _unsolved(runs, S, harmonics, variant.model.shaft.n_dof)
    groups = list(runs.groupby("eccentric_mass_g", sort=True))
    if not groups:
        return out
    # the masses' run-ups side by side, the longest first: the scenarios still on their ramp at a step are then the
    # first columns, and each step's system slices the assembled matrices as a view, not a copy
    linear = not any(effect.is_nonlinear for effect in variant.model.effects)
    ramps = [np.unique(group["rpm"].to_numpy(float)) if linear else
             ramp(start_rpm, group["rpm"].to_numpy(float), step_rpm)
             for _, group in groups]
    order = sorted(range(len(groups)), key=lambda g: -len(ramps[g]))
    groups, ramps = [groups[g] for g in order], [ramps[g] for g in order]
    speeds = padded_speeds(ramps, S)  # column g S + s: mass g (in that order), scenario s
    scenario_values = {k: np.tile(np.broadcast_to(v, (S,)), len(groups)) for k, v in base.items()}
    if "m_e" not in values:  # an unknown m_e keeps each scenario's own value
        scenario_values["m_e"] = np.repeat([float(mass_g) * 1e-3 for mass_g, _ in groups], S)

    sweep, build = sweep_model(variant.model, scenario_values, speeds, len(groups) * S, harmonics)
    stored: list[tuple[int, int, int]] = []  # (run position, sweep step, mass group)
    for g, ((_, group), grid) in enumerate(zip(groups, ramps)):
        for position, rpm in zip(np.flatnonzero(runs.index.isin(group.index)), group["rpm"].to_numpy(float)):
            stored.append((position, int(np.flatnonzero(grid == rpm)[0]), g))
    # the converged points at a run's speed, assessed in one batch across steps and masses
    points = sorted({(step, column) for _, step, g in stored for column in range(g * S, (g + 1) * S)
                     if sweep.results[step].success[column]})
    if points:
        step, column = np.array(points).T
        harmonics_at = np.stack([sweep.results[s].harmonics[c] for s, c in points])
        radius = floquet_radius(build(speeds[step, column], column), harmonics_at)
        for s in np.unique(step):
            flag_unstable(sweep.results[s], column[step == s], radius[step == s])
    for position, step, g in stored:
        _store(out, position, sweep.results[step], slice(g * S, (g + 1) * S))
    return out


def _unsolved(runs: pd.DataFrame, S: int, harmonics: int, n_dof: int) -> RunSolutions:
    """S scenarios at the runs, nothing solved yet: NaN harmonics, no success, empty messages."""
    R = len(runs)
    return RunSolutions(list(runs["run"].astype(str)), runs["rpm"].astype(float).tolist(),
                        runs["eccentric_mass_g"].astype(float).tolist(), np.full((R, S, harmonics + 1, n_dof), np.nan + 0j),
                        np.zeros((R, S), bool), np.full((R, S), "", object), np.full((R, S), "", object))


def _store(out: RunSolutions, position: int, result: SteadyState, rows: slice) -> None:
    """Run ``position``'s solutions: ``result``'s scenarios ``rows``."""
    out.harmonics[position] = result.harmonics[rows]
    out.success[position] = result.success[rows]
    out.message[position] = result.message[rows]
    out.branch[position] = result.branch[rows]
    out.floquet_radius[position] = result.floquet_radius[rows]


def write_scenarios(table: pd.DataFrame, path, float_format: str | None = tables.REFIT) -> None:
    """A scenario table: ``sample_scenarios``' scenarios.tsv at 12 significant digits (the values the chunks
    solve), ``sample_enrichment``'s enrichment.tsv with ``float_format`` None (every digit, as it always was);
    ``read_scenarios`` reads either."""
    (tables.SCENARIOS if float_format == tables.SCENARIOS.float_format else tables.ENRICHMENT_SCENARIOS).write(
        table, path)


def read_scenarios(path) -> pd.DataFrame:
    """A scenario table written by ``write_scenarios``: scenario, split (text), eccentric_mass_g (enrichment),
    one column per unknown."""
    return tables.SCENARIOS.read(path)  # the enrichment's: the same text column


#: message of an enrichment scenario at a run it was not solved for (it targets other runs); not a failure. The
#: sentence is for people: code reads ``RunSolutions.solved`` (stored as the snapshot stores' ``solved`` array)
NOT_SOLVED = "not solved at this run: an enrichment scenario of the runs at"


def sample_enrichment(variant: Variant, values: Array, split: Array, observable: Array, runs: pd.DataFrame,
                      first_scenario: int, n: int, below: float, seed: int, validation_fraction: float = 0.2,
                      neighbours: int = 8, oversampling: int = 40) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Extra scenarios where the thin runs can be measured (adaptive sampling after the first design).

    A run is thin when fewer than ``below`` of the fitting scenarios (train and validation)
    are observable there (converged and inside the sensor range): near the resonance most of
    the box is not (e.g. geometric at 950 RPM, 0 g: 21 %), so its library rests on few points.
    Per eccentric mass with a thin run: a Latin hypercube of ``oversampling`` x ``n``
    candidates, each kept when most of its ``neighbours`` nearest first-design scenarios
    (scaled to the unit box) are observable at one of that mass's thin runs; the first ``n``
    kept (the hypercube's order is random) become new scenarios, split train/validation.
    They are solved at that mass's runs only. The test scenarios are never enriched, so the
    libraries are still scored on an independent hypercube over the whole box.

    values (S, d) SI, split (S,), observable (R, S) in the order of ``runs`` (run, eccentric_mass_g).
    Returns the new scenarios (scenario from ``first_scenario``, split, eccentric_mass_g, one
    column per unknown) and a summary per thin run (observable share, candidates kept, added).
    """
    from scipy.spatial import cKDTree
    from scipy.stats import qmc

    names = variant.unknown_names
    lo, hi = variant.bounds(names)
    fit = np.asarray(split) != "test"
    share = observable[:, fit].mean(axis=1)
    thin = share < below
    rng = np.random.default_rng(seed)
    tree = cKDTree((values[fit] - lo) / (hi - lo))
    tables, summary = [], []
    masses = runs["eccentric_mass_g"].to_numpy(float)
    for mass in np.unique(masses[thin]):
        rows = np.flatnonzero(thin & (masses == mass))
        candidates = qmc.LatinHypercube(d=len(names), seed=rng).random(oversampling * n)
        _, nearest = tree.query(candidates, k=min(neighbours, tree.n))
        votes = observable[np.ix_(rows, np.flatnonzero(fit))][:, nearest.reshape(len(candidates), -1)].mean(axis=2)
        kept = np.flatnonzero((votes > 0.5).any(axis=0))
        chosen = candidates[kept[:n]]
        table = pd.DataFrame(qmc.scale(chosen, lo, hi), columns=names) if chosen.size else pd.DataFrame(columns=names)
        table.insert(0, "eccentric_mass_g", float(mass))
        tables.append(table)
        for r, v in zip(rows, votes):
            summary.append({"run": runs["run"].iloc[r], "eccentric_mass_g": float(mass),
                            "observable_share": float(share[r]), "candidates_kept_pct": 100 * float((v > 0.5).mean()),
                            "added": len(table)})
    table = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame(columns=["eccentric_mass_g", *names])
    table.insert(0, "split", np.where(rng.random(len(table)) < validation_fraction, "validation", "train"))
    table.insert(0, "scenario", np.arange(first_scenario, first_scenario + len(table)))
    return table, pd.DataFrame(summary, columns=["run", "eccentric_mass_g", "observable_share",
                                                 "candidates_kept_pct", "added"])


def solve_enrichment(variant: Variant, runs: pd.DataFrame, table: pd.DataFrame, harmonics: int = DEFAULT_HARMONICS) -> RunSolutions:
    """Enrichment scenarios (``sample_enrichment``) solved at the runs of their eccentric mass, by run-up;
    at every other run they are not solved (``solved`` False, the message ``NOT_SOLVED``; not a failure)."""
    S = len(table)
    out = _unsolved(runs, S, harmonics, variant.model.shaft.n_dof)
    masses = runs["eccentric_mass_g"].to_numpy(float)
    for mass, group in table.groupby("eccentric_mass_g", sort=True):
        cols = table.index.get_indexer(group.index)
        at = np.flatnonzero(masses == mass)
        if not at.size:
            raise ValueError(f"enrichment scenarios for {mass:g} g, but no run has that eccentric mass "
                             f"(runs: {sorted(set(masses))} g)")
        elsewhere = np.ix_(np.flatnonzero(masses != mass), cols)
        out.solved[elsewhere] = False
        out.message[elsewhere] = f"{NOT_SOLVED} {mass:g} g"
        part = solve_runs(variant, runs.iloc[at], {k: group[k].to_numpy(float) for k in variant.unknown_names},
                          harmonics)
        for name in ("harmonics", "success", "message", "branch", "floquet_radius"):
            getattr(out, name)[np.ix_(at, cols)] = getattr(part, name)
    return out


def solve_operating_points(variant: Variant, points: pd.DataFrame, overrides: Mapping[str, float] | None = None,
                           harmonics: int = DEFAULT_HARMONICS, **options) -> pd.DataFrame:
    """One parameter set over a run plan: ``points`` plus sensor harmonics and status per run.

    Adds, per harmonic h (1..H), columns U{h}_re_m, U{h}_im_m, V{h}_re_m,
    V{h}_im_m (sensor node, 0-peak), and success, stable, floquet_radius, branch, message.
    """
    solutions = solve_runs(variant, points, overrides or {}, harmonics, **options)
    out = points.copy()
    U, V = sensor_harmonics(solutions.harmonics[:, 0], variant.model.shaft)  # (R, H+1) each
    for h in range(1, harmonics + 1):
        for name, values in ((f"U{h}", U[:, h]), (f"V{h}", V[:, h])):
            out[tables.part_column(name, "re")] = values.real
            out[tables.part_column(name, "im")] = values.imag
    out["success"] = solutions.success[:, 0]
    out["stable"] = solutions.stable[:, 0]
    out["floquet_radius"] = solutions.floquet_radius[:, 0]
    out["branch"] = solutions.branch[:, 0]
    out["message"] = solutions.message[:, 0]
    return out

