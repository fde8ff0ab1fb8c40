"""Coverage of the intervals over a loose parameter (issue 41, item 2), over seeds.

The case the issue reports: the bundled plan's 19 fit runs made by our harmonic-balance solver from the bundled
truth (Geometric + the slope force k_w u' + k_z u'^3, k_z = 301.1 N), Gaussian noise of the bundled records' sigma
(8e-7 m per real and imaginary part), no keyphasor; fitted with the variant that carries the whole slope force
(geometric + slope_spring, k_z in [0, 1000] N) and the bow per run, as the config's former `geometric_slope`. k_z is
barely seen by these runs, so it lands at a range edge or is not identifiable, and the other intervals depend on
where it lands.

Per seed and shared parameter, whether the truth lies inside

- ``linear``: the linearised interval (``uncertainty.analyse_uncertainty``: the loose parameter as if free);
- ``profile``: the one-degree profile-likelihood interval (chi^2 rise s^2 chi2_1(0.95), the loose ones free);
- ``projection``: the workflow's (``hybridtwin.identify.profile``): the shadow of the joint region of the parameter
  and the loose ones (s^2 chi2_(1 + loose)(0.95)), united with the linearised one.

The two profile intervals are not searched here: the truth lies inside a profile interval exactly when its own
profile value, the chi^2 with the parameter held at its truth and the rest refitted, rises by less than the
threshold. One fit per parameter (from the optimum and from the truth, the lower kept) gives that. H = 3 harmonics
(the workflow's 5 cost twice as much; the 1X and 2X carry the information).

    OMP_NUM_THREADS=1 python benchmarks/interval_profile_coverage.py [--seeds 12] [--harmonics 3]

``--bundled HARMONICS`` instead fits that variant (the bow per run, ``fit_joint`` on the full solver as with
``offline.scope: none``, the workflow's identification options, H = 5) to the bundled records' measured harmonics
(a main job's results/data/harmonics.tsv) and prints each shared parameter's interval linearised (the profile off)
and over the loose one (the workflow's), against the truth (data/default/truth.yaml).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from hybridtwin.data.measurements import read_runs
from hybridtwin.identify import forward as fwd
from hybridtwin.identify.arrow_problem import Layout
from hybridtwin.identify import identification as idn
from hybridtwin.identify.lm import levenberg_marquardt
from hybridtwin.identify.profile import OPTIONS, threshold
from hybridtwin.identify.protocol import ProtocolOptions
from hybridtwin.identify.uncertainty import loose_entries
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant
from hybridtwin.settings import IdentificationSettings

TRUTH = {"k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "k_w": 324.2, "k_z": 301.1, "q_x": 0.002, "q_y": 0.0015}
SIGMA = 8e-7  # m, the bundled records' harmonic sigma (results/data/harmonics.tsv: 6-10e-7)
GEOMETRIC = BUILTIN_VARIANTS["geometric"]
SPEC = {"effects": GEOMETRIC["effects"] + ["slope_spring"],
        "unknown": dict(GEOMETRIC["unknown"]) | {"k_w": (0.0, 1000.0), "k_z": (0.0, 1000.0)}}
SHARED = ["k_b", "zeta_s", "zeta_bup", "k_w", "k_z"]


def fit_runs(sheet: str = "data/default/runs.tsv") -> list[tuple[str, float, float]]:
    runs = read_runs(sheet)
    runs = runs[runs["role"] == "fit"]
    return [(r.run, float(r.rpm), float(r.eccentric_mass_g)) for r in runs.itertuples()]


def case(seed: int, H: int, runs: list[tuple[str, float, float]]) -> list[dict]:
    variant = Variant.from_spec("geometric_slope", SPEC)
    names = list(variant.unknown)
    lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
    models = [fwd.SolverModel(variant, run, rpm, mass, names, lower, upper, H) for run, rpm, mass in runs]
    x_true = np.array([[2 * (TRUTH[p] - lo) / (hi - lo) - 1 for p, lo, hi in zip(names, lower, upper)]])
    rng = np.random.default_rng(seed)
    data = []
    for (run, rpm, mass), model in zip(runs, models):
        M = model.evaluate(x_true, jacobian=False)[0][0]
        phase = rng.uniform(-np.pi, np.pi)  # no keyphasor: each record's time origin arbitrary
        M = M * np.exp(1j * np.arange(1, H + 1) * phase)[:, None]
        data.append(idn.RunData(run, rpm, mass, "fit", M + SIGMA * (rng.standard_normal(M.shape)
                                                                    + 1j * rng.standard_normal(M.shape)),
                                np.full(M.shape, SIGMA)))
    layout = Layout.for_data(names, lower, upper, data, ["q_x", "q_y"])
    truth_theta = np.array([0.0 if p == "phase" else float(layout.normalise(p, TRUTH[p])) for p, _ in layout.entries()])
    fit = idn.identify(models, data, ["q_x", "q_y"], ProtocolOptions(trials=2, monte_carlo=0, seed=seed),
                       extra_starts=truth_theta)  # the truth's phases are set by the first LM step (1X aligned)
    u, L = fit.uncertainty, fit.layout
    loose = loose_entries(L, u.at_bound, u.identifiable)
    table = fit.table().set_index(["parameter", "run"])
    base = float(fit.problem.evaluate(fit.theta[None], fit.X[None], jacobian=False).objective[0])
    index = [L.entries().index((p, "all")) for p in SHARED]
    # each shared parameter held at its truth, the rest refitted from the optimum and from the truth's fit point
    starts = []
    for i, p in zip(index, SHARED):
        for source in (fit.theta, np.where(L.is_phase, fit.theta, truth_theta)):
            theta = source.copy()
            theta[i] = float(L.normalise(p, TRUTH[p]))
            starts.append(theta)
    starts = np.array(starts)
    fixed = np.zeros(starts.shape, bool)
    fixed[np.arange(len(starts)), np.repeat(index, 2)] = True
    result = levenberg_marquardt(fit.problem, starts, np.repeat(fit.X[None], len(starts), 0), OPTIONS, fixed)
    rise = (2.0 * result.cost - base).reshape(len(SHARED), 2).min(axis=1)
    rows = []
    for i, p, r in zip(index, SHARED, rise):
        row = table.loc[(p, "all")]
        n_other = int(loose.sum()) - int(loose[i])
        rows.append({"seed": seed, "parameter": p, "value": float(row["value"]), "truth": TRUTH[p],
                     "at_bound": bool(row["at_bound"]), "identifiable": bool(row["identifiable"]),
                     "loose": ",".join(n for n, k in zip([e[0] for e in L.entries()], loose) if k),
                     "chi2_dof": fit.chi2_dof, "truth_rise": float(r),
                     "linear": bool(row["ci_low"] <= TRUTH[p] <= row["ci_high"]),
                     "profile": bool(r <= threshold(0.95, 1, u.chi2_dof)),
                     "projection": bool(r <= threshold(0.95, 1 + n_other, u.chi2_dof)
                                        or row["ci_low"] <= TRUTH[p] <= row["ci_high"])})
    return rows


def bundled(harmonics_path: str) -> None:
    """The issue's case on the bundled records (module docstring)."""
    import yaml

    from hybridtwin.identify import profile as prf
    from hybridtwin.identify.run_fits import fit_joint

    config = yaml.safe_load(open("config/config.yaml"))
    variant = Variant.from_spec("geometric_slope", SPEC)
    table = idn.read_harmonics(harmonics_path)
    runs = fit_runs()
    options = IdentificationSettings.from_config(config).rule("geometric", "joint") | {"per_run": ["q_x", "q_y"],
                                                                                     "profile": False}
    start = time.process_time()
    fit = fit_joint(variant, options, [], table, {}, None, 5, runs=[r for r, _, _ in runs]).fit
    print(f"joint fit on the full solver: chi^2/dof {fit.chi2_dof:.4g}, {time.process_time() - start:.0f} s CPU")
    start = time.process_time()
    profiled = prf.with_profile(fit)
    print(f"profile: {time.process_time() - start:.0f} s CPU; " + "; ".join(profiled.profile.notes))
    before = fit.table().set_index(["parameter", "run"])
    after = profiled.table().set_index(["parameter", "run"])
    for p in SHARED:
        a, b = before.loc[(p, "all")], after.loc[(p, "all")]
        inside = [lo <= TRUTH[p] <= hi for lo, hi in ((a.ci_low, a.ci_high), (b.ci_low, b.ci_high))]
        print(f"  {p}: {b.value:.6g}{' (at its edge)' if b.at_bound else ''}; linearised [{a.ci_low:.6g}, "
              f"{a.ci_high:.6g}] ({a.interval}) {'holds' if inside[0] else 'misses'} the truth {TRUTH[p]}; "
              f"{b.interval} over {b.loose or 'its range'} [{b.ci_low:.6g}, {b.ci_high:.6g}] "
              f"{'holds' if inside[1] else 'misses'} it")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--harmonics", type=int, default=3)
    parser.add_argument("--output", default="results/benchmarks/interval_profile_coverage.tsv")
    parser.add_argument("--bundled", help="a main job's results/data/harmonics.tsv: the issue's case on it")
    args = parser.parse_args()
    if args.bundled:
        bundled(args.bundled)
        return 0
    runs = fit_runs()
    rows = []
    for seed in range(1, args.seeds + 1):
        start = time.process_time()
        found = case(seed, args.harmonics, runs)
        rows += found
        misses = {m: [r["parameter"] for r in found if not r[m]] for m in ("linear", "profile", "projection")}
        print(f"seed {seed}: chi^2/dof {found[0]['chi2_dof']:.3f}, loose {found[0]['loose'] or 'none'}; outside: "
              + "; ".join(f"{m} {', '.join(v) or '-'}" for m, v in misses.items())
              + f" ({time.process_time() - start:.0f} s CPU)", flush=True)
    table = pd.DataFrame(rows)
    from pathlib import Path

    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.output, sep="\t", index=False, float_format="%.6g")
    with_loose = table[table["loose"] != ""]
    print(f"\n{len(table)} intervals over {args.seeds} seeds ({with_loose['seed'].nunique()} with a loose parameter); "
          "truths inside:")
    for name, group in (("all parameters", table), ("not loose themselves", table[~table.apply(
            lambda r: r["parameter"] in r["loose"].split(","), axis=1)])):
        print(f"  {name}: " + ", ".join(f"{m} {group[m].sum()}/{len(group)} ({100 * group[m].mean():.0f} %)"
                                        for m in ("linear", "profile", "projection")))
    every = table.groupby("seed")[["linear", "profile", "projection"]].all()
    print("  seeds with every truth inside: " + ", ".join(f"{m} {every[m].sum()}/{len(every)}" for m in every))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
