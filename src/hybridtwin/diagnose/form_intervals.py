"""Intervals over the effects the data cannot exclude: what a fit's intervals hold when its form may be wrong.

A fit's 95 % intervals (``hybridtwin.identify.uncertainty``, or the profile over a loose parameter,
``hybridtwin.identify.profile``) hold for the variant's own form: they are conditional on every effect it leaves
out being absent. A variant can fit its runs to the noise and still leave out something that moves its estimates:
on the bundled data the recommended variant (the slope force's linear term) fits to chi^2/dof 1.03, and its two
dampings' intervals exclude their truths, since the slope force's cubic part, which the runs hardly see, trades
with them. What the data say about that is in the candidates the diagnosis already tests.

For each candidate effect c not in the model (its parameters beta, absent at 0), the model extended by c is
linearised at the fit, with the Jacobian the score test uses (``score_test.score_tests``: J = d r / d theta of
the fit's free entries, G = d r / d beta at beta = 0). In that linear model the profile interval of a shared
parameter p_i over beta, beta held to the candidate's range (its physical bounds), is

    I_c(p_i) = { p_i : min over the rest and beta in its range of chi^2 <= chi^2_c + Delta },
    Delta = s^2 chi2_quantile(confidence, 1),  s^2 = max(1, chi^2/dof),

chi^2_c the extended model's minimum over beta in its range. With V the inverse information of (theta, beta) and
q the quadratic form, min over the rest at fixed (p_i, beta) is chi^2_lin + g(beta) + (p_i - p_i*(beta))^2 /
V_ii|beta, where g(beta) = (beta - beta^)' V_bb^-1 (beta - beta^), p_i*(beta) = p_i^ + V_ib V_bb^-1 (beta - beta^)
and V_ii|beta = V_ii - V_ib V_bb^-1 V_bi: on a grid of beta across the range, the interval is the union of
p_i*(beta) +- sqrt((chi^2_c + Delta - chi^2_lin - g(beta)) V_ii|beta) where the root is real, within p_i's own
range. A candidate that the
data pin near zero leaves the interval as it was; one they cannot pin (its beta free across a stretch of its range)
and that trades with p_i widens it by as much as it trades. The interval reported "over the candidates" is the union
of the fit's own interval and every I_c: it holds whichever of the candidates (or none) is the missing part,
to first order. Without candidate (beta empty) the same formula gives the fit's linearised interval, which the
tests check against the identification's.

Listed are the shared parameters the fit leaves free (one held at a range edge has the identification's profile
interval, parameters.tsv). A candidate whose columns the model already spans (the same term under another name)
changes nothing: the pseudo-inverse leaves out its direction. ``beta_low``, ``beta_high``: the stretch of the
candidate's (first) parameter, normalised, that the data leave open.

This is the linearisation at the fit: a candidate whose beta the data leave free far across its range (a response
that bends with beta) is only approximated; ``tests/test_form_intervals.py`` compares it with the profile of the
extended model refitted on the full solver.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables

Array = np.ndarray

#: the table's columns (``diagnosis_intervals.tsv``): one row per shared parameter and candidate, candidate ""
#: for the fit's own interval (the one it reports); low/high [SI]
COLUMNS = list(tables.DIAGNOSIS_INTERVALS.columns)
#: the union's columns (``FormIntervals.union``): per shared parameter, the fit's own interval, the interval over
#: the candidates and the candidates that widen it (beyond the own interval by more than WIDENS of its width)
UNION_COLUMNS = ["parameter", "estimate", "own_low", "own_high", "low", "high", "widened_by"]
#: a candidate "widens" an interval when it moves one of its ends out by more than this share of the own width
WIDENS = 0.05
#: grid points across a one-parameter candidate's range (two-parameter: GRID_2D per axis)
GRID, GRID_2D = 801, 61


@dataclass
class FormIntervals:
    """Each shared parameter's interval under the fit's own form and under each candidate (module docstring)."""

    table: pd.DataFrame  # COLUMNS
    confidence: float
    chi2_dof: float

    def union(self) -> pd.DataFrame:
        """Per shared parameter: its own interval, the union over the candidates, and which candidates widen it
        (``UNION_COLUMNS``; widened_by: names joined by ", ", widest first)."""
        rows = []
        for name, group in self.table.groupby("parameter", sort=False):
            own = group[group["candidate"] == ""].iloc[0]
            lo, hi = float(np.nanmin(group["low"])), float(np.nanmax(group["high"]))
            width = max(float(own["high"] - own["low"]), 1e-300)
            others = group[group["candidate"] != ""]
            beyond = np.maximum(own["low"] - others["low"], others["high"] - own["high"]) / width
            widening = others.assign(beyond=beyond.to_numpy())
            widening = widening[widening["beyond"] > WIDENS].sort_values("beyond", ascending=False)
            rows.append({"parameter": name, "estimate": float(own["estimate"]), "own_low": float(own["low"]),
                         "own_high": float(own["high"]), "low": lo, "high": hi,
                         "widened_by": ", ".join(widening["candidate"])})
        return pd.DataFrame(rows, columns=UNION_COLUMNS)

    @classmethod
    def empty(cls) -> "FormIntervals":
        """No intervals (the final fit could not be linearised): an empty table, written and read like any."""
        return cls(pd.DataFrame(columns=COLUMNS), 0.95, float("nan"))

    def write(self, path) -> None:
        """``diagnosis_intervals.tsv``; ``read`` is its inverse."""
        tables.DIAGNOSIS_INTERVALS.write(self.table, path)

    @classmethod
    def read(cls, path, confidence: float = 0.95, chi2_dof: float = float("nan")) -> "FormIntervals":
        table = tables.DIAGNOSIS_INTERVALS.read(path)
        missing = [c for c in COLUMNS if c not in table]
        if missing:
            raise ValueError(f"{path}: not a table of intervals over the candidates (missing columns {missing})")
        table["candidate"] = table["candidate"].fillna("").astype(str)
        return cls(table[COLUMNS], confidence, chi2_dof)


def form_intervals(J: Array, r: Array, theta: Array, entries: Sequence[tuple[str, str]], free: Array,
                   candidate_columns: Mapping[str, Sequence[int]], own: Mapping[str, tuple[float, float]],
                   lower: Mapping[str, float], upper: Mapping[str, float], dof: int,
                   confidence: float = 0.95) -> FormIntervals:
    """The intervals of the shared physical parameters (entries ``(name, "all")`` that are ``free``) over each
    candidate (module docstring).

    J (m, n), r (m,): the weighted residuals' Jacobian and residuals at the fit, theta (n,) normalised, over the
    fit's entries and every candidate's (at beta = 0); ``free``: the fit's entries that are free (not held at a
    range edge; the candidates' are not); ``candidate_columns``: each candidate's columns of J; ``own``: the fit's
    reported interval per parameter [SI] (the union includes it; a parameter without one takes the linearised);
    ``lower``/``upper``: each parameter's range [SI] (the normalisation); ``dof``: the fit's degrees of freedom."""
    J, r, theta, free = (np.asarray(a, float) for a in (J, r, theta, free))
    free = free.astype(bool)
    chi2 = float(r @ r)
    s2 = max(1.0, chi2 / max(dof, 1))
    delta = s2 * float(stats.chi2.ppf(confidence, 1))
    base_cols = np.flatnonzero(free)
    shared = [(k, name) for k, (name, run) in enumerate(entries) if run == "all" and free[k]
              and name in lower and name in upper]

    def si(name: str, t: Array | float) -> Array:
        return lower[name] + 0.5 * (np.asarray(t, float) + 1.0) * (upper[name] - lower[name])

    rows = []
    fits = {"": []} | {c: list(cols) for c, cols in candidate_columns.items()}
    for candidate, cols in fits.items():
        columns = np.r_[base_cols, np.asarray(cols, int)]
        A = J[:, columns]
        V = np.linalg.pinv(A.T @ A, rcond=1e-12, hermitian=True)
        step = -V @ (A.T @ r)
        chi2_lin = float(np.sum((r + A @ step) ** 2))
        k = len(cols)
        if k:
            beta_hat = theta[cols] + step[len(base_cols):]
            grid = (np.linspace(-1.0, 1.0, GRID)[:, None] if k == 1 else
                    np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, GRID_2D)] * k), -1).reshape(-1, k))
            Vbb = V[len(base_cols):, len(base_cols):]
            Vbb_inv = np.linalg.pinv(Vbb, hermitian=True)
            d = grid - beta_hat
            g = np.einsum("gi,ij,gj->g", d, Vbb_inv, d)
            ref = chi2_lin + float(g.min())
        for k_entry, name in shared:
            i = int(np.flatnonzero(base_cols == k_entry)[0])
            estimate = float(si(name, theta[k_entry]))
            p_hat = theta[k_entry] + step[i]
            if not k:  # the fit's own: as reported, else linearised (what the identification reports then)
                half = np.sqrt(delta * max(V[i, i], 0.0))
                lo, hi = own.get(name, (float(si(name, p_hat - half)), float(si(name, p_hat + half))))
                rows.append({"parameter": name, "candidate": "", "estimate": estimate, "low": float(lo),
                             "high": float(hi), "beta_low": np.nan, "beta_high": np.nan})
                continue
            Vib = V[i, len(base_cols):]
            centre = p_hat + d @ (Vbb_inv @ Vib)
            conditional = max(V[i, i] - Vib @ Vbb_inv @ Vib, 0.0)
            room = ref + delta - chi2_lin - g
            inside = room >= 0
            half = np.sqrt(np.where(inside, room, 0.0) * conditional)
            # a parameter's range bounds it here too (the fit's own interval is kept as reported)
            lo = float(si(name, max((centre - half)[inside].min(), -1.0)))
            hi = float(si(name, min((centre + half)[inside].max(), 1.0)))
            b = grid[inside]
            rows.append({"parameter": name, "candidate": candidate, "estimate": estimate, "low": lo, "high": hi,
                         "beta_low": float(b[:, 0].min()), "beta_high": float(b[:, 0].max())})
    return FormIntervals(pd.DataFrame(rows, columns=COLUMNS), confidence, chi2 / max(dof, 1))


def own_intervals(table: pd.DataFrame) -> dict[str, tuple[float, float]]:
    """The reported 95 % interval [SI] of each shared physical parameter of a parameter table
    (``Identification.table``: rows with run "all" and kind shared or physical)."""
    rows = table[(table["run"].astype(str) == "all") & (table["kind"].astype(str) != "nuisance")]
    return {str(r.parameter): (float(r.ci_low), float(r.ci_high)) for r in rows.itertuples()
            if np.isfinite(float(r.ci_low)) and np.isfinite(float(r.ci_high))}
