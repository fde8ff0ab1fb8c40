"""``hybridtwin rig``: the virtual rig's data set from the command line (docs/model.md, "The rig and its measured
runs"). The rig itself is the data stage's (``hybridtwin.rig.rig``); this is the command line around it."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import pandas as pd

from ..data.measurements import DataError
from ..rig.rig import (
    INTEGRATORS, UNIT_SCALES, Imperfections, RigError, RigSpec, RigWarning, Truth, generate, load_spec, peak_columns,
    read_plan,
)
from .common import config_file, load_catalog


def add_rig_command(sub) -> None:
    """Register ``hybridtwin rig`` on the CLI's subparsers."""
    parser = sub.add_parser(
        "rig", help="virtual rig: write measured-format records from a truth model with hidden effects",
        description="Generate a data set (runs.tsv, records/*.csv, and the answer key truth.tsv, truth.yaml) "
                    "for a run plan from a truth model: steady state by run-up at each run's true speed (checked "
                    "against a run-down; harmonic balance or, with --integrator time, time integration), then "
                    "sampling, random phase origin, DC offsets, Gaussian noise, optional keyphasor and clipping. "
                    "Seeded and reproducible. The truth is built on the config's machine (its 'machine:' section; the "
                    "VARM without one) and its probes give the records' x and y. Defaults: the paper's final model "
                    "(Geometric + slope spring, Table 5) with the bundled data's bow, 4 s at 2 kHz, 0.1 % speed "
                    "error, 0.05 mm noise, +-0.5 mm offsets, no keyphasor, clipping at +-14 mm.")
    parser.add_argument("--plan", type=Path, default=None,
                        help="run plan TSV (run, rpm, eccentric_mass_g[, role]; a row of kind runup or coastdown "
                             "with rpm_start, rpm_end and rpm empty is a transient record made by time "
                             "integration along a speed profile); a runs sheet works too (default: the spec's plan)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--spec", type=Path, default=None,
                        help="YAML with truth: {effects, values}, imperfections: {...}, seed, harmonics "
                             "(the form of the workflow config's rig entries)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the spec's, else 0)")
    parser.add_argument("--set", dest="values", action="append", default=[], metavar="NAME=VALUE",
                        help="truth parameter value in SI units (repeatable), e.g. --set q_x=0.003")
    parser.add_argument("--effects-file", type=Path, action="append", default=[],
                        help="Python file defining extra Effect instances for the truth (repeatable)")
    parser.add_argument("--config", type=Path, default=None,
                        help="workflow config whose 'machine:' the truth is built on (and whose 'effects_files:' "
                             "it may use); default ./config/config.yaml when it exists, else the VARM")
    parser.add_argument("--harmonics", type=int, default=None, help="harmonics 0..H of the truth (default 7)")
    parser.add_argument("--integrator", choices=INTEGRATORS, default=None,
                        help="steady states by harmonic balance (hb, default) or by time integration (time: "
                             "independent of the solver the identification uses; ~80 s instead of ~2 s for the "
                             "bundled 22 runs)")
    group = parser.add_argument_group("imperfections (override the spec)")
    group.add_argument("--duration-s", type=float, default=None, help="record length [s] (default 4)")
    group.add_argument("--sample-rate-hz", type=float, default=None, help="sampling rate [Hz] (default 2000)")
    group.add_argument("--speed-error", type=float, default=None,
                       help="std of the relative speed error (default 0.001)")
    group.add_argument("--noise-mm", type=float, nargs="+", default=None, metavar="MM",
                       help="Gaussian noise std [mm], or LOW HIGH drawn per run and channel (default 0.05)")
    group.add_argument("--offset-mm", type=float, default=None, help="DC offsets uniform in +-MM (default 0.5)")
    group.add_argument("--keyphasor", action=argparse.BooleanOptionalAction, default=None,
                       help="write a keyphasor column (default no)")
    group.add_argument("--random-phase", action=argparse.BooleanOptionalAction, default=None,
                       help="random rotor angle at the first sample (default yes)")
    group.add_argument("--clip", action=argparse.BooleanOptionalAction, default=None,
                       help="clip at +-sensor range like a saturated sensor (default yes)")
    group.add_argument("--sensor-range-mm", type=float, default=None, help="sensor range [mm] (default 14)")
    group.add_argument("--unit", choices=tuple(UNIT_SCALES), default=None, help="displacement unit of the records")
    group.add_argument("--sweep-rate-rpm-s", type=float, default=None,
                       help="run-ups and coast-downs (plan rows of kind runup/coastdown): nominal rate (default 10)")
    group.add_argument("--sweep-sample-rate-hz", type=float, default=None,
                       help="run-ups and coast-downs: sample rate [Hz] (default 5000)")
    parser.set_defaults(handler=rig_command)


def rig_command(args) -> int:
    """``hybridtwin rig``: generate, print a per-run report; 0 ok, 1 on an unusable spec or plan."""
    _, config_effects, machine = load_catalog(config_file(args.config), [])
    try:
        spec, spec_plan = load_spec(args.spec, args.effects_file, machine, config_effects)
        spec = _override(spec, args)
        plan_path = args.plan or spec_plan
        if plan_path is None:
            raise RigError("no run plan: give --plan (or 'plan:' in the --spec file)")
        plan = read_plan(plan_path)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RigWarning)
            truth = generate(plan, spec, args.out)
    except (RigError, DataError) as err:
        print(f"hybridtwin rig: error: {err}", file=sys.stderr)
        return 1
    sweep = {c: truth[c] for c in ("kind", "rpm_start", "rpm_end") if c in truth}  # run-ups and coast-downs
    report = pd.DataFrame({
        "run": truth["run"], "rpm": truth["rpm"], **sweep, "eccentric_mass_g": truth["eccentric_mass_g"],
        "rpm_true": truth["rpm_true"].round(3), "unique": truth["unique"], "stable": truth["stable"],
        "updown_diff_rel": truth["updown_difference_rel"].map(lambda v: f"{v:.1e}"),
        **{f"{c[:-2]}_mm": (1e3 * truth[c]).round(3) for c in peak_columns(truth)},
        "inside_range": truth["inside_range"], "clipped_samples": truth["clipped_samples"],
    })
    print(report.to_string(index=False))
    for warning in caught:
        print(f"hybridtwin rig: warning: {warning.message}", file=sys.stderr)
    print(f"# wrote {len(truth)} record(s), runs.tsv, truth.tsv and truth.yaml to {args.out} (seed {spec.seed})",
          file=sys.stderr)
    return 0


def _override(spec: RigSpec, args) -> RigSpec:
    """The spec with the command line's explicit options applied."""
    values = dict(spec.truth.values)
    for text in args.values:
        name, sep, value = text.partition("=")
        try:
            values[name.strip()] = float(value)
        except ValueError:
            raise RigError(f"--set expects NAME=VALUE with a number, got {text!r}") from None
        if not sep:
            raise RigError(f"--set expects NAME=VALUE, got {text!r}")
    truth = Truth.from_spec({"effects": [e.name for e in spec.truth.variant.model.effects], "values": values,
                             "description": spec.truth.variant.description},
                            {e.name: e for e in spec.truth.variant.model.effects}, spec.truth.machine)
    names = {"duration_s": "duration_s", "sample_rate_hz": "sample_rate_hz", "speed_error": "speed_error",
             "offset_mm": "offset_mm", "keyphasor": "keyphasor", "random_phase": "random_phase", "clip": "clip",
             "sensor_range_mm": "sensor_range_mm", "unit": "unit", "sweep_rate_rpm_s": "sweep_rate_rpm_s",
             "sweep_sample_rate_hz": "sweep_sample_rate_hz"}
    imperfections = spec.imperfections.to_mapping()
    imperfections.update({key: getattr(args, arg) for arg, key in names.items() if getattr(args, arg) is not None})
    if args.noise_mm is not None:
        if len(args.noise_mm) > 2:
            raise RigError(f"--noise-mm takes one value or LOW HIGH, got {args.noise_mm}")
        imperfections["noise_mm"] = args.noise_mm
    return RigSpec(truth, Imperfections.from_mapping(imperfections),
                   spec.seed if args.seed is None else args.seed,
                   spec.harmonics if args.harmonics is None else args.harmonics,
                   spec.start_rpm, spec.step_rpm, spec.rundown_margin_rpm,
                   spec.integrator if args.integrator is None else args.integrator)
