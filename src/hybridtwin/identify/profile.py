"""Intervals that account for the parameters a fit leaves loose (profile likelihood).

A shared parameter at a range edge or not identifiable is "loose": the data put it anywhere in a stretch of its
range. The linearised intervals of the others (``uncertainty.analyse_uncertainty``) are then conditional on where
the fit happened to leave it, and can exclude the truth: on the bundled data the slope force's cubic term k_z of a
variant that carried it sat at its upper edge 1000 N (truth 301 N), and k_b and k_w's intervals missed their truths
by 2.9 and 2.4 standard errors, while the truth's chi^2 was only 6.2 above the optimum's.

Here each shared physical parameter p_i gets the interval

    { p_i : min over the rest (the loose ones free across their ranges) of chi^2 - chi^2_min <= Delta_i },
    Delta_i = s^2 chi2_quantile(confidence, 1 + number of loose parameters other than p_i),  s^2 = max(1, chi^2/dof),

the shadow on p_i of the joint confidence region of p_i and the loose parameters (Scheffe-type projection). A
plain profile-likelihood interval (one degree of freedom) is not robust to a weakly identified nuisance parameter:
the projection is (Dufour 1997; Dufour and Taamouti 2005), and on the case above it held every truth where the
one-degree profile still missed k_b and k_w (their truths 5.0 and 4.6 above the minimum, against 4.0 and 6.3).
The price is width: with one loose parameter a well-determined parameter's interval grows by sqrt(5.99 / 3.84) =
1.25 over a profile interval. Coverage over seeds: benchmarks/README.md. The interval is never narrower than the
linearised one (their union), and a loose parameter's own interval is its profile over its range.

The ends are found per parameter and side by a short search: from the linearised step, fits with p_i held fixed
(``levenberg_marquardt(..., fixed=)``: everything else, bows and phases included, refitted from the nearest point
inside) are extrapolated while the chi^2 rise stays below Delta_i and interpolated on sqrt(rise) once bracketed;
every parameter and side advances in the same batched fits.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables
from .lm import LMOptions, levenberg_marquardt
from .uncertainty import Profiled, loose_entries

Array = np.ndarray

#: search rounds per parameter and side (each one batched fit of all that are still open)
ROUNDS = 7
#: an end is accepted when the chi^2 rise is within this fraction of the threshold, or bracketed this tightly
#: (normalised units; a range is 2 wide: 0.2 % of it)
RISE_TOLERANCE, BRACKET_TOLERANCE = 0.05, 4e-3
#: the largest extrapolation factor of a step that stayed inside the region
GROWTH = 4.0
#: values across its range at which each loose parameter is held first (the valley, ``profile_intervals``)
GRID = 9
#: LM options of the fits with a parameter held (the polish's, fewer iterations: they start next to the optimum)
OPTIONS = LMOptions(max_iterations=30, ftol=1e-8, xtol=1e-8, gtol=1e-10, stall_chi2=1e-3, geodesic=True)


def threshold(confidence: float, dof: int, chi2_dof: float) -> float:
    """Delta: the chi^2 rise that bounds a joint region of ``dof`` parameters, scaled by max(1, chi^2/dof)."""
    return max(1.0, chi2_dof) * float(stats.chi2.ppf(confidence, dof))


def profile_intervals(fit, options: LMOptions = OPTIONS, rounds: int = ROUNDS, grid: int = GRID) -> Profiled | None:
    """The intervals of a fit's shared physical parameters over its loose ones (module docstring), or None when
    no parameter is loose (the linearised intervals then stand). ``fit``: an ``Identification`` with its problem
    (a fit, not a table read back).

    First each loose parameter is held at ``grid`` values across its range, the rest fitted: the valley the data
    leave (a loose parameter can sit where its own gradient vanishes, and a fit from the optimum would never leave
    it). Each end search then starts from the valley point farthest out on its side that lies inside its region."""
    u, L = fit.uncertainty, fit.layout
    loose = loose_entries(L, u.at_bound, u.identifiable)
    if not loose.any():
        return None
    start = time.perf_counter()
    names = [p for p, _ in L.entries()]
    targets = np.flatnonzero([run == "all" and p != "phase" for p, run in L.entries()])
    deltas = {i: threshold(fit.confidence, 1 + int(loose.sum()) - int(loose[i]), u.chi2_dof) for i in targets}
    base = float(fit.problem.evaluate(fit.theta[None], fit.X[None], jacobian=False).objective[0])
    lower_si, upper_si = (np.asarray(v, float) for v in fit.ranges())
    half = 0.5 * (upper_si - lower_si)
    stderr = np.where(L.is_nuisance, np.nan, u.stderr / np.where(half > 0, half, 1.0))  # normalised
    points: list[dict] = []

    def fits(theta0: Array, held: Array, labels: list[tuple[int, str]], k: int) -> tuple[Array, Array]:
        fixed = np.zeros(theta0.shape, bool)
        fixed[np.arange(len(held)), held] = True
        result = levenberg_marquardt(fit.problem, theta0, np.repeat(fit.X[None], len(theta0), 0), options, fixed)
        rise = 2.0 * result.cost - base
        for (i, side), x, r, status in zip(labels, result.x, rise, result.status):
            points.append({"parameter": names[i], "side": side, "round": k, "value": float(L.to_si(x)[i]),
                           "normalised": float(x[i]), "chi2_rise": float(r),
                           "threshold": deltas[i], "status": int(status)})
        return result.x, rise

    # the valley: every loose parameter held across its range (round 0)
    held = [(i, t) for i in np.flatnonzero(loose) for t in np.linspace(-1.0, 1.0, grid)
            if abs(t - fit.theta[i]) > 1e-9]
    theta0 = np.repeat(fit.theta[None], len(held), 0)
    theta0[np.arange(len(held)), [i for i, _ in held]] = [t for _, t in held]
    valley, rise = fits(theta0, np.array([i for i, _ in held], int), [(i, "grid") for i, _ in held], 0)
    valley = np.vstack([fit.theta[None], valley])
    rise = np.concatenate([[0.0], rise])
    searches = [_Search(i, side, deltas[i], float(fit.theta[i]), stderr[i], valley, rise)
                for i in targets for side in (-1, 1)]
    for k in range(1, rounds + 1):
        open_ = [s for s in searches if not s.done]
        if not open_:
            break
        x, rise = fits(np.array([s.start() for s in open_]), np.array([s.i for s in open_], int),
                       [(s.i, "upper" if s.side > 0 else "lower") for s in open_], k)
        for s, xs, r in zip(open_, x, rise):
            s.update(xs, float(r))
    lower, upper, limits = np.full(L.n, np.nan), np.full(L.n, np.nan), np.full(L.n, np.nan)
    notes = []
    for s in searches:
        end = s.end()
        (upper if s.side > 0 else lower)[s.i] = lower_si[s.i] + (end + 1.0) * half[s.i]
        limits[s.i] = s.delta
        if not s.done:
            notes.append(f"the profile of {names[s.i]} ({'upper' if s.side > 0 else 'lower'} end) did not settle in "
                         f"{rounds} rounds: its end is the last point outside the region, or inside when none was")
    better = [p for p in points if p["chi2_rise"] < -RISE_TOLERANCE * p["threshold"]]
    if better:
        best = min(better, key=lambda p: p["chi2_rise"])
        notes.append(f"the profile found a lower chi^2 than the fit's ({best['chi2_rise']:.3g} at "
                     f"{best['parameter']} = {best['value']:.6g}): the fit's optimum is not the global one there")
    loose_names = tuple(names[i] for i in np.flatnonzero(loose))
    notes.insert(0, f"{', '.join(loose_names)} loose (at a range edge or not identifiable): the intervals of "
                    f"{', '.join(names[i] for i in targets)} are the joint region's shadows over "
                    f"{'it' if len(loose_names) == 1 else 'them'} (chi^2 rise "
                    f"{', '.join(f'{d:.3g}' for d in sorted(set(round(v, 6) for v in deltas.values())))}), from "
                    f"{len(points)} fits with one parameter held")
    return Profiled(lower, upper, loose_names, limits, pd.DataFrame(points, columns=tables.PROFILE.columns), notes,
                    time.perf_counter() - start)


class _Search:
    """One end of one parameter's interval, in normalised units (the optimum at t0): the point inside the region
    farthest out on its side (its rise and fitted theta: the next fit's warm start) and the nearest point outside.
    Starts from the valley (``profile_intervals``): its points inside the region and, for a loose parameter held on
    the grid, those outside too."""

    def __init__(self, i: int, side: int, delta: float, t0: float, stderr: float, valley: Array, rise: Array):
        self.i, self.side, self.delta, self.t0 = i, side, delta, t0
        self.edge = float(side)  # the range edge on this side
        self.step = float(np.clip(np.sqrt(delta) * stderr if np.isfinite(stderr) and stderr > 0 else 0.5, 2e-3, 1.0))
        t = side * valley[:, i]  # larger: farther out on this side
        inside = np.flatnonzero(np.isfinite(rise) & (rise <= delta))
        k = inside[np.argmax(t[inside])]
        self.inside = (float(valley[k, i]), max(float(rise[k]), 0.0), np.array(valley[k], float))
        beyond = np.flatnonzero((t > t[k] + 1e-12) & ~(np.isfinite(rise) & (rise <= delta)))
        self.outside: tuple[float, float] | None = None
        if beyond.size:  # the nearest valley point beyond, outside the region (a loose parameter's own grid)
            j = beyond[np.argmin(t[beyond])]
            self.outside = (float(valley[j, i]), float(rise[j]) if np.isfinite(rise[j]) else np.inf)
        self.done, self.settled, self.moved = False, None, False
        self.next = self.inside[0]
        self._advance()

    def start(self) -> Array:
        theta = self.inside[2].copy()
        theta[self.i] = self.next
        return theta

    def update(self, x: Array, rise: float) -> None:
        t = self.next
        self.moved = True
        if np.isfinite(rise) and rise <= self.delta:
            self.inside = (t, max(rise, 0.0), np.array(x, float))
        elif self.outside is None or self.side * (t - self.outside[0]) < 0:
            self.outside = (t, rise if np.isfinite(rise) else np.inf)
        if np.isfinite(rise) and abs(rise - self.delta) <= RISE_TOLERANCE * self.delta:
            self._settle(t)
            return
        self._advance()

    def _advance(self) -> None:
        """The next value to hold, or settle: at the range edge when it is inside, else between a tight bracket."""
        t_in, r_in, _ = self.inside
        if abs(t_in - self.edge) < 1e-12:
            self._settle(self.edge)
            return
        if self.outside is None:  # still inside: the linearised step first, then extrapolate as if the rise grew
            # with the square of the distance from the optimum
            factor = min(GROWTH, float(np.sqrt(self.delta / max(r_in, 1e-3 * self.delta))))
            gap = max(abs(t_in - self.t0) * (factor - 1.0), 2 * BRACKET_TOLERANCE) if self.moved else self.step
            self.next = float(np.clip(t_in + self.side * gap, -1.0, 1.0))
            return
        if abs(self.outside[0] - t_in) <= BRACKET_TOLERANCE:
            self._settle(self._interpolate())
            return
        self.next = self._interpolate()

    def _interpolate(self) -> float:
        """Where sqrt(rise) reaches sqrt(delta) between the bracket's ends (linear in sqrt(rise), which is linear in
        the distance for a quadratic profile); the bracket's middle when the outer end has no solution."""
        (t_in, r_in, _), (t_out, r_out) = self.inside, self.outside
        if not np.isfinite(r_out):
            return 0.5 * (t_in + t_out)
        a, b = np.sqrt(r_in), np.sqrt(r_out)
        w = (np.sqrt(self.delta) - a) / (b - a) if b > a else 0.5
        return float(t_in + float(np.clip(w, 0.05, 0.95)) * (t_out - t_in))

    def _settle(self, t: float) -> None:
        self.done, self.settled = True, t

    def end(self) -> float:
        """The interval's end (normalised): where the search settled; unsettled, the nearest point outside (wider),
        or the farthest inside when none was found outside."""
        if self.settled is not None:
            return self.settled
        return self.outside[0] if self.outside is not None else self.inside[0]


def profile_table(profiled: Profiled | None) -> pd.DataFrame:
    """The profile's fits (identification/profile.tsv; empty without a loose parameter)."""
    if profiled is None or profiled.points is None:
        return pd.DataFrame(columns=tables.PROFILE.columns)
    return profiled.points


def with_profile(fit, options: LMOptions = OPTIONS):
    """``fit`` with its intervals over the loose parameters (``profile_intervals``; unchanged when none is loose)."""
    return replace(fit, profile=profile_intervals(fit, options))
