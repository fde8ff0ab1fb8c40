"""Sweep-rate study: when is a run-up or coast-down quasi-steady? Measured on the virtual rig's truth.

    OMP_NUM_THREADS=1 python benchmarks/sweep_rate_study.py [--rates 5,10,20,50,100] [--mass-g 0]
                                                            [--rpm 700,1200] [--band 50] [--noise-mm 0.05]
                                                            [--sample-rate-hz 5000] [--out FILE.tsv]

The truth is the rig's default (config/config.yaml's rig entry ``default``, data/default/truth.yaml: the
Geometric model + slope spring, bow q_x 2 mm, q_y 1.5 mm), with the eccentric mass ``--mass-g`` (default 0: the
bow alone; its 1X resonance near 980 RPM, 11.8 mm at the sensor, one branch). For each rate, a run-up and a
coast-down through ``--rpm`` (linear profile, 1 s dwell, 0.5 s onset ramps, no wobble), integrated in time
(hybridtwin.solvers.sweep: Radau on the equations of motion with Omega(t), theta(t) and the inertial Omega' term,
started on the harmonic-balance orbit at the start speed), its 1X vector fitted per revolution at the sensors
x and y (``sweep.order_vectors``); the quasi-steady 1X is harmonic balance continued along the same speeds in
the sweep's direction (``continuation.solve_sweep``, H = 7).

Printed per rate and direction: the quasi-steady and transient peaks (0-peak, the larger sensor) and their
speeds, the attenuation 1 - peak_transient / peak_qs, the peak's shift [RPM], the largest vector error
max |X_tr - X_qs| / peak_qs, the same predicted by the criterion (``sweep_rate.sweep_rate_check``: one mode,
omega_n and zeta of the model's Campbell diagram at rest, first-order adiabatic theory) and eta / zeta^2; then
per speed band the measured and predicted errors against the noise-to-amplitude ratio of a one-revolution
1X vector (noise sigma sqrt(2 / samples per revolution) / peak_qs), and the verdicts.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from hybridtwin.solvers.continuation import solve_sweep  # noqa: E402
from hybridtwin.model.model import campbell  # noqa: E402
from hybridtwin.rig.rig import Truth  # noqa: E402
from hybridtwin.model.sensor import sensor_dofs  # noqa: E402
from hybridtwin.solvers.solver import solve  # noqa: E402
from hybridtwin.solvers.sweep import SpeedProfile, SpeedSystem, integrate_sweep, order_vectors  # noqa: E402
from hybridtwin.solvers.sweep_rate import dimensionless_rate, sweep_rate_check  # noqa: E402


def run(rate: float, direction: str, rpm: tuple[float, float], truth: Truth, values: dict, system: SpeedSystem,
        dofs: list[int], sample_rate: float) -> dict:
    lo, hi = rpm
    start, end = (lo, hi) if direction == "up" else (hi, lo)
    sweep_s = (hi - lo) / rate
    profile = SpeedProfile.sweep(start, end, sweep_s, dwell_start_s=1.0, ramp_s=min(0.5, sweep_s / 4))
    t = np.arange(0.0, profile.t1 + 1e-9, 1.0 / sample_rate)
    hb = solve(truth.variant.model.system(values, start), 7)
    clock = time.process_time()
    result = integrate_sweep(system, profile, t, dofs, start=hb)
    cpu = time.process_time() - clock
    speeds, X = order_vectors(t, result.theta, result.displacements)
    order = np.argsort(speeds) if direction == "up" else np.argsort(-speeds)
    sweep = solve_sweep(lambda r, rows: truth.variant.model.system(values, r), speeds[order], 1, harmonics=7,
                        direction=direction, stability=False)
    X_qs = np.empty_like(X)
    X_qs[order] = np.array([r.harmonics[0][1, dofs] for r in sweep.results])
    return {"speeds": speeds, "X": X, "X_qs": X_qs, "cpu": cpu, "steps": result.steps,
            "revolutions": (result.theta[-1] - result.theta[0]) / (2 * math.pi)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rates", default="5,10,20,50,100", help="sweep rates [RPM/s], comma-separated")
    parser.add_argument("--mass-g", type=float, default=0.0)
    parser.add_argument("--rpm", default="700,1200", help="the sweep's lower and upper speed [RPM]")
    parser.add_argument("--band", type=float, default=50.0, help="speed band width [RPM] of the per-band table")
    parser.add_argument("--noise-mm", type=float, default=0.05, help="noise sigma per sample [mm]")
    parser.add_argument("--sample-rate-hz", type=float, default=5000.0,
                        help="the record's sample rate for the noise of a 1X vector (the study samples at 2 kHz)")
    parser.add_argument("--directions", default="up,down")
    parser.add_argument("--out", type=Path, default=None, help="per-band table as TSV")
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    rpm = tuple(float(r) for r in args.rpm.split(","))
    truth = Truth.from_spec()
    values = truth.variant.values({**truth.values, "m_e": args.mass_g * 1e-3})
    model = truth.variant.model
    system = SpeedSystem.from_model(model, values, rpm[1] * 1.2)
    dofs = sensor_dofs(model.shaft)
    scalar = {k: float(np.atleast_1d(v)[0]) for k, v in values.items()}
    modes = campbell(model, scalar, [0.0], n_modes=1)
    f_hz, zeta = float(modes["frequency_hz"].iloc[0]), float(modes["damping_ratio"].iloc[0])
    omega_n = 2 * math.pi * f_hz / math.sqrt(1 - zeta ** 2)
    print(f"# truth: {truth.variant.description}; eccentric mass {args.mass_g:g} g; first mode at rest "
          f"{f_hz:.3f} Hz, zeta {zeta:.4f} (Campbell); crossing {omega_n / math.sqrt(2) * 30 / math.pi:.0f} RPM")
    rows, bands = [], []
    for direction in args.directions.split(","):
        for rate in rates:
            r = run(rate, direction, rpm, truth, values, system, dofs, 2000.0)
            amp, amp_qs = np.abs(r["X"]).max(1), np.abs(r["X_qs"]).max(1)
            i, j = int(np.argmax(amp)), int(np.argmax(amp_qs))
            peak_qs = amp_qs[j]
            error = np.abs(r["X"] - r["X_qs"]).max(1) / peak_qs
            samples_per_rev = args.sample_rate_hz * 60.0 / r["speeds"][j]
            noise_ratio = args.noise_mm * 1e-3 * math.sqrt(2.0 / samples_per_rev) / peak_qs
            predicted = sweep_rate_check([(omega_n, zeta)], rate, noise_ratio, *rpm, band_rpm=args.band)
            rows.append({"direction": direction, "rate_rpm_s": rate,
                         "eta_over_zeta2": dimensionless_rate(rate, omega_n, zeta),
                         "peak_qs_mm": 1e3 * peak_qs, "rpm_peak_qs": r["speeds"][j],
                         "peak_tr_mm": 1e3 * amp[i], "rpm_peak_tr": r["speeds"][i],
                         "attenuation": 1 - amp[i] / peak_qs, "shift_rpm": r["speeds"][i] - r["speeds"][j],
                         "max_error": error.max(), "predicted_error": max(b.expected_error for b in predicted),
                         "noise_ratio": noise_ratio, "cpu_s": r["cpu"], "revolutions": r["revolutions"]})
            for b in predicted:
                inside = (r["speeds"] >= b.rpm_low) & (r["speeds"] < b.rpm_high)
                measured = float(error[inside].max()) if inside.any() else float("nan")
                bands.append({"direction": direction, "rate_rpm_s": rate, "band_rpm": f"{b.rpm_low:.0f}-{b.rpm_high:.0f}",
                              "measured_error": measured, "predicted_error": b.expected_error,
                              "noise_ratio": noise_ratio,
                              "measured_verdict": "ok" if measured <= noise_ratio else "too fast",
                              "predicted_verdict": b.verdict})
            last = rows[-1]
            print(f"# {direction} {rate:g} RPM/s: {r['revolutions']:.0f} revolutions, {r['steps']} Radau steps, "
                  f"{r['cpu']:.1f} s CPU; " + ", ".join(f"{k} {v:.4g}" for k, v in last.items()
                                                       if isinstance(v, float)), flush=True)
    table = pd.DataFrame(rows)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        band_table = pd.DataFrame(bands)
        print(band_table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        band_table.to_csv(args.out, sep="\t", index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
