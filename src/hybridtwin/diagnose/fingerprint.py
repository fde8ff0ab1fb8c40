"""The physical fingerprint of a model's residual: what a missing effect looks like.

When no candidate effect explains a discrepancy (``diagnosis``), the residual E = X_measured - X_model
still tells a rotordynamics engineer where the missing effect acts and how it behaves. This module
describes it from arrays only (numpy/pandas, no solver call).

Convention (as elsewhere in hybridtwin): per run r, harmonic h = 0..H and channel c = x, y the complex
amplitude X_hc [m] with x(t) = Re(sum_h X_hx exp(i h Omega t)), Omega = 2 pi rpm / 60 [rad/s]; sigma_hc [m]
is the standard uncertainty of each of its real and imaginary parts, so a pure-noise entry has
E|E / sigma|^2 = 2 (two degrees of freedom). sigma = inf marks an entry that is not used. The DC term
(h = 0: the probes' gap, not modelled by the identification) is left out unless ``include_dc``.

1. Where: chi^2 = sum_{r,h,c} |E_rhc / sigma_rhc|^2, its shares per run and per harmonic.
2. Whirl (h >= 1): z = x + i y = F exp(i h Omega t) + conj(B) exp(-i h Omega t), F = (X + i Y) / 2,
   B = (X - i Y) / 2. The rotor turns from +x to +y, so x = cos, y = sin (Y = -i X) is a forward orbit:
   F = X, B = 0. With w = 2 / (sigma_x^2 + sigma_y^2) noise gives E[w |F|^2] = E[w |B|^2] = 1, and the
   forward share is F_ex / (F_ex + B_ex), F_ex = max(sum_r (w |F|^2 - 1), 0) (likewise B_ex): "forward"
   above WHIRL, "backward" below 1 - WHIRL, else "mixed" (an elliptical or straight-line orbit).
3. Phase against the model response M (where M is above the noise): p = Re(E conj M) / |M| is in phase
   with the displacement (stiffness-like), q = Im(E conj M) / |M| with the velocity i h Omega M
   (damping-like). in_phase = P / (P + Q), P = max(sum (p / sigma)^2 - n, 0), likewise Q (noise: 1 each).
   The least-squares E ~ c M, c = sum(E conj M / sigma^2) / sum(|M|^2 / sigma^2), gives measured ~ (1 + c) M:
   an amplitude ratio |1 + c| and a phase lead arg(1 + c); its coherence |sum E conj M / sigma^2|^2 /
   (sum |E / sigma|^2 sum |M / sigma|^2) is the share of that residual a scaled, rotated copy of M explains.
4. Growth: over the runs where E_h is significant, log|E_h| = a_g + s log Omega by weighted least squares
   (one intercept a_g per eccentric mass, so different unbalances do not pose as speed), weights
   |E|^2 / s^2, s^2 = (sigma_x^2 + sigma_y^2) / 2 (the variance of log|E|), |E|^2 = |E_x|^2 + |E_y|^2; the
   standard error is scaled by the reduced chi^2 when above 1. Likewise log|E_h| = a + t log|M_h|.
   Resonance: the run where the model's 1X amplitude peaks (inside the speed range); the band is the speed
   range of the runs whose 1X amplitude is at least 1/sqrt(2) of the peak (half power).
5. Harmonic content: the residual at entries (r, h) where the model is within the noise but E is
   significant (a missing excitation or a nonlinearity at that harmonic).

Significance: chi^2 of k = 2 j real numbers against chi^2(k), exactly (sf = exp(-x/2) sum_{i<j} (x/2)^i / i!),
at level ``alpha``. Where along the shaft an equivalent force would act is not estimated. With more than one
sensor plane (issue 24) every channel counts in 1, 3, 4 and 5; the whirl (2) is that of the first plane's x, y
probes, channels 0 and 1 (the machine orders them first, ``Machine.sensors``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..identify.uncertainty import ALPHA
from ..model.faults import FAULTS
from ..tables import FINGERPRINT

Array = np.ndarray

WHIRL = 0.8  # forward share above which a residual "whirls forward" (below 1 - WHIRL: backward)
_HARMONIC = ("share", "significant", "forward", "in_phase", "coefficient_re", "coefficient_im", "coherence",
             "speed_slope", "speed_slope_se", "response_slope", "response_slope_se", "growth_runs",
             "unmodelled_share", "unmodelled_runs")
_ALL = ("chi2", "dof", "resonance_rpm", "band_lo_rpm", "band_hi_rpm", "band_share", "band_fraction", "alpha")


@dataclass(eq=False)
class Fingerprint:
    """The residual's fingerprint; per-harmonic arrays have H+1 entries (h = 0..H), NaN where undefined."""

    runs: list  # run names (R,)
    rpm: Array  # (R,) [rev/min]
    eccentric_mass_g: Array  # (R,) [g]
    harmonics: Array  # (H+1,) 0..H
    chi2: float  # sum |E / sigma|^2 over the entries used
    dof: int  # real numbers in that sum
    run_share: Array  # (R,) share of chi2 per run
    harmonic_share: Array  # (H+1,) share of chi2 per harmonic
    significant: Array  # (H+1,) bool, the harmonic's residual is above the noise
    forward: Array  # (H+1,) forward share of the whirl energy above the noise
    in_phase: Array  # (H+1,) stiffness-like share (the rest is damping-like)
    coefficient: Array  # (H+1,) complex c of E ~ c M
    coherence: Array  # (H+1,) share of that residual c M explains
    speed_slope: Array  # (H+1,) s of |E| ~ Omega^s
    speed_slope_se: Array
    response_slope: Array  # (H+1,) t of |E| ~ |M|^t
    response_slope_se: Array
    growth_runs: Array  # (H+1,) int, runs in the slope fits (significant residual)
    unmodelled_share: Array  # (H+1,) share of chi2 at runs where the model is within the noise, E is not
    unmodelled_runs: Array  # (H+1,) int, those runs
    resonance_rpm: float  # speed of the model's 1X peak; NaN when the peak is at the edge of the range
    band_rpm: tuple  # (lo, hi) speed range of the half-power band
    band_share: float  # share of chi2 in the runs of that band
    band_fraction: float  # share of the runs in it
    alpha: float

    @property
    def dominant(self) -> int:
        """The harmonic holding the largest share of chi^2."""
        return int(np.nanargmax(self.harmonic_share))

    @property
    def whirl(self) -> list[str]:
        """Per harmonic: "forward", "backward", "mixed", "noise" (not significant) or "" (DC)."""
        out = []
        for h, f, sig in zip(self.harmonics, self.forward, self.significant):
            out.append("" if h == 0 else "noise" if not sig or not np.isfinite(f) else
                       "forward" if f >= WHIRL else "backward" if f <= 1 - WHIRL else "mixed")
        return out

    def table(self) -> pd.DataFrame:
        """Long table: scope ("all", "run", "harmonic"), key (run name, harmonic), quantity, value (float)."""
        rows = [("all", "", q, float(v)) for q, v in zip(_ALL, (self.chi2, self.dof, self.resonance_rpm,
                                                                 *self.band_rpm, self.band_share,
                                                                 self.band_fraction, self.alpha))]
        for r, name in enumerate(self.runs):
            rows += [("run", name, q, float(v)) for q, v in (("rpm", self.rpm[r]),
                                                             ("eccentric_mass_g", self.eccentric_mass_g[r]),
                                                             ("share", self.run_share[r]))]
        for i, h in enumerate(self.harmonics):
            values = {q: getattr(self, q)[i] for q in _HARMONIC if not q.startswith(("share", "coefficient"))}
            values.update(share=self.harmonic_share[i], coefficient_re=self.coefficient[i].real,
                          coefficient_im=self.coefficient[i].imag)
            rows += [("harmonic", str(int(h)), q, float(values[q])) for q in _HARMONIC]
        return pd.DataFrame(rows, columns=FINGERPRINT.columns)

    @classmethod
    def from_table(cls, table: pd.DataFrame) -> Fingerprint:
        """The exact inverse of ``table()``."""
        scalar = table[table["scope"] == "all"].set_index("quantity")["value"]
        runs = table[table["scope"] == "run"]
        names = list(dict.fromkeys(runs["key"]))
        run = runs.pivot(index="key", columns="quantity", values="value").loc[names]
        hs = table[table["scope"] == "harmonic"]
        harm = hs.pivot(index="key", columns="quantity", values="value")
        harm = harm.loc[sorted(harm.index, key=int)]
        col = {q: harm[q].to_numpy(float) for q in _HARMONIC}
        kw = {q: col[q] for q in _HARMONIC if not q.startswith("coefficient")}
        kw["significant"] = col["significant"].astype(bool)
        for q in ("growth_runs", "unmodelled_runs"):
            kw[q] = col[q].astype(int)
        return cls(runs=names, rpm=run["rpm"].to_numpy(float), eccentric_mass_g=run["eccentric_mass_g"].to_numpy(float),
                   harmonics=np.array([int(k) for k in harm.index]), chi2=float(scalar["chi2"]),
                   dof=int(scalar["dof"]), run_share=run["share"].to_numpy(float), harmonic_share=kw.pop("share"),
                   coefficient=col["coefficient_re"] + 1j * col["coefficient_im"],
                   resonance_rpm=float(scalar["resonance_rpm"]),
                   band_rpm=(float(scalar["band_lo_rpm"]), float(scalar["band_hi_rpm"])),
                   band_share=float(scalar["band_share"]), band_fraction=float(scalar["band_fraction"]),
                   alpha=float(scalar["alpha"]), **kw)

    def summary(self) -> str:
        """3-6 plain sentences: where the residual sits, how it whirls, its phase, growth and harmonics."""
        excess = self.chi2 / max(self.dof, 1)
        if not self.significant.any():
            return (f"The residual is within the measurement noise (chi^2 {_num(self.chi2)} over {self.dof} "
                    f"numbers, {excess:.2g} times the noise expectation): there is nothing to fingerprint.")
        h = self.dominant
        order = [k for k in np.argsort(-self.harmonic_share) if self.harmonic_share[k] >= 0.05][:3]
        where = ", ".join(f"{_name(k)} ({_pct(self.harmonic_share[k])})" for k in order)
        top = [r for r in np.argsort(-self.run_share)[:3] if self.run_share[r] >= 0.1]
        s = [f"The residual carries {_num(excess)} times the energy the measurement noise alone would give "
             f"(chi^2 {_num(self.chi2)} over {self.dof} numbers) and sits at {where}"
             + ("; the largest runs are " + ", ".join(f"run {self.runs[r]} ({self.rpm[r]:.0f} RPM, "
                                                      f"{_pct(self.run_share[r])})" for r in top) if top else "")
             + "."]
        if np.isfinite(self.resonance_rpm) and self.band_fraction < 1:
            lo, hi = self.band_rpm
            near = self.band_share >= max(0.5, 1.5 * self.band_fraction)
            s.append(f"{'It concentrates near' if near else 'It does not concentrate at'} the model's resonance "
                     f"({self.resonance_rpm:.0f} RPM): the runs at {lo:.0f}-{hi:.0f} RPM, where the modelled 1X "
                     f"response is above 71 % of its peak, hold {_pct(self.band_share)} of it "
                     f"({_pct(self.band_fraction)} of the runs).")
        w = self.whirl[h]
        if w in ("forward", "backward", "mixed"):
            f = self.forward[h]
            s.append(f"At {_name(h)} it whirls " + {"forward": f"forward, with the rotor ({_pct(f)} of its energy)",
                                                     "backward": f"backward, against the rotor ({_pct(1 - f)} of "
                                                                 f"its energy)",
                                                     "mixed": f"both ways (an elliptical or straight-line orbit, "
                                                              f"{_pct(f)} forward)"}[w] + ".")
        if np.isfinite(self.in_phase[h]):
            p, c = self.in_phase[h], self.coefficient[h]
            kind = ("stiffness-like (along the displacement" if p >= 0.5 else
                    "damping-like (along the velocity, 90 degrees from the displacement")
            text = f"Against the model's {_name(h)} response it is mostly {kind}, {_pct(max(p, 1 - p))})"
            if self.coherence[h] >= 0.5:
                text += (f"; a scaled, rotated copy of the model explains {_pct(self.coherence[h])} of it: the "
                         f"measurement is {abs(1 + c):.3g} times the model and " + (
                             "in phase with it" if abs(np.degrees(np.angle(1 + c))) < 1 else
                             f"{'leads' if np.angle(1 + c) > 0 else 'lags'} it by "
                             f"{abs(np.degrees(np.angle(1 + c))):.0f} degrees"))
            s.append(text + ".")
        if self.growth_runs[h] >= 3 and np.isfinite(self.speed_slope[h]):
            v, e = self.speed_slope[h], self.speed_slope_se[h]
            law = ("follows no single power of the speed" if e > 0.5 else "stays roughly constant with speed"
                   if abs(v) < max(0.3, 2 * e) else f"{'grows' if v > 0 else 'falls'} like Omega^{v:.1f}")
            text = (f"Over the {self.growth_runs[h]} runs where it is significant its amplitude {law} "
                    f"(log-log slope {v:.2f} +- {e:.2f}; an unbalance force grows like Omega^2)")
            if np.isfinite(self.response_slope[h]):
                text += (f" and like |model|^{self.response_slope[h]:.2f} +- {self.response_slope_se[h]:.2f} "
                         "(1: proportional to the modelled response)")
            s.append(text + ".")
        missing = [k for k in range(1, len(self.harmonics)) if self.unmodelled_share[k] >= 0.05]
        if missing:
            s.append("The model is within the noise where the measurement is not at " + ", ".join(
                f"{_name(k)} (in {self.unmodelled_runs[k]} runs, holding {_pct(self.unmodelled_share[k])} of the "
                "residual)" for k in missing) + ": an excitation or a nonlinearity the model lacks.")
        return " ".join(s)


#: a harmonic counts as present in a residual (``resembles``) when it is above the noise and holds at least this share
#: of the residual's chi^2: a percent, so a 1X misfit's round-off leaking into 2X does not pose as a fault's order
PRESENT_SHARE = 0.01


def _present(fp: Fingerprint, h: int) -> bool:
    return h < len(fp.harmonics) and bool(fp.significant[h]) and fp.harmonic_share[h] >= PRESENT_SHARE


def _one_x(fp: Fingerprint, sense: str) -> bool:
    """Whether the residual's 1X does what ``sense`` says (``faults.Signature.one_x``): held down or raised when the
    measured 1X is c M + M, c fitted (``coefficient``), and the amplitude's change |1 + c| - 1 is at least half of
    |c| (mostly a change of size, not of phase)."""
    changed = _present(fp, 1)
    c = fp.coefficient[1] if len(fp.harmonics) > 1 else np.nan
    size = abs(1 + c) - 1 if changed and np.isfinite(c) else 0.0
    mostly = changed and abs(size) >= 0.5 * abs(c)
    return {"any": True, "changed": changed, "unchanged": not changed,
            "held down": mostly and size < 0, "raised": mostly and size > 0}[sense]


def resembles(fp: Fingerprint, signatures=None) -> tuple[list[str], str]:
    """Which fault families the residual resembles, best first, and the words for what it shows.

    ``signatures``: the faults' (``faults.Signature``; default those of ``faults.FAULTS``). A family is a candidate
    when every order it needs beyond 1X that the data hold is present (above the noise and at least
    ``PRESENT_SHARE`` of the residual; a form needing none the data hold is no candidate);
    those with the fewest of their other marks failing (an order they must not have present, their 1X doing
    otherwise) are named, all of them when tied. None when the residual is within the noise or no family's orders are in
    it (a 1X-only change: the unbalance, a bearing, a support; the score tests name those)."""
    signatures = [s for f in FAULTS for s in f.signatures] if signatures is None else list(signatures)
    if not fp.significant.any():
        return [], ""
    held = len(fp.harmonics) - 1  # the data's highest harmonic
    scored = []
    for sig in signatures:
        needed = [h for h in sig.with_orders if h <= held]
        if not needed or not all(_present(fp, h) for h in needed):
            continue
        marks = [not _present(fp, h) for h in sig.without_orders if h <= held] + [_one_x(fp, sig.one_x)]
        scored.append((marks.count(False), sig.family))
    orders = [_name(h) for h in range(2, len(fp.harmonics)) if _present(fp, h)]
    words = (", ".join(orders[:-1]) + " and " + orders[-1] if len(orders) > 1 else "".join(orders)) + (
        " above the noise" if orders else "no order beyond 1X")
    if _present(fp, 1) and np.isfinite(fp.coefficient[1]) and fp.coherence[1] > 0:
        # |E| / |M| over the 1X (noise-weighted): |c| / sqrt(coherence), c = <E, M> / <M, M>
        size = abs(fp.coefficient[1]) / np.sqrt(fp.coherence[1])
        sense = " held down" if _one_x(fp, "held down") else " raised" if _one_x(fp, "raised") else ""
        words += f" with a 1X change of {100 * size:.2g} % of the model's 1X{sense and ','}{sense}"
    elif _present(fp, 1):
        words += " with a 1X change"
    elif orders:
        words += ", the 1X unchanged"
    if not scored:
        return [], words
    fewest = min(failed for failed, _ in scored)
    named = list(dict.fromkeys(family for failed, family in scored if failed == fewest))
    return named, words


def _name(h: int) -> str:
    return "DC" if h == 0 else f"{h}X"


def _num(x: float) -> str:
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def chi2_sf(x: float, dof: int) -> float:
    """P(chi^2(dof) > x) for an even dof (pairs of real and imaginary parts): exp(-x/2) sum_{i<dof/2} (x/2)^i/i!."""
    if dof % 2:
        raise ValueError(f"chi2_sf needs an even dof, got {dof}")
    if dof <= 0:
        return 1.0
    if x <= 0:
        return 1.0
    i = np.arange(dof // 2)
    terms = i * math.log(x / 2) - np.array([math.lgamma(k + 1) for k in i]) - x / 2
    return float(min(1.0, np.exp(np.logaddexp.reduce(terms))))


def _slope(x: Array, y: Array, w: Array, groups: Array | None = None) -> tuple[float, float]:
    """Weighted least-squares slope of y on x, one intercept per group: (slope, standard error)."""
    if len(x) < 3:
        return math.nan, math.nan
    groups = np.zeros(len(x)) if groups is None else groups
    xd, yd = x.astype(float).copy(), y.astype(float).copy()
    for g in np.unique(groups):
        m = groups == g
        xd[m] -= np.average(x[m], weights=w[m])
        yd[m] -= np.average(y[m], weights=w[m])
    sxx = float(np.sum(w * xd ** 2))
    if sxx <= 1e-12 * float(np.sum(w)):  # no speed spread within any group: pool the groups (if several)
        return _slope(x, y, w) if len(np.unique(groups)) > 1 else (math.nan, math.nan)
    slope = float(np.sum(w * xd * yd) / sxx)
    dof = len(x) - len(np.unique(groups)) - 1
    scale = max(1.0, float(np.sum(w * (yd - slope * xd) ** 2)) / dof) if dof > 0 else 1.0
    return slope, math.sqrt(scale / sxx)


def _check(measured, model, sigma, rpm, eccentric_mass_g, runs):
    measured, model = np.asarray(measured), np.asarray(model)
    if measured.ndim != 3 or measured.shape[2] < 2 or measured.shape[1] < 2 or measured.shape[0] < 1:
        raise ValueError(f"measured must be (runs, H+1, channels) with the first plane's x, y as channels 0, 1 and "
                         f"H >= 1, got shape {measured.shape}")
    if model.shape != measured.shape:
        raise ValueError(f"model has shape {model.shape}, measured {measured.shape}: they must match")
    for name, a in (("measured", measured), ("model", model)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} has non-finite entries")
    try:
        sigma = np.broadcast_to(np.asarray(sigma, float), measured.shape)
    except ValueError:
        raise ValueError(f"sigma of shape {np.shape(sigma)} does not broadcast to {measured.shape}") from None
    if np.any(np.isnan(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma must be positive (inf for an unused entry), found NaN or <= 0")
    R = measured.shape[0]
    rpm, mass = np.asarray(rpm, float).reshape(-1), np.asarray(eccentric_mass_g, float).reshape(-1)
    if rpm.shape != (R,) or not np.all(np.isfinite(rpm) & (rpm > 0)):
        raise ValueError(f"rpm must hold {R} positive finite speeds (one per run), got shape {rpm.shape}")
    if mass.shape != (R,) or not np.all(np.isfinite(mass)):
        raise ValueError(f"eccentric_mass_g must hold {R} finite masses (one per run), got shape {mass.shape}")
    runs = [str(r) for r in (range(R) if runs is None else runs)]
    if len(runs) != R or len(set(runs)) != R:
        raise ValueError(f"runs must hold {R} distinct names (one per run), got {len(runs)} ({len(set(runs))} "
                         "distinct)")
    return measured.astype(complex), model.astype(complex), sigma, rpm, mass, runs


def fingerprint(measured, model, sigma, rpm, eccentric_mass_g, runs=None, alpha: float = ALPHA,
                include_dc: bool = False) -> Fingerprint:
    """The fingerprint of E = measured - model (module docstring).

    measured, model: (R, H+1, C) complex [m], h = 0..H, channels x, y (C = 2, the VARM), or the machine's
    sensors with the first plane's x, y first (the whirl reads channels 0 and 1); sigma: broadcastable to it [m], the
    standard uncertainty of each real and imaginary part (inf: entry unused); rpm, eccentric_mass_g: (R,);
    runs: R distinct names (default "0".."R-1"); alpha: significance level of the noise tests.
    """
    X, M, sigma, rpm, mass, runs = _check(measured, model, sigma, rpm, eccentric_mass_g, runs)
    R, H1 = X.shape[:2]
    E = X - M
    used = np.isfinite(sigma)
    if not include_dc:
        used[:, 0] = False
    inv2 = np.where(used, 1.0 / np.where(used, sigma, 1.0) ** 2, 0.0)  # 1 / sigma^2, 0 where unused
    e2, m2 = np.abs(E) ** 2 * inv2, np.abs(M) ** 2 * inv2  # (R, H+1, 2)
    k = 2 * used.sum(2)  # (R, H+1) real numbers per run and harmonic
    chi_rh, dof = e2.sum(2), int(k.sum())
    chi2 = float(chi_rh.sum())
    total = chi2 if chi2 > 0 else 1.0
    sig_rh = np.array([[chi2_sf(chi_rh[r, h], k[r, h]) < alpha for h in range(H1)] for r in range(R)])
    model_on = np.array([[chi2_sf(m2[r, h].sum(), k[r, h]) < alpha for h in range(H1)] for r in range(R)])
    significant = np.array([chi2_sf(chi_rh[:, h].sum(), int(k[:, h].sum())) < alpha for h in range(H1)])

    Omega = 2 * np.pi * rpm / 60.0
    nan = np.full(H1, np.nan)
    forward, in_phase, coherence = nan.copy(), nan.copy(), nan.copy()
    coefficient = np.full(H1, np.nan + 0j)
    speed, speed_se, resp, resp_se = nan.copy(), nan.copy(), nan.copy(), nan.copy()
    growth_runs, unmod_runs, unmod_share = np.zeros(H1, int), np.zeros(H1, int), np.zeros(H1)
    for h in range(H1):
        if h >= 1:  # whirl: both channels of the first x, y pair (channels 0, 1) needed
            both = used[:, h, :2].all(1)
            w = np.where(both, 2.0 / np.where(both, sigma[:, h, 0] ** 2 + sigma[:, h, 1] ** 2, 1.0), 0.0)
            F, B = (E[:, h, 0] + 1j * E[:, h, 1]) / 2, (E[:, h, 0] - 1j * E[:, h, 1]) / 2
            f_ex = max(float(np.sum(w * np.abs(F) ** 2)) - both.sum(), 0.0)
            b_ex = max(float(np.sum(w * np.abs(B) ** 2)) - both.sum(), 0.0)
            forward[h] = f_ex / (f_ex + b_ex) if f_ex + b_ex > 0 else np.nan
        on = model_on[:, h, None] & used[:, h] & (np.abs(M[:, h]) > 0)  # entries with a response above the noise
        if on.any():
            Mh, Eh, ih = M[:, h][on], E[:, h][on], inv2[:, h][on]
            proj = Eh * np.conj(Mh) / np.abs(Mh)
            p_ex = max(float(np.sum(proj.real ** 2 * ih)) - on.sum(), 0.0)
            q_ex = max(float(np.sum(proj.imag ** 2 * ih)) - on.sum(), 0.0)
            in_phase[h] = p_ex / (p_ex + q_ex) if p_ex + q_ex > 0 else np.nan
            num, den = np.sum(Eh * np.conj(Mh) * ih), float(np.sum(np.abs(Mh) ** 2 * ih))
            coefficient[h] = num / den
            eh = float(np.sum(np.abs(Eh) ** 2 * ih))
            coherence[h] = abs(num) ** 2 / (den * eh) if eh > 0 else np.nan
        a_e = np.sqrt(np.sum(np.abs(E[:, h]) ** 2 * used[:, h], 1))
        a_m = np.sqrt(np.sum(np.abs(M[:, h]) ** 2 * used[:, h], 1))
        s2 = np.sum(np.where(used[:, h], sigma[:, h], 0) ** 2, 1) / np.maximum(used[:, h].sum(1), 1)
        g = sig_rh[:, h] & (a_e > 0)
        growth_runs[h] = g.sum()
        if g.sum() >= 3:
            w = a_e[g] ** 2 / s2[g]
            speed[h], speed_se[h] = _slope(np.log(Omega[g]), np.log(a_e[g]), w, mass[g])
            gm = a_m[g] > 0
            if gm.sum() >= 3:
                resp[h], resp_se[h] = _slope(np.log(a_m[g][gm]), np.log(a_e[g][gm]), w[gm])
        if h >= 1:
            miss = sig_rh[:, h] & ~model_on[:, h]
            unmod_runs[h], unmod_share[h] = miss.sum(), chi_rh[miss, h].sum() / total

    a1 = np.sqrt(np.sum(np.abs(M[:, 1]) ** 2, 1))
    peak = int(np.argmax(a1))
    inside = rpm.min() < rpm[peak] < rpm.max()
    band = a1 >= a1[peak] / np.sqrt(2)
    lo, hi = (float(rpm[band].min()), float(rpm[band].max())) if inside else (np.nan, np.nan)
    in_band = (rpm >= lo) & (rpm <= hi)
    return Fingerprint(runs=runs, rpm=rpm, eccentric_mass_g=mass, harmonics=np.arange(H1), chi2=chi2, dof=dof,
                       run_share=chi_rh.sum(1) / total, harmonic_share=chi_rh.sum(0) / total, significant=significant,
                       forward=forward, in_phase=in_phase, coefficient=coefficient, coherence=coherence,
                       speed_slope=speed, speed_slope_se=speed_se, response_slope=resp, response_slope_se=resp_se,
                       growth_runs=growth_runs, unmodelled_share=unmod_share, unmodelled_runs=unmod_runs,
                       resonance_rpm=float(rpm[peak]) if inside else np.nan, band_rpm=(lo, hi),
                       band_share=float(chi_rh[in_band].sum() / total) if inside else np.nan,
                       band_fraction=float(in_band.mean()) if inside else np.nan, alpha=float(alpha))
