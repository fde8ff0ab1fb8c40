"""Why a validation run fails: parameters the fit runs leave loose, or physics the variant lacks (issue 41, item 3).

A validation run predicted beyond the noise (p < ``ALPHA``, as the report counts a run) is either a failure of the
model or a run that sees a direction of the parameters the fit runs do not pin: near a resonance a change of the
damping or of the bow too small for the fit runs to notice moves the response by many sigmas. The question is then
whether some parameter set the fit runs allow predicts the run within its noise, i.e. whether the spread of its
prediction over the fit runs' confidence region covers the measurement. ``explain_run`` answers it with the fit
the user would make next, the joint fit with the run included (full solver, from the joint estimates; the run's own
per-run parameters and phase free as a fit run's, starting from their law and aligned phase):

- the run comes within the noise (p >= ALPHA on its own 2 C H - k degrees of freedom, k its per-run entries) and the
  fit runs' chi^2 rises by at most s^2 chi2_d(0.95) (the joint region of the d shared parameters, as the intervals'
  profile, ``hybridtwin.identify.profile``): ``not_pinned``, "the fit runs do not pin X; this run does", X what
  moved by more than one unit (or the one that moved most): a shared parameter in its standard errors, a loose one
  (at its edge or not identifiable) in tenths of its range, the run's own per-run parameters in sigmas of their law;
- the same, but the run's own per-run parameters (the bow) end outside their law's 95 % prediction band over the
  fit runs (``law_band``): ``bow_law``, the law of the per-run parameters does not carry to this run;
- otherwise ``missing_physics``: no parameter set the fit runs allow predicts it.

A variant that misfits its own fit runs (their chi^2 beyond the noise) is not refitted: ``misfit``, its diagnosis
says what it lacks. Runs within the noise are ``within_noise``; ``not_checked`` where no refit could be made (a
library-only prediction, no periodic solution). The refit's parameter table is offered as is
(validation_refits.tsv): the run's role set to ``fit`` gives that fit in the workflow.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables
from .arrow_problem import ArrowProblem, Layout
from . import identification as idn
from .lm import levenberg_marquardt
from .profile import OPTIONS, threshold
from .protocol import ProtocolResult
from .run_fits import ranges, solver_models
from .uncertainty import ALPHA  # a run is beyond the noise below this p-value, as the report counts it
from .validation import bow_law

Array = np.ndarray

#: the explanation codes of validation.tsv's ``explanation`` column; the sentence a user reads is derived from them
EXPLANATIONS = {
    "within_noise": "predicted within the noise",
    "misfit": "the variant misfits its own fit runs too: what it lacks is in its diagnosis",
    "not_pinned": "the fit runs do not pin these parameters; this run does",
    "bow_law": "the per-run parameters' law over the fit runs does not carry to this run",
    "missing_physics": "no parameter set the fit runs allow predicts this run: the model lacks something here",
    "not_checked": "not checked (no full-solver refit)",
}
#: validation.tsv's columns about why a run is predicted as it is, and all its columns in order (the table layer's)
VALIDATION_COLUMNS = list(tables.VALIDATION_EXPLAINED)
VALIDATION_TABLE = list(tables.VALIDATION_COLUMNS)


def write_validation(rows: Sequence[Mapping] | pd.DataFrame, path) -> None:
    """validation.tsv from its rows (one per validation run and model): every ``VALIDATION_TABLE`` column, also
    when no run could be predicted (all flagged); ``read_validation`` reads it back."""
    table = pd.DataFrame(rows)
    tables.VALIDATION.write(table.reindex(columns=list(dict.fromkeys([*table.columns, *VALIDATION_TABLE]))), path)


def read_validation(path) -> pd.DataFrame:
    """validation.tsv as ``write_validation`` wrote it: runs, models, notes, explanation codes and pinned names as
    text ("" where empty), beyond_noise as bool (``measured.flags``), the rest as numbers (NaN where empty)."""
    return tables.VALIDATION.read(path)


#: validation_refits.tsv: the parameter table of each refit with the run included, and which run that was
REFIT_COLUMNS = list(tables.VALIDATION_REFITS.columns)


@dataclass
class Explanation:
    """Why one validation run is predicted as it is (module docstring). pinned: the parameters this run pins (name,
    move, value before and after, the move's unit: a shared parameter's standard errors in the joint fit, a loose
    one's tenths of its range, the run's own per-run parameters' sigmas of their law); chi2_*: the run's chi^2 per
    residual predicted and after the refit; fit_rise:
    the fit runs' chi^2 rise in the refit, allowed: its threshold; law: per per-run parameter of the run, its refit
    value, its law's value and the law band's half-width; table: the refit's parameter table (None without one)."""

    run: str
    code: str
    pinned: list[tuple[str, float, float, float, str]] = field(default_factory=list)
    chi2_predicted: float = np.nan
    chi2_refit: float = np.nan
    fit_rise: float = np.nan
    allowed: float = np.nan
    fit_chi2_dof: float = np.nan
    law: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    table: pd.DataFrame | None = None
    detail: str = ""

    @property
    def sentence(self) -> str:
        """What the user reads (derived from the code and the numbers; no code branches on it)."""
        if self.code == "not_pinned":
            moved = ", ".join(f"{p} {a:.4g} -> {b:.4g} ({m:+.2g} {unit})" for p, m, a, b, unit in self.pinned)
            return (f"the fit runs do not pin {', '.join(m[0] for m in self.pinned)}; this run does: fitted with the "
                    f"fit runs it comes within the noise (chi^2 per residual {self.chi2_predicted:.3g} -> "
                    f"{self.chi2_refit:.3g}) while theirs changes by {self.fit_rise:+.3g} (at most "
                    f"{self.allowed:.3g} allowed); moved: {moved} (validation_refits.tsv)")
        if self.code == "bow_law":
            outside = "; ".join(f"{p} = {v:.4g} against its law's {w:.4g} +- {b:.2g}" for p, (v, w, b)
                                in self.law.items() if abs(v - w) > b)
            return (f"{EXPLANATIONS['bow_law']}: fitted with the fit runs it comes within the noise (chi^2 per "
                    f"residual {self.chi2_predicted:.3g} -> {self.chi2_refit:.3g}), but with {outside}")
        if self.code == "missing_physics":
            return (f"{EXPLANATIONS['missing_physics']}: fitted with the fit runs, chi^2 per residual "
                    f"{self.chi2_predicted:.3g} -> {self.chi2_refit:.3g}, the fit runs' chi^2 rising by "
                    f"{self.fit_rise:.3g} (allowed {self.allowed:.3g})")
        if self.code == "misfit":
            return f"{EXPLANATIONS['misfit']} (their chi^2/dof {self.fit_chi2_dof:.3g})"
        return EXPLANATIONS[self.code] + (f": {self.detail}" if self.detail else "")


def beyond_noise(chi2_per_residual: float, n_residuals: int) -> bool:
    """A validation run's prediction beyond the noise: p < ALPHA on n - 1 degrees of freedom (its phase aligned)."""
    return bool(stats.chi2.sf(chi2_per_residual * n_residuals, max(n_residuals - 1, 1)) < ALPHA)


def law_band(joint: pd.DataFrame, parameter: str, rpm: float, mass_g: float, runs: pd.DataFrame | None,
             law: str = "law", confidence: float = 0.95) -> tuple[float, float]:
    """A per-run parameter's law (``validation.bow_law``) at a run and the half-width of its prediction band: the
    law's own uncertainty plus a new run's scatter about it (the runs' median stderr), both scaled by the weighted
    residuals' chi^2/dof when above 1, times the normal quantile (the stderrs are taken as known)."""
    rows = joint[(joint["parameter"] == parameter) & (joint["run"] != "all")]
    if runs is not None:
        rows = rows.drop(columns=[c for c in ("rpm", "eccentric_mass_g") if c in rows]).merge(
            runs[["run", "rpm", "eccentric_mass_g"]], on="run", how="left")
    coef, predict = bow_law(rows, parameter, law)
    omega2 = (rows["rpm"].to_numpy(float) * 2 * np.pi / 60) ** 2
    mass = rows["eccentric_mass_g"].to_numpy(float) * 1e-3
    stderr = rows["stderr"].to_numpy(float)
    w = 1.0 / np.where(np.isfinite(stderr) & (stderr > 0), stderr, np.nanmax(np.append(stderr, 1.0))) ** 2
    used = [k for k in range(3) if coef[k] != 0.0] or [0]
    A = np.column_stack([np.ones_like(omega2), omega2, omega2 * mass])[:, used]
    value = float(predict(rpm, mass_g))
    speeds, masses = (rows[c].to_numpy(float) for c in ("rpm", "eccentric_mass_g"))
    residual = rows["value"].to_numpy(float) - predict(speeds, masses)
    dof = max(len(rows) - len(used), 1)
    s2 = max(1.0, float((w * residual**2).sum()) / dof)
    o2 = (rpm * 2 * np.pi / 60) ** 2
    a = np.array([1.0, o2, o2 * mass_g * 1e-3])[used]
    variance = s2 * (a @ np.linalg.pinv(A.T @ (A * w[:, None])) @ a + float(np.median(1.0 / w)))
    return value, float(stats.norm.ppf(0.5 + 0.5 * confidence) * np.sqrt(variance))


def explain_run(variant, joint: pd.DataFrame, harmonics: pd.DataFrame, data: idn.RunData, values: Mapping[str, float],
                phase: float, chi2_predicted: float, options: Mapping, n_harmonics: int,
                runs: pd.DataFrame | None = None) -> Explanation:
    """Why ``data`` (a validation run, predicted with ``values`` and aligned ``phase``, chi^2 per residual
    ``chi2_predicted``) is predicted as it is (module docstring). joint: the variant's parameters.tsv; harmonics: the
    measured harmonics of every run (the fit runs are the joint table's); options:
    ``IdentificationSettings.rule(..., "validation")``
    (per_run, keyphasor, validation_bow); runs: the fit runs' run, rpm, eccentric_mass_g (the law's)."""
    n = 2 * data.X.size
    if not beyond_noise(chi2_predicted, n):
        return Explanation(data.run, "within_noise", chi2_predicted=chi2_predicted)
    names, lower, upper = ranges(variant)
    fit_runs = idn.fit_runs(joint)
    fitted = [idn.run_data(harmonics, r, keyphasor=options["keyphasor"], channels=variant.channels) for r in fit_runs]
    every = [*fitted, data]
    H = min(n_harmonics, *(d.H for d in every))
    every = [replace(d, X=d.X[:H], sigma=d.sigma[:H]) for d in every]
    per_run = [p for p in options["per_run"] if p in names]
    layout = Layout.for_data(names, lower, upper, every, per_run)
    start = {(str(r.parameter), str(r.run)): float(r.value) for r in joint.itertuples()}
    start |= {(p, data.run): float(values[p]) for p in per_run} | {("phase", data.run): float(phase)}
    if any(e not in start for e in layout.entries()):
        return Explanation(data.run, "not_checked", chi2_predicted=chi2_predicted,
                           detail="the joint table lacks an entry of the fit with this run")
    theta0 = np.clip([layout.theta_of((p, run), start[(p, run)]) for p, run in layout.entries()],
                     *layout.bounds())
    models = solver_models(variant, every, H)
    sigma = np.stack([d.sigma for d in every])
    X = np.stack([d.X for d in every])
    problem = ArrowProblem(models, layout, sigma)
    own = [i for i, (_, run) in enumerate(layout.entries()) if run == data.run]

    def parts(theta: Array) -> tuple[float, float]:
        """(the fit runs' objective, the validation run's chi^2) at theta."""
        ev = problem.evaluate(theta[None], X[None], jacobian=False)
        chi2_run = float((ev.r[0, -1] ** 2).sum())
        return float(ev.objective[0]) - chi2_run - float((ev.rho[0, own] ** 2).sum()), chi2_run

    before, _ = parts(theta0)
    n_fit = 2 * sum(d.X.size for d in fitted)
    dof_fit = n_fit - (layout.n - len(own)) + int(np.count_nonzero(layout.phase_prior[:own[0]]))
    fit_chi2_dof = before / max(dof_fit, 1)
    if not np.isfinite(before):
        return Explanation(data.run, "not_checked", chi2_predicted=chi2_predicted,
                           detail="the full solver has no periodic solution at the joint estimates")
    if stats.chi2.sf(before, max(dof_fit, 1)) < ALPHA:
        return Explanation(data.run, "misfit", chi2_predicted=chi2_predicted, fit_chi2_dof=fit_chi2_dof)
    result = levenberg_marquardt(problem, theta0[None], X[None], replace(OPTIONS, max_iterations=40))
    refit = idn.conclude(problem, ProtocolResult.without_monte_carlo(result, 0), every, X,
                         units=idn.units(variant))
    after, chi2_run = parts(refit.theta)
    table = refit.table()
    shared = [i for i, (p, run) in enumerate(layout.entries()) if run == "all" and p != "phase"]
    allowed = threshold(0.95, len(shared), fit_chi2_dof)
    k_own = len(own)
    explanation = Explanation(data.run, "missing_physics", chi2_predicted=chi2_predicted, chi2_refit=chi2_run / n,
                              fit_rise=after - before, allowed=allowed, fit_chi2_dof=fit_chi2_dof, table=table)
    if not (np.isfinite(chi2_run) and stats.chi2.sf(chi2_run, max(n - k_own, 1)) >= ALPHA
            and after - before <= allowed):
        return explanation
    old = joint.set_index(["parameter", "run"])
    moves = []  # (name, move in its unit (module docstring), before, after, unit's name)
    for i in shared:
        p = layout.entries()[i][0]
        row = old.loc[(p, "all")]
        value, after_value = float(row["value"]), float(refit.x[i])
        if bool(row["at_bound"]) or not bool(row["identifiable"]):  # loose: how far across its range it moved
            moves.append((p, (after_value - value) / (0.1 * (row["upper"] - row["lower"])), value, after_value,
                          "tenths of its range (loose in the fit runs)"))
        else:
            stderr = float(row["stderr"])
            moves.append((p, (after_value - value) / stderr if stderr > 0 else np.inf, value, after_value,
                          "standard errors"))
    for p in per_run:
        value, band = law_band(joint, p, data.rpm, data.eccentric_mass_g, runs, options["validation_bow"])
        after_value = float(refit.x[layout.entries().index((p, data.run))])
        explanation.law[p] = (after_value, value, band)
        sigma = band / stats.norm.ppf(0.975)
        moves.append((f"{p} at this run", (after_value - value) / sigma if sigma > 0 else np.inf, value, after_value,
                      "sigmas of its law over the fit runs"))
    moves.sort(key=lambda m: -abs(m[1]))
    explanation.pinned = [m for m in moves if abs(m[1]) > 1.0] or moves[:1]
    outside = [p for p, (v, w, b) in explanation.law.items() if abs(v - w) > b]
    explanation.code = "bow_law" if outside else "not_pinned"
    return explanation


def refits_table(explanations: Sequence[Explanation]) -> pd.DataFrame:
    """validation_refits.tsv: the refit with each explained run included (``REFIT_COLUMNS``; empty when none)."""
    tables = [e.table.assign(validation_run=e.run) for e in explanations if e.table is not None]
    if not tables:
        return pd.DataFrame(columns=REFIT_COLUMNS)
    return pd.concat(tables, ignore_index=True)[REFIT_COLUMNS]
