"""Why the fits' own intervals miss on run-ups: the systematic part of an estimate, per order and band.

    python benchmarks/transient_interval_study.py --case excitation_3x [--seed 38] [--quiet 0.1]
        [--quiet-sweep-rate 5] [--drop up0:600,up0:620] [--data results/benchmarks/transient_diagnosis_data]

On one case of ``benchmarks/transient_diagnosis_benchmark.py`` (its records, kept in ``--data`` and reused), the
Geometric model plus the case's hidden effect(s), every parameter free (the hidden ones in a range of +-10 times
their value around it), is fitted to the benchmark's usable bands (the form the diagnosis ends with, here given).
Printed:

1. the estimates with their standard errors, and each order's chi^2 over its numbers (a per-order check of the
   bands' sigmas: 1 where they are right);
2. the cluster sandwich (one cluster per band: its 2 H C residuals; the prior rows as information): its standard
   error over the linearised one, a measure of what the bands' misfit and heteroscedasticity do to the intervals;
3. with ``--quiet F``: the same bands (the same names, the noisy records' selection) from records made anew with the
   noise times F and everything else equal (same seed: runout, offsets, speed profile), fitted alike: an estimate's
   systematic part (what does not shrink with the noise) against the noisy fit's standard error, and the bands whose
   residual in the quiet records is largest in units of the noisy sigma (a systematic below the noise per band that
   many bands share);
   ``--quiet-sweep-rate R``: the quiet records swept at R RPM/s instead of the example's rate (a systematic that
   scales with R is the sweep's, a first-order transient effect the quasi-steady model leaves out);
4. with ``--drop RUN:RPM,...``: both fits again without those bands (the band of record RUN nearest RPM).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnosis_benchmark import CASES, TRUTH  # noqa: E402
from transient_diagnosis_benchmark import EXAMPLE, band_table, fit_case_form, make_data  # noqa: E402

from hybridtwin.data.measured import run_data  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def all_bands(where: Path, harmonics: int) -> dict:
    """Every band of the records in ``where`` (usable or not), by run name: the quiet records' bands are chosen by
    the noisy records' selection, not by their own sweep check (whose sigmas are F times smaller)."""
    table = band_table(where, harmonics).assign(usable=True)
    return {run: run_data(table, run, harmonics) for run in table["run"]}


def fit_truth_form(case: str, data: list, harmonics: int, config: dict):
    """The Geometric variant plus the case's hidden effect(s), every parameter free (the hidden ones in +-10 times
    their value around it), fitted to ``data``."""
    values = CASES[case][1]
    unknown = dict(config["variants"]["geometric"]["unknown"]) | {p: sorted([v - 10 * abs(v), v + 10 * abs(v)])
                                                                  for p, v in values.items()}
    return fit_case_form(case, data, config, harmonics, unknown, trials=3)


def fit_sigmas(fit) -> dict:
    """{run: (H, C) sigma [m]} as the fit weighs each band: its sigma with the runout estimate's share taken out
    where the record's runout offsets are fitted (``arrow_problem``'s module docstring), else the band's own."""
    return {d.run: fit.problem.sigma[k] for k, d in enumerate(fit.data)}


def per_order(fit, sigma_of=None) -> list[tuple[float, int]]:
    """Each order's (chi^2, numbers) at the fit (the fitted runout offsets in the model, the sigmas the fit weighs
    with); ``sigma_of``: {run: (H, C) sigma} to measure in instead."""
    F = fit.fitted()
    sigma_of = fit_sigmas(fit) if sigma_of is None else sigma_of
    out = []
    for h in range(F.shape[1]):
        chi2 = n = 0
        for k, d in enumerate(fit.data):
            s = sigma_of[d.run][h]
            z = (d.X[h] - F[k, h]) / s
            chi2, n = chi2 + float(np.sum(z.real ** 2 + z.imag ** 2)), n + 2 * z.size
        out.append((chi2, n))
    return out


def sandwich_ratio(fit) -> np.ndarray:
    """The cluster sandwich's standard error (one cluster per band) over the linearised one, per entry."""
    r, J = np.asarray(fit.fun), np.asarray(fit.jac)
    rows = [2 * d.X.size for d in fit.data]
    m = int(sum(rows))
    A_inv = np.linalg.pinv(J.T @ J)
    B = J[m:].T @ J[m:]  # the prior rows: their information as it is
    start = 0
    for n in rows:
        g = J[start:start + n].T @ r[start:start + n]
        B += np.outer(g, g)
        start += n
    naive = np.sqrt(np.diag(A_inv) * max(1.0, fit.chi2_dof))
    return np.sqrt(np.abs(np.diag(A_inv @ B @ A_inv))) / naive


def report(label: str, fit, truth: dict, reference=None, sigma_of=None) -> None:
    stats = fit.statistics()
    ref = fit if reference is None else reference
    ref_stderr = ref.statistics()["stderr"]
    print(f"{label}: {len(fit.data)} bands, chi^2/dof {fit.chi2_dof:.4f}; per order (chi^2 / numbers"
          f"{' in the noisy sigmas' if sigma_of else ''}): "
          + ", ".join(f"{h + 1}X {c:.1f}/{n}" for h, (c, n) in enumerate(per_order(fit, sigma_of))))
    ratio = sandwich_ratio(fit)
    for name, value in truth.items():
        i, j = fit.entry(name), ref.entry(name)
        se = ref_stderr[j]
        print(f"  {name:9s} {fit.x[i]:.6g} +- {stats['stderr'][i]:.3g} (truth {value:g}: off by "
              f"{(fit.x[i] - value) / se:+.2f} of the noisy fit's stderr); sandwich / linearised {ratio[i]:.2f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="excitation_3x", choices=sorted(CASES))
    parser.add_argument("--seed", type=int, default=38)
    parser.add_argument("--harmonics", type=int, default=3)
    parser.add_argument("--quiet", type=float, default=None, help="noise factor of the quiet records (e.g. 0.1)")
    parser.add_argument("--quiet-sweep-rate", type=float, default=None,
                        help="the quiet records' sweep rate [RPM/s] (default: the example's)")
    parser.add_argument("--drop", default="", help="bands left out, RUN:RPM,... (the band of RUN nearest RPM)")
    parser.add_argument("--data", default=str(ROOT / "results/benchmarks/transient_diagnosis_data"))
    args = parser.parse_args()
    config = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    _, values, _ = CASES[args.case]
    truth = dict(TRUTH) | dict(values)
    truth = {k: v for k, v in truth.items() if k not in ("q_x", "q_y")}
    with threadpool_limits(1):
        where = Path(args.data) / f"seed{args.seed}" / args.case
        where.mkdir(parents=True, exist_ok=True)
        noisy, _, _, _ = make_data(args.case, where, args.seed, args.harmonics)
        drop = [(s.split(":")[0], float(s.split(":")[1])) for s in args.drop.split(",") if s.strip()]

        def dropped(data):
            out = list(data)
            for run, rpm in drop:
                mine = [d for d in out if d.record == run]
                if mine:
                    out.remove(min(mine, key=lambda d: abs(d.rpm - rpm)))
            return out

        sets = [("all usable bands", noisy)] + ([("without " + args.drop, dropped(noisy))] if drop else [])
        fits = {}
        for label, data in sets:
            fits[label] = fit_truth_form(args.case, data, args.harmonics, config)
            report(f"noisy records, {label}", fits[label], truth)
        if args.quiet:
            rate = "" if args.quiet_sweep_rate is None else f"_rate{args.quiet_sweep_rate:g}"
            quiet_dir = Path(args.data) / f"quiet{args.quiet:g}{rate}_seed{args.seed}" / args.case
            quiet_dir.mkdir(parents=True, exist_ok=True)
            noise_mm = yaml.safe_load((EXAMPLE / "config/config.yaml").read_text())["rig"]["runup"][
                "imperfections"]["noise_mm"]
            override = {"noise_mm": args.quiet * noise_mm}
            if args.quiet_sweep_rate is not None:
                override["sweep_rate_rpm_s"] = args.quiet_sweep_rate
            make_data(args.case, quiet_dir, args.seed, args.harmonics, imperfections=override)
            bands = all_bands(quiet_dir, args.harmonics)
            for label, data in sets:
                sigma_of = fit_sigmas(fits[label])  # the noisy fit's weights, band by band
                missing = [d.run for d in data if d.run not in bands]
                if missing:
                    print(f"  the quiet records have no band {', '.join(missing)}: left out of both fits below")
                quiet = [bands[d.run] for d in data if d.run in bands]
                fit = fit_truth_form(args.case, quiet, args.harmonics, config)
                report(f"quiet records (noise x {args.quiet:g}), {label}", fit, truth, fits[label], sigma_of)
                F = fit.fitted()
                worst = sorted(((float(np.abs((d.X - F[k]) / sigma_of[d.run]).max()), d.run,
                                 int(np.unravel_index(np.abs((d.X - F[k]) / sigma_of[d.run]).argmax(), d.X.shape)[0]) + 1)
                                for k, d in enumerate(fit.data)), reverse=True)[:6]
                print("  largest quiet residuals, in the noisy sigmas: "
                      + ", ".join(f"{run} {h}X {z:.2f}" for z, run, h in worst))
    return 0


if __name__ == "__main__":
    sys.exit(main())
