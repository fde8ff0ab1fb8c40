"""Virtual rig: measured-format records from a "truth" model with hidden effects.

The rig plays the part of the paper's test bench (docs/model.md,
"The rig and its measured runs"; docs/measurement-format.md). A truth is a model
variant (any list of effects, e.g. the Geometric model plus the slope force
the Geometric model lacks) with parameter values, built on a machine (the
config's ``machine:`` section, hybridtwin.model.machine; the VARM by default), whose
x and y probes the records hold. For every run of a plan
(run, rpm, eccentric_mass_g[, eccentric_mass_angle_deg], role) the rig

1. draws the run's conditions from a seeded generator: the true speed
   rpm (1 + speed_error * N(0, 1)), the rotor angle at the first sample
   (uniform in [0, 2 pi) when the phase origin is random), a DC offset per
   channel (uniform in +-offset_mm) and a noise level per channel (uniform in
   the noise_mm range);
2. solves the truth's periodic steady state of eq. 29 at the true speed by
   run-up and again by run-down from rundown_margin_rpm above the mass's
   highest speed: the two must agree, else the steady state is not unique and
   the run's response depends on the rig's history (reported, column
   ``unique``). The run-up's state must also be stable (its largest Floquet
   multiplier inside the unit circle), else the machine would not stay on it
   and the record shows a state no rig could hold (reported, columns
   ``stable`` and ``floquet_radius``). ``integrator`` says how:

   - "hb" (default): harmonic balance, ``solve_sweep`` per eccentric mass from
     start_rpm in steps <= step_rpm;
   - "time": time integration (``hybridtwin.solvers.transient.run_up_harmonics``,
     Radau, no harmonic-balance code), per eccentric mass through the runs'
     true speeds only (start_rpm, step_rpm unused): the run-up starts from
     rest at the lowest speed, the run-down from rest at the highest speed +
     rundown_margin_rpm, each next speed from the previous one's settled
     state; at each speed period after period until the sensor harmonics
     (DFT of a period) of successive periods agree to TIME_SETTLE_TOLERANCE
     of the largest; the last period's give X_h, Y_h. Data independent of the
     solver the identification uses, to test the diagnosis on. Cost: ~80 s of
     CPU for the bundled 22-run plan (50 speeds settled), against ~2 s by "hb".
     A settled orbit is stable by construction (an unstable one is left, not
     settled on): ``stable`` is True, ``floquet_radius`` not computed (NaN);
3. evaluates the sensor response x(t) = Re(sum_h X_h exp(i h Omega (t + t0)))
   at the sampling instants, t0 = angle / Omega, adds the offsets and white
   Gaussian noise, clips at +-sensor_range_mm if asked (a saturated laser
   micrometer) and marks the keyphasor on the sample nearest to each instant
   the rotor's reference points to +x (if asked: where a trial mass at 0 deg
   sits; a plan row's eccentric_mass_angle_deg places its mass that far
   ahead in the sense of rotation, ``trial_groups``);
4. writes runs.tsv, records/{run}.csv, and the answer key truth.tsv (per run:
   true speed, phase origin, offsets, noise levels, truth harmonics in the
   model's frame, run-up/run-down agreement, stability, peak vs sensor range) and
   truth.yaml (truth, imperfections, seed), which an identification must not read.

Each run's random stream is seeded from (seed, run id), so a run's record does
not change when other runs are added to the plan.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ..model.effects import Effect, trial_mass_values
from ..tables import RIG_RUNS, RIG_TRUTH
from ..model.machine import Machine, default_machine
from ..data.measurements import read_runs, trial_angles
from ..data.preprocessing import harmonic_column
from .sweep import (SWEEP_FIELDS, check_sweep_plan, has_sweep_columns, read_sweep_plan, sweep_field_problems,
                    sweep_fields_from_mapping, sweep_records, sweep_rows)
from .base import RANGE_SIGMAS, UNIT_SCALES, RigError, RigWarning, run_rng, write_record  # noqa: F401 (re-exported)
from ..model.model import rpm_to_rad_s
from ..model.sensor import sensor_dofs, sensor_names
from ..solvers.continuation import RUN_UP_FROM_RPM, ramp, solve_sweep
from ..solvers.resolution import needed_harmonics
from ..solvers.transient import RESOLVED_HARMONICS, NotSettledError, SettledPeriod, run_up_harmonics
from ..model.variants import EffectsFileError, Variant, load_effects_files

Array = np.ndarray
#: the values the rig sets per run from the plan (its trial mass), never the truth's: model.effects.trial_mass_values
RUN_VALUES = ("m_e", "angle_me")

#: the paper's final finding (Table 5): the Geometric model's effects plus the bearing force on the shaft
#: slope, k_w u' + k_z u'^3, that the Geometric model lacks; bow chosen for the bundled data (data/default)
DEFAULT_TRUTH: dict = {
    "description": "Geometric model + slope spring k_w u' + k_z u'^3 (paper Table 5)",
    "effects": ["centrifugal_softening", "structural_damping", "upper_housing", "lower_bearing", "unbalance",
                "shaft_bow", "geometric_spring", "slope_spring"],
    "values": {"k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "k_w": 324.2, "k_z": 301.1,
               "q_x": 0.002, "q_y": 0.0015},
}
#: run-up and run-down harmonics agreeing to this relative difference are the same steady state
UNIQUE_TOLERANCE = 1e-6
#: how the truth's steady states are computed (RigSpec.integrator; module docstring, step 2)
INTEGRATORS = ("hb", "time")
#: "time": settled when the sensor harmonics of successive periods differ by less than this fraction of the
#: largest, integrated with atol = TIME_ATOL_RELATIVE x the amplitude (hybridtwin.solvers.transient.settle, where the
#: measurements behind both are). The harmonics are then within ~5.5 x the last change of the orbit (the residual
#: transient) plus ~1e-7 (integration error): measured <= 2e-6 of the largest against harmonic balance.
TIME_SETTLE_TOLERANCE = 1e-6
TIME_ATOL_RELATIVE = 3e-6
#: "time": run-up and run-down agreeing to this relative difference are the same steady state; each is within
#: ~1e-5 of the periodic orbit (above), distinct branches differ by 1e-2 or more (0.5 in tests/test_rig.py)
TIME_UNIQUE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Imperfections:
    """How the virtual measurement departs from the model's clean steady state (SI at the boundary noted)."""

    duration_s: float = 4.0  # record length
    sample_rate_hz: float = 2000.0  # the paper's rig samples at 2 kHz
    speed_error: float = 1e-3  # standard deviation of the relative speed error (true vs nominal)
    noise_mm: tuple[float, float] = (0.05, 0.05)  # Gaussian noise std range [mm], drawn per run and channel
    offset_mm: float = 0.5  # DC offsets uniform in +-offset_mm per run and channel
    random_phase: bool = True  # rotor angle at the first sample uniform in [0, 2 pi); else 0 (start at a mark)
    keyphasor: bool = False  # write a keyphasor column
    clip: bool = True  # clip at +-sensor_range_mm like a saturated laser micrometer
    sensor_range_mm: float = 14.0  # the laser micrometers' range
    unit: str = "mm"  # displacement columns x_mm, y_mm ("mm"), x_m ("m"), x_um ("um") or x_mils ("mils")
    # run-ups and coast-downs only (plan rows of kind runup / coastdown; hybridtwin.rig.sweep): SWEEP_FIELDS
    sweep_rate_rpm_s: float = 10.0  # nominal |rpm'| of the sweep: its duration is |rpm_end - rpm_start| / rate
    sweep_shape: str = "linear"  # the rate's shape: "linear" (constant) or "exponential" (approach to the end)
    sweep_wobble: float = 0.1  # the rate wobbles smoothly by +-this fraction of itself (seeded; < 1: no reversal)
    sweep_ramp_s: float = 0.5  # the acceleration's smooth onset and end (at most a quarter of the sweep)
    dwell_start_s: float = 2.0  # the record starts this long at rpm_start (a slow-roll band on a run-up) ...
    dwell_end_s: float = 1.0  # ... and ends this long at rpm_end
    sweep_sample_rate_hz: float = 5000.0  # sample rate of transient records
    runout_um: tuple[float, float] = (10.0, 3.0)  # slow-roll runout size at 1X, 2X per probe [um] (x U(0.5, 1))
    probe_angles_deg: Mapping = field(default_factory=dict)  # {sensor: angle from +x towards +y}; x 0, y 90

    def __post_init__(self) -> None:
        lo, hi = self.noise_mm
        checks = [
            (self.duration_s > 0, f"duration_s must be positive, got {self.duration_s}"),
            (self.sample_rate_hz > 0, f"sample_rate_hz must be positive, got {self.sample_rate_hz}"),
            (self.speed_error >= 0, f"speed_error must be >= 0, got {self.speed_error}"),
            (0 <= lo <= hi, f"noise_mm must be [low, high] with 0 <= low <= high, got {self.noise_mm}"),
            (self.offset_mm >= 0, f"offset_mm must be >= 0, got {self.offset_mm}"),
            (self.sensor_range_mm > 0, f"sensor_range_mm must be positive, got {self.sensor_range_mm}"),
            (self.unit in UNIT_SCALES, f"unit must be 'mm' or 'm', or 'um' or 'mils', got {self.unit!r}"),
        ]

        checks += sweep_field_problems(self)
        for ok, message in checks:
            if not ok:
                raise RigError(f"imperfections: {message}")

    @classmethod
    def from_mapping(cls, values: Mapping | None) -> "Imperfections":
        """From a config mapping; ``noise_mm`` may be one value or [low, high]."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        stray = sorted(set(values) - known)
        if stray:
            raise RigError(f"imperfections: unknown key(s) {stray} (known: {sorted(known)})")
        if "noise_mm" in values:
            noise = values["noise_mm"]
            noise = [noise, noise] if np.isscalar(noise) else list(noise)
            if len(noise) != 2:
                raise RigError(f"imperfections: noise_mm must be one value or [low, high], got {values['noise_mm']}")
            values["noise_mm"] = (float(noise[0]), float(noise[1]))

        return cls(**sweep_fields_from_mapping(values))

    def to_mapping(self, sweep: bool | None = None) -> dict:
        """The config form; the run-up / coast-down fields (sweep.SWEEP_FIELDS) only with ``sweep`` True,
        or (None) when one differs from its default: a steady data set's answer key reads as before."""

        out = asdict(self)
        out["noise_mm"] = list(self.noise_mm)
        out["runout_um"], out["probe_angles_deg"] = list(self.runout_um), dict(self.probe_angles_deg)
        default = Imperfections()
        if sweep is None:
            sweep = any(getattr(self, f) != getattr(default, f) for f in SWEEP_FIELDS)
        return out if sweep else {k: v for k, v in out.items() if k not in SWEEP_FIELDS}


@dataclass
class Truth:
    """The model behind the rig: a variant (its effects are the truth's physics, its model's structure the
    machine) and parameter values [SI]."""

    variant: Variant
    values: dict[str, float] = field(default_factory=dict)

    @property
    def machine(self) -> Machine:
        """The machine the truth is built on (the VARM unless the spec named another)."""
        return self.variant.model.shaft

    @classmethod
    def from_spec(cls, spec: Mapping | None = None, effects: Mapping[str, Effect] | None = None,
                  machine: Machine | None = None) -> "Truth":
        """From {description, effects: [...], values: {name: value}}; missing keys take DEFAULT_TRUTH's.

        ``machine``: the rotor (hybridtwin.model.machine; default the VARM); the effects may be its placed ones
        (``linear_bearing@drive_end``, ``unbalance@impeller``, ``gyroscopic``, ...). DEFAULT_TRUTH is the
        VARM's: on another machine the effects must be given, and missing values are the nominal ones.
        """
        machine = default_machine() if machine is None else machine
        spec = dict(spec or {})
        stray = sorted(set(spec) - {"description", "effects", "values"})
        if stray:
            raise RigError(f"truth: unknown key(s) {stray} (expected description, effects, values)")
        if "effects" not in spec and not machine.is_varm:
            raise RigError(f"truth: machine {machine.name!r} needs the truth's effects (the default truth, "
                           f"{DEFAULT_TRUTH['description']}, is the VARM's)")
        try:
            machine.sensor_node  # at least one x, y probe pair; the records hold a channel per sensor
        except ValueError as err:
            raise RigError(f"truth: {err}") from None
        effect_names = spec.get("effects", DEFAULT_TRUTH["effects"])
        default_values = DEFAULT_TRUTH["values"] if machine.is_varm else {}
        values = {k: float(v) for k, v in dict(spec.get("values", default_values)).items()}
        description = spec.get("description", DEFAULT_TRUTH["description"] if "effects" not in spec else "")
        try:
            variant = Variant.from_spec("truth", {"effects": list(effect_names), "description": description},
                                        dict(effects or {}) | machine.effects(), shaft=machine)
            variant.values(values)
        except ValueError as err:
            raise RigError(f"truth: {err}") from None
        if "m_e" in values:
            raise RigError("truth: m_e comes from each run's eccentric_mass_g, do not set it in the values")
        if "angle_me" in values:
            raise RigError("truth: angle_me comes from each run's eccentric_mass_angle_deg, do not set it in the "
                           "values")
        return cls(variant, values)

    def run_values(self, mass_g: float, angle_deg: float) -> dict[str, Array]:
        """The truth's values with a run's trial mass of ``mass_g`` [g] at ``angle_deg`` (``trial_mass_values``)."""
        return self.variant.values({**self.values, **trial_mass_values(mass_g, angle_deg)})

    def to_mapping(self) -> dict:
        """Effects and every parameter value in effect (given or nominal), for the answer key (the per-run trial
        mass, m_e and angle_me, left out)."""
        everything = {k: float(v) for k, v in self.variant.values(self.values).items() if k not in RUN_VALUES}
        return {"description": self.variant.description,
                "effects": [e.name for e in self.variant.model.effects],
                "values": {k: self.values[k] for k in self.values},
                "nominal_values_used": {k: v for k, v in everything.items() if k not in self.values}}


@dataclass
class RigSpec:
    """Everything that defines a generated data set besides the plan."""

    truth: Truth = field(default_factory=Truth.from_spec)
    imperfections: Imperfections = field(default_factory=Imperfections)
    seed: int = 0
    harmonics: int = RESOLVED_HARMONICS  # harmonics 0..H of the truth's steady state
    start_rpm: float = RUN_UP_FROM_RPM  # run-up start
    step_rpm: float = 25.0  # largest continuation step
    rundown_margin_rpm: float = 200.0  # run-down starts this far above a mass's highest speed
    integrator: str = "hb"  # steady states by harmonic balance ("hb") or time integration ("time")

    def __post_init__(self) -> None:
        if self.integrator not in INTEGRATORS:
            raise RigError(f"rig: integrator must be one of {list(INTEGRATORS)}, got {self.integrator!r}")

    @classmethod
    def from_mapping(cls, spec: Mapping | None, effects: Mapping[str, Effect] | None = None,
                     machine: Machine | None = None) -> "RigSpec":
        """From the config form: {truth: {...}, imperfections: {...}, seed, harmonics, ...} (plan ignored); the
        truth built on ``machine`` (the config's ``machine:`` section; default the VARM)."""
        spec = dict(spec or {})
        known = {"truth", "imperfections", "seed", "harmonics", "start_rpm", "step_rpm", "rundown_margin_rpm",
                 "integrator", "plan", "effects_files"}
        stray = sorted(set(spec) - known)
        if stray:
            raise RigError(f"rig: unknown key(s) {stray} (known: {sorted(known)})")
        options = {k: spec[k] for k in ("seed", "harmonics", "start_rpm", "step_rpm", "rundown_margin_rpm")
                   if k in spec}
        if int(options.get("harmonics", 1)) < 1:
            raise RigError(f"rig: harmonics must be >= 1, got {options['harmonics']}")
        return cls(Truth.from_spec(spec.get("truth"), effects, machine),
                   Imperfections.from_mapping(spec.get("imperfections")),
                   **{k: (int(v) if k in ("seed", "harmonics") else float(v)) for k, v in options.items()},
                   **({"integrator": spec["integrator"]} if "integrator" in spec else {}))

    def to_mapping(self, sweep: bool | None = None) -> dict:
        """The answer key's form (truth.yaml); ``machine`` (its config form) only when it is not the VARM;
        ``sweep``: with the run-up / coast-down imperfections (``Imperfections.to_mapping``)."""
        machine = self.truth.machine
        other = isinstance(machine, Machine) and not machine.is_varm  # a plain Shaft is the VARM's structure
        return {"seed": self.seed, "harmonics": self.harmonics, "start_rpm": self.start_rpm,
                "step_rpm": self.step_rpm, "rundown_margin_rpm": self.rundown_margin_rpm,
                "integrator": self.integrator, **({"machine": machine.to_mapping()} if other else {}),
                "truth": self.truth.to_mapping(), "imperfections": self.imperfections.to_mapping(sweep)}


# --- the steps --------------------------------------------------------------------------


def read_plan(path: str | Path) -> pd.DataFrame:
    """A run plan (run, rpm, eccentric_mass_g[, role, ...]); a runs sheet's path column is ignored. A plan with
    the columns kind, rpm_start, rpm_end (run-ups and coast-downs) is read by ``sweep.read_sweep_plan``."""

    if has_sweep_columns(path):
        return read_sweep_plan(path)
    plan = read_runs(path, check_files=False, require_path=False)
    unknown = plan["eccentric_mass_g"].isna()
    if unknown.any():
        raise RigError(f"{path}: the rig needs every run's eccentric mass; empty for "
                       f"{plan['run'][unknown].tolist()}")
    return plan.drop(columns=["path", "record"])


def draw_conditions(plan: pd.DataFrame, imperfections: Imperfections, seed: int,
                    channels: Sequence[str] = ("x", "y")) -> pd.DataFrame:
    """Per run: rpm_true, phase_origin_rad, then offset_<c>_m for each channel c (the sensors: x, y on the VARM),
    then noise_<c>_m for each, drawn from (seed, run id)."""
    rows = []
    C = len(channels)
    for run_id, rpm in zip(plan["run"], plan["rpm"].to_numpy(float)):
        rng = run_rng(seed, run_id, 0)
        speed = rpm * (1.0 + imperfections.speed_error * rng.standard_normal())
        phase = rng.uniform(0.0, 2.0 * np.pi) if imperfections.random_phase else 0.0
        offsets = rng.uniform(-imperfections.offset_mm, imperfections.offset_mm, C) * 1e-3
        noise = rng.uniform(*imperfections.noise_mm, C) * 1e-3
        rows.append({"run": run_id, "rpm_true": speed, "phase_origin_rad": phase,
                     **{f"offset_{c}_m": offsets[i] for i, c in enumerate(channels)},
                     **{f"noise_{c}_m": noise[i] for i, c in enumerate(channels)}})
    return pd.DataFrame(rows)


@dataclass
class TruthResponse:
    """Sensor harmonics of the truth at each run's true speed: Z (R, H+1, C) complex [m], one channel per sensor
    (x, y on the VARM), by run-up, and the run-down's Z_down for the uniqueness
    check (agreeing to ``unique_tolerance``, relative); success/branch/message per run; stable: the run-up's state
    is stable (harmonic balance: its largest Floquet multiplier ``floquet_radius`` < 1; time integration: settled
    on, so stable, radius NaN)."""

    Z: Array
    Z_down: Array
    success: Array
    branch: Array
    message: Array
    unique_tolerance: float = UNIQUE_TOLERANCE
    stable: Array | None = None  # (R,) bool
    floquet_radius: Array | None = None  # (R,) NaN where not computed

    def __post_init__(self) -> None:
        R = len(self.success)
        self.stable = np.zeros(R, bool) if self.stable is None else self.stable
        self.floquet_radius = np.full(R, np.nan) if self.floquet_radius is None else self.floquet_radius

    @classmethod
    def empty(cls, runs: int, harmonics: int, channels: int, **kwargs) -> "TruthResponse":
        return cls(np.full((runs, harmonics + 1, channels), np.nan + 0j),
                   np.full((runs, harmonics + 1, channels), np.nan + 0j), np.zeros(runs, bool),
                   np.empty(runs, object), np.empty(runs, object), **kwargs)

    @property
    def difference_rel(self) -> Array:
        """max_h |run-up - run-down| / max_h |run-up| over every channel, per run."""
        diff = np.abs(self.Z - self.Z_down).max(1).max(-1)
        scale = np.abs(self.Z).max(1).max(-1)
        return diff / np.maximum(scale, 1e-300)

    @property
    def unique(self) -> Array:
        return self.difference_rel < self.unique_tolerance


def solve_truth(truth: Truth, runs: pd.DataFrame, harmonics: int = RESOLVED_HARMONICS,
                start_rpm: float = RUN_UP_FROM_RPM,
                step_rpm: float = 25.0, rundown_margin_rpm: float = 200.0, integrator: str = "hb") -> TruthResponse:
    """Truth's sensor harmonics at each row's (rpm_true, eccentric_mass_g), run-up and run-down per mass.

    The periodic steady states of eq. 29 by harmonic balance (``integrator`` "hb": ``solve_sweep`` from
    start_rpm in steps <= step_rpm) or by time integration ("time": ``_solve_truth_time``).
    """
    if integrator == "time":
        return _solve_truth_time(truth, runs, harmonics, rundown_margin_rpm)
    if integrator != "hb":
        raise RigError(f"rig: integrator must be one of {list(INTEGRATORS)}, got {integrator!r}")
    dofs = sensor_dofs(truth.variant.model.shaft)
    out = TruthResponse.empty(len(runs), harmonics, len(dofs))
    # a non-smooth truth effect (a rub) is solved with the harmonics it declares, its 0..H kept
    solved = needed_harmonics(truth.variant.model.effects, harmonics)
    for values, group in trial_groups(truth, runs):
        speeds = group["rpm_true"].to_numpy(float)
        positions = np.flatnonzero(runs.index.isin(group.index))
        up = _sweep(truth.variant, values, ramp(min(start_rpm, speeds.min()), speeds, step_rpm), solved, "up")
        down = _sweep(truth.variant, values, ramp(speeds.max() + rundown_margin_rpm, speeds, step_rpm),
                      solved, "down")
        for pos, speed in zip(positions, speeds):
            res_up, res_down = up[speed], down[speed]
            out.Z[pos] = res_up.harmonics[0][:harmonics + 1, dofs]
            out.Z_down[pos] = res_down.harmonics[0][:harmonics + 1, dofs]
            out.success[pos] = bool(res_up.success[0])
            out.stable[pos], out.floquet_radius[pos] = bool(res_up.stable[0]), res_up.floquet_radius[0]
            out.branch[pos] = str(res_up.branch[0])
            out.message[pos] = str(res_up.message[0]) if res_down.success[0] else (
                f"{res_up.message[0]}; run-down: {res_down.message[0]}")
    return out


def trial_groups(truth: Truth, runs: pd.DataFrame):
    """(the truth's values, the rows) per trial mass: each (eccentric_mass_g, eccentric_mass_angle_deg) of ``runs``
    (angle 0 where the column is absent), in increasing mass, then angle."""
    angle = pd.Series(trial_angles(runs), index=runs.index)
    for (mass_g, angle_deg), group in runs.groupby([runs["eccentric_mass_g"], angle], sort=True):
        yield truth.run_values(mass_g, angle_deg), group


def _solve_truth_time(truth: Truth, runs: pd.DataFrame, harmonics: int, rundown_margin_rpm: float) -> TruthResponse:
    """``solve_truth`` by time integration of eq. 29 (hybridtwin.solvers.transient, no harmonic-balance code).

    Per eccentric mass, a run-up through the runs' distinct true speeds from rest at the lowest, and a
    run-down from rest at the highest + ``rundown_margin_rpm`` down through them (``run_up_harmonics``
    with TIME_SETTLE_TOLERANCE, TIME_ATOL_RELATIVE); X, Y [m] are the DFT of the last settled period at the
    sensor DOFs. Up and down agreeing to TIME_UNIQUE_TOLERANCE is a unique steady state. A speed that does
    not settle fails (``success`` False, the reason in ``message``), and so do the speeds after it.
    """
    dofs = sensor_dofs(truth.variant.model.shaft)
    out = TruthResponse.empty(len(runs), harmonics, len(dofs), unique_tolerance=TIME_UNIQUE_TOLERANCE)
    for values, group in trial_groups(truth, runs):
        speeds = np.unique(group["rpm_true"].to_numpy(float))
        up = _time_sweep(truth.variant, values, speeds, harmonics, dofs)
        down = _time_sweep(truth.variant, values, np.append(speeds.max() + rundown_margin_rpm, speeds[::-1]),
                           harmonics, dofs)
        positions = np.flatnonzero(runs.index.isin(group.index))
        for pos, speed in zip(positions, group["rpm_true"].to_numpy(float)):
            res_up, res_down = up[speed], down[speed]
            out.branch[pos] = "time run-up"
            if isinstance(res_up, SettledPeriod):
                out.Z[pos] = res_up.harmonics
                out.success[pos] = out.stable[pos] = True  # settled on: a stable orbit
                out.message[pos] = (f"settled after {res_up.n_periods} periods (last change "
                                    f"{res_up.change:.1e} of the largest harmonic)")
            else:
                out.message[pos] = f"time run-up: {res_up}"
            if isinstance(res_down, SettledPeriod):
                out.Z_down[pos] = res_down.harmonics
            else:
                out.message[pos] += f"; time run-down: {res_down}"
    return out


def _time_sweep(variant: Variant, values: Mapping[str, Array], speeds: Array, harmonics: int,
                dofs: list[int]) -> dict:
    """{rpm: SettledPeriod, or the reason it failed} along a time run-up or run-down through ``speeds``."""
    systems = [variant.model.system(values, rpm) for rpm in speeds]  # the assembly solve_sweep uses (_sweep)
    try:
        results: list = run_up_harmonics(systems, dofs, harmonics, tolerance=TIME_SETTLE_TOLERANCE,
                                         atol_relative=TIME_ATOL_RELATIVE)
    except NotSettledError as err:
        results = err.settled + [str(err)] * (len(speeds) - len(err.settled))
    return dict(zip(speeds, results))


def synthesise(Z: Array, rpm_true: float, conditions: Mapping[str, float], imperfections: Imperfections,
               rng: np.random.Generator, channels: Sequence[str] = ("x", "y")) -> dict[str, Array]:
    """One record's columns [SI]: time_s, <c>_m for each channel c (the sensors; x_m, y_m on the VARM),
    keyphasor (or None), and the clipping mask. Z: (H+1, C) the channels' harmonics.

    x(t) = Re(sum_h X_h exp(i h Omega (t + t0))) + offset + noise, t0 = phase / Omega
    (the rotor angle at t = 0 is ``phase``), then clipped at +-sensor range if
    ``imperfections.clip``. The keyphasor marks the sample nearest to each time
    the unbalance points to +x, Omega (t + t0) = 2 pi k. The noise is drawn channel
    after channel, in order.
    """
    n = int(round(imperfections.duration_s * imperfections.sample_rate_hz))
    t = np.arange(n) / imperfections.sample_rate_hz
    omega = float(rpm_to_rad_s(rpm_true))
    angle = omega * t + conditions["phase_origin_rad"]
    rotation = np.exp(1j * np.outer(angle, np.arange(Z.shape[0])))  # (N, H+1)
    limit = imperfections.sensor_range_mm * 1e-3
    out: dict = {"time_s": t}
    clipped = np.zeros(n, bool)
    for i, c in enumerate(channels):
        z = (rotation @ np.ascontiguousarray(Z[:, i])).real + conditions[f"offset_{c}_m"] + conditions[f"noise_{c}_m"] * rng.standard_normal(n)
        clipped |= np.abs(z) > limit
        out[f"{c}_m"] = z
    if imperfections.clip:
        for c in channels:
            out[f"{c}_m"] = np.clip(out[f"{c}_m"], -limit, limit)
    keyphasor = None
    if imperfections.keyphasor:
        period = 2.0 * np.pi / omega
        first = -conditions["phase_origin_rad"] / omega
        marks = first + period * np.arange(np.ceil((t[-1] - first) / period) + 1)
        index = np.round(marks * imperfections.sample_rate_hz).astype(int)
        keyphasor = np.zeros(n, np.int8)
        keyphasor[index[(index >= 0) & (index < n)]] = 1
    return out | {"keyphasor": keyphasor, "clipped": clipped}


def generate(plan: pd.DataFrame, spec: RigSpec, out_dir: str | Path) -> pd.DataFrame:
    """Generate a data set (runs.tsv, records/, truth.tsv, truth.yaml) in ``out_dir``; returns the truth table.

    Raises ``RigError`` when the truth has no periodic steady state at some run
    (no record could honestly be written for it). Runs whose steady state is not
    unique (run-up and run-down differ) or unstable, or whose record leaves the
    sensor range, are kept and reported with a ``RigWarning`` and in truth.tsv
    (columns unique, stable, inside_range).
    """
    out_dir = Path(out_dir)
    channels = sensor_names(spec.truth.variant.model.shaft)  # one per sensor of the truth's machine

    sweeps = sweep_rows(plan)  # run-ups and coast-downs (hybridtwin.rig.sweep); the others as always
    check_sweep_plan(plan, sweeps, spec)
    truth = _steady_records(plan[~sweeps], spec, out_dir, channels) if not sweeps.all() else None
    if sweeps.any():
        truth = sweep_records(plan, sweeps, truth, spec, out_dir, channels)
    sheet = plan.copy()
    sheet["path"] = [f"records/{r}.csv" for r in plan["run"]]
    columns = ["run", "rpm", "eccentric_mass_g", "path", "role"]
    sheet = sheet[columns + [c for c in sheet.columns if c not in columns]]
    RIG_RUNS.write(sheet, out_dir / "runs.tsv")
    RIG_TRUTH.write(truth, out_dir / "truth.tsv")
    with open(out_dir / "truth.yaml", "w") as stream:
        yaml.safe_dump(spec.to_mapping(True if sweeps.any() else None), stream, sort_keys=False)
    return truth


def _steady_records(plan: pd.DataFrame, spec: RigSpec, out_dir: Path, channels: Sequence[str]) -> pd.DataFrame:
    """The steady runs of ``generate``: conditions, the truth's steady states, records; their truth table."""
    conditions = draw_conditions(plan, spec.imperfections, spec.seed, channels)
    runs = plan.reset_index(drop=True).join(conditions.drop(columns="run"))
    response = solve_truth(spec.truth, runs, spec.harmonics, spec.start_rpm, spec.step_rpm, spec.rundown_margin_rpm,
                           spec.integrator)
    failed = ~response.success
    if failed.any():
        detail = "; ".join(f"{r} ({m})" for r, m in zip(runs["run"][failed], response.message[failed]))
        raise RigError(f"the truth has no periodic steady state at: {detail}")
    truth = write_steady_records(_truth_table(runs, response, spec, channels), spec, out_dir, channels)
    _warn(truth, spec.imperfections)
    return truth


def write_steady_records(truth: pd.DataFrame, spec: RigSpec, out_dir: str | Path,
                         channels: Sequence[str] = ("x", "y")) -> pd.DataFrame:
    """The steady runs' records, synthesised from an answer key's rows (truth.tsv: the conditions and the truth's
    harmonics, as ``generate`` wrote them) into ``out_dir``/records; the table with ``clipped_samples`` counted.

    What ``generate`` does after solving the truth: the records of an answer key can be written again (the same
    seeds, so the same records to the truth.tsv's digits) without solving it again, e.g. from a time-integrated
    truth kept small (the suite's time-integrated diagnosis cases, tests/rig_cases)."""
    truth = truth.copy()
    Z = harmonics_of(truth, spec.harmonics, channels)
    for i, (_, row) in enumerate(truth.iterrows()):
        record = synthesise(Z[i], row["rpm_true"], row, spec.imperfections, run_rng(spec.seed, row["run"], 1),
                            channels)
        write_record(Path(out_dir) / "records" / f"{row['run']}.csv", record, spec.imperfections.unit, channels)
        truth.loc[truth.index[i], "clipped_samples"] = int(record["clipped"].sum())
    return truth


def harmonics_of(truth: pd.DataFrame, harmonics: int, channels: Sequence[str] = ("x", "y")) -> Array:
    """(R, H+1, C) complex [m]: the truth's harmonics from an answer key's columns (the inverse of
    ``_truth_table``'s harmonic columns)."""

    return np.stack([np.stack([truth[harmonic_column(c, h, "re")].to_numpy(float)
                               + 1j * truth[harmonic_column(c, h, "im")].to_numpy(float) for c in channels], -1)
                     for h in range(harmonics + 1)], 1)


# --- helpers ----------------------------------------------------------------------------


def _sweep(variant: Variant, values: Mapping[str, Array], speeds: Array, harmonics: int, direction: str) -> dict:
    """{rpm: SteadyState} along a run-up ("up") or run-down ("down") through ``speeds``."""
    sweep = solve_sweep(lambda rpm, rows: variant.model.system(values, rpm), speeds, 1, harmonics=harmonics,
                        direction=direction)
    return dict(zip(sweep.rpm, sweep.results))


def _truth_table(runs: pd.DataFrame, response: TruthResponse, spec: RigSpec,
                 channels: Sequence[str] = ("x", "y")) -> pd.DataFrame:
    """The answer key: conditions, truth harmonics (model frame), uniqueness, peak vs sensor range."""

    table = runs.copy()
    for h in range(spec.harmonics + 1):
        for i, name in enumerate(channels):
            table[harmonic_column(name, h, "re")] = response.Z[:, h, i].real
            table[harmonic_column(name, h, "im")] = response.Z[:, h, i].imag
    table["updown_difference_rel"] = response.difference_rel
    table["unique"] = response.unique
    table["stable"], table["floquet_radius"] = response.stable, response.floquet_radius
    table["branch"], table["message"] = response.branch, response.message
    angle = np.linspace(0.0, 2.0 * np.pi, 721)
    rotation = np.exp(1j * np.outer(angle, np.arange(spec.harmonics + 1)))
    limit = spec.imperfections.sensor_range_mm * 1e-3
    inside = np.ones(len(table), bool)
    for i, name in enumerate(channels):
        wave = (rotation @ np.ascontiguousarray(response.Z[:, :, i]).T).real + table[f"offset_{name}_m"].to_numpy()
        peak = np.abs(wave).max(0)
        table[f"peak_{name}_m"] = peak
        inside &= peak + RANGE_SIGMAS * table[f"noise_{name}_m"].to_numpy() < limit
    table["inside_range"] = inside
    table["clipped_samples"] = 0
    return table


def peak_columns(truth: pd.DataFrame) -> list[str]:
    """The truth table's largest-displacement columns, one per sensor (peak_<sensor>_m)."""
    return [c for c in truth.columns if c.startswith("peak_") and c.endswith("_m")]


def _warn(truth: pd.DataFrame, imperfections: Imperfections) -> None:
    peaks = peak_columns(truth)
    for row in truth.itertuples(index=False):
        if not row.unique and not np.isfinite(row.updown_difference_rel):
            warnings.warn(f"run {row.run}: uniqueness of the steady state at {row.rpm_true:.2f} RPM not checked, "
                          f"the run-down found no steady state ({row.message}); the record follows the run-up "
                          "branch", RigWarning, stacklevel=3)
        elif not row.unique:
            warnings.warn(f"run {row.run}: the steady state at {row.rpm_true:.2f} RPM is not unique (run-up and "
                          f"run-down differ by {row.updown_difference_rel:.1e} relative); the record follows the "
                          "run-up branch", RigWarning, stacklevel=3)
        if not row.stable:
            warnings.warn(f"run {row.run}: the truth's steady state at {row.rpm_true:.2f} RPM is unstable (largest "
                          f"Floquet multiplier |mu| = {row.floquet_radius:.4g} >= 1): the machine would not stay on "
                          "it, so the record shows a state no rig could hold (truth.tsv, column stable)",
                          RigWarning, stacklevel=3)
        if not row.inside_range:
            peak = max(getattr(row, c) for c in peaks) * 1e3
            action = (f"{row.clipped_samples} sample(s) clipped" if imperfections.clip else "not clipped (clip off)")
            warnings.warn(f"run {row.run}: the response reaches {peak:.2f} mm (+ noise) against the sensor range "
                          f"+-{imperfections.sensor_range_mm:g} mm: {action}", RigWarning, stacklevel=3)



# --- command line -----------------------------------------------------------------------


def read_answer_key(path: str | Path, effects: Mapping[str, Effect] | None = None) -> RigSpec:
    """The RigSpec of a generated data set from its answer key (truth.yaml, as ``generate`` wrote it:
    ``RigSpec.to_mapping``): the inverse of that writer. ``nominal_values_used`` is what the truth's model takes
    for the values not given; it must be what this version's model takes (else the records came from another
    model, and are refused). ``effects``: the user effects the truth names (e.g. the rig's effects files)."""
    path = Path(path)
    try:
        mapping = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise RigError(f"answer key {path}: cannot read it ({err})") from None
    if not isinstance(mapping, dict) or not isinstance(mapping.get("truth"), dict):
        raise RigError(f"answer key {path}: expected the mapping generate writes (seed, ..., truth: {{...}})")
    mapping = dict(mapping)
    truth = dict(mapping["truth"])
    nominal = truth.pop("nominal_values_used", {}) or {}
    machine = Machine.from_mapping(mapping.pop("machine")) if "machine" in mapping else None
    spec = RigSpec.from_mapping(mapping | {"truth": truth}, effects, machine)
    used = spec.truth.to_mapping()["nominal_values_used"]
    differ = sorted(k for k in set(nominal) | set(used) if not np.isclose(nominal.get(k, np.nan), used.get(k, np.nan),
                                                                         rtol=1e-12, atol=0.0))
    if differ:
        raise RigError(f"answer key {path}: nominal value(s) {differ} differ from this model's "
                       f"({ {k: nominal.get(k) for k in differ} } against { {k: used.get(k) for k in differ} })")
    return spec


def load_spec(path: Path | None, effects_files: list[Path] | None = None, machine: Machine | None = None,
              effects: Mapping[str, Effect] | None = None) -> tuple[RigSpec, Path | None]:
    """A rig spec from YAML (the config's rig entry form; effects_files and plan relative to the file), its
    truth built on ``machine`` (default the VARM) with ``effects`` (e.g. a config's) besides the files'."""
    mapping, base = {}, None
    if path is not None:
        if not path.is_file():
            raise RigError(f"rig spec {path} does not exist")
        try:
            mapping = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as err:
            raise RigError(f"rig spec {path} is not valid YAML: {err}") from None
        if not isinstance(mapping, dict):
            raise RigError(f"rig spec {path}: expected a mapping (truth, imperfections, seed, ...)")
        base = path.parent
    files = [base / f for f in mapping.pop("effects_files", []) or []] + list(effects_files or [])
    try:
        effects = dict(effects or {}) | load_effects_files(files)
    except EffectsFileError as err:
        raise RigError(str(err)) from None
    plan = mapping.get("plan")
    return RigSpec.from_mapping(mapping, effects, machine), (base / plan if plan and base else None)
