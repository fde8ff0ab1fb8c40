"""The next run to take (issue 41, item 4): the speeds and unbalance masses, with or without a keyphasor, that would
most shrink the intervals of the loosely pinned parameters, within what the rig can measure.

Experiment design on the Fisher information of the fitted twin (the full solver's sensitivities at the joint
estimates). With J the weighted Jacobian of a set of runs (residuals over sigma, normalised parameters), the
information on the shared physical parameters is the Schur complement of J^T J that profiles out each run's own
entries (its phase without a keyphasor, its per-run parameters: nuisances a new run brings with it)

    I = J_s^T J_s - J_s^T J_n (J_n^T J_n)^+ J_n^T J_s,

which adds up over runs. The fit runs give I_0; a candidate run c (a speed and a mass, its bow from the law over
the fit runs, the noise the fit runs' median sigma per harmonic and channel) gives I_c; with a keyphasor its phase
has the fit's prior N(0, (Omega sigma_t)^2), sigma_t the timing of a keyphasor (``keyphasor_timing``). The
covariance after adding runs is s^2 (I_0 + sum I_c)^-1, s^2 = max(1, chi^2/dof) of the joint fit, so the
expected 95 % intervals are linear predictions: where the current intervals come from a profile (a loose
parameter), they are compared with the linearised ones.

Criterion: D_s-optimality on the parameters of interest, the loose ones (at a range edge or not identifiable), or,
when none is loose, those whose interval is within a factor ``INTEREST_FACTOR`` of the widest relative to its
range: maximise det of the information on them with the others profiled out (the volume of their joint region,
which for one parameter is its variance). D-optimality is invariant to how each parameter is scaled and needs no
weights between parameters of different units; a Bayesian criterion would need a prior the project does not have.
Runs are chosen greedily, one after the other (each one given the runs chosen before; greedy D-optimal selection is
within 1 - 1/e of the best subset for this submodular criterion; a run may be chosen again, a repeat), a keyphasor
asked for only where it adds ``KEYPHASOR_WORTH`` to the run's gain, from the candidates the rig can measure: a
periodic, stable steady state (Floquet multipliers inside the unit circle) whose peak displacement plus the largest
sensor offset stays inside the sensor range.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy import stats

from .. import tables
from . import forward as fwd
from .arrow_problem import ArrowProblem, Layout
from . import identification as idn
from .run_fits import ranges, solver_models
from .validation import values_along

Array = np.ndarray

#: without a loose parameter, the parameters of interest are those whose interval, relative to its range, is within
#: this factor of the widest
INTEREST_FACTOR = 3.0
#: the largest sensor offset the design allows for under the sensor range [m] (the virtual rig's offset_mm: 0.5)
OFFSET_MARGIN_M = 5e-4
#: candidates' columns (design/candidates.tsv), the chosen runs' (next_runs.tsv): the table layer's
CANDIDATE_COLUMNS = list(tables.DESIGN_CANDIDATES.columns)
CHOSEN_COLUMNS = list(tables.DESIGN_NEXT_RUNS.columns)
#: a run is asked with a keyphasor only when that adds this much to its gain (log det: 5 % of the joint region's
#: volume over the same run without one; a keyphasor is one more sensor)
KEYPHASOR_WORTH = 0.05
#: the intervals' columns (design/intervals.tsv)
INTERVAL_COLUMNS = list(tables.DESIGN_INTERVALS.columns)


@dataclass
class Design:
    """A design: every candidate (``CANDIDATE_COLUMNS``), the runs chosen in order (``CHOSEN_COLUMNS``), per shared
    parameter its interval now and the one expected after the chosen runs (``INTERVAL_COLUMNS``), the parameters of
    interest, and the information matrices (normalised units): the fit runs' and each chosen run's."""

    candidates: pd.DataFrame
    chosen: pd.DataFrame
    intervals: pd.DataFrame
    interest: list[str]
    information: Array
    added: list[Array]
    notes: list[str]


def candidate_grid(rpm: Sequence[float] | None, step_rpm: float, masses: Sequence[float] | None,
                   plan: pd.DataFrame) -> tuple[list[float], list[float]]:
    """Candidate speeds and eccentric masses (config ``design:``, hybridtwin.settings.DesignSettings): speeds from
    ``rpm`` (from, to), else the runs sheet's range of steady speeds, in steps of ``step_rpm`` (both ends included);
    ``masses``, else the sheet's (``plan``: run_plan's rpm, eccentric_mass_g)."""
    speeds = pd.to_numeric(plan["rpm"], errors="coerce").dropna()
    low, high = (float(v) for v in (rpm if rpm is not None else (speeds.min(), speeds.max())))
    step = float(step_rpm)
    grid = np.arange(low, high + 0.5 * step, step)
    if masses is None:
        masses = sorted(set(pd.to_numeric(plan["eccentric_mass_g"], errors="coerce").dropna().astype(float)))
    return [float(v) for v in grid], [float(m) for m in masses]


def schur(J: Array, shared: Array) -> Array:
    """The information J^T J on the columns ``shared`` with the other columns profiled out (module docstring)."""
    Js, Jn = J[:, shared], J[:, ~shared]
    F = Js.T @ Js
    if Jn.shape[1]:
        F = F - Js.T @ Jn @ np.linalg.pinv(Jn.T @ Jn) @ Jn.T @ Js
    return 0.5 * (F + F.T)


def _real_rows(z: Array) -> Array:
    """(H, C, ...) complex -> (2 H C, ...) real: the residuals' layout (real parts, then imaginary parts)."""
    flat = z.reshape((z.shape[0] * z.shape[1],) + z.shape[2:])
    return np.concatenate([flat.real, flat.imag])


def fit_information(variant, joint: pd.DataFrame, harmonics: pd.DataFrame, options: Mapping, n_harmonics: int
                    ) -> tuple[Array, list[str], float, list[idn.RunData]]:
    """The fit runs' information on the shared physical parameters at the joint estimates (full solver), their
    names, s^2 = max(1, chi^2/dof) and the fit runs' data."""
    names, lower, upper = ranges(variant)
    runs = list(dict.fromkeys(joint.loc[joint["parameter"] == "phase", "run"].astype(str)))
    data = [idn.run_data(harmonics, r, keyphasor=options["keyphasor"], channels=variant.channels) for r in runs]
    H = min(n_harmonics, *(d.H for d in data))
    data = [replace(d, X=d.X[:H], sigma=d.sigma[:H]) for d in data]
    layout = Layout.for_data(names, lower, upper, data, [p for p in options["per_run"] if p in names])
    theta = idn.theta_from_table(joint, layout)
    problem = ArrowProblem(solver_models(variant, data, H), layout, np.stack([d.sigma for d in data]))
    ev = problem.evaluate(theta[None], np.stack([d.X for d in data])[None])
    prior_J, prior_r = problem.prior_rows(theta)
    J = np.vstack([problem.dense_jacobian(ev), prior_J])
    chi2 = float((ev.r[0] ** 2).sum() + prior_r @ prior_r)
    dof = max(J.shape[0] - layout.n, 1)
    shared = np.array([run == "all" and p != "phase" for p, run in layout.entries()])
    return schur(J, shared), [p for (p, run), s in zip(layout.entries(), shared) if s], max(1.0, chi2 / dof), data


def keyphasor_timing(harmonics: pd.DataFrame, rpm: float) -> float:
    """sigma_t [s]: how well a new record's keyphasor fixes its time origin at ``rpm``. The fit runs' own
    (phase_origin_sigma_s, their median) where they have a keyphasor; else each mark rounded to a sample
    (dt / sqrt 12) averaged over the record's marks, dt and the record's length the fit runs' medians. 0 (the phase
    exact, an upper bound of the keyphasor's worth) for a table without those columns."""
    if not {"phase_reference", "phase_origin_sigma_s", "sample_rate_hz", "duration_s"} <= set(harmonics):
        return 0.0
    marked = harmonics[harmonics["phase_reference"].astype(str) == "keyphasor"]
    if len(marked):
        return float(np.median(marked["phase_origin_sigma_s"].astype(float)))
    dt = 1.0 / float(np.median(harmonics["sample_rate_hz"].astype(float)))
    marks = max(float(np.median(harmonics["duration_s"].astype(float))) * rpm / 60.0, 2.0)
    return dt / np.sqrt(12.0 * marks)


def candidate_information(variant, joint: pd.DataFrame, runs: pd.DataFrame, shared: Sequence[str],
                          rpm: Sequence[float], masses: Sequence[float], sigma: Array, options: Mapping,
                          n_harmonics: int, sensor_range_m: float, timing=None) -> tuple[pd.DataFrame, dict]:
    """Every candidate (speed x mass, with and without a keyphasor): whether the rig can measure it and its
    information on ``shared`` (normalised units). sigma: (H, C) the noise a new run is expected to have; timing:
    rpm -> sigma_t [s] of a keyphasor (``keyphasor_timing``; None: a keyphasor fixes the phase exactly). With a
    keyphasor the run's phase has the prior N(0, (Omega sigma_t)^2), as in the fit (a row of the Jacobian)."""
    names, lower, upper = ranges(variant)
    law = values_along(joint, options["validation_bow"], runs)
    per_run = [p for p in options["per_run"] if p in names]
    grid = [(float(r), float(m)) for m in masses for r in rpm]
    models = [fwd.SolverModel(variant, f"candidate {r:g} rpm {m:g} g", r, m, names, lower, upper, n_harmonics)
              for r, m in grid]
    xs = [np.array([[2 * (law(r, m)[p] - lo) / (hi - lo) - 1 for p, lo, hi in zip(names, lower, upper)]])
          for r, m in grid]
    xs = [np.clip(x, -1.0, 1.0) for x in xs]
    responses = fwd.evaluate_runs(models, xs, jacobian=True)
    radii = fwd.floquet_radii(models, xs)
    h = np.arange(1, sigma.shape[0] + 1)
    angle = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
    wave = np.exp(1j * np.outer(angle, h))  # (T, H)
    shared_columns = np.array([names.index(p) for p in shared])
    rows, information = [], {}
    for (r, m), (M, dM), radius in zip(grid, responses, radii):
        M, dM = M[0, : len(h)], dM[0, : len(h)]
        peak = float(np.abs((wave @ M).real).max()) if np.isfinite(M).all() else np.nan
        stable = radius is not None and np.isfinite(radius[0]) and radius[0] < 1.0
        reason = ("no periodic steady state" if not np.isfinite(peak) else
                  "unstable steady state" if not stable else
                  "beyond the sensor range" if peak + OFFSET_MARGIN_M > sensor_range_m else "")
        for keyphasor in (False, True):
            gain_info = None
            if not reason:
                columns = [_real_rows(-dM[..., j] / sigma) for j in range(len(names))]
                own = [names.index(p) for p in per_run]
                phase = _real_rows(-1j * h[:, None] * M / sigma)
                sigma_t = timing(r) if keyphasor and timing is not None else 0.0
                nuisance = [columns[j] for j in own] + ([phase] if not keyphasor or sigma_t > 0 else [])
                J = np.column_stack([columns[j] for j in shared_columns] + nuisance)
                if keyphasor and sigma_t > 0:  # the phase's prior: a pseudo-measurement
                    prior = np.zeros(J.shape[1])
                    prior[-1] = 1.0 / (r * np.pi / 30.0 * sigma_t)
                    J = np.vstack([J, prior])
                is_shared = np.r_[np.ones(len(shared_columns), bool), np.zeros(len(nuisance), bool)]
                gain_info = schur(J, is_shared)
                information[(r, m, keyphasor)] = gain_info
            rows.append({"rpm": r, "eccentric_mass_g": m, "keyphasor": keyphasor, "feasible": not reason,
                         "reason": reason or "ok", "peak_mm": 1e3 * peak,
                         "floquet_radius": np.nan if radius is None else float(radius[0]), "gain": np.nan})
    return pd.DataFrame(rows, columns=CANDIDATE_COLUMNS), information


def interest(table: pd.DataFrame, shared: Sequence[str]) -> list[str]:
    """The parameters of interest (module docstring) from the joint table's shared rows."""
    rows = table[(table["run"] == "all") & table["parameter"].isin(shared)].set_index("parameter").loc[list(shared)]
    loose = [p for p in shared if rows.loc[p, "at_bound"] or not rows.loc[p, "identifiable"]]
    if loose:
        return loose
    width = (rows["ci_high"] - rows["ci_low"]) / (rows["upper"] - rows["lower"])
    return [p for p in shared if width[p] >= width.max() / INTEREST_FACTOR]


def log_det(information: Array, keep: Array) -> float:
    """log det of the information on the columns ``keep`` with the others profiled out (D_s)."""
    F = information[np.ix_(keep, keep)]
    other = ~keep
    if other.any():
        F = F - information[np.ix_(keep, other)] @ np.linalg.pinv(information[np.ix_(other, other)]) @ \
            information[np.ix_(other, keep)]
    sign, value = np.linalg.slogdet(F)
    return float(value) if sign > 0 else -np.inf


def design_runs(variant, joint: pd.DataFrame, harmonics: pd.DataFrame, runs: pd.DataFrame, options: Mapping,
                n_harmonics: int, rpm: Sequence[float], masses: Sequence[float], n_runs: int, sensor_range_m: float,
                keyphasor: Sequence[bool] = (False, True), confidence: float = 0.95) -> Design:
    """The next ``n_runs`` runs (module docstring) among ``rpm`` x ``masses`` (x keyphasor or not, as allowed by
    ``keyphasor``) for the variant's joint fit ``joint`` (parameters.tsv) on the measured ``harmonics``; runs: the
    fit runs' run, rpm, eccentric_mass_g (the bow's law); options:
    ``IdentificationSettings.rule(..., "validation")``."""
    information, shared, s2, data = fit_information(variant, joint, harmonics, options, n_harmonics)
    sigma = np.median(np.stack([d.sigma for d in data]), axis=0)  # (H, C) a new run's expected noise
    candidates, added = candidate_information(variant, joint, runs, shared, rpm, masses, sigma, options,
                                              sigma.shape[0], sensor_range_m,
                                              timing=lambda r: keyphasor_timing(harmonics, r))
    wanted = interest(joint, shared)
    keep = np.array([p in wanted for p in shared])
    allowed = candidates["feasible"] & candidates["keyphasor"].isin(list(keyphasor))
    now = log_det(information, keep)
    for i in np.flatnonzero(allowed):
        r = candidates.loc[i]
        candidates.loc[i, "gain"] = log_det(information + added[(r.rpm, r.eccentric_mass_g, r.keyphasor)], keep) - now
    total, chosen, matrices = information.copy(), [], []
    for step in range(1, n_runs + 1):
        base = log_det(total, keep)
        gains = {i: log_det(total + added[tuple(candidates.loc[i, ["rpm", "eccentric_mass_g", "keyphasor"]])], keep)
                 - base for i in np.flatnonzero(allowed)}
        if not gains:
            break
        best = max(gains, key=gains.get)
        r = candidates.loc[best]
        same = {i for i in gains if candidates.loc[i, "rpm"] == r.rpm
                and candidates.loc[i, "eccentric_mass_g"] == r.eccentric_mass_g}
        plain = {i: gains[i] for i in same if not candidates.loc[i, "keyphasor"]}
        if r.keyphasor and plain and gains[best] - max(plain.values()) < KEYPHASOR_WORTH:
            best = max(plain, key=plain.get)  # the same run without a keyphasor does nearly as well
            r = candidates.loc[best]
        with_keyphasor = [gains[i] for i in same if candidates.loc[i, "keyphasor"]]
        matrix = added[(r.rpm, r.eccentric_mass_g, r.keyphasor)]
        total, base = total + matrix, base + gains[best]
        matrices.append(matrix)
        chosen.append({"step": step, "rpm": r.rpm, "eccentric_mass_g": r.eccentric_mass_g,
                       "keyphasor": bool(r.keyphasor), "gain": gains[best], "log_det": base,
                       "gain_with_keyphasor": max(with_keyphasor) if with_keyphasor else np.nan})
    intervals = _intervals(variant, joint, shared, wanted, information, total, s2, confidence)
    notes = [] if chosen else ["no candidate run the rig can measure"]
    return Design(candidates, pd.DataFrame(chosen, columns=CHOSEN_COLUMNS), intervals, wanted, information,
                  matrices, notes)


def _intervals(variant, joint: pd.DataFrame, shared: Sequence[str], wanted: Sequence[str], now: Array, after: Array,
               s2: float, confidence: float) -> pd.DataFrame:
    """Per shared parameter: its interval now (the table's, and the linearised half-width from ``now``) and the
    half-width expected after the chosen runs (from ``after``), in SI."""
    names, lower, upper = ranges(variant)
    half = np.array([0.5 * (upper[names.index(p)] - lower[names.index(p)]) for p in shared])
    z = stats.norm.ppf(0.5 + 0.5 * confidence)
    width_now = z * np.sqrt(s2 * np.diag(np.linalg.pinv(now)).clip(min=0)) * half
    width_after = z * np.sqrt(s2 * np.diag(np.linalg.pinv(after)).clip(min=0)) * half
    rows = joint[joint["run"] == "all"].set_index("parameter")
    out = []
    for p, a, b in zip(shared, width_now, width_after):
        r = rows.loc[p]
        out.append({"parameter": p, "unit": r["unit"], "value": r["value"], "ci_low": r["ci_low"],
                    "ci_high": r["ci_high"], "interval": r["interval"], "lower": r["lower"], "upper": r["upper"],
                    "linear_half_width": a,
                    "expected_half_width": b, "shrink": a / b if b > 0 else np.nan, "interest": p in wanted})
    return pd.DataFrame(out, columns=INTERVAL_COLUMNS)


DESIGN_FLAGS = tables.DESIGN_FLAGS


def write_design(design: Design, chosen, intervals, candidates) -> None:
    """The design's tables: next_runs.tsv (``chosen``), intervals.tsv and candidates.tsv, 6 significant digits;
    ``read_design_table`` reads each back."""
    tables.DESIGN_NEXT_RUNS.write(design.chosen, chosen)
    tables.DESIGN_INTERVALS.write(design.intervals, intervals)
    tables.DESIGN_CANDIDATES.write(design.candidates, candidates)


def read_design_table(path) -> pd.DataFrame:
    """One of ``write_design``'s tables: its true/false columns (``DESIGN_FLAGS``) as bool, parameter names and
    units as text, the rest as numbers."""
    return tables.DESIGN_NEXT_RUNS.read(path)  # the three share their text and flag columns


def plot_design(design: Design, variant_name: str):
    """The design's figure: per mass, the gain of each candidate speed alone (log det of the interest's information,
    without and with a keyphasor; infeasible speeds marked), the chosen runs starred; and per parameter its
    interval's half-width now and expected after them, relative to its range's half."""
    from ..plots import plt  # here: matplotlib, for the figure only

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1.6, 1]})
    c = design.candidates
    for k, (mass, rows) in enumerate(c.groupby("eccentric_mass_g")):
        colour = f"C{k}"
        for keyphasor, style in ((False, "-"), (True, ":")):
            sub = rows[rows["keyphasor"] == keyphasor]
            ax.plot(sub["rpm"], sub["gain"], style, color=colour, marker="." if not keyphasor else None, ms=4,
                    label=f"{mass:g} g{', keyphasor' if keyphasor else ''}")
        bad = rows[~rows["feasible"] & ~rows["keyphasor"]]
        ax.plot(bad["rpm"], np.zeros(len(bad)), "x", color=colour, ms=5)
    labels: dict[tuple, list[str]] = {}
    for r in design.chosen.itertuples():
        gain = c[(c["rpm"] == r.rpm) & (c["eccentric_mass_g"] == r.eccentric_mass_g)
                 & (c["keyphasor"] == r.keyphasor)]["gain"].iloc[0]
        ax.plot(r.rpm, gain, "k*", ms=12)
        labels.setdefault((r.rpm, gain), []).append(str(r.step))
    for (rpm, gain), steps in labels.items():
        ax.annotate(", ".join(steps), (rpm, gain), textcoords="offset points", xytext=(-8, 6), ha="right", fontsize=8)
    ax.set_xlabel("speed [RPM]")
    ax.set_ylabel("gain alone: Delta log det (information on " + ", ".join(design.interest) + ")")
    ax.set_title(f"{variant_name}: candidate runs (x: not measurable; *: chosen, in order)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    t = design.intervals
    y = np.arange(len(t))
    scale = 0.5 * (t["upper"] - t["lower"]).to_numpy(float)
    bx.barh(y + 0.2, t["linear_half_width"] / scale, 0.4, label="now (linearised)", color="0.6")
    bx.barh(y - 0.2, t["expected_half_width"] / scale, 0.4, label="expected after the chosen runs", color="C3")
    bx.plot(0.5 * (t["ci_high"] - t["ci_low"]) / scale, y + 0.2, "k|", ms=10, label="now (parameters.tsv)")
    bx.set_yticks(y, [f"{p}{' *' if i else ''}" for p, i in zip(t["parameter"], t["interest"])])
    bx.set_xscale("log")
    bx.set_xlabel("95 % half-width / half the range  (* of interest)")
    bx.legend(fontsize=7)
    fig.tight_layout()
    return fig
