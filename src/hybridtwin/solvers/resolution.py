"""Is a harmonic balance resolved? The harmonics and time samples a non-smooth force needs (issue 54).

A harmonic balance truncated at H harmonics and sampled at N instants a period converges (Newton's residual 1e-10)
to the fixed point of the truncated problem. For a smooth force that is the periodic orbit to a truncation error
that falls fast with H. A contact's or a clearance's force (``faults.Rub``, ``faults.Looseness``) has a kink where
the contact starts: its spectrum falls off slowly, and the truncated orbit can differ from the true one by more than
a record's noise while the solver reports success. Such an effect declares what it needs
(``Effect.needs_harmonics``, ``Effect.needs_time_samples``), and this module

- reads the declarations: ``needed_harmonics(effects, H)`` the harmonics a model's harmonic balance carries (at
  least H, the harmonics compared), ``needed_time_samples(effects)``;
- says when an orbit is not resolved (``check_resolution``): the same system solved again with twice the harmonics
  and four times the time samples, started from the orbit found; the orbit is resolved when its harmonics 1..H at
  the nonlinear force's DOFs move by less than ``tolerance`` times their largest. A refined solve that does not
  converge is reported as such, never as resolved.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..model.effect_base import Array, Effect
from ..model.model import System
from .solver import SteadyState, solve

#: an orbit is resolved when refining it moves its harmonics 1..H by less than this share of their largest: a tenth
#: of a percent, below a probe's calibration uncertainty (1-2 %) and a record's noise at a few um of 1X
RESOLUTION_TOLERANCE = 1e-3


def needed_harmonics(effects: Sequence[Effect], harmonics: int) -> int:
    """The harmonics a harmonic balance of ``effects`` carries when ``harmonics`` are compared: the most any effect
    declares (``needs_harmonics``), at least ``harmonics``."""
    return max([int(harmonics)] + [int(e.needs_harmonics) for e in effects if getattr(e, "needs_harmonics", None)])


def needed_time_samples(effects: Sequence[Effect]) -> int | None:
    """The time samples a period the effects declare (``needs_time_samples``; the most of them), None if none does
    (the solver's own then)."""
    declared = [int(e.needs_time_samples) for e in effects if getattr(e, "needs_time_samples", None)]
    return max(declared) if declared else None


@dataclass
class Resolution:
    """Per scenario: ``change``, how far refining moved the harmonics 1..H at the nonlinear DOFs relative to their
    largest (NaN where either solve failed); ``resolved`` below the tolerance; ``message`` says which and why."""

    change: Array
    resolved: Array
    message: Array


def check_resolution(system: System, steady: SteadyState, tolerance: float = RESOLUTION_TOLERANCE,
                     harmonics: int | None = None, n_time: int | None = None) -> Resolution:
    """Whether the orbits ``steady`` of ``system`` are resolved (module docstring): solved again with ``harmonics``
    (default twice steady's) and ``n_time`` samples (default four times steady's), from steady's orbit."""
    H = steady.H
    H2 = 2 * H if harmonics is None else int(harmonics)
    N2 = 4 * steady.n_time if n_time is None else int(n_time)
    if H2 < H:
        raise ValueError(f"check_resolution: {H2} harmonics cannot refine {H}")
    S = steady.n_scenarios
    change = np.full(S, np.nan)
    resolved = np.zeros(S, bool)
    message = np.full(S, "", dtype=object)
    if not system.forces:  # linear: the harmonic balance is exact at any H
        change[steady.success] = 0.0
        resolved[:] = steady.success
        message[:] = np.where(steady.success, "linear: exact at any number of harmonics", steady.message)
        return Resolution(change, resolved, message)
    start = np.zeros(steady.state.shape[:2] + (2 * H2 + 1,))
    start[:, :, :2 * H + 1] = np.nan_to_num(steady.state)
    refined = solve(system, H2, initial=start, n_time=N2, stability=False)
    dofs = np.unique(np.concatenate([f.dofs for f in system.forces]))
    ours, finer = steady.harmonics[:, 1:, dofs], refined.harmonics[:, 1:H + 1, dofs]
    both = steady.success & refined.success
    scale = np.abs(ours).reshape(S, -1).max(axis=1)
    change[both] = np.abs(finer - ours)[both].reshape(both.sum(), -1).max(axis=1) / np.where(
        scale[both] > 0, scale[both], 1.0)
    resolved = both & (change <= tolerance)
    for s in range(S):
        if not steady.success[s]:
            message[s] = f"no orbit to check: {steady.message[s]}"
        elif not refined.success[s]:
            message[s] = (f"not resolved: with {H2} harmonics and {N2} time samples the harmonic balance does not "
                          f"converge ({refined.message[s]}): the orbit at {H} harmonics is not to be trusted")
        elif resolved[s]:
            message[s] = (f"resolved: {H2} harmonics and {N2} time samples move its 1X..{H}X by {change[s]:.1e} of "
                          "the largest")
        else:
            message[s] = (f"not resolved: {H2} harmonics and {N2} time samples move its 1X..{H}X by {change[s]:.1e} "
                          f"of the largest (tolerance {tolerance:g}): raise the harmonics")
    return Resolution(change, resolved, message)
