"""A record's first verdict from the twin's sPGD library; the full solver where the library's error cannot decide
(docs/online.md, "The library answers first").

A twin built with libraries (``offline.scope`` run or global, the card's ``library``: ``twin.library_card``) answers
a steady record from them: the record's fits (``fits.RecordProblem``) take the responses and their exact Jacobians
from the library (``forward.SensorSurrogate``, microseconds per evaluation) instead of harmonic-balance solves. Which
library (``choose``):

- scope run: the library of the runs sheet's run at the record's eccentric mass (to ``MASS_TOLERANCE_G``) nearest
  in speed, within ``SPEED_MATCH`` of the record's speed, **anchored** on the full solver when the card was written
  (``anchors``, rule twin_card): shifted to equal the solver at the twin's values at that run's operating point and
  corrected to its slope there (``fits.Anchor``: first order), plus the solver's change per RPM there times the
  record's speed difference. Its error near the twin (inside the box x0 -+ ``ANCHOR_PRIOR_SDS`` of the twin's
  standard deviations, within [``ANCHOR_MIN_HALF_WIDTH``, ``ANCHOR_HALF_WIDTH``], and -+ ``SPEED_MATCH`` of the
  speed, measured then against the solver) is its own error at a record whose fits stay there; elsewhere twice the
  run's largest test error plus that. Without an anchor
  (a card without one), the speed difference is counted as an error estimated from the libraries of the
  neighbouring speeds at the same mass (the largest relative change per RPM to them, times ``SPEED_SAFETY``),
  or, with none, only a record within ``SPEED_EXACT`` of the library's speed is served;
- scope global: the global library sliced at the record's speed and mass (``Library.at_operating_point``: exact),
  inside the range it was fitted over; its errors the pooled test errors ("all runs").

A record at an operating point without a library (scope run, another speed or mass), a transient record, a trial
mass at an angle (the libraries hold the mass on +x), or a library over other ranges goes to the full solver, and
the assessment says why (``route_note``).

The library's own error, in the verdict's sigma: the anchored library's error near the twin (else each run's median
test error against the full solver, library_validation.tsv's ``SIGMA_ERROR``, with the speed's) added in quadrature
to the measured sigmas (``measured.total_sigma``, as the identification on the libraries). Whether the library
decides the verdict (``decide``): with e the library's error bound at a fit (near the twin, the anchor's; elsewhere
the largest test error, ``BOUND_ERROR``, doubled, plus the anchor's), the library misses the solver's sensor
harmonics by at most e ||M|| (the anchor's measure: h = 1..H; the validation's: Parseval, h = 0 included, a factor
2 on the square), so by at most

    B = sqrt(sum_runs e^2 ||M||^2 / sigma_min^2)

in the whitened residual's norm (sigma_min the run's smallest measured sigma). The triangle inequality then bounds
the full solver's chi^2 (measured sigmas) of each hypothesis from the library's fit of it:
(sqrt(chi^2_lib) - B)^2 <= chi^2_solver <= (sqrt(chi^2_lib,measured) + B)^2, chi^2_lib with the library's error in
the sigmas (the smaller), chi^2_lib,measured the library's optimum with the measured sigmas alone. Every test of the
verdict (``assess``: the fit's p-value, each group's likelihood ratio D = chi^2_twin - chi^2_freed, which group
explains the record and which one is named) is taken at both ends of these intervals: when the verdict is the same
at both, the library's verdict is the solver's and it stands; otherwise (a p-value near the level, two changes the
record can barely tell apart, a fit leaving the library's box) the full solver confirms. A change of two groups at
once (the pairs) and a new discrepancy with more than one group are always confirmed by the solver. B is a bound only
as far as e bounds the library's error between the points where it was measured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import chdtrc

from ..identify.forward import SensorSurrogate, SolverModel, evaluate_runs
from ..offline.library import Library, sensor_signal_norm
from .fits import Anchor
from .intake import Intake
from .twin import Twin

Array = np.ndarray

#: the library error added to the verdict's sigma, and the one that bounds it (library_validation.tsv columns, %)
SIGMA_ERROR = "median_error_pct"
BOUND_ERROR = "max_error_pct"
#: a scope-run library serves a record at its eccentric mass to this many grams
MASS_TOLERANCE_G = 1e-3
#: ... and within this relative speed of its own (the rig's speed error is 0.1 %: a record at a fit run's nominal
#: speed is within 0.5 % of that run's solved speed at five standard deviations)
SPEED_MATCH = 5e-3
#: without a neighbouring library to estimate the speed's effect, only this close (relative)
SPEED_EXACT = 1e-9
#: the speed's effect between two libraries, a finite difference, times this (a resonance's slope is steeper than the
#: chord over tens of RPM)
SPEED_SAFETY = 2.0
#: the anchor's neighbourhood: the twin's values -+ this along each parameter (normalised: the range is 2 wide, so
#: 5 % of the range), where a record's fits stay unless it moved (a record's own estimate of a damping moves by a few
#: prior standard deviations of the twin, which are far smaller)
ANCHOR_HALF_WIDTH = 0.1
#: ... or, narrower, this many of the twin's own standard deviations of the parameter (its prior at the run: a record
#: of the unchanged machine moves a freed parameter by a few of its own, larger, standard deviations), but not below
#: ``ANCHOR_MIN_HALF_WIDTH``; a fit outside the box is judged with the library's bound elsewhere (``bound``)
ANCHOR_PRIOR_SDS = 30.0
ANCHOR_MIN_HALF_WIDTH = 0.005
#: the wider boxes an anchor's error is also measured over (normalised half widths: 5 % and 15 % of each range), for
#: the fits of a record less precise than the twin, which move a freed parameter further
ANCHOR_WIDER_BOXES = (ANCHOR_HALF_WIDTH, 0.3)

_CACHE: dict[Path, Library] = {}


@dataclass
class Choice:
    """The libraries serving a record (one per run of it) and their relative errors at it (fractions): ``offsets``
    (H, C) [m] the anchor's shift at the record's speed (None: not anchored), ``near`` the anchored library's error
    inside the neighbourhood ``centre`` -+ ``half_width`` (normalised) where it was measured, ``bound_error``
    elsewhere."""

    libraries: list[Library]
    sigma_error: list[float]
    bound_error: list[float]
    names: list[str]
    notes: list[str] = field(default_factory=list)
    offsets: list = field(default_factory=list)
    near: list = field(default_factory=list)  # per run: [(centre, half_width, error), ...] narrowest first, or None

    @property
    def name(self) -> str:
        return ", ".join(self.names)


def load(path: Path) -> Library:
    """A library store, read once per process (a runs sheet of records reuses it)."""
    path = Path(path).resolve()
    if path not in _CACHE:
        _CACHE[path] = Library.load(path)
    return _CACHE[path]


def choose(twin: Twin, record: Intake) -> tuple[Choice | None, str]:
    """The libraries that answer ``record`` (module docstring), or None and why the full solver does."""
    library = twin.library
    if library is None:
        return None, "the twin has no library (offline.scope: none)"
    if record.kind != "steady" or len(record.data) != 1:
        return None, "a transient record: its speed bands on the full solver (the library answers steady records)"
    data = record.data[0]
    if data.eccentric_mass_angle_deg % 360.0 != 0.0:
        return None, (f"its trial mass is at {data.eccentric_mass_angle_deg:g} deg; the libraries hold the mass on "
                      "+x")
    try:
        if library["scope"] == "global":
            choice = _global(twin, data)
        else:
            choice = _run(twin, data)
    except (OSError, ValueError, KeyError) as err:
        return None, f"its library cannot be used: {' '.join(str(err).split())}"
    if isinstance(choice, str):
        return None, choice
    names, lower, upper = (list(twin.variant.unknown),
                           *(np.array(v, float) for v in zip(*twin.variant.unknown.values())))
    for served in choice.libraries:
        if served.parameters != names or not (np.allclose(served.lower, lower) and np.allclose(served.upper, upper)):
            return None, (f"library {served.run} is over {served.parameters}, not the variant's unknowns and ranges "
                          "(a library of another build)")
    return choice, ""


def _run(twin: Twin, data) -> Choice | str:
    """Scope run: the library of the sheet's run at the record's mass nearest in speed (module docstring)."""
    runs = [r for r in twin.library["runs"] if abs(r["eccentric_mass_g"] - data.eccentric_mass_g) <= MASS_TOLERANCE_G]
    if not runs:
        return f"no library at {data.eccentric_mass_g:g} g (scope run: one library per run of the sheet)"
    runs.sort(key=lambda r: abs(r["rpm"] - data.rpm))
    nearest = runs[0]
    gap = abs(nearest["rpm"] - data.rpm) / data.rpm
    if gap > SPEED_MATCH:
        return (f"no library within {100 * SPEED_MATCH:g} % of {data.rpm:.1f} RPM at {data.eccentric_mass_g:g} g "
                f"(nearest: {nearest['run']} at {nearest['rpm']:.1f} RPM; scope run: one library per run)")
    folder = twin.folder
    library = load(folder / twin.library["file"].format(run=nearest["run"]))
    notes = [f"library {nearest['run']} solved at {nearest['rpm']:.2f} RPM"]
    anchor = nearest.get("anchor")
    name = twin.library["file"].format(run=nearest["run"])
    if anchor and abs(data.rpm - nearest["rpm"]) <= anchor["speed_step_rpm"]:
        offset = (np.array(anchor["offset_re_m"]) + 1j * np.array(anchor["offset_im_m"])
                  + (data.rpm - nearest["rpm"]) * (np.array(anchor["slope_re_m_per_rpm"])
                                                   + 1j * np.array(anchor["slope_im_m_per_rpm"])))
        if "gradient_re_m" in anchor:  # to first order (a card written before it: the shift alone)
            offset = Anchor(offset, np.array(anchor["gradient_re_m"]) + 1j * np.array(anchor["gradient_im_m"]),
                            np.array(anchor["x"]))
        near = anchor["error_pct"] / 100
        tiers = [(np.array(anchor["x"]), np.array(anchor["half_width"]), near)]
        for wider in anchor.get("wider", ()):  # the same anchor over wider boxes (ANCHOR_WIDER_BOXES)
            tiers.append((np.array(anchor["x"]), np.array(wider["half_width"]), wider["error_pct"] / 100))
        notes.append(f"anchored at the twin, {data.rpm - nearest['rpm']:+.2f} RPM from the record: error "
                     f"{anchor['error_pct']:.2g} % near the twin"
                     + "".join(f", {100 * e:.2g} % over {50 * h.max():.3g} % of the ranges" for _, h, e in tiers[1:]))
        return Choice([library], [near], [2 * nearest[BOUND_ERROR] / 100 + tiers[-1][2]], [name], notes, [offset],
                      [tiers])
    speed_error = 0.0
    if gap > SPEED_EXACT:
        x0 = _twin_values(twin, data.rpm, data.eccentric_mass_g)
        here = library.sensor(x0)
        slopes = []
        for other in runs[1:]:
            if abs(other["rpm"] - nearest["rpm"]) < 1e-9:
                continue
            neighbour = load(folder / twin.library["file"].format(run=other["run"])).sensor(x0)
            change = float(sensor_signal_norm(neighbour - here)[0] / sensor_signal_norm(here)[0])
            slopes.append(change / abs(other["rpm"] - nearest["rpm"]))
            if len(slopes) == 2:
                break
        if not slopes:
            return (f"the record is {abs(nearest['rpm'] - data.rpm):.2f} RPM from library {nearest['run']} and no "
                    f"other library at {data.eccentric_mass_g:g} g tells how the response changes with speed")
        speed_error = SPEED_SAFETY * max(slopes) * abs(nearest["rpm"] - data.rpm)
        notes.append(f"{data.rpm - nearest['rpm']:+.2f} RPM from the record: speed error {100 * speed_error:.3g} %")
    sigma = math.hypot(nearest[SIGMA_ERROR] / 100, speed_error)
    bound = nearest[BOUND_ERROR] / 100 + speed_error
    return Choice([library], [sigma], [bound], [name], notes, [None], [None])


def _global(twin: Twin, data) -> Choice | str:
    """Scope global: the global library sliced at the record's operating point."""
    library = load(twin.folder / twin.library["file"])
    outside = library.outside_operating_range(data.rpm, data.eccentric_mass_g)
    if outside:
        return outside
    pooled = twin.library["all_runs"]
    sliced = library.at_operating_point(data.run, data.rpm, data.eccentric_mass_g)
    return Choice([sliced], [pooled[SIGMA_ERROR] / 100], [pooled[BOUND_ERROR] / 100],
                  [f"{twin.library['file']} at {data.rpm:.1f} RPM, {data.eccentric_mass_g:g} g"], [], [None], [None])


def _twin_values(twin: Twin, rpm: float, eccentric_mass_g: float) -> Array:
    """The twin's parameter values [SI] at an operating point (the per-run ones from their law), (1, d)."""
    prior = twin.prior([(rpm, eccentric_mass_g)])
    values = []
    for p in twin.variant.unknown:
        if p in prior.undetermined:
            values.append(prior.undetermined[p][0])
        else:
            values.append(prior.mean[prior.index(p, 0 if (p, 0) in prior.names else None)])
    return np.array([values])


# --- the anchor: the library against the full solver at the twin, when the card is written ----------------------


def anchors(twin: Twin, order: int = 1, seed: int = 0) -> dict[str, dict]:
    """Each scope-run library of ``twin`` anchored on the full solver at the twin (module docstring, "the anchor"):
    per run, the shift (H, C) [m] that makes the library equal to the solver at the twin's values at the run's
    operating point (x0: the shared estimates, the per-run ones from their law), with ``order`` 1 also the solver's
    Jacobian less the library's there (H, C, d) (``fits.Anchor``: the corrected library then has the solver's
    response and slope at x0, its error second order in the distance), the solver's change per RPM there (central
    difference over -+ ``SPEED_MATCH``), and the anchored library's largest relative error against the solver over
    two boxes (``_box_points``: each face along each parameter and a Latin hypercube inside, ``seed``), with x0 at
    -+ ``SPEED_MATCH`` of the speed with the speed's correction: ``error_pct`` over the twin's own box
    (``_anchor_half_width``; with ``order`` 0, x0 -+ ``ANCHOR_HALF_WIDTH``), and in ``wider`` over each of
    ``ANCHOR_WIDER_BOXES`` (normalised half widths, for the fits of records less precise than the twin). ``bound``
    takes the narrowest box that holds a fit. Two batched solves of every run's points (x0 with its sensitivities,
    then the rest)."""
    names = list(twin.variant.unknown)
    d = len(names)
    lower, upper = (np.array(v, float) for v in zip(*twin.variant.unknown.values()))
    half_range = 0.5 * (upper - lower)
    H = twin.harmonics
    rng = np.random.default_rng(seed)
    runs, centres, models, xs = [], [], [], []
    for entry in twin.library["runs"]:
        rpm, mass = entry["rpm"], entry["eccentric_mass_g"]
        x0 = (_twin_values(twin, rpm, mass)[0] - (lower + upper) / 2) / half_range
        half = _anchor_half_width(twin, names, half_range, rpm, mass) if order >= 1 else np.full(d, ANCHOR_HALF_WIDTH)
        boxes = [half] + ([np.full(d, w) for w in ANCHOR_WIDER_BOXES] if order >= 1 else [])
        points = np.concatenate([_box_points(x0, box, rng) for box in boxes])
        step = SPEED_MATCH * rpm
        centres.append(SolverModel(twin.variant, entry["run"], rpm, mass, names, lower, upper, H))
        for speed, x in ((rpm, points), (rpm - step, x0[None]), (rpm + step, x0[None])):
            models.append(SolverModel(twin.variant, entry["run"], speed, mass, names, lower, upper, H))
            xs.append(x)
        runs.append((entry, x0, half, step))
    at_centre = evaluate_runs(centres, [r[1][None] for r in runs], order >= 1)
    solved = evaluate_runs(models, xs, False)
    out = {}
    for i, (entry, x0, half, step) in enumerate(runs):
        here, J_here = at_centre[i]
        checked, below, above = (solved[3 * i + j][0] for j in range(3))
        library = SensorSurrogate(load(twin.folder / twin.library["file"].format(run=entry["run"])), H)
        if library.H < H or not all(np.isfinite(a).all() for a in (here, checked, below, above)):
            continue  # no steady state at a checked point: the library is not anchored there
        predicted, J_lib = library.evaluate(x0[None], order >= 1)
        offset = here[0] - predicted[0]
        slope = (above[0] - below[0]) / (2 * step)
        gradient = J_here[0] - J_lib[0] if order >= 1 else np.zeros(offset.shape + (d,))
        corrected = (library.evaluate(xs[3 * i], False)[0] + offset
                     + np.einsum("hcd,nd->nhc", gradient, xs[3 * i] - x0))
        errors = [np.linalg.norm(corrected[k] - checked[k]) / np.linalg.norm(checked[k]) for k in range(len(checked))]
        speed = [np.linalg.norm(predicted[0] + offset + sign * step * slope - state[0]) / np.linalg.norm(state[0])
                 for sign, state in ((-1, below), (1, above))]
        n_box = len(errors) // len(boxes)
        # each box's error over its points and every narrower box's (a wider box holds the narrower ones)
        box_errors = [max(errors[: (b + 1) * n_box] + speed) for b in range(len(boxes))]
        out[entry["run"]] = {
            "x": x0.tolist(), "half_width": half.tolist(), "speed_step_rpm": float(step),
            "offset_re_m": offset.real.tolist(), "offset_im_m": offset.imag.tolist(),
            "slope_re_m_per_rpm": slope.real.tolist(), "slope_im_m_per_rpm": slope.imag.tolist(),
            **({"gradient_re_m": gradient.real.tolist(), "gradient_im_m": gradient.imag.tolist()} if order >= 1
               else {}),
            "error_pct": 100 * float(box_errors[0]),
            **({"wider": [{"half_width": box.tolist(), "error_pct": 100 * float(e)}
                          for box, e in zip(boxes[1:], box_errors[1:])]} if order >= 1 else {}),
            "raw_error_pct": 100 * float(np.linalg.norm(offset) / np.linalg.norm(here[0]))}
    return out


def _box_points(x0: Array, half: Array, rng: np.random.Generator) -> Array:
    """Where an anchor's error is measured in the box x0 -+ ``half``: its faces' centres along each parameter and as
    many points of a Latin hypercube inside it (the directions between the axes), inside [-1, 1]."""
    d = len(x0)
    axes = [x0 + sign * half[j] * np.eye(d)[j] for j in range(d) for sign in (-1, 1)]
    spread = (rng.permuted(np.tile(np.arange(2 * d), (d, 1)), axis=1).T + rng.random((2 * d, d))) / (2 * d)
    return np.clip(np.array(axes + list(x0 + half * (2 * spread - 1))), -1, 1)


def _anchor_half_width(twin: Twin, names: list[str], half_range: Array, rpm: float, mass: float) -> Array:
    """The anchor's box (normalised half widths, per parameter): ``ANCHOR_PRIOR_SDS`` of the twin's standard
    deviations at the run (its prior), within [``ANCHOR_MIN_HALF_WIDTH``, ``ANCHOR_HALF_WIDTH``]; a parameter without
    a prior (undetermined by the twin) the widest."""
    prior = twin.prior([(rpm, mass)])
    sd = np.sqrt(np.clip(np.diag(prior.covariance), 0.0, None))
    half = np.full(len(names), ANCHOR_HALF_WIDTH)
    for i, (name, _) in enumerate(prior.names):
        if name in names:
            j = names.index(name)
            half[j] = min(ANCHOR_HALF_WIDTH, max(ANCHOR_MIN_HALF_WIDTH, ANCHOR_PRIOR_SDS * sd[i] / half_range[j]))
    return half


# --- does the library decide? -----------------------------------------------------------------------------------


@dataclass
class Decision:
    """Whether the library's verdict is the solver's (``decided``), the interval of the record's p-value the
    library's error bound allows, and, when it does not decide, why."""

    decided: bool
    p_low: float
    p_high: float
    bound: float  # B, the whitened norm of the library's largest error
    why: str = ""


def bound(problem, choice: Choice, v: Array) -> float:
    """B of the module docstring at the problem's entries ``v``: per run, an anchored library's error near the twin
    when v is inside the neighbourhood where it was measured (relative to the response h = 1..H, as measured), else
    the validation's bound (relative to the Parseval norm, h = 0 included: the factor 2)."""
    total = 0.0
    for k, (library, x) in enumerate(zip(choice.libraries, problem.run_x(v[None]))):
        tiers = choice.near[k] if choice.near else None
        inside = [e for centre, half, e in tiers or () if np.all(np.abs(x[0] - centre) <= half * (1 + 1e-9))]
        if inside:  # the narrowest box measured around the twin that holds the fit
            M = problem.models[k].evaluate(x, False)[0]
            total += (inside[0] * float(np.linalg.norm(M)) / float(problem.measured_sigma[k].min())) ** 2
            continue
        values = library.lower + (np.clip(x, -1, 1) + 1.0) * (library.upper - library.lower) / 2.0
        norm = float(sensor_signal_norm(library.sensor(values))[0])
        total += 2.0 * (choice.bound_error[k] * norm / float(problem.measured_sigma[k].min())) ** 2
    return math.sqrt(total)


def interval(problem, fit, B) -> tuple[float, float]:
    """The full solver's chi^2 of ``fit``'s hypothesis, bounded from the library's fit (module docstring); ``B`` a
    number or a function of the fit's entries."""
    B = B(fit.v) if callable(B) else B
    measured = float(np.sum(np.abs(problem.X - fit.model) ** 2 / problem.measured_sigma ** 2)) + fit.chi2_prior
    return max(math.sqrt(fit.chi2) - B, 0.0) ** 2, (math.sqrt(measured) + B) ** 2


def decide(problem, judgement, alpha: float, choice: Choice, tie: float) -> Decision:
    """Whether ``judgement`` (``assess._judge`` on the libraries) holds at both ends of every test's interval
    (module docstring)."""
    def B(v):
        return bound(problem, choice, v)

    base = interval(problem, judgement.base, B)
    B0 = B(judgement.base.v)

    def move_p(singles) -> tuple[float, float]:
        lows, highs = [], []
        for f in singles:
            lo, hi = interval(problem, f, B)
            k = sum(problem.R if p in problem.local else 1 for p in f.hypothesis.free)
            lows.append(float(chdtrc(k, max(base[1] - lo, 0.0))))   # the largest D: the smallest p
            highs.append(float(chdtrc(k, max(base[0] - hi, 0.0))))
        G = len(singles)
        return min(1.0, G * min(lows, default=1.0)), min(1.0, G * min(highs, default=1.0))

    dof = judgement.base.dof
    p_fit = (float(chdtrc(dof, base[1])), float(chdtrc(dof, base[0])))
    move = move_p(judgement.linear)
    p_low, p_high = min(1.0, 2 * min(p_fit[0], move[0])), min(1.0, 2 * min(p_fit[1], move[1]))
    outside = [f for f in [judgement.base, *judgement.tried]
               if any(np.any(np.abs(x) > 1 + 1e-9) for x in problem.run_x(f.v[None]))]
    if any(f is judgement.base or f is judgement.named for f in outside):
        return Decision(False, p_low, p_high, B0, "a fit left the library's box (extrapolation)")
    if p_low >= alpha:
        return Decision(True, p_low, p_high, B0)
    if p_high >= alpha:
        return Decision(False, p_low, p_high, B0, f"the record's p-value lies in [{p_low:.2g}, {p_high:.2g}] "
                                                 f"across the library's error, on both sides of {alpha:g}")
    # an alarm at both ends: is the change, or its absence, decided?
    if judgement.pairs:
        return Decision(False, p_low, p_high, B0, "no single change explains it: changes of two groups and a new "
                                                 "discrepancy are confirmed on the solver")
    G = len(judgement.singles)
    explains = []
    for f in judgement.singles:
        lo, hi = interval(problem, f, B)
        fit_ok = (float(chdtrc(f.dof, hi)) >= alpha, float(chdtrc(f.dof, lo)) >= alpha)
        k = sum(problem.R if p in problem.local else 1 for p in f.hypothesis.free)
        moved = (2 * G * float(chdtrc(k, max(base[0] - hi, 0.0))) < alpha,
                 2 * G * float(chdtrc(k, max(base[1] - lo, 0.0))) < alpha)
        both = (fit_ok[0] and moved[0], fit_ok[1] and moved[1])
        if both[0] != both[1]:
            return Decision(False, p_low, p_high, B0, f"whether {f.hypothesis.name} explains the record depends on "
                                                     "the library's error")
        explains.append((f, lo, hi) if both[0] else None)
    explaining = [e for e in explains if e is not None]
    if not explaining:
        if p_fit[0] >= alpha:
            return Decision(True, p_low, p_high, B0)  # the move does not hold up and the fit is at the noise
        if p_fit[1] < alpha and G == 1:
            return Decision(True, p_low, p_high, B0)  # a new discrepancy (no pairs to try)
        return Decision(False, p_low, p_high, B0, "the fit's p-value straddles the level across the library's error")
    named = judgement.named
    first = max((e[0] for e in explaining), key=lambda f: f.p_value)
    if named is not first:
        return Decision(False, p_low, p_high, B0, "the record cannot tell the named change from another: the solver "
                                                 "confirms which")
    mine = next(e for e in explaining if e[0] is named)
    for f, lo, hi in explaining:
        if f is named:
            continue
        if float(chdtrc(named.dof, mine[2])) <= float(chdtrc(f.dof, lo)) or (
                len(f.hypothesis.free) == len(named.hypothesis.free) and lo <= mine[2] + tie):
            return Decision(False, p_low, p_high, B0, f"{named.hypothesis.name} and {f.hypothesis.name} explain it "
                                                     "within the library's error: the solver confirms which")
    return Decision(True, p_low, p_high, B0)
