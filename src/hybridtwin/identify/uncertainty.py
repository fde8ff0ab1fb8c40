"""Uncertainty and identifiability at an optimum (linearised).

Covariance s^2 V S^-2 V^T from the SVD of the weighted Jacobian of the
parameters, s^2 = max(1, chi^2 / dof) (Birge ratio); parameters at a bound
are held fixed (their covariance is not valid, and the others' include their
uncertainty, computed as if free); correlation matrix; collinearity index
(Brun et al. 2001) of the unit-normalised sensitivities of the physical
parameters with the phases projected out; flags for non-identifiable
parameters and estimates at a range edge ("revise the range").

``layout`` below is an identification's ``Layout`` (``n``, ``entries()``,
``is_phase``, ``scale()``, ``bounds()``); it is duck-typed so that this module
sits below the identification.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: the false-alarm rate of one test that says "beyond the noise": a run (p < ALPHA, the report and the validation
#: refit), a drifting parameter (report.drift), a fingerprint's pattern; the config's diagnosis.alpha and online.alpha
#: default to it (tests/test_config.py checks the schema's defaults)
ALPHA = 0.01

Array = np.ndarray

#: an estimate within this distance of a range edge (0.1 % of the range) is "at the bound"
BOUND_TOLERANCE = 2e-3
#: collinearity index above which a parameter set is poorly identifiable (Brun et al. 2001: 10-15)
COLLINEARITY_LIMIT = 15.0
#: singular values below this fraction of the largest are treated as zero (non-identifiable directions)
RCOND = 1e-12



@dataclass
class Uncertainty:
    """Linearised uncertainty at the optimum (entries of theta; SI through ``scale``).

    covariance (n, n) [SI^2], NaN for entries held at a bound; chi2, dof,
    chi2_dof = chi^2 / dof (the residual noise the covariance is scaled by);
    singular_values of the weighted Jacobian of the free entries;
    collinearity_index of the physical free entries (phases projected out);
    vif: variance inflation of each physical entry; identifiable, at_bound flags;
    notes: sentences for the log and the summary.
    """

    covariance: Array
    stderr: Array
    correlation: Array
    chi2: float
    dof: int
    singular_values: Array
    collinearity_index: float
    vif: Array
    at_bound: Array
    identifiable: Array
    null_loading: Array
    notes: list[str] = field(default_factory=list)

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")


def analyse_uncertainty(J: Array, r: Array, theta: Array, layout, scale_by_residual: bool = True,
                        rcond: float = RCOND) -> Uncertainty:
    """Covariance from the SVD of the weighted Jacobian J (m, n) at theta, scaled by chi^2/dof (module docstring).

    The scale is max(1, chi^2/dof) (Birge ratio): residuals above the stated
    noise widen the intervals; below it (chance, dof finite) they never shrink
    them under what the measured sigmas allow.
    J is d r / d theta (normalised parameters, phases in rad), so the SVD
    compares dimensionless directions; the covariance is converted to SI after.
    Entries at a bound have no valid interval of their own; the covariance is
    computed with them as if free, so the others' intervals include their
    uncertainty rather than being conditional on the edge values (said in
    ``notes``). Directions with a
    singular value below rcond * the largest are numerically null: left out of
    the pseudo-inverse, and the entries loading on them flagged. A parameter is
    identifiable when it is free, not on a null direction, and its 95 %
    interval is narrower than its range.
    """
    n = layout.n
    scale = layout.scale()
    lo, hi = layout.bounds()
    undefined = ~np.isfinite(J).all(0)  # a sensitivity the model could not give (no solution either side)
    J = np.where(undefined, 0.0, J)
    at_bound = (theta <= lo + BOUND_TOLERANCE) | (theta >= hi - BOUND_TOLERANCE)
    free = ~at_bound
    chi2 = float(r @ r)
    dof = int(J.shape[0] - free.sum())
    s2 = max(chi2 / dof, 1.0) if (scale_by_residual and dof > 0) else 1.0
    # all entries, those at a bound as if free: the free ones' intervals then include how little the data fix
    # the bound ones (conservative), instead of being conditional on the edge values
    U, S, Vt = np.linalg.svd(J, full_matrices=False)
    keep = S > rcond * (S[0] if S.size else 1.0)
    inverse = np.where(keep, 1.0 / np.where(keep, S, 1.0) ** 2, 0.0)
    covariance = s2 * (Vt.T * inverse) @ Vt * np.outer(scale, scale)
    covariance[at_bound, :] = np.nan  # an interval around an estimate pinned at a range edge is not valid
    covariance[:, at_bound] = np.nan
    stderr = np.sqrt(np.diag(covariance).clip(min=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(stderr, stderr)
    null = (Vt[~keep] ** 2).sum(0) if (~keep).any() else np.zeros(n)
    gamma, vif = _collinearity(J, free, layout)
    width = np.where(nuisance(layout), np.inf, 2.0 * scale)  # the range width [SI]
    identifiable = free & (null < 0.1) & (2 * 1.96 * stderr < width) & np.isfinite(stderr)
    notes = _uncertainty_notes(layout, at_bound, identifiable, gamma, chi2, dof)
    if undefined.any():
        names = [p if run == "all" else f"{p}[{run}]" for (p, run), u in zip(layout.entries(), undefined) if u]
        notes.append(f"no sensitivity for {', '.join(names)} (the model has no solution next to the estimate): "
                     "treated as not identifiable")
    return Uncertainty(covariance, stderr, correlation, chi2, dof, S, gamma, vif, at_bound, identifiable, null,
                       notes)


def nuisance(layout) -> Array:
    """The layout's nuisance entries (``Layout.is_nuisance``: phases and runout offsets), its phases for a layout
    without that property (duck-typed)."""
    return np.asarray(getattr(layout, "is_nuisance", layout.is_phase), bool)


def _collinearity(J: Array, free: Array, layout) -> tuple[float, Array]:
    """Brun's collinearity index of the free physical entries, the nuisance ones (phases, runout offsets)
    projected out, and their VIFs."""
    phys = free & ~nuisance(layout)
    vif = np.full(layout.n, np.nan)
    if not phys.any():
        return float("nan"), vif
    S = J[:, phys]
    phases = J[:, free & nuisance(layout)]
    if phases.size:
        Q, _ = np.linalg.qr(phases)
        S = S - Q @ (Q.T @ S)
    norms = np.linalg.norm(S, axis=0)
    if (norms <= 0).any():
        vif[phys] = np.where(norms > 0, np.nan, np.inf)
        return float("inf"), vif
    Sn = S / norms
    sv = np.linalg.svd(Sn, compute_uv=False)
    gamma = float(1.0 / sv[-1]) if sv[-1] > 0 else float("inf")
    try:
        vif[phys] = np.diag(np.linalg.inv(Sn.T @ Sn))
    except np.linalg.LinAlgError:
        vif[phys] = np.inf
    return gamma, vif


def _uncertainty_notes(layout, at_bound: Array, identifiable: Array, gamma: float, chi2: float,
                       dof: int) -> list[str]:
    notes = []
    names = [p if run == "all" else f"{p}[{run}]" for p, run in layout.entries()]
    bound = [n for n, b, ph in zip(names, at_bound, nuisance(layout)) if b and not ph]
    if bound:
        caveat = (" (the parameters are poorly identifiable together here, so an edge estimate may only mean "
                  "that the data do not determine it)" if np.isfinite(gamma) and gamma > COLLINEARITY_LIMIT else "")
        notes.append(f"estimate at a range edge for {', '.join(bound)}: revise the range (widen it and rebuild "
                     "the library); their own intervals are not valid there, and the others' include their "
                     f"uncertainty (computed as if they were free){caveat}")
    weak = [n for n, ok, b, ph in zip(names, identifiable, at_bound, nuisance(layout)) if not ok and not b and not ph]
    if weak:
        notes.append(f"not identifiable from these data: {', '.join(weak)} (null direction of the Jacobian or "
                     "95 % interval wider than the range)")
    if np.isfinite(gamma) and gamma > COLLINEARITY_LIMIT:
        notes.append(f"collinearity index {gamma:.1f} > {COLLINEARITY_LIMIT:g}: the physical parameters are "
                     "poorly identifiable together (their effects on the response nearly compensate)")
    if dof > 0 and chi2 / dof > 4.0:
        notes.append(f"chi^2/dof = {chi2 / dof:.3g}: the residuals exceed the stated noise (model or library "
                     "error); the covariance is scaled up by it")
    return notes


#: the ``interval`` codes of a parameter table (parameters.tsv), what each interval is; ``loose`` names the parameters
INTERVAL_CODES = {
    "linear": "linearised at the estimate (the Jacobian's covariance); no parameter is loose",
    "conditional": "linearised at the estimate: valid only with the parameters in `loose` where the fit left them",
    "profile": "the shadow of the joint region of this parameter and those in `loose` (profile likelihood, the loose "
               "ones free across their ranges), never narrower than the linearised interval",
    "none": "no interval: the estimate sits at a range edge, or the run was not fitted",
}


@dataclass
class Profiled:
    """Intervals that account for the loose parameters (``hybridtwin.identify.profile``), per entry of theta.

    low, high [SI]: the profile's interval ends (NaN for an entry not profiled); loose: the loose parameters'
    names; threshold: the chi^2 rise that bounds each profiled entry's region (NaN elsewhere); points: every
    profile fit (parameter, side, value, chi2 rise, ...); notes: sentences for the log and the summary.
    """

    low: Array
    high: Array
    loose: tuple[str, ...]
    threshold: Array
    points: object = None  # a pandas table (``tables.PROFILE``)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def profiled(self) -> Array:
        return np.isfinite(self.low) & np.isfinite(self.high)


def loose_entries(layout, at_bound: Array, identifiable: Array) -> Array:
    """The loose entries of theta: shared physical parameters at a range edge or not identifiable (the data leave
    them anywhere in a stretch of their range, so the others' linearised intervals are conditional on them)."""
    shared = np.array([run == "all" and p != "phase" for p, run in layout.entries()])
    return shared & (np.asarray(at_bound, bool) | ~np.asarray(identifiable, bool))


def interval_basis(layout, at_bound: Array, identifiable: Array, finite: Array,
                   profiled: Array | None = None) -> tuple[list[str], list[str]]:
    """Per entry of theta, the ``interval`` code (``INTERVAL_CODES``) and the ``loose`` parameters it is conditional
    on or profiled over (comma-separated, "" when none). finite: the entry has an interval; profiled: it comes from
    the profile (``Profiled.profiled``)."""
    loose = loose_entries(layout, at_bound, identifiable)
    names = [p for p, _ in layout.entries()]
    profiled = np.zeros(layout.n, bool) if profiled is None else np.asarray(profiled, bool)
    codes, over = [], []
    for i in range(layout.n):
        others = ",".join(names[j] for j in np.flatnonzero(loose) if j != i)
        code = ("profile" if profiled[i] else "none" if not finite[i] else "conditional" if others else "linear")
        codes.append(code)
        over.append(others if code in ("profile", "conditional") else "")
    return codes, over


def student_t(confidence: float, dof: int) -> float:
    """Two-sided quantile of Student's t (the normal one for dof > 1000)."""
    from scipy.stats import t  # here: scipy.stats (~0.4 s) only for an interval; the command line imports ALPHA

    return float(t.ppf(0.5 + 0.5 * confidence, max(dof, 1)))
