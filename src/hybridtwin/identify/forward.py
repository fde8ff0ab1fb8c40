"""Forward models: a run's sensor harmonics h = 1..H as a function of the unknown parameters.

Two kinds share one interface (``HarmonicModel``: ``parameters``, ``lower``,
``upper``, ``H``, ``evaluate(x (N, d), jacobian)`` -> M (N, H, C) complex [m]
and dM/dx (N, H, C, d), x the parameters normalised to [-1, 1], C the machine's
sensors in the machine's order, ``sensor.sensor_dofs``: x, y on the VARM):

- ``SensorSurrogate``: a run's sPGD library (microseconds per evaluation,
  exact Jacobian of the surrogate);
- ``SolverModel``: the full harmonic-balance solver (no surrogate error).

Used by the identification, its full-solver polish, the validation
predictions and the diagnosis.

Stability: the LM iterations solve without the Floquet check (``stability=False``,
30-40 % of a solve saved per evaluation); the steady states a fit reports are
checked afterwards (``floquet_radii``, ``SolverModel.floquet_radius``;
``check_stability`` for a fit's optimum: an unstable one is flagged on the fit
and warned about, never reported as a plain converged fit).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..model.effects import trial_mass_values
from ..model.sensor import sensor_channels, sensor_dofs
from ..offline.library import Library
from ..offline.pod import feature_index
from ..solvers.continuation import RUN_UP_FROM_RPM, padded_speeds, ramp, sweep_model
from ..solvers.solver import SteadyState, assess_stability, sensitivity, solve
from ..solvers.resolution import needed_harmonics
from ..solvers.sweep_forward import swept_response

Array = np.ndarray

class HarmonicModel(Protocol):
    """A run's sensor harmonics h = 1..H as a function of its parameters normalised to [-1, 1]."""

    parameters: list[str]
    lower: Array
    upper: Array
    H: int

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """x (N, d) -> M (N, H, C) complex [m] and dM/dx (N, H, C, d)."""


class SensorSurrogate:
    """A library's sensor harmonics h = 1..H and exact derivatives, evaluated for many trials at once.

    Same numbers as ``Library.sensor`` (the sPGD of eq. 6-7 on the POD basis,
    projected on the sensor DOFs once): y = (prod_j F_j(x_j)) A_s with
    A_s = amplitudes Phi_sensor^T, evaluated by ``SparsePGD.evaluate``, here in
    normalised coordinates and without the mean (h = 0).
    """

    def __init__(self, library: Library, harmonics: int | None = None):
        H_lib = library.n_harmonics - 1
        self.H = H_lib if harmonics is None else min(int(harmonics), H_lib)
        if self.H < 1:
            raise ValueError(f"library {library.run} has no harmonic h >= 1")
        h = np.arange(1, self.H + 1)
        rows = [feature_index(h, dof, library.n_harmonics, library.n_dof, imaginary)
                for imaginary in (False, True) for dof in library.sensor_dofs]
        self.C = len(library.sensor_dofs)  # channels: the sensors (x, y on the VARM)
        sensor_modes = library.modes[np.concatenate(rows)]  # (2CH, m): Re of each sensor, then Im of each
        self.model = library.model.projected(sensor_modes.T)  # outputs Re x, Re y, Im x, Im y (2CH)
        self.parameters = list(library.parameters)
        self.lower, self.upper = np.asarray(library.lower, float), np.asarray(library.upper, float)
        self.run = library.run

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """M (N, H, C) complex and dM/dx (N, H, C, d) at normalised x (N, d) in [-1, 1]."""
        x = np.clip(np.atleast_2d(x), -1.0, 1.0)
        y, J = self.model.evaluate(x, jacobian=jacobian)
        if not jacobian:
            return self._complex(y), None
        N, d = x.shape
        out = self._complex(J.reshape(d * N, -1)).reshape(d, N, self.H, self.C)
        return self._complex(y), np.moveaxis(out, 0, -1)

    def _complex(self, features: Array) -> Array:
        """(N, 2CH) [Re x, Re y, Im x, Im y] -> (N, H, C) complex."""
        parts = features.reshape(features.shape[0], 2, self.C, self.H)  # (N, Re/Im, channel, h)
        return np.swapaxes(parts[:, 0] + 1j * parts[:, 1], 1, 2)



def run_up(variant, rpm: Sequence[float], values: Mapping[str, Array | float], harmonics: int,
           start_rpm: float = RUN_UP_FROM_RPM, step_rpm: float = 50.0, jumps: bool = False) -> list:
    """Steady states of S parameter sets at each of ``rpm``, reached by one run-up from ``start_rpm``.

    values: parameter values [SI], scalars or (S,) arrays, m_e included (unlike
    ``scenarios.solve_runs``, which sets m_e from the run plan, an unknown m_e
    keeps each set's own value). Steps between speeds are at most ``step_rpm``
    (the offline stage's run-up). Returns the ``SteadyState`` at each of ``rpm``;
    with ``jumps``, also (S,) flags: True for a set whose run-up jumped between
    branches at any step up to the highest of ``rpm`` (a fold crossed on the way).
    """
    base = variant.values(values)
    S = max(np.size(v) for v in base.values())
    arrays = {k: np.broadcast_to(np.asarray(v, float), (S,)) for k, v in base.items()}
    targets = np.asarray(rpm, float)
    grid = ramp(min(start_rpm, targets.min()), targets, step_rpm)
    # stability=False: the fits use the response only (as before the Floquet check, which would add ~30-40 %)
    sweep, _ = sweep_model(variant.model, arrays, grid, S, harmonics)
    by_rpm = dict(zip(sweep.rpm, sweep.results))
    states = [by_rpm[r] for r in targets]
    if not jumps:
        return states
    jumped = np.zeros(S, bool)
    for speed, result in zip(sweep.rpm, sweep.results):
        if speed <= targets.max():
            jumped |= np.array(["jump" in str(b) for b in result.branch])
    return states, jumped


def run_ups(variant, rpm: Array, values: Mapping[str, Array], harmonics: int, start_rpm: float = RUN_UP_FROM_RPM,
            step_rpm: float = 50.0, down_from_rpm: Array | None = None) -> tuple:
    """Steady states of S parameter sets, set s at its own speed ``rpm[s]``, each reached by its own run-up
    from ``start_rpm`` as in ``run_up`` (the same speed steps, so the same states), all solved in lockstep
    (``solve_sweep`` with per-scenario speeds): one batched sweep instead of one per run.

    down_from_rpm: (S,) where finite, set s is reached by a run-down from that speed instead (a coast-down's band:
    the branch the rotor follows coming down, which differs from the run-up's where both are stable near a
    nonlinear resonance), in steps of at most ``step_rpm``; the run-downs solved in one lockstep sweep of their own.

    values: complete parameter values [SI], each (S,). Returns the ``SteadyState`` of the S sets and (S,)
    flags: True for a set whose sweep jumped between branches on the way (a fold crossed)."""
    rpm = np.asarray(rpm, float)
    S = rpm.size
    values = {k: np.broadcast_to(np.asarray(v, float), (S,)) for k, v in values.items()}
    down = np.zeros(S, bool) if down_from_rpm is None else np.isfinite(np.asarray(down_from_rpm, float))
    jumped = np.zeros(S, bool)
    parts, order = [], []
    for going_down in (False, True):
        sets = np.flatnonzero(down == going_down)
        if not sets.size:
            continue
        if going_down:
            tops = np.asarray(down_from_rpm, float)[sets]
            ramps = [ramp(max(top, r), [r], step_rpm)[::-1] for r, top in zip(rpm[sets], tops)]
        else:
            ramps = [ramp(min(start_rpm, r), [r], step_rpm) for r in rpm[sets]]
        states, jump = _lockstep(variant, ramps, {k: v[sets] for k, v in values.items()}, harmonics,
                                 "down" if going_down else "up")
        parts.append(states)
        order.append(sets)
        jumped[sets] = jump
    return SteadyState.concatenate(parts, np.argsort(np.concatenate(order))), jumped


def _lockstep(variant, ramps: Sequence[Array], values: Mapping[str, Array], harmonics: int, direction: str) -> tuple:
    """Each set's sweep along its own ramp (speeds in sweep order), all in one ``solve_sweep``: the last step's
    states in the sets' order and (S,) flags of a jump on the way."""
    S = len(ramps)
    sweep, _ = sweep_model(variant.model, dict(values), padded_speeds(ramps), S, harmonics, direction)
    last = np.array([len(r) for r in ramps]) - 1
    jumped = np.zeros(S, bool)
    parts, order = [], []
    for step, result in enumerate(sweep.results):
        active = np.flatnonzero(last >= step)
        jumped[active] |= np.array(["jump" in str(result.branch[a]) for a in active], bool)
        here = np.flatnonzero(last == step)
        if here.size:
            parts.append(result.take(here))
            order.append(here)
    return SteadyState.concatenate(parts, np.argsort(np.concatenate(order))), jumped


#: the speed [RPM] at which a slow-roll compensated model's own runout is read (``SolverModel``): low enough that a
#: response growing as Omega^2 is 1e-5 of its value at 1000 RPM, the Omega -> 0 limit the data's estimate takes
SLOW_ROLL_RPM = 3.0
#: a warm start is kept when Newton's solution lies within this fraction of the predicted change of the
#: condensed state (plus ``WARM_FLOOR`` of its size) from the predictor: a solution farther away means the
#: continuation in the parameters left the branch the run-up reaches (a fold in between)
WARM_TOLERANCE = 0.25
WARM_FLOOR = 1e-3
#: steady states kept for warm starts per model (a few LM trials' worth of iterates)
CACHE_SIZE = 256
#: the assembly's central-difference step of the analytic sensitivities, as a fraction of each range
#: (``solver.sensitivity``: exact for parameters entering linearly; smaller steps meet round-off)
SENSITIVITY_STEP = 1e-4


class SolverModel:
    """A run's sensor harmonics from the full harmonic-balance solver.

    Same interface as ``SensorSurrogate``: evaluate(x (N, d)) -> M (N, H, C), dM/dx (N, H, C, d), C the
    machine's sensors (``sensor.sensor_dofs``).
    The response at a parameter set is the steady state a run-up from 300 RPM reaches (the rig's
    history, ``run_up``), or, with ``sweep_from_rpm`` (a coast-down's band, ``RunData.sweep_from_rpm``), the one a
    run-down from that speed reaches. Two things make repeated evaluations (an LM's iterates) cheap:

    - warm starts (``warm``): a set close to one solved before continues from it, Newton started at
      the first-order predictor x_old + dx/dp (p - p_old) (the condensed state's sensitivity), no
      run-up. The continued solution is kept only if Newton converges within ``WARM_TOLERANCE`` of
      the predicted change and the earlier set's run-up never jumped between branches; otherwise
      (a fold in between, a lost branch) the set is solved by a run-up as before;
    - analytic sensitivities (``analytic``): dM/dp of the converged steady state by the implicit
      function theorem (``solver.sensitivity``), one linear solve per set for all parameters,
      instead of d forward-difference solves (``analytic=False``: forward differences of step
      ``step`` in normalised units, the former method).

    m_e is the run's eccentric mass unless it is one of the parameters. Counters: ``n_solves``
    sets solved, ``n_warm`` of them by a warm start, ``n_run_ups`` by a run-up.

    ``slow_roll_harmonics`` (a speed band of a transient record whose slow-roll runout was subtracted,
    ``RunData.slow_roll_harmonics``): the model is compensated as the data were, its own response at slow roll
    (at SLOW_ROLL_RPM, the Omega -> 0 limit the data's runout estimate extrapolates to) subtracted from those
    harmonics. A response that does not vanish at slow roll (the static deflection under a 2X force of constant
    amplitude) is then removed from model and data alike; forces growing as Omega^2 (unbalance, bow) have none.

    ``sweep_rpm_s`` (a run-up's or coast-down's band, ``RunData.sweep_rpm_s``): the response is the swept one, the
    steady state corrected to first order in the sweep rate (``hybridtwin.solvers.sweep_forward``: the lag and
    flattening near a resonance), its parameter derivative by forward differences of the correction along the
    steady state's own sensitivities (``_swept``). 0: the steady state (a steady run; a band fitted quasi-steadily).

    ``evaluate`` does not assess stability (the LM needs the response only); ``floquet_radius(x)``
    does, for the states ``evaluate`` reports at x (``check_stability``: a fit's optimum).
    """

    def __init__(self, variant, run: str, rpm: float, eccentric_mass_g: float, parameters: Sequence[str],
                 lower: Array, upper: Array, harmonics: int, step: float = 1e-5, *, warm: bool = True,
                 analytic: bool = True, cache_size: int = CACHE_SIZE, slow_roll_harmonics: Sequence[int] = (),
                 sweep_from_rpm: float | None = None, eccentric_mass_angle_deg: float = 0.0,
                 sweep_rpm_s: float = 0.0, resolve: bool = True):
        self.variant, self.run = variant, run
        # the band's sweep rate [RPM/s, signed]: the response corrected for it to first order (``_swept``); 0: steady
        self.sweep_rpm_s = float(sweep_rpm_s) if np.isfinite(sweep_rpm_s) else 0.0
        # None: the run-up from RUN_UP_FROM_RPM; a speed: the run-down from there (a coast-down's band)
        self.sweep_from_rpm = None if sweep_from_rpm is None or not np.isfinite(sweep_from_rpm) else float(sweep_from_rpm)
        self.rpm, self.eccentric_mass_g = float(rpm), float(eccentric_mass_g)
        # the trial mass's angle [deg] (its force turned by it, model.effects.trial_mass_values); 0: on +x
        self.eccentric_mass_angle_deg = float(eccentric_mass_angle_deg)
        self.parameters = list(parameters)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        # H: the harmonics compared (the data's); harmonics: those the harmonic balance carries, more where an effect
        # is non-smooth and declares them (a rub: ``resolution.needed_harmonics``), its 1X..HX then resolved;
        # ``resolve`` False: the data's only (the score tests, where every candidate is absent)
        self.H = int(harmonics)
        self.harmonics = needed_harmonics(variant.model.effects, self.H) if resolve and variant is not None else self.H
        self.step = float(step)
        self.warm, self.analytic, self.cache_size = bool(warm), bool(analytic), int(cache_size)
        self.n_solves = self.n_warm = self.n_run_ups = 0
        d = len(self.parameters)
        self._x = np.zeros((0, d))  # cached normalised points, their condensed states and derivatives
        self._state = None
        self._dstate = None
        self.slow_roll_harmonics = tuple(h for h in slow_roll_harmonics if 1 <= h <= self.H)
        self.reference = None  # the same model at slow roll, subtracted from the slow-roll harmonics
        if self.slow_roll_harmonics:
            self.reference = SolverModel(variant, f"{run} at slow roll", SLOW_ROLL_RPM, eccentric_mass_g, parameters,
                                         lower, upper, harmonics, step, warm=warm, analytic=analytic,
                                         cache_size=cache_size, eccentric_mass_angle_deg=eccentric_mass_angle_deg)

    @classmethod
    def for_data(cls, variant, data, parameters: Sequence[str], lower: Array, upper: Array, harmonics: int,
                 **options) -> "SolverModel":
        """The model of one run of ``data`` (``measured.RunData``): its speed and eccentric mass at its angle,
        compensated for slow roll and swept as its record was (a transient band's ``slow_roll_harmonics`` and
        ``sweep_from_rpm``)."""
        return cls(variant, data.run, data.rpm, data.eccentric_mass_g, parameters, lower, upper, harmonics,
                   slow_roll_harmonics=data.slow_roll_harmonics, sweep_from_rpm=data.sweep_from_rpm,
                   eccentric_mass_angle_deg=data.eccentric_mass_angle_deg,
                   sweep_rpm_s=getattr(data, "sweep_rpm_s", 0.0), **options)

    # --- parameter values and systems -------------------------------------------------------

    @property
    def half_range(self) -> Array:
        """dp/dx [SI per normalised unit] of each parameter."""
        return 0.5 * (self.upper - self.lower)

    def _values(self, x: Array) -> dict[str, Array]:
        """Complete parameter values [SI], each (N,), at normalised x (N, d)."""
        values = trial_mass_values(self.eccentric_mass_g, self.eccentric_mass_angle_deg)
        values |= {p: self.lower[j] + (x[:, j] + 1) * self.half_range[j] for j, p in enumerate(self.parameters)}
        base = self.variant.values(values)
        return {k: np.broadcast_to(np.asarray(v, float), (x.shape[0],)).copy() for k, v in base.items()}

    # --- solves -------------------------------------------------------------------------------

    def _remember(self, x: Array, result, dstate: Array, jumped: Array) -> None:
        """Cache the converged sets whose run-up never jumped (warm starts continue only on that branch)."""
        keep = result.success & ~jumped & np.isfinite(dstate).reshape(len(x), -1).all(1)
        if not keep.any():
            return
        if self._state is None:
            self._state, self._dstate = result.state[keep], dstate[keep]
        else:
            self._state = np.concatenate([self._state, result.state[keep]])[-self.cache_size:]
            self._dstate = np.concatenate([self._dstate, dstate[keep]])[-self.cache_size:]
        self._x = np.concatenate([self._x, x[keep]])[-self.cache_size:]

    @property
    def C(self) -> int:
        """Channels: the machine's sensors (x, y on the VARM)."""
        return len(sensor_dofs(self.variant.model.shaft))

    def _sensor(self, harmonics: Array) -> Array:
        """Every sensor's harmonics h = 1..H (..., H, C) from full harmonics (..., H+1, n)."""
        return sensor_channels(harmonics, self.variant.model.shaft)[..., 1:self.H + 1, :]

    def _solve(self, x: Array) -> Array:
        """Sensor harmonics (N, H, C) at normalised x (N, d) by the run-up alone (the differences' path)."""
        values = self._values(x)
        if self.sweep_from_rpm is None:
            result = run_up(self.variant, [self.rpm], values, self.harmonics)[0]
        else:
            result = run_ups(self.variant, np.full(x.shape[0], self.rpm), values, self.harmonics,
                             down_from_rpm=np.full(x.shape[0], self.sweep_from_rpm))[0]
        self.n_solves += x.shape[0]
        self.n_run_ups += x.shape[0]
        M = self._sensor(result.harmonics)
        M[~result.success] = np.nan
        ok = np.flatnonzero(result.success)
        if self.sweep_rpm_s and ok.size:
            M[ok] += self._sensor(swept_response(self.variant.model, {k: v[ok] for k, v in values.items()},
                                                 np.full(ok.size, self.rpm), self.sweep_rpm_s,
                                                 result.state[ok], self.harmonics, result.n_time).correction)
        return M

    def evaluate(self, x: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
        """M (N, H, C) complex [m] and dM/dx (N, H, C, d) at normalised x (N, d); NaN where there is no
        steady state (or x is NaN)."""
        x = np.atleast_2d(np.asarray(x, float))
        N, d = x.shape
        finite = np.flatnonzero(np.isfinite(x).all(axis=1))
        if finite.size == 0:
            return (np.full((N, self.H, self.C), np.nan + 0j),
                    np.full((N, self.H, self.C, d), np.nan + 0j) if jacobian else None)
        if self.analytic:  # the batched path with one run: warm starts and exact sensitivities
            return SolverModel.evaluate_together([self], [x], jacobian)[0]
        M_finite, J = self._differences(x[finite], jacobian)
        M = np.full((N, self.H, M_finite.shape[2]), np.nan + 0j)
        M[finite] = M_finite
        dM = None
        if jacobian:
            dM = np.full((N, self.H, M_finite.shape[2], d), np.nan + 0j)
            dM[finite] = J
        if self.reference is not None:
            self._compensate(M, dM, *self.reference.evaluate(x, jacobian))
        return M, dM

    def _compensate(self, M: Array, dM: Array | None, M_ref: Array, dM_ref: Array | None) -> None:
        """Subtract the slow-roll reference's response from the slow-roll harmonics, in place."""
        h = np.array(self.slow_roll_harmonics) - 1
        M[:, h] -= M_ref[:, h]
        if dM is not None and dM_ref is not None:
            dM[:, h] -= dM_ref[:, h]

    def floquet_radius(self, x: Array) -> Array:
        """The largest |Floquet multiplier| (N,) of the steady states ``evaluate(x)`` reports at normalised x
        (N, d): the same states (warm start from the cache or run-up), each checked once (``floquet_radii``).
        Below 1: stable; NaN where there is no steady state."""
        return floquet_radii([self], [x])[0]

    @staticmethod
    def evaluate_together(models: Sequence["SolverModel"], xs: Sequence[Array], jacobian: bool = True
                          ) -> list[tuple[Array, Array | None]]:
        """``evaluate`` of several runs' models (one variant, same parameters, analytic) in one batched solve
        and one sensitivity call (``evaluate_runs``)."""
        first = models[0]
        H, d, C = first.H, len(first.parameters), first.C
        batch = SolverModel.steady_states(models, xs)
        if batch is None:  # no finite parameter set at all
            return [(np.full((x.shape[0], H, C), np.nan + 0j),
                     np.full((x.shape[0], H, C, d), np.nan + 0j) if jacobian else None) for x in _as_2d(xs)]
        result, values, rpm, offsets = batch.result, batch.values, batch.rpm, batch.offsets
        S = result.n_scenarios
        M_all = first._sensor(result.harmonics)
        M_all[~result.success] = np.nan
        if jacobian:
            # the sensitivity drops failed sets from the values it assembles: build at the speeds of the others
            ok = np.flatnonzero(result.success)
            steps = SENSITIVITY_STEP * (first.upper - first.lower)
            dQ_ok, dstate_ok = sensitivity(lambda v: batch.build(v, rpm[ok]), {k_: v[ok] for k_, v in values.items()},
                                           first.parameters, result.take(ok), steps,
                                           condensed=True)
            dQ = np.full((S,) + dQ_ok.shape[1:], np.nan + 0j)
            dstate = np.full((S,) + dstate_ok.shape[1:], np.nan)
            dQ[ok], dstate[ok] = dQ_ok, dstate_ok
            dM_all = np.moveaxis(first._sensor(dQ) * first.half_range[None, :, None, None], 1, -1)
        rate = np.concatenate([np.full(r.size, m.sweep_rpm_s) for m, r in zip(models, batch.rows)])
        swept = np.flatnonzero(result.success & (rate != 0.0))
        if swept.size:
            M1, dM1 = _swept(first, batch, rate, swept, dstate if jacobian else None)
            M_all[swept] += M1
            if jacobian:
                dM_all[swept] += dM1
        out = []
        for k, (m, x, r) in enumerate(zip(models, batch.xs, batch.rows)):
            sl = slice(offsets[k], offsets[k + 1])
            M = np.full((x.shape[0], H, C), np.nan + 0j)
            M[r] = M_all[sl]
            dM = None
            if jacobian:
                dM = np.full((x.shape[0], H, C, d), np.nan + 0j)
                dM[r] = dM_all[sl]
                if m.warm and r.size:
                    own = result.take(np.arange(offsets[k], offsets[k + 1]))
                    m._remember(x[r], own, dstate[sl], batch.jumped[sl])
            out.append((M, dM))
        compensated = [k for k, m in enumerate(models) if m.reference is not None]
        if compensated:  # the slow-roll references, solved together too; the bands of one record share theirs
            # (the same mass at the same parameters: one 3-RPM state), so each distinct one is solved once
            key = {k: (models[k].eccentric_mass_g, batch.xs[k].tobytes()) for k in compensated}
            first = list({key[k]: k for k in reversed(compensated)}.values())
            solved = SolverModel.evaluate_together([models[k].reference for k in first],
                                                   [batch.xs[k] for k in first], jacobian)
            by_key = {key[k]: value for k, value in zip(first, solved)}
            for k in compensated:
                models[k]._compensate(*out[k], *by_key[key[k]])
        return out

    @staticmethod
    def steady_states(models: Sequence["SolverModel"], xs: Sequence[Array]) -> "_Batch | None":
        """The steady states ``evaluate_together`` reports at xs (each model's finite rows, stacked run after
        run): warm starts where a cached neighbour allows, run-ups for the others; None if no row is finite.
        Their stability is not assessed (``stability=False``: the LM iterations need the response only)."""
        first = models[0]
        H = first.harmonics
        xs = _as_2d(xs)
        rows = [np.flatnonzero(np.isfinite(x).all(axis=1)) for x in xs]
        counts = [r.size for r in rows]
        offsets = np.concatenate([[0], np.cumsum(counts)])
        values_k = [m._values(x[r]) for m, x, r in zip(models, xs, rows)]
        keys = list(values_k[0])
        values = {key: np.concatenate([v[key] for v in values_k]) for key in keys}
        rpm = np.concatenate([np.full(c, m.rpm) for m, c in zip(models, counts)])
        down_from = np.concatenate([np.full(c, np.nan if m.sweep_from_rpm is None else m.sweep_from_rpm)
                                    for m, c in zip(models, counts)])
        S = int(offsets[-1])

        def build_at(v: Mapping[str, Array], speeds: Array):
            """The systems of sets ``v`` (n,), n a multiple of len(speeds) (the sensitivity's stacked copies)."""
            n = max(np.size(a) for a in v.values())
            rest = first.variant.model.at_rest(v, n)
            return first.variant.model.system_at(rest, np.tile(speeds, n // speeds.size))

        # warm starts of every run in one solve, for the sets with a cached neighbour
        predicted, old, change = (np.full((S,) + _state_shape(models), np.nan) for _ in range(3))
        has_cache = np.zeros(S, bool)
        for k, (m, x, r) in enumerate(zip(models, xs, rows)):
            if m.warm and len(m._x) and r.size:
                sl = slice(offsets[k], offsets[k + 1])
                nearest = np.abs(x[r][:, None, :] - m._x[None]).max(-1).argmin(1)
                old[sl] = m._state[nearest]
                change[sl] = np.einsum("npcj,np->ncj", m._dstate[nearest], (x[r] - m._x[nearest]) * m.half_range)
                has_cache[sl] = True
        predicted = old + change
        kept = np.zeros(S, bool)
        parts, order = [], []
        if has_cache.any():
            where = np.flatnonzero(has_cache)
            result = solve(build_at({k_: v[where] for k_, v in values.items()}, rpm[where]), H,
                           initial=predicted[where], stall_window=8, stability=False)
            gap = np.linalg.norm((result.state - predicted[where]).reshape(where.size, -1), axis=1)
            allowed = (WARM_TOLERANCE * np.linalg.norm(change[where].reshape(where.size, -1), axis=1)
                       + WARM_FLOOR * np.linalg.norm(old[where].reshape(where.size, -1), axis=1))
            good = result.success & (gap <= allowed)
            kept[where[good]] = True
            if good.any():
                parts.append(result.take(np.flatnonzero(good)))
                order.append(where[good])
        jumped = np.zeros(S, bool)
        for k, m in enumerate(models):
            cold = np.flatnonzero(~kept[offsets[k]:offsets[k + 1]])
            m.n_solves += counts[k]
            m.n_warm += counts[k] - cold.size
            m.n_run_ups += cold.size
        cold = np.flatnonzero(~kept)
        if cold.size:  # every run's cold sets in one lockstep sweep, each on its own run's run-up
            states, jump = run_ups(first.variant, rpm[cold], {k_: v[cold] for k_, v in values.items()}, H,
                                   down_from_rpm=down_from[cold])
            parts.append(states)
            order.append(cold)
            jumped[cold] = jump
        if not parts:
            return None
        result = SteadyState.concatenate(parts, np.argsort(np.concatenate(order)))
        return _Batch(result, values, rpm, offsets, rows, xs, jumped, build_at)

    def _differences(self, x: Array, jacobian: bool) -> tuple[Array, Array | None]:
        """Forward differences of run-up solves (the method before the analytic sensitivities)."""
        N, d = x.shape
        if not jacobian:
            return self._solve(x), None
        steps = np.where(x + self.step <= 1.0, self.step, -self.step)  # (N, d), backwards at the upper bound
        shifted = np.repeat(x[:, None, :], d, axis=1)
        shifted[:, np.arange(d), np.arange(d)] += steps
        M_all = self._solve(np.concatenate([x, shifted.reshape(N * d, d)]))
        M = M_all[:N]
        M_shifted = M_all[N:].reshape(N, d, *M.shape[1:])
        # a shifted solve that fails (next to a fold, say) while the point itself solves: step the other way
        failed = ~np.isfinite(M_shifted).all(axis=(2, 3)) & np.isfinite(M).all(axis=(1, 2))[:, None]
        if failed.any():
            n, j = np.nonzero(failed)
            steps[n, j] = -steps[n, j]
            retry = x[n].copy()
            retry[np.arange(n.size), j] += steps[n, j]
            M_shifted[n, j] = self._solve(retry)
        dM = (M_shifted - M[:, None]) / steps[:, :, None, None]
        return M, np.moveaxis(dM, 1, -1)


def _swept(first: SolverModel, batch: "_Batch", rate: Array, rows: Array, dstate: Array | None
           ) -> tuple[Array, Array | None]:
    """The first-order sweep correction of the sensor harmonics (n, H, C) at the converged ``rows`` of ``batch``,
    each swept at ``rate`` [RPM/s] (``sweep_forward.swept_response``), and, given the condensed states' parameter
    sensitivities ``dstate`` (S, P, c, 2H+1), its derivative in the normalised parameters (n, H, C, d): forward
    differences of the correction, each parameter stepped by SENSITIVITY_STEP of its range and the state moved
    along its own sensitivity (no new steady state), all sets in one call."""
    result, n, P = batch.result, rows.size, len(first.parameters)
    values = {k: v[rows] for k, v in batch.values.items()}
    state = result.state[rows]
    if dstate is None:
        Q1 = swept_response(first.variant.model, values, batch.rpm[rows], rate[rows], state, first.harmonics,
                            result.n_time).correction
        return first._sensor(Q1), None
    steps = SENSITIVITY_STEP * (first.upper - first.lower)
    stacked = {k: np.tile(v, P + 1) for k, v in values.items()}
    states = [state]
    for j, name in enumerate(first.parameters):
        stacked[name][(j + 1) * n:(j + 2) * n] += steps[j]
        states.append(state + dstate[rows, j] * steps[j])
    Q1 = swept_response(first.variant.model, stacked, np.tile(batch.rpm[rows], P + 1), np.tile(rate[rows], P + 1),
                        np.concatenate(states), first.harmonics, result.n_time).correction
    M1 = first._sensor(Q1).reshape((P + 1, n) + (first.H, -1))
    dM1 = (M1[1:] - M1[0]) / steps[:, None, None, None] * first.half_range[:, None, None, None]
    return M1[0], np.moveaxis(dM1, 0, -1)


class StabilityWarning(UserWarning):
    """A fit whose reported steady state is unstable at some run (the machine would not stay on it)."""


@dataclass
class _Batch:
    """Steady states of several runs' models solved together (``SolverModel.steady_states``)."""

    result: object  # solver.SteadyState of every finite row, stacked run after run
    values: dict[str, Array]  # complete parameter values [SI] of those rows
    rpm: Array
    offsets: Array  # run k's rows are offsets[k]:offsets[k + 1]
    rows: list[Array]  # each run's finite rows of its x
    xs: list[Array]
    jumped: Array
    build: Callable  # build(values, speeds) -> System


def floquet_radii(models: Sequence[HarmonicModel], xs: Sequence[Array]) -> list[Array | None]:
    """Each model's largest |Floquet multiplier| (N_k,) at normalised xs[k] (N_k, d), for the steady states its
    ``evaluate`` reports there; None for a model without a steady state of its own (a library).

    The LM iterations solve without the stability check (``stability=False``: 30-40 % of a solve saved per
    evaluation); this is the check, for the points a fit reports: the steady states solved again as
    ``evaluate`` does (a warm start from the cached state at the same point converges at once, on the same
    branch) and one Floquet analysis of each (``solver.assess_stability``). Models of one variant with the
    same parameters are solved together, as in ``evaluate_runs``.
    """
    out: list[Array | None] = [None] * len(models)
    groups: dict[tuple, list[int]] = {}
    for k, model in enumerate(models):
        if isinstance(model, SolverModel):
            groups.setdefault((id(model.variant), tuple(model.parameters)), []).append(k)
    for members in groups.values():
        batch = SolverModel.steady_states([models[k] for k in members], [xs[k] for k in members])
        if batch is None:
            for k in members:
                out[k] = np.full(np.atleast_2d(xs[k]).shape[0], np.nan)
            continue
        result = batch.result
        ok = np.flatnonzero(result.success)
        if ok.size:
            assess_stability(batch.build({key: v[ok] for key, v in batch.values.items()}, batch.rpm[ok]), result, ok)
        for j, k in enumerate(members):
            radius = np.full(batch.xs[j].shape[0], np.nan)
            radius[batch.rows[j]] = result.floquet_radius[batch.offsets[j]:batch.offsets[j + 1]]
            out[k] = radius
    return out


@dataclass
class StabilityCheck:
    """The stability of the steady states a fit reports: per run, the largest |Floquet multiplier| at the
    returned parameters (``floquet_radii``); NaN for a run without a steady state there, or whose model is a
    library (no steady state of its own to check)."""

    runs: list[str]
    floquet_radius: Array  # (R,)

    @property
    def stable(self) -> Array:
        """(R,) a steady state with every multiplier inside the unit circle."""
        return np.nan_to_num(self.floquet_radius, nan=np.inf) < 1.0

    @property
    def unstable_runs(self) -> list[str]:
        """Runs whose reported steady state is unstable (radius >= 1)."""
        return [r for r, mu in zip(self.runs, self.floquet_radius) if np.isfinite(mu) and mu >= 1.0]

    def note(self) -> str | None:
        """One sentence for the fit's notes and the log when some run is unstable, else None."""
        bad = [(r, mu) for r, mu in zip(self.runs, self.floquet_radius) if np.isfinite(mu) and mu >= 1.0]
        if not bad:
            return None
        listed = ", ".join(f"{r} (|mu| = {mu:.4g})" for r, mu in bad)
        return (f"unstable steady state at run(s) {listed}: at the fitted parameters the model's periodic "
                "solution there has a Floquet multiplier outside the unit circle, a state the machine would "
                "leave, so the fit does not describe a steady state the rig can hold")


def check_stability(fit) -> StabilityCheck | None:
    """The stability check of a full-solver fit's optimum (``fit``: ``identification.Identification``), made
    visible on the fit when some run's steady state is unstable.

    Each run's steady state at the returned parameters (``fit.theta``, the point ``identification.conclude``
    evaluated) gets its Floquet radius (``floquet_radii``). When one is unstable, the fit is never left
    looking like a plain converged one: its ``message`` starts with "unstable steady state at run(s) ...",
    the same sentence joins ``fit.uncertainty.notes`` (the summary's notes; the per-run parameter table's
    note column), and a ``StabilityWarning`` naming the runs is issued and logged (logger
    ``hybridtwin.identify.forward``: the rule's log). Returns None for a fit without any ``SolverModel`` (a library
    fit: its surrogate has no steady state of its own; a fit read back from a table), else the check.
    """
    models = [] if fit.problem is None else fit.problem.models  # a fit read back from its table has no models
    if not any(isinstance(m, SolverModel) for m in models):
        return None
    theta = np.asarray(fit.theta, float)[None]
    xs = [fit.layout.run_parameters(theta, k)[0] for k in range(fit.layout.n_runs)]
    radii = floquet_radii(models, xs)
    check = StabilityCheck(list(fit.layout.runs),
                           np.array([np.nan if r is None else float(r[0]) for r in radii]))
    note = check.note()
    if note is not None:
        if not fit.unstable_runs:  # once: a second check of the same fit does not say it again
            fit.message = f"unstable steady state at run(s) {', '.join(check.unstable_runs)}; {fit.message}"
        fit.unstable_runs = tuple(check.unstable_runs)
        if note not in fit.uncertainty.notes:
            fit.uncertainty.notes.append(note)
        logging.getLogger(__name__).warning("%s", note)
        warnings.warn(note, StabilityWarning, stacklevel=2)
    return check


def _as_2d(xs: Sequence[Array]) -> list[Array]:
    return [np.atleast_2d(np.asarray(x, float)) for x in xs]


def evaluate_runs(models: Sequence[HarmonicModel], xs: Sequence[Array], jacobian: bool = True
                  ) -> list[tuple[Array, Array | None]]:
    """Each model's ``evaluate(xs[k], jacobian)``, batched across runs where that pays.

    SolverModels of one variant with the same parameters and analytic sensitivities are solved together:
    their warm starts in one batched Newton solve and their sensitivities in one call (each run at its own
    speed and eccentric mass; the solver treats scenarios independently, so the numbers are those of the
    models one by one). The fixed cost of a solve and of a sensitivity (assembly, first mode, condensation)
    is then paid once per evaluation instead of once per run: 19 runs of the bundled plan cost about as
    much as 3. Other models (libraries) are evaluated one by one.
    """
    batched = [k for k, m in enumerate(models) if isinstance(m, SolverModel) and m.analytic]
    if len(batched) < 2 or len({id(models[k].variant) for k in batched}) > 1 or len(
            {tuple(models[k].parameters) for k in batched}) > 1:
        batched = []
    out: list = [None] * len(models)
    for k, model in enumerate(models):
        if k not in batched:
            out[k] = model.evaluate(xs[k], jacobian)
    if batched:
        for k, value in zip(batched, SolverModel.evaluate_together([models[k] for k in batched],
                                                                   [xs[k] for k in batched], jacobian)):
            out[k] = value
    return out


def _state_shape(models: Sequence["SolverModel"]) -> tuple[int, ...]:
    """Shape (c, 2H+1) of one condensed state (from a cache, else from the condensation of the first model)."""
    for m in models:
        if m._state is not None:
            return m._state.shape[1:]
    return (0, 2 * models[0].harmonics + 1)
