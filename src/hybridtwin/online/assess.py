"""A record judged against a built twin: consistent, changed, or a new discrepancy (docs/online.md).

1. **Consistent?** The twin's hypothesis (``fits``: every parameter on the twin's prior, the per-run ones such as
   the bow at their law, the phases free or on the keyphasor's prior) fitted to the record, and two tests of it:
   the fit, chi^2 against chi^2(dof) (``p_fit``: is the record within its noise?), and the largest single move,
   each parameter group (each shared parameter alone, the per-run ones together) freed of its prior to first order
   from that fit (``fits.linearised``: a score test, no solve), its likelihood ratio D against chi^2(k),
   Bonferroni-corrected over the groups (``p_move``: has one parameter moved beyond the twin's uncertainty?). A
   record with many data (a run-up's hundreds) hides a one-parameter move in its chi^2; the move's own test does
   not. The record's p-value is the smaller of the two, doubled (Bonferroni over the two tests): at p >= ``alpha``
   the record is **consistent**, and the first-order estimates say what it tells of each parameter.
2. **Changed?** Otherwise every group is freed in turn in full fits, all in one batch. A group *explains* the
   record when its fit is at the noise (p >= alpha) and its move is significant (D, Bonferroni over the groups and
   the two tests); the best (highest p of its fit) is the change, with its estimate, interval and D, the
   significance against the twin's own uncertainty (its correlations included); the other explaining groups are
   named as alternatives the record cannot tell apart from it. When no single group explains a record beyond its
   noise, pairs of the three best are tried. A parameter the twin left undetermined has no prior (``twin``): the
   record estimates it in every fit, and it is never a "move". (A first-order move that the full fits do not
   confirm, on a record at its noise, leaves the record consistent.)
3. **New discrepancy.** When no parameter change explains a record beyond its noise: the residual of the best
   change, its fingerprint (``diagnose.fingerprint``: harmonic, whirl, speed band), the fault family it resembles
   (``fingerprint.resembles``, the faults' signatures: "2X above the noise with a 1X change ..., like a breathing
   crack") and the diagnosis candidates ranked by their score test at the twin (``diagnose.score_test``, with every
   parameter's sensitivity and its prior projected out, so a candidate scores what no parameter change the twin
   allows can absorb).

The outcome is a code (``RecordVerdict``); the sentences are derived from it (``Assessment.line``).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.special import chdtrc, ndtri  # chi^2's survival function, the normal quantile (not scipy.stats:
# its import costs more than a consistent record's fits)

from ..diagnose.fingerprint import Fingerprint, fingerprint, resembles
from ..identify.arrow_problem import Layout
from ..settings import defaults
from .. import tables
from . import fits, library_route
from .intake import Intake
from .twin import Twin

Array = np.ndarray

#: the level of every test: a record is beyond the noise at p < ALPHA (the project's "beyond the noise", README)
ALPHA = defaults("online")["alpha"]  # config online.alpha's, the schema's default
#: pairs of groups are tried among this many best single groups when none explains the record alone
PAIRS_OF = 3
#: two changes whose fits' chi^2 differ by less than this cannot be told apart by the record (one standard deviation
#: of a likelihood ratio): the smaller relative move is named first (``_ranked``)
TIE = 1.0
#: intervals: estimate -+ this many standard errors (95 %, normal)
Z95 = float(ndtri(0.975))


class RecordVerdict(str, Enum):
    CONSISTENT = "consistent"
    CHANGED = "changed"
    NEW_DISCREPANCY = "new_discrepancy"


OPENINGS = {RecordVerdict.CONSISTENT: "consistent with the twin", RecordVerdict.CHANGED: "CHANGED",
            RecordVerdict.NEW_DISCREPANCY: "NEW DISCREPANCY"}

#: the tables' columns (the table layer's): an assessment's parameters, harmonics (measured, the twin's prediction
#: and the best change's fit, per run, harmonic and channel), candidates (the score tests of a new discrepancy, most
#: significant first), and its one-row summary (assessment.tsv)
PARAMETER_COLUMNS = list(tables.ASSESSMENT_PARAMETERS.columns)
HARMONIC_COLUMNS = list(tables.ASSESSMENT_HARMONICS.columns)
CANDIDATE_COLUMNS = list(tables.ASSESSMENT_CANDIDATES.columns)
SUMMARY_COLUMNS = list(tables.ASSESSMENT.columns)


@dataclass
class Assessment:
    """A record's assessment: the verdict and what backs it (module docstring). ``summary`` holds the scalar
    fields (``SUMMARY_COLUMNS``); the tables are ``parameters``, ``harmonics``, ``candidates`` (empty unless a new
    discrepancy) and the residual's ``fingerprint`` (None unless a new discrepancy)."""

    summary: dict
    parameters: pd.DataFrame
    harmonics: pd.DataFrame
    candidates: pd.DataFrame
    fingerprint: Fingerprint | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> RecordVerdict:
        return RecordVerdict(self.summary["verdict"])

    @property
    def changed(self) -> list[str]:
        """The parameters of the named change (empty unless changed)."""
        return [p for p in str(self.summary["changed"]).split(",") if p]

    @property
    def resemblance(self) -> tuple[list[str], str]:
        """A new discrepancy's fault families, best first, and what its residual shows (``fingerprint.resembles``:
        the faults' signatures); nothing for any other verdict."""
        if self.verdict is not RecordVerdict.NEW_DISCREPANCY or self.fingerprint is None:
            return [], ""
        return resembles(self.fingerprint)

    def line(self) -> str:
        """The one-line verdict for the console."""
        s = self.summary
        where = "library" if s.get("route") == "library" else "solver"
        head = (f"{s['record']}: {OPENINGS[self.verdict]} ({s['twin']}, on the {where}): chi^2/dof {s['chi2_dof']:.3g} on {s['dof']} "
                f"dof (p {s['p_fit']:.2g}), largest move {s['move']} (p {s['p_move']:.2g}): p = {s['p_value']:.2g}")
        if self.verdict is RecordVerdict.CONSISTENT:
            return head
        if self.verdict is RecordVerdict.CHANGED:
            moved = self.parameters[self.parameters["moved"]]
            moves = [_move(row) for row in moved.itertuples() if row.run == "all" or moved["run"].nunique() == 1]
            spread = moved[moved["run"] != "all"]
            if spread["run"].nunique() > 1:  # a per-run parameter of a transient record: one move per band
                moves += [f"{p} at {len(rows)} bands, median {100 * rows['change_rel'].median():+.1f} % (D = "
                          f"{rows['statistic'].iloc[0]:.3g} on {int(rows['dof'].iloc[0])} dof)"
                          for p, rows in spread.groupby("parameter", sort=False)]
            also = f"; the record cannot tell it from: {s['alternatives']}" if s["alternatives"] else ""
            return (f"{head}; {'; '.join(moves)} (with it chi^2/dof {s['best_chi2'] / max(s['best_dof'], 1):.3g})"
                    f"{also}")
        top = ", ".join(f"{row.candidate} (p {row.p_value:.1g})" for row in self.candidates.head(3).itertuples())
        where = self.fingerprint.summary().split(". ")[0] if self.fingerprint is not None else ""
        families, shows = self.resemblance
        like = f"{shows}, like {' or '.join(families)}; " if families else f"{shows}; " if shows else ""
        return (f"{head}; {like}no parameter change explains it (best: {s['best']}, chi^2/dof "
                f"{s['best_chi2'] / max(s['best_dof'], 1):.3g}); candidates: {top or 'none significant'}. {where}")

    # --- files: one folder per record, each table with its exact inverse -------------------------

    def write(self, folder: str | Path) -> None:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        tables.ASSESSMENT.write(pd.DataFrame([self.summary], columns=SUMMARY_COLUMNS), folder / "assessment.tsv")
        for name, table, frame in (("parameters", tables.ASSESSMENT_PARAMETERS, self.parameters),
                                   ("harmonics", tables.ASSESSMENT_HARMONICS, self.harmonics),
                                   ("candidates", tables.ASSESSMENT_CANDIDATES, self.candidates)):
            table.write(frame, folder / f"{name}.tsv")
        if self.fingerprint is not None:
            tables.FINGERPRINT.write(self.fingerprint.table(), folder / "fingerprint.tsv")

    @classmethod
    def read(cls, folder: str | Path) -> "Assessment":
        """The exact inverse of ``write`` (the warnings, said on the console, are not kept)."""
        folder = Path(folder)
        summary = read_assessment(folder / "assessment.tsv").iloc[0].to_dict()
        parameters = tables.ASSESSMENT_PARAMETERS.read(folder / "parameters.tsv")
        harmonics = tables.ASSESSMENT_HARMONICS.read(folder / "harmonics.tsv")
        candidates = tables.ASSESSMENT_CANDIDATES.read(folder / "candidates.tsv")
        path = folder / "fingerprint.tsv"
        found = Fingerprint.from_table(tables.FINGERPRINT.read(path)) if path.is_file() else None
        return cls(summary, parameters, harmonics, candidates, found)


def read_assessment(path: str | Path) -> pd.DataFrame:
    """assessment.tsv (or rows of them), text columns as text, numbers as numbers (``SUMMARY_COLUMNS``)."""
    table = tables.ASSESSMENT.read(path)
    for column in ("n_runs", "n_data", "dof", "best_dof"):
        table[column] = table[column].astype(int)
    return table


def _move(row) -> str:
    return (f"{row.parameter} {row.twin_value:.4g} -> {row.value:.4g} [{row.ci_low:.4g}, {row.ci_high:.4g}] {row.unit} "
            f"({100 * row.change_rel:+.1f} %, D = {row.statistic:.3g} on {int(row.dof)} dof, p = {row.p_value:.2g})")


# --- the assessment ------------------------------------------------------------------------------


@dataclass
class _Judgement:
    """The tests of a record on one forward model (module docstring): the twin's fit, the groups' first-order moves
    (``linear``), the groups' fits (``singles``: the full fits after an alarm, else the first-order ones), every fit
    tried, the verdict and the change named."""

    verdict: RecordVerdict
    base: fits.RecordFit
    linear: list
    singles: list
    tried: list
    named: fits.RecordFit | None
    alternatives: list[str]
    best: fits.RecordFit
    p_fit: float
    move: str
    p_move: float
    pairs: bool = False


def _judge(problem: fits.RecordProblem, alpha: float) -> _Judgement:
    """The verdict of the record in ``problem`` at level ``alpha`` (module docstring, steps 1-3 without the
    candidates)."""
    groups = [(p,) for p in problem.shared if p not in problem.prior.undetermined] + (
        [tuple(problem.local)] if problem.local else [])
    base = fits.fit(problem, [fits.Hypothesis()])[0]
    singles = linear = [fits.linearised(problem, base, fits.Hypothesis((g,))) for g in groups]
    p_fit, (move, p_move) = base.p_value, _largest_move(problem, base, singles)
    named, alternatives, best, tried, pairs = None, [], base, [], False
    verdict = RecordVerdict.CONSISTENT
    if min(1.0, 2 * min(p_fit, p_move)) < alpha:  # an alarm: the fit beyond the noise, or a move beyond the prior
        singles = fits.fit(problem, [fits.Hypothesis((g,)) for g in groups], base)
        move, p_move = _largest_move(problem, base, singles)
        tried = list(singles)
        explaining = [f for f in tried if f.p_value >= alpha and 2 * len(groups) * _lr(problem, base, f)[2] < alpha]
        if not explaining and p_fit < alpha and len(groups) > 1:
            top = sorted(singles, key=lambda f: f.chi2)[:PAIRS_OF]
            combined = [fits.Hypothesis(a.hypothesis.groups + b.hypothesis.groups)
                        for a, b in itertools.combinations(top, 2)]
            tried += fits.fit(problem, combined, base)
            explaining, pairs = [f for f in tried if f.p_value >= alpha], True
        if explaining:
            explaining = _ranked(problem, base, explaining)
            verdict, named = RecordVerdict.CHANGED, explaining[0]
            best = named
            alternatives = [f.hypothesis.name for f in explaining[1:]]
        elif p_fit < alpha:
            verdict, best = RecordVerdict.NEW_DISCREPANCY, min(tried, key=lambda f: f.chi2)
        # else: the move the first-order test saw does not hold up in the full fits, and the fit is at the noise
    return _Judgement(verdict, base, linear, singles, tried, named, alternatives, best, p_fit, move, p_move, pairs)


def assess(twin: Twin, record: Intake, alpha: float = ALPHA, candidates: bool = True,
           route: str = "auto") -> Assessment:
    """``record`` judged against ``twin`` at level ``alpha`` (module docstring); ``candidates`` False skips the
    score tests of a new discrepancy (the benchmark's speed). ``route``: "auto" (the twin's library first when it
    has one for the record, the full solver where the library's error cannot decide: ``library_route``), "solver"
    (the full solver only) or "library" (the library's verdict even where it cannot decide: a benchmark's
    comparison)."""
    if route not in ("auto", "solver", "library"):
        raise ValueError(f"route {route!r}: auto, solver or library")
    start = time.perf_counter()
    prior = twin.prior([(d.rpm, d.eccentric_mass_g) for d in record.data])
    info = {"route": "solver", "library": "", "library_verdict": "", "library_p_low": math.nan,
            "library_p_high": math.nan, "library_bound": math.nan, "library_seconds": math.nan, "route_note": ""}
    judgement = None
    if route != "solver":
        choice, why = library_route.choose(twin, record)
        if choice is None:
            info["route_note"] = f"on the full solver: {why}"
        else:
            problem = fits.RecordProblem(twin.variant, record.data, prior, twin.harmonics, choice.libraries,
                                         choice.sigma_error, choice.offsets)
            judgement = _judge(problem, alpha)
            decision = library_route.decide(problem, judgement, alpha, choice, TIE)
            info |= {"library": choice.name, "library_verdict": judgement.verdict.value,
                     "library_p_low": decision.p_low, "library_p_high": decision.p_high,
                     "library_bound": decision.bound, "library_seconds": time.perf_counter() - start}
            notes = "; ".join(choice.notes)
            if decision.decided or route == "library":
                info["route"] = "library"
                info["route_note"] = (f"the library decides: p in [{decision.p_low:.2g}, {decision.p_high:.2g}] "
                                      f"across its error" if decision.decided else
                                      f"the library's verdict, undecided: {decision.why}") + (
                                      f" ({notes})" if notes else "")
            else:
                info["route_note"] = f"the full solver confirms: {decision.why}" + (f" ({notes})" if notes else "")
                judgement = None
    if judgement is None:
        problem = fits.RecordProblem(twin.variant, record.data, prior, twin.harmonics)
        judgement = _judge(problem, alpha)
    j = judgement
    ranked, found = pd.DataFrame(columns=CANDIDATE_COLUMNS), None
    if j.verdict is RecordVerdict.NEW_DISCREPANCY:
        found = _fingerprint(problem, j.best)
        if candidates:
            ranked = _candidates(twin, problem, j.base)
    table = parameter_table(twin, problem, j.base, j.singles, j.named, alpha)
    lo, hi = min(d.rpm for d in record.data), max(d.rpm for d in record.data)
    base, best, named = j.base, j.best, j.named
    summary = {
        "record": record.run, "path": str(record.path), "kind": record.kind, "timestamp": record.timestamp,
        "timestamp_source": record.timestamp_source, "twin": twin.name, "verdict": j.verdict.value, "alpha": alpha,
        "n_runs": len(record.data), "rpm_low": lo, "rpm_high": hi, "eccentric_mass_g": record.eccentric_mass_g,
        "n_data": int(problem.X.size * 2), "chi2": base.chi2, "dof": base.dof, "chi2_dof": base.chi2 / max(base.dof, 1),
        "p_value": min(1.0, 2 * min(j.p_fit, j.p_move)), "p_fit": j.p_fit, "move": j.move, "p_move": j.p_move,
        "changed": ",".join(named.hypothesis.free) if named else "",
        "alternatives": "; ".join(j.alternatives), "best": best.hypothesis.name, "best_chi2": best.chi2,
        "best_dof": best.dof, "best_p_value": best.p_value, "twin_chi2_dof": float(twin.card["fit"]["chi2_dof"]),
        "left_out": "; ".join(f"{run}: {why}" for run, why in record.left_out.items()),
        **info, "seconds": time.perf_counter() - start}
    return Assessment(summary, table, harmonic_table(problem, base, best), ranked, found, list(record.warnings))


def _lr(problem: fits.RecordProblem, base: fits.RecordFit, freed: fits.RecordFit) -> tuple[float, int, float]:
    """The likelihood ratio of freeing ``freed``'s parameters from the twin's fit: D = chi^2 drop, its dof (the
    entries freed: a per-run parameter once per run) and its p-value, D ~ chi^2(k) when nothing moved."""
    statistic = max(base.chi2 - freed.chi2, 0.0)
    k = sum(problem.R if p in problem.local else 1 for p in freed.hypothesis.free)
    return statistic, k, float(chdtrc(k, statistic))


def _ranked(problem: fits.RecordProblem, base: fits.RecordFit, explaining: Sequence[fits.RecordFit]
            ) -> list[fits.RecordFit]:
    """The explaining changes, the one to name first: the highest p-value of its fit; among those the record cannot
    tell from it (chi^2 within TIE of it and as many parameters freed), the smallest relative move (a bearing 10 %
    softer before a slope stiffness 67 % softer that fits as well: one steady record cannot tell the upper bearing's
    two stiffnesses apart, measured at 900 RPM, chi^2 2880.08 against 2880.37)."""
    first = max(explaining, key=lambda f: f.p_value)
    tied = [f for f in explaining if len(f.hypothesis.free) == len(first.hypothesis.free)
            and f.chi2 <= first.chi2 + TIE]
    named = min(tied, key=lambda f: _relative_move(problem, base, f))
    return [named] + sorted((f for f in explaining if f is not named), key=lambda f: -f.p_value)


def _relative_move(problem: fits.RecordProblem, base: fits.RecordFit, freed: fits.RecordFit) -> float:
    """How far a change moves its parameters from the twin's fit, relative to their values (largest of them)."""
    si, at = problem.to_si(freed.v), problem.to_si(base.v)
    moves = [abs(si[c] - at[c]) / max(abs(at[c]), 1e-300) for c, (p, _) in enumerate(problem.entries)
             if p in freed.hypothesis.free]
    return max(moves, default=0.0)


def _largest_move(problem: fits.RecordProblem, base: fits.RecordFit, singles: Sequence[fits.RecordFit]
                  ) -> tuple[str, float]:
    """The most significant single group's name and its p-value, Bonferroni-corrected over the groups."""
    p = [_lr(problem, base, f)[2] for f in singles]
    i = int(np.argmin(p))
    return singles[i].hypothesis.name, min(1.0, len(singles) * p[i])


def parameter_table(twin: Twin, problem: fits.RecordProblem, base: fits.RecordFit, singles: Sequence[fits.RecordFit],
                    named: fits.RecordFit | None, alpha: float) -> pd.DataFrame:
    """One row per parameter entry (shared: run "all"; per-run: each run of the record): the twin's value and
    standard error (the prior's), the record's estimate with its group freed (``singles``, or the named change's
    fit for its own entries), the change, z against both uncertainties, and the group's likelihood-ratio test. A
    parameter the twin left undetermined: the record's estimate in the twin's fit, no test (nothing to compare)."""
    units = {name: p.unit for name, p in twin.variant.model.parameters.items()}
    prior_sd = np.sqrt(np.diag(problem.prior.covariance))
    runs = [d.run for d in problem.data]
    groups = [(single.hypothesis.free, named if named is not None and set(named.hypothesis.free)
               >= set(single.hypothesis.free) else single) for single in singles]
    groups += [((p,), base) for p in problem.prior.undetermined]  # estimated in the twin's fit, never tested
    rows = []
    for group, source in groups:
        undetermined = group[0] in problem.prior.undetermined
        statistic, k, p_value = (math.nan, 0, math.nan) if undetermined else _lr(problem, base, source)
        for column, (p, k_run) in enumerate(problem.entries):
            if p not in group:
                continue
            value = problem.to_si(source.v)[column]
            stderr = math.sqrt(max(source.covariance[column, column], 0.0)) * problem.scale[column]
            if undetermined:
                twin_value, twin_sd = problem.prior.undetermined[p][0], math.nan
            else:
                twin_value = problem.prior.mean[problem.prior.index(p, k_run)]
                twin_sd = prior_sd[problem.prior.index(p, k_run)]
            change = value - twin_value
            rows.append({
                "parameter": p, "run": "all" if k_run is None else runs[k_run], "unit": units.get(p, ""),
                "twin_value": twin_value, "twin_stderr": twin_sd, "value": value, "stderr": stderr,
                "ci_low": value - Z95 * stderr, "ci_high": value + Z95 * stderr, "change": change,
                "change_rel": change / twin_value if twin_value else math.nan,
                "z": change / math.hypot(stderr, twin_sd), "statistic": statistic, "dof": k, "p_value": p_value,
                "explains": not undetermined and source.p_value >= alpha,
                "moved": named is not None and p in named.hypothesis.free,
                "estimate": "linear" if source.linear else "fit",
                "note": f"the twin left it undetermined ({problem.prior.undetermined[p][1]}): estimated from the "
                        "record alone" if undetermined else "at its physical limit: the interval is not valid there"
                        if source.v[column] in (problem.lo_v[column], problem.hi_v[column]) else ""})
    return pd.DataFrame(rows, columns=PARAMETER_COLUMNS)


def harmonic_table(problem: fits.RecordProblem, base: fits.RecordFit, best: fits.RecordFit) -> pd.DataFrame:
    """Measured harmonics [m] of every run, harmonic and channel of the record (its frame), the twin's own prediction
    (``RecordFit.prediction``: its estimates, the bow from its law) and the best change's fit (the twin's fit of the
    record when it is consistent)."""
    rows = []
    channels = problem.data[0].channels
    for k, d in enumerate(problem.data):
        for h in range(problem.H):
            for c, channel in enumerate(channels):
                X, T, B = problem.X[k, h, c], base.prediction[k, h, c], best.model[k, h, c]
                rows.append({"run": d.run, "rpm": d.rpm, "harmonic": h + 1, "channel": channel,
                             "measured_re_m": X.real, "measured_im_m": X.imag, "sigma_m": problem.sigma[k, h, c],
                             "twin_re_m": T.real, "twin_im_m": T.imag, "best_re_m": B.real, "best_im_m": B.imag})
    return pd.DataFrame(rows, columns=HARMONIC_COLUMNS)


def _fingerprint(problem: fits.RecordProblem, best: fits.RecordFit) -> Fingerprint:
    """The fingerprint of the residual the best parameter change leaves (DC unused)."""
    def with_dc(z: Array, fill) -> Array:
        return np.concatenate([np.full((z.shape[0], 1, z.shape[2]), fill, dtype=z.dtype), z], axis=1)

    return fingerprint(with_dc(problem.X, 0j), with_dc(best.model, 0j), with_dc(problem.sigma, np.inf),
                       [d.rpm for d in problem.data], [d.eccentric_mass_g for d in problem.data],
                       [d.run for d in problem.data])


def _candidates(twin: Twin, problem: fits.RecordProblem, base: fits.RecordFit) -> pd.DataFrame:
    """The diagnosis candidates ranked by their score test at the twin's fit of the record (``base``), the twin's
    prior included: the residual and every parameter's sensitivity (with its prior's rows) projected out, so that a
    candidate scores what no parameter change the twin allows can absorb (``score_test.candidate_score``). A
    candidate whose sensitivity is one of the twin's own parameters' (the linear slope force expansion_k4 of a
    variant with slope_spring's k_w) is a parameter change under another name: it scores 0 (``score_test.nested``
    in that parameter's columns), or, free of the prior, it would stand in for a move the prior forbids."""
    from ..diagnose.score_test import (  # a new discrepancy only: scipy.stats with it
        BaseFit, by_score, candidate_score, column_basis, extended_problem, nested)

    variant, found = twin.variant, twin.candidates()
    lower, upper = zip(*variant.unknown.values())
    layout = Layout.for_data(list(variant.unknown), lower, upper, problem.data, problem.local, runout=False)
    theta = np.array([base.v[problem.column[(p, None if run == "all" else layout.runs.index(run))]]
                      for p, run in layout.entries()])
    extended, theta = extended_problem(BaseFit(variant, layout, theta, problem.data, problem.H), found,
                                       resolve=False)  # every candidate at 0, absent: as the diagnosis's scores
    sensitivities = extended.dense_jacobian(extended.evaluate(theta[None], problem.X[None], jacobian=True))
    r, J, n_data = problem.residuals(base.v[None], base.responses, [base.hypothesis])[0]
    Q = column_basis(J)
    r_p = r - Q @ (Q.T @ r)
    groups = [[problem.column[e] for e in problem.entries if e[0] == p] for p in problem.shared]
    groups.append([problem.column[e] for e in problem.entries if e[0] in problem.local])
    entries = extended.layout.entries()
    scores = []
    for candidate in found:
        columns = [entries.index((p.name, "all")) for p in candidate.parameters]
        G = np.zeros((r.size, len(columns)))
        G[:n_data] = sensitivities[:, columns]  # a candidate has no prior: nothing in the prior's rows
        if any(columns_ and nested(G[:n_data], J[:n_data, columns_]) for columns_ in groups):
            G[:] = 0.0
        scores.append(candidate_score(candidate, G, Q, r_p, theta[columns]))
    rows = [{"candidate": s.candidate.name, "statistic": s.statistic, "dof": len(s.step), "p_value": s.p_value,
             "log_p": s.log_p, "beyond_range": s.beyond_range} for s in sorted(scores, key=by_score)]
    return pd.DataFrame(rows, columns=CANDIDATE_COLUMNS)
