"""The virtual rig's run-ups and coast-downs (issue 38, item 8): transient records by time integration.

A plan row with ``kind`` = ``runup`` or ``coastdown`` and the nominal sweep ``rpm_start``, ``rpm_end`` (``rpm``
empty) becomes a record of the truth integrated along a speed profile (hybridtwin.solvers.sweep: Radau on the equations
of motion with Omega(t), theta(t) and the inertial Omega' term; no harmonic-balance code), with every nuisance:

1. conditions drawn from (seed, run id), stream 0: the true start and end speeds (each x (1 + speed_error
   N(0, 1))), the rotor angle at the first sample (uniform when random_phase), a DC offset and a noise level
   per channel (as steady runs), and a slow-roll runout per channel: 1X and 2X vectors R1, R2 of sizes
   ``runout_um`` x U(0.5, 1) at uniform phases;
2. the speed profile (stream 2 for its wobble): ``dwell_start_s`` at the start speed, a sweep of
   |rpm_end - rpm_start| / ``sweep_rate_rpm_s`` seconds (nominal), ``dwell_end_s`` at the end speed
   (``SpeedProfile.sweep``: smooth onset over ``sweep_ramp_s``, at most a quarter of the sweep; shape
   ``sweep_shape``; the rate wobbling by +-``sweep_wobble`` of itself);
3. the start: the periodic steady state at the start speed settled by time integration from rest
   (``transient.settle``, as the rig's "time" integrator; where its harmonics stall above the settle tolerance,
   1e-6, settled again to START_TOLERANCE_RETRY, the tolerance in the answer key's message), then the
   integration along the profile, sampled at
   ``sweep_sample_rate_hz`` (atol SWEEP_ATOL_RELATIVE x the start orbit's amplitude);
4. each probe reads cos(a) u + sin(a) v at its node, a its angle (``probe_angles_deg``, from +x towards +y;
   default 0 for an x probe, 90 for a y probe: the model's directions), plus its runout
   Re(R1 exp(i theta) + R2 exp(2 i theta)) (rotating with the shaft, speed-independent), offset and noise
   (stream 1), clipped at +-sensor_range_mm when ``clip``; the keyphasor (always written: required for
   transient records) marks the sample nearest each instant theta = 2 pi k (the unbalance on +x);
5. the answer key: per row the true profile's summary (true start and end speeds, sweep start and end times,
   mean and largest rate), the runout vectors, the probe angles, the start, Radau's steps, the peak and range
   check (truth.tsv); the imperfections with the sweep fields (truth.yaml).

Steady rows of the same plan are made exactly as in a plan without transient rows (``rig.generate``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..data import measurements
from ..data.measurements import ROLES, RUN_ID, TRIAL_ANGLE_COLUMN, DataError, read_text_table
from ..model.sensor import DEFAULT_SENSORS, SENSOR_NODE
from ..data.record_columns import listed, numeric_column
from .base import RANGE_SIGMAS, RigError, RigWarning, run_rng, write_record
from ..solvers.sweep import SpeedProfile, SpeedSystem, integrate_sweep
from ..solvers.transient import NotSettledError

Array = np.ndarray

TRANSIENT_KINDS = ("runup", "coastdown")
KINDS = ("steady",) + TRANSIENT_KINDS
PLAN_SWEEP_COLUMNS = ("kind", "rpm_start", "rpm_end")
#: the Imperfections fields that only transient rows use (left out of a steady data set's truth.yaml)
SWEEP_FIELDS = ("sweep_rate_rpm_s", "sweep_shape", "sweep_wobble", "sweep_ramp_s", "dwell_start_s", "dwell_end_s",
                "sweep_sample_rate_hz", "runout_um", "probe_angles_deg")
#: displacement tolerance of a transient record's integration, relative to the start orbit's amplitude: the
#: records are written to 0.1 um against noise of ~50 um; 1e-5 of a 0.3-12 mm orbit is 3-120 nm (transient.py:
#: 1e-5 -> error <= 4e-7 of the amplitude at a constant speed)
SWEEP_ATOL_RELATIVE = 1e-5
#: the start's settle tolerance when the default's (1e-6) is not reached: measured on a run-up without added mass
#: from 100 RPM of the Geometric truth with a cross-coupled stiffness and the slope force, the harmonics' period-
#: to-period change stalls at 1.2e-6-3e-6 of the largest for 80 periods whatever the integration tolerance (a
#: persistent motion of that relative size, not integration noise); 1e-5 of a slow-roll orbit is far below the
#: records' noise, and the start's dwell follows
START_TOLERANCE_RETRY = 1e-5
#: the sweep's speed laws are fitted up to this factor above the record's highest speed (sweep.SpeedSystem)
SPEED_MARGIN = 1.1


# --- imperfections ---------------------------------------------------------------------------------------


def sweep_field_problems(imperfections) -> list[tuple[bool, str]]:
    """(ok, message) checks of the transient fields of ``rig.Imperfections``."""
    i = imperfections
    runout = tuple(i.runout_um)
    angles = dict(i.probe_angles_deg)
    return [
        (i.sweep_rate_rpm_s > 0, f"sweep_rate_rpm_s must be positive, got {i.sweep_rate_rpm_s}"),
        (i.sweep_shape in ("linear", "exponential"),
         f"sweep_shape must be 'linear' or 'exponential', got {i.sweep_shape!r}"),
        (0 <= i.sweep_wobble < 1, f"sweep_wobble must be in [0, 1) (a fraction of the rate; 1 or more would let "
                                  f"the speed reverse), got {i.sweep_wobble}"),
        (i.sweep_ramp_s > 0, f"sweep_ramp_s must be positive, got {i.sweep_ramp_s}"),
        (i.dwell_start_s >= 0 and i.dwell_end_s >= 0,
         f"dwell_start_s and dwell_end_s must be >= 0, got {i.dwell_start_s}, {i.dwell_end_s}"),
        (i.sweep_sample_rate_hz > 0, f"sweep_sample_rate_hz must be positive, got {i.sweep_sample_rate_hz}"),
        (len(runout) == 2 and all(np.isfinite(r) and r >= 0 for r in runout),
         f"runout_um must be [1X, 2X] sizes >= 0 in um, got {list(runout)}"),
        (all(isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
             for k, v in angles.items()),
         f"probe_angles_deg must map sensor names to angles in degrees, got {angles}"),
    ]


def sweep_fields_from_mapping(values: dict) -> dict:
    """``values`` (a config's imperfections) with runout_um as a pair of floats (one value: 1X only) and
    probe_angles_deg as a dict."""
    values = dict(values)
    if "runout_um" in values:
        runout = values["runout_um"]
        runout = [runout, 0.0] if np.isscalar(runout) else list(runout)
        try:
            values["runout_um"] = tuple(float(r) for r in runout)
        except (TypeError, ValueError):
            raise RigError(f"imperfections: runout_um must be [1X, 2X] in um, got {values['runout_um']}") from None
    if "probe_angles_deg" in values:
        angles = values["probe_angles_deg"]
        if not isinstance(angles, Mapping):
            raise RigError(f"imperfections: probe_angles_deg must be a mapping {{sensor: degrees}}, got {angles!r}")
        values["probe_angles_deg"] = {str(k): (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                                               else v) for k, v in angles.items()}
    return values


def probe_angles(machine, imperfections) -> dict[str, float]:
    """Every sensor's angle [deg]: the imperfections' probe_angles_deg, else 0 (an x probe) or 90 (a y probe)."""

    sensors = _sensors(machine)
    given = dict(imperfections.probe_angles_deg)
    stray = sorted(set(given) - {name for name, _, _ in sensors})
    if stray:
        raise RigError(f"imperfections: probe_angles_deg names sensor(s) {stray} the machine does not have "
                       f"(its sensors: {[name for name, _, _ in sensors]})")
    return {name: float(given.get(name, 0.0 if direction == "x" else 90.0)) for name, _, direction in sensors}


def _sensors(machine) -> list[tuple[str, int, str]]:
    """(name, node, direction) of each sensor: a Machine's, x and y at node 1 for a plain Shaft."""
    if hasattr(type(machine), "sensor_node"):
        return [(s.name, int(s.node), s.direction) for s in machine.sensors]

    return [(DEFAULT_SENSORS[0], SENSOR_NODE, "x"), (DEFAULT_SENSORS[1], SENSOR_NODE, "y")]


# --- the plan --------------------------------------------------------------------------------------------


def has_sweep_columns(path: str | Path) -> bool:
    """Whether a plan's header names kind, rpm_start or rpm_end (any case)."""
    table, _ = read_text_table(path, "\t")
    return any(c.lower() in PLAN_SWEEP_COLUMNS for c in table.columns)


def sweep_rows(plan: pd.DataFrame) -> Array:
    """(R,) bool: the plan's runup and coastdown rows."""
    if "kind" not in plan:
        return np.zeros(len(plan), bool)
    return plan["kind"].astype(str).str.lower().isin(TRANSIENT_KINDS).to_numpy()


def read_sweep_plan(path: str | Path) -> pd.DataFrame:
    """A plan with transient rows: run, rpm (NaN on transient rows), eccentric_mass_g, role, kind, rpm_start,
    rpm_end (NaN on steady rows), extra columns kept.

    When ``measurements.read_runs`` reads these columns (it does on the data side's branch), it is used; until
    then a minimal reading here checks what the rig needs, naming the file and line: run ids (present, valid,
    unique), kind (steady, runup, coastdown; empty: steady), rpm on steady rows, rpm_start and rpm_end on
    transient rows (positive, a runup rising and a coastdown falling), eccentric_mass_g (every row), role.
    """

    path = Path(path)
    if hasattr(measurements, "SWEEP_COLUMNS"):  # read_runs reads transient rows
        plan = measurements.read_runs(path, check_files=False, require_path=False)
    else:
        plan = _read_sweep_plan(path)
    unknown = plan["eccentric_mass_g"].isna()
    if unknown.any():
        raise RigError(f"{path}: the rig needs every run's eccentric mass; empty for {plan['run'][unknown].tolist()}")
    return plan.drop(columns=[c for c in ("path", "record") if c in plan])


def _read_sweep_plan(path: Path) -> pd.DataFrame:

    known = ("run", "rpm", "eccentric_mass_g", "path", "role") + PLAN_SWEEP_COLUMNS
    table, line = read_text_table(path, "\t", known)
    missing = [c for c in ("run", "eccentric_mass_g") if c not in table]
    if missing:
        raise DataError(f"{path}: a run plan needs the column(s) {missing}")
    if table.empty:
        raise DataError(f"{path}: the plan has no runs (only a header)")
    problems: list[str] = []
    n = len(table)
    empty = pd.Series([""] * n, index=table.index)
    runs = table["run"]
    bad = (runs == "") | ~runs.str.fullmatch(RUN_ID.pattern)
    problems += [f"line {ln}, column run: {v!r} is not a valid run id (letters, digits, '-', '_')"
                 for ln, v in zip(line[bad.to_numpy()], runs[bad])]
    duplicated = runs.str.lower().duplicated(keep=False) & (runs != "")
    problems += listed("column run: duplicate run id", line[duplicated.to_numpy()], list(runs[duplicated]))
    kind = table.get("kind", empty).str.lower()
    kind = kind.where(kind != "", "steady").to_numpy(str)
    problems += [f"line {ln}, column kind: {str(v)!r} is not a kind of run: use {', '.join(KINDS)} (empty: steady)"
                 for ln, v in zip(line[~np.isin(kind, KINDS)], table["kind"][~np.isin(kind, KINDS)])]
    transient = np.isin(kind, TRANSIENT_KINDS)
    steady = kind == "steady"  # neither: an unknown kind, reported above
    rpm = np.full(n, np.nan)
    cells = table.get("rpm", empty)
    rpm[steady], found = numeric_column(cells[steady], "rpm", line[steady], allow_empty=False)
    problems += found
    rpm[~steady], found = numeric_column(cells[~steady], "rpm", line[~steady], allow_empty=True)
    problems += found
    problems += [f"line {ln}, column rpm: {v:g} is not a positive speed" for ln, v in zip(line, rpm) if v <= 0]
    ends = {}
    for column in ("rpm_start", "rpm_end"):
        ends[column] = np.full(n, np.nan)
        cells = table.get(column, empty)
        ends[column][transient], found = numeric_column(
            cells[transient], column, line[transient], allow_empty=False,
            empty_hint="a runup or coastdown row needs its nominal sweep, rpm_start and rpm_end")
        problems += found
        problems += [f"line {ln}, column {column}: {v:g} is not a positive speed"
                     for ln, v in zip(line[transient], ends[column][transient]) if v <= 0]
        given = steady & (cells != "").to_numpy()
        problems += listed(f"column {column}: a speed on a steady row (set its kind, or empty the cell)",
                           line[given], list(cells[given]))
    for ln, k, a, b in zip(line[transient], kind[transient], ends["rpm_start"][transient],
                           ends["rpm_end"][transient]):
        if a > 0 and b > 0 and (a == b or (k == "runup") != (b > a)):
            problems.append(f"line {ln}, columns rpm_start, rpm_end: a {k} from {a:g} to {b:g} RPM " + (
                "never leaves one speed (a record at one speed is a steady row)" if a == b else
                f"goes the wrong way: a {k} goes {'up' if k == 'runup' else 'down'} in speed (swap them, or the "
                f"kind is {'coastdown' if k == 'runup' else 'runup'})"))
    mass, found = numeric_column(table["eccentric_mass_g"], "eccentric_mass_g", line, allow_empty=True)
    problems += found + [f"line {ln}, column eccentric_mass_g: {v:g} g is negative" for ln, v in zip(line, mass)
                         if v < 0]
    role = table.get("role", empty).str.lower()
    role = role.where(role != "", "fit")
    problems += [f"line {ln}, column role: {v!r} is not a role: use {' or '.join(ROLES)}"
                 for ln, v in zip(line[~role.isin(ROLES).to_numpy()], role[~role.isin(ROLES)])]
    if problems:
        raise DataError(f"{path}: " + "; ".join(problems))
    out = table.copy()
    out["run"], out["rpm"], out["eccentric_mass_g"], out["role"] = runs, rpm, mass, role
    out["kind"], out["rpm_start"], out["rpm_end"] = kind, ends["rpm_start"], ends["rpm_end"]
    out.attrs.update(lines=line.tolist(), source=str(path))
    return out


# --- the records -----------------------------------------------------------------------------------------


def draw_sweep_conditions(row: Mapping, imperfections, seed: int, channels: Sequence[str]) -> dict:
    """One transient row's conditions from (seed, run id) stream 0 (module docstring, step 1)."""

    rng = run_rng(seed, row["run"], 0)
    start = float(row["rpm_start"]) * (1.0 + imperfections.speed_error * rng.standard_normal())
    end = float(row["rpm_end"]) * (1.0 + imperfections.speed_error * rng.standard_normal())
    phase = rng.uniform(0.0, 2.0 * np.pi) if imperfections.random_phase else 0.0
    C = len(channels)
    offsets = rng.uniform(-imperfections.offset_mm, imperfections.offset_mm, C) * 1e-3
    noise = rng.uniform(*imperfections.noise_mm, C) * 1e-3
    runout = {}
    for order, size in zip((1, 2), imperfections.runout_um):
        magnitude = size * 1e-6 * rng.uniform(0.5, 1.0, C)
        angle = rng.uniform(0.0, 2.0 * np.pi, C)
        for i, c in enumerate(channels):
            runout[f"runout{order}_{c}_re_m"] = magnitude[i] * math.cos(angle[i])
            runout[f"runout{order}_{c}_im_m"] = magnitude[i] * math.sin(angle[i])
    return {"run": row["run"], "rpm_start_true": start, "rpm_end_true": end, "phase_origin_rad": phase,
            **{f"offset_{c}_m": offsets[i] for i, c in enumerate(channels)},
            **{f"noise_{c}_m": noise[i] for i, c in enumerate(channels)}, **runout}


def sweep_profile(row: Mapping, conditions: Mapping, imperfections, seed: int) -> SpeedProfile:
    """The row's true speed profile (module docstring, step 2); its wobble from (seed, run id) stream 2."""

    sweep_s = abs(float(row["rpm_end"]) - float(row["rpm_start"])) / imperfections.sweep_rate_rpm_s
    return SpeedProfile.sweep(conditions["rpm_start_true"], conditions["rpm_end_true"], sweep_s,
                              dwell_start_s=imperfections.dwell_start_s, dwell_end_s=imperfections.dwell_end_s,
                              ramp_s=min(imperfections.sweep_ramp_s, sweep_s / 4.0), shape=imperfections.sweep_shape,
                              wobble=imperfections.sweep_wobble, rng=run_rng(seed, row["run"], 2),
                              theta0=conditions["phase_origin_rad"])


def synthesise_sweep(truth, row: Mapping, conditions: Mapping, imperfections, seed: int, harmonics: int,
                     channels: Sequence[str]) -> tuple[dict, dict]:
    """One transient record's columns [SI] (time_s, <c>_m, keyphasor, clipped) and its answer-key entries."""

    machine = truth.machine
    profile = sweep_profile(row, conditions, imperfections, seed)
    fs = imperfections.sweep_sample_rate_hz
    n = int(round(profile.t1 * fs)) + 1
    t = np.arange(n) / fs
    values = truth.run_values(row["eccentric_mass_g"], row.get(TRIAL_ANGLE_COLUMN, 0.0))
    rpm_max = max(conditions["rpm_start_true"], conditions["rpm_end_true"]) * SPEED_MARGIN
    system = SpeedSystem.from_model(truth.variant.model, values, rpm_max)
    sensors = _sensors(machine)
    angles = probe_angles(machine, imperfections)
    nodes = sorted({node for _, node, _ in sensors})
    dofs = [machine.dof(f"{p}{node}") for node in nodes for p in ("u", "v")]
    try:
        try:
            result = integrate_sweep(system, profile, t, dofs, harmonics=harmonics,
                                     atol_relative=SWEEP_ATOL_RELATIVE)
        except NotSettledError as err:
            if not err.budget:  # diverged, or Radau failed: not a matter of tolerance
                raise
            result = integrate_sweep(system, profile, t, dofs, harmonics=harmonics, atol_relative=SWEEP_ATOL_RELATIVE,
                                     settle_options={"tolerance": START_TOLERANCE_RETRY})
            result.start += f" to {START_TOLERANCE_RETRY:g} (the default tolerance not reached: {err})"
    except NotSettledError as err:
        raise RigError(f"run {row['run']}: the truth's {row['kind']} could not be integrated: {err}") from None
    noise_rng = run_rng(seed, row["run"], 1)
    limit = imperfections.sensor_range_mm * 1e-3
    rotation1, rotation2 = np.exp(1j * result.theta), np.exp(2j * result.theta)
    out: dict = {"time_s": t}
    clipped = np.zeros(n, bool)
    key: dict = {}
    inside = True
    for name, node, _ in sensors:
        a = math.radians(angles[name])
        k = nodes.index(node)
        clean = math.cos(a) * result.displacements[:, 2 * k] + math.sin(a) * result.displacements[:, 2 * k + 1]
        R1 = conditions[f"runout1_{name}_re_m"] + 1j * conditions[f"runout1_{name}_im_m"]
        R2 = conditions[f"runout2_{name}_re_m"] + 1j * conditions[f"runout2_{name}_im_m"]
        wave = clean + (R1 * rotation1 + R2 * rotation2).real + conditions[f"offset_{name}_m"]
        z = wave + conditions[f"noise_{name}_m"] * noise_rng.standard_normal(n)
        clipped |= np.abs(z) > limit
        out[f"{name}_m"] = np.clip(z, -limit, limit) if imperfections.clip else z
        peak = float(np.abs(wave).max())
        key[f"peak_{name}_m"] = peak
        key[f"probe_angle_{name}_deg"] = angles[name]
        inside &= peak + RANGE_SIGMAS * conditions[f"noise_{name}_m"] < limit
    first = math.ceil(result.theta[0] / (2 * math.pi) - 1e-12)
    last = math.floor(result.theta[-1] / (2 * math.pi))
    marks = profile.times_at_angles(2 * math.pi * np.arange(first, last + 1))
    index = np.round(marks * fs).astype(int)
    keyphasor = np.zeros(n, np.int8)
    keyphasor[index[(index >= 0) & (index < n)]] = 1
    out |= {"keyphasor": keyphasor, "clipped": clipped}
    summary = profile.summary()
    key |= {k: v for k, v in summary.items() if k not in ("rpm_start_true", "rpm_end_true")}
    key |= {"record_duration_s": float(t[-1]), "sample_rate_hz": fs, "keyphasor_marks": int(keyphasor.sum()),
            "inside_range": bool(inside), "clipped_samples": int(clipped.sum()), "radau_steps": result.steps,
            "branch": f"time {row['kind']}", "message": f"start {result.start}; {result.steps} Radau steps",
            "polynomial_speed_laws": system.polynomial}
    return out, key


def check_sweep_plan(plan: pd.DataFrame, sweeps: Array, spec) -> None:
    """Before any record is made: probe angles name the machine's sensors, and steady rows (which read the model's
    x and y) are not given rotated probes."""

    angles = probe_angles(spec.truth.machine, spec.imperfections)
    default = probe_angles(spec.truth.machine, replace(spec.imperfections, probe_angles_deg={}))
    if angles != default and not sweeps.all():
        raise RigError(f"imperfections: probe_angles_deg {dict(spec.imperfections.probe_angles_deg)} applies to "
                       "run-ups and coast-downs only: the plan's steady rows read the model's x and y (give them "
                       "their own plan)")


def sweep_records(plan: pd.DataFrame, sweeps: Array, steady_truth: pd.DataFrame | None, spec, out_dir: Path,
                  channels: Sequence[str]) -> pd.DataFrame:
    """Write the transient rows' records; the answer key of the whole plan (steady rows from ``steady_truth``),
    in the plan's order."""

    imperfections = spec.imperfections
    rows = []
    for _, row in plan[sweeps].iterrows():
        conditions = draw_sweep_conditions(row, imperfections, spec.seed, channels)
        record, key = synthesise_sweep(spec.truth, row, conditions, imperfections, spec.seed, spec.harmonics,
                                       channels)
        write_record(out_dir / "records" / f"{row['run']}.csv", record, imperfections.unit, channels)
        entry = {**row.to_dict(), "rpm_true": np.nan, **conditions, **key, "updown_difference_rel": np.nan,
                 "unique": np.nan, "stable": np.nan, "floquet_radius": np.nan}
        rows.append(entry)
        if not key["inside_range"]:
            peak = max(key[f"peak_{c}_m"] for c in channels) * 1e3
            action = (f"{key['clipped_samples']} sample(s) clipped" if imperfections.clip else "not clipped (clip off)")
            warnings.warn(f"run {row['run']}: the {row['kind']} reaches {peak:.2f} mm (+ noise) against the sensor "
                          f"range +-{imperfections.sensor_range_mm:g} mm: {action}", RigWarning, stacklevel=3)
    table = pd.DataFrame(rows)
    if steady_truth is not None:
        table = pd.concat([steady_truth, table], ignore_index=True)
    order = {run: i for i, run in enumerate(plan["run"])}
    return table.sort_values("run", key=lambda s: s.map(order)).reset_index(drop=True)
