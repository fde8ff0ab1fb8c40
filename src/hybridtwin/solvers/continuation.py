"""Continuation: steady states along a speed sweep (run-up or run-down), as the rig is driven.

Each speed starts from the previous speed's solution of the same scenario (``solver.solve`` with ``initial``);
a step that fails is retried with the speed halved; a branch that ends at a fold jumps to the remaining one,
found from several starts and preferring a stable landing, and says so in its ``branch``. Many scenarios, and
sweeps with speeds of their own (one run-up per eccentric mass), advance in lockstep in the same batched
solves; a step that fails waits while the others go on, and the waiting scenarios of all steps are then
refined and jumped together (``_sweep_pass``). Every scenario's steady states are those of a sweep of its
own, to the last bit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from . import solver
from ..model.effect_base import Array
from ..model.model import System
from .solver import INVALID, SteadyState, assess_stability, solve

# continuation steps give up (and are refined) when the residual has not halved over this many iterations;
# longer than a fresh start's window because near a fold Newton may need long damped progress. Expansion
# chunk (120 scenarios, 22 runs): 34 -> 21-24 s against no window, 1 of 2640 points lost; Geometric: 6 of
# 4385 lost, all beyond 50 mm where no sensor reads.
_CONTINUATION_STALL = 16
#: the speed [RPM] a run-up starts from when nothing else is said: the rig's truth, the offline scenarios, the
#: fits' forward models and the command line all start here, so that they reach the same branch
RUN_UP_FROM_RPM = 300.0
_STALL_WINDOW = 8  # fresh starts in sweeps give up when the residual has not halved over this many iterations


@dataclass
class Sweep:
    """Steady states along a speed sweep, in sweep order.

    rpm: (n,) the speeds shared by every scenario, or (n, S) each scenario's own (NaN after its last);
    results[i] holds every scenario at step i (a scenario whose sweep has ended is marked unsolved).
    """

    rpm: Array
    results: list[SteadyState]
    direction: str


def solve_sweep(
    build: Callable[[Array, Array], System],
    rpm: Sequence[float] | Array,
    n_scenarios: int,
    *,
    direction: str = "up",
    max_refine: int = 3,
    stability: bool = True,
    **options,
) -> Sweep:
    """Solve a speed sweep by continuation (run-up or run-down) for S scenarios.

    build(rpm, rows) -> System of scenarios ``rows`` at their speeds ``rpm`` (len(rows),).
    Each speed starts from the previous speed's solution of the same scenario; a
    scenario that fails to continue is retried with the speed step halved up to
    ``max_refine`` times. If it still fails, its branch has ended at a fold and
    the machine would jump: the other branch is sought from several starting
    points (the linear response, the last state scaled by 0.5 .. 5), preferring
    a stable branch to an unstable one (``_jump``), and the result's ``branch``
    says "run-up, jump between A and B RPM". Nothing is jumped silently, and a
    scenario for which no start converges is reported failed with the reason.

    rpm: the speeds (n,), shared (sorted in the sweep's direction), or per scenario (n, S),
    column s the speeds of scenario s in sweep order, NaN-padded after its last. Scenarios of
    different sweeps (e.g. one run-up per eccentric mass) are then solved in lockstep: every
    batched Newton call, step halving and jump serves all of them at once. Each scenario's
    result is the same as in a sweep of its own (the solver treats scenarios independently).

    stability: assess the stability of every step's converged solutions (``assess_stability``:
    the continuation itself goes on from unstable ones too); False leaves it to the caller
    (e.g. ``scenarios.solve_runs``, which assesses the run speeds only).
    """
    if direction not in ("up", "down"):
        raise ValueError(f"direction must be 'up' or 'down', got {direction!r}")
    speeds = _sweep_speeds(rpm, n_scenarios, direction)
    label = "run-up" if direction == "up" else "run-down"
    options = {**options, "stability": False}  # assessed once per step, below
    results: list[SteadyState | None] = [None] * speeds.shape[0]
    # Passes over the steps: a scenario whose continuation fails at a step waits there (``_sweep_pass``) while the
    # others go on; then the step halvings and jumps of every waiting scenario, whatever its step, run in one
    # batch (few scenarios per step would each pay a batched call's fixed cost), and those scenarios go on from
    # the step after, in the next pass. Each scenario meets the same computations as in a step-by-step sweep.
    begin = np.full(n_scenarios, -1)  # the last step already final, per scenario
    columns = np.arange(n_scenarios)
    while True:
        waits = _sweep_pass(build, speeds, results, columns, begin, label, options, stability)
        rows = np.flatnonzero(waits >= 0)
        if not rows.size:
            break
        rows = rows[np.argsort(waits[rows], kind="stable")]  # by step, then scenario
        step = waits[rows]
        steps = np.unique(step)
        # each waiting row's first attempt is its row of results[step], its start that of results[step - 1]
        first = SteadyState.concatenate([results[k].take(rows[step == k]) for k in steps])
        x0 = np.concatenate([results[k - 1].state[rows[step == k]] for k in steps])
        rpm_from, rpm_to = speeds[step - 1, rows], speeds[step, rows]
        res = _refine(build, first, rpm_from, rpm_to, x0, rows, max_refine, label, options)
        lost = np.flatnonzero(~res.success)
        if lost.size:
            res.put(lost, _in_blocks(lost.size, lambda b: _jump(
                build, rpm_from[lost[b]], rpm_to[lost[b]], x0[lost[b]], rows[lost[b]], label, options)))
        if stability:  # (jumps assessed their own landings)
            _assess_new(build, rpm_to, rows, res, np.arange(rows.size))
        for k in steps:
            results[k].put(rows[step == k], res.take(np.flatnonzero(step == k)))
        begin[rows] = step
        columns = rows
    return Sweep(speeds[:, 0] if np.ndim(rpm) == 1 else speeds, results, direction)


def _sweep_pass(build, speeds: Array, results: list, columns: Array, begin: Array, label: str, options: dict,
                stability: bool) -> Array:
    """Advance scenarios ``columns`` from their step ``begin + 1`` on, in lockstep, into ``results`` (a step's
    SteadyState of every scenario; a scenario that waits, or has not reached the step yet, holds a placeholder
    row there until a later pass). A scenario whose continuation fails stops there, its failed first attempt in
    ``results``: the step where each waits for its step halvings and jumps, (S,), -1 where none does."""
    n_steps, S = speeds.shape
    waits = np.full(S, -1)
    for i in range(begin[columns].min() + 1, n_steps):
        mine = columns[(begin[columns] < i) & (waits[columns] < 0)]
        speed = speeds[i]
        previous = results[i - 1] if i > 0 else None
        active = mine[~np.isnan(speed[mine])]
        cont = active[previous.success[active]] if previous is not None else np.arange(0)
        fresh = np.setdiff1d(active, cont)
        ended = np.setdiff1d(mine, active)
        parts, rows = [], []
        if cont.size:
            first = _attempt(build, speed[cont], previous.state[cont], cont, label, options)
            waits[cont[~first.success]] = i
            parts.append(first)
            rows.append(cont)
        if fresh.size:
            parts.append(_in_blocks(fresh.size, lambda b: solve(build(speed[fresh[b]], fresh[b]),
                                                                stall_window=_STALL_WINDOW, **options)))
            rows.append(fresh)
        if ended.size:
            parts.append(_ended(previous, ended))
            rows.append(ended)
        if results[i] is None:  # the first pass: rows for the scenarios that wait, to be replaced later
            rest = np.setdiff1d(np.arange(S), np.concatenate(rows) if rows else np.arange(0))
            if rest.size:
                parts.append(_ended(previous, rest))
                rows.append(rest)
            results[i] = SteadyState.concatenate(parts, np.argsort(np.concatenate(rows)))
        elif rows:
            results[i].put(np.concatenate(rows), SteadyState.concatenate(parts))
        if stability:
            _assess_new(build, speed[active], active, results[i], active)
    return waits


def _assess_new(build, rpm: Array, rows: Array, result: SteadyState, where: Array) -> None:
    """The stability of the converged, not yet assessed rows ``where`` of ``result`` (scenarios ``rows`` at
    speeds ``rpm``, one per row of ``where``)."""
    new = result.success[where] & np.isnan(result.floquet_radius[where])
    if new.any():
        assess_stability(build(rpm[new], rows[new]), result, where[new])


def _sweep_speeds(rpm: Sequence[float] | Array, n_scenarios: int, direction: str) -> Array:
    """Every scenario's speed at every step (n, S): shared speeds sorted in the sweep's direction,
    per-scenario ones checked (monotone in that direction, NaN only after a scenario's last)."""
    speeds = np.asarray(rpm, dtype=float)
    if speeds.ndim == 1:
        speeds = np.sort(speeds)[::-1] if direction == "down" else np.sort(speeds)
        return np.repeat(speeds[:, None], n_scenarios, axis=1)
    if speeds.ndim != 2 or speeds.shape[1] != n_scenarios:
        raise ValueError(f"per-scenario speeds must have shape (n_steps, {n_scenarios}), got {speeds.shape}")
    missing = np.isnan(speeds)
    if missing[0].any() or (missing[:-1] & ~missing[1:]).any():
        raise ValueError("per-scenario speeds: every scenario needs a first speed, and NaN only after its last")
    steps = np.diff(speeds, axis=0)
    if ((steps <= 0) if direction == "up" else (steps >= 0))[~np.isnan(steps)].any():
        raise ValueError(f"per-scenario speeds must be strictly {'increasing' if direction == 'up' else 'decreasing'}"
                         f" along a {direction} sweep")
    return speeds


def intermediate_speeds(speeds: Array, step: float) -> Array:
    """The sorted speeds plus evenly spaced intermediate ones so no gap exceeds ``step``."""
    if speeds.size < 2:
        return speeds
    parts = [np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)[:-1] for a, b in zip(speeds[:-1], speeds[1:])]
    return np.concatenate(parts + [speeds[-1:]])


def ramp(start_rpm: float, speeds: Sequence[float] | Array, step_rpm: float) -> Array:
    """The speed grid of a run-up (or, reversed, a run-down) from ``start_rpm`` through ``speeds``: both, sorted,
    with intermediate speeds so that no step exceeds ``step_rpm`` (``intermediate_speeds``). The one grid of the
    offline stage's run-ups, the fits' (``forward.run_up``) and the rig's."""
    return intermediate_speeds(np.unique(np.append(np.asarray(speeds, float), start_rpm)), step_rpm)


def sweep_model(model, values: dict[str, Array], speeds: Array, n_scenarios: int, harmonics: int,
                direction: str = "up", stability: bool = False) -> tuple[Sweep, Callable[[Array, Array], System]]:
    """``n_scenarios`` parameter sets of ``model`` (a ``Model``; ``values`` complete, each (n,) or scalar) swept
    along ``speeds`` (one speed per step for all, or per scenario: ``padded_speeds``): the speed-independent
    stages assembled once (``Model.at_rest``), the system at each step's speeds from them. The run-up of the
    offline stage, of the fits and of a lockstep of sets each on its own ramp. Returns the sweep and its
    ``build`` (rows' system at speeds), for a stability check after it."""
    rest = model.at_rest(values, n_scenarios)

    def build(rpm: Array, rows: Array) -> System:
        return model.system_at(rest.rows(rows), rpm)

    sweep = solve_sweep(build, speeds, n_scenarios, harmonics=harmonics, direction=direction, stability=stability)
    return sweep, build


def padded_speeds(ramps: Sequence[Array], each: int = 1) -> Array:
    """Per-scenario sweep speeds for ``solve_sweep`` (n, len(ramps) * each): ``each`` columns per
    ramp, in order, NaN after a ramp's last speed."""
    speeds = np.full((max(map(len, ramps)), len(ramps) * each), np.nan)
    for g, ramp in enumerate(ramps):
        speeds[:len(ramp), g * each:(g + 1) * each] = np.asarray(ramp, float)[:, None]
    return speeds


def _in_blocks(n: int, solve_block: Callable[[Array], SteadyState]) -> SteadyState:
    """solve_block(b) over index blocks b of 0..n-1 of at most ``solver.BLOCK`` scenarios, stacked in order.

    The result does not depend on the blocking (the solver treats scenarios independently), but
    the time does: per scenario a batched solve costs least at a few hundred (final variant,
    700 RPM, one thread: 0.23 ms at 128-256 scenarios, 0.25 at 512, 0.31 at 2048, 0.46 at
    4096), beyond which its temporaries outgrow the caches. Sweeps in lockstep (several
    run-ups) and enrichment designs would otherwise batch thousands.
    """
    blocks = solver.index_blocks(np.arange(n))
    parts = [solve_block(b) for b in blocks]
    return parts[0] if len(parts) == 1 else SteadyState.concatenate(parts)


def _ended(previous: SteadyState, rows: Array) -> SteadyState:
    """Scenarios ``rows`` at a step after their sweep's last speed: unsolved, with the reason."""
    out = previous.take(rows)
    out.harmonics[:], out.state[:], out.residual[:] = np.nan, np.nan, np.nan
    out.success[:], out.status[:], out.iterations[:], out.floquet_radius[:] = False, INVALID, 0, np.nan
    out.message[:] = "no speed at this step: the scenario's sweep has ended"
    return out


_JUMP_STARTS = (None, 1.5, 2.0, 3.0, 5.0, 0.5)  # None: the linear response; a number: scaled last state


def _jump(build, rpm_from: Array, rpm_to: Array, x_last, rows, label, options) -> SteadyState:
    """Past a fold: look for the remaining branch at ``rpm_to`` (per row) from several starts.

    Near the nonlinear resonance the response is multi-valued, and a start may land on an unstable branch
    (the middle one between two folds), a state the machine leaves. So every landing's stability is assessed
    (whatever the sweep's ``stability``: jumps are rare, and the check costs about one solve of the few rows
    that jump), and the starts go on until each row has a stable one; an unstable landing is kept only when
    no start reaches a stable branch (its message then says it is unstable).
    """
    system = build(rpm_to, rows)
    branch = np.array([f"{label}, jump between {a:g} and {b:g} RPM" for a, b in zip(rpm_from, rpm_to)], object)
    best = None
    for scale in _JUMP_STARTS:
        open_ = np.arange(len(rows)) if best is None else np.flatnonzero(~best.stable)
        if open_.size == 0:
            break
        start = None if scale is None else scale * x_last[open_]
        if start is not None and start.size and np.isnan(start).any():
            continue
        trial = solve(system.subset(open_), initial=start, stall_window=_STALL_WINDOW,
                      **{**options, "stability": True})
        trial.branch[:] = branch[open_]
        if best is None:
            best = trial
        else:  # a stable landing, or a first landing at all, replaces what the earlier starts found
            better = np.flatnonzero(trial.stable | (trial.success & ~best.success[open_]))
            best.put(open_[better], trial.take(better))
    failed = np.flatnonzero(~best.success)
    best.message[failed] = [
        f"no periodic solution found at {rpm_to[i]:g} RPM: the {label} branch ends at a fold after {rpm_from[i]:g} "
        f"RPM and none of {len(_JUMP_STARTS)} starting points converged" for i in failed]
    best.branch[failed] = label
    return best


def _attempt(build, rpm_to: Array, x0, rows, label, options) -> SteadyState:
    """One continuation step from ``x0`` to ``rpm_to`` (per row), no halving."""
    return _in_blocks(rows.size, lambda b: solve(build(rpm_to[b], rows[b]), initial=x0[b], branch=label,
                                                 stall_window=_CONTINUATION_STALL, **options))


def _continue(build, rpm_from: Array, rpm_to: Array, x0, rows, depth, label, options) -> SteadyState:
    """Continue from ``x0`` at ``rpm_from`` to ``rpm_to`` (per row), halving the step where Newton fails."""
    return _refine(build, _attempt(build, rpm_to, x0, rows, label, options), rpm_from, rpm_to, x0, rows, depth,
                   label, options)


def _refine(build, res: SteadyState, rpm_from: Array, rpm_to: Array, x0, rows, depth, label, options
            ) -> SteadyState:
    """``res``, a continuation step's first attempt, with each failed row's step halved (two half steps, each
    continued the same way) up to ``depth`` times; in place."""
    failed = np.flatnonzero(~res.success)
    if depth == 0 or failed.size == 0:
        return res
    mid = 0.5 * (rpm_from[failed] + rpm_to[failed])
    half = _continue(build, rpm_from[failed], mid, x0[failed], rows[failed], depth - 1, label, options)
    ok = np.flatnonzero(half.success)
    if ok.size:
        again = _continue(build, mid[ok], rpm_to[failed[ok]], half.state[ok], rows[failed[ok]], depth - 1, label,
                          options)
        res.put(failed[ok], again)
    return res
