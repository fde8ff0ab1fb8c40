"""Diagnosis benchmark: a hidden-effect detection study with the full solver (issue 6).

    python benchmarks/diagnosis_same_solver_study.py [--quick] [--weak-seeds 2] [--strong-seeds 1] [--none-seeds 6]
                                             [--harmonics 5] [--out FILE]

Synthetic measured runs are made by the full harmonic-balance solver from a Geometric truth (k_b 2411.3,
zeta_s 0.024, zeta_bup 0.016, q_x 0.002, q_y 0.0015: the bundled data's) with one hidden candidate effect on
top (or none), plus noise of the bundled records' sigma (8e-7 m per real/imaginary part). For each case the
base Geometric variant is fitted with the solver and ``diagnosis.diagnose`` tests every built-in candidate.

Design (the choices and why):
- Runs: 8 of the bundled plan's speeds, spanning its three unbalance masses: 25.9 g at 350, 500, 650 RPM,
  14.8 g at 550, 700, 850 RPM, 0 g (bow only) at 800, 950 RPM.
- H = 5 harmonics, the workflow's identification setting (config.yaml ``harmonics: 5``): the 2X/3X lines of
  the excitations and of the nonlinear terms are in the data, and H = 5 costs only ~1.2x H = 3 here.
- Shared bow (q_x, q_y shared by all runs, the truth's structure): 5 shared unknowns + 8 phases, a base fit
  of ~10 s (3 random starts + the nominal one). A per-run bow would add 16 unknowns and absorb part of
  every 1X effect.
- Strengths: "strong" is a clearly visible value (the bundled slope force for slope_spring); "weak" is
  chosen so that the first-order excess chi^2 the effect leaves after the base absorbs what it can,
  lam1 = ||G_p delta||^2 (G_p: the candidate's sensitivities at the truth with the base's projected out),
  is ~50: the score test's Bonferroni threshold is chi^2 ~ 12 (k = 1) and a confirmation needs
  Delta BIC < -10, i.e. LR > 10 + k ln n ~ 15, so weak effects sit near the edge of what the noise allows.
  lam1 is printed per case. speed_damping is taken at the top of its range (0-0.05) for "strong": to first
  order the base's zeta_s absorbs most of it (lam1 ~ 70), but the fitted base runs into the tops of its
  zeta_s and zeta_bup ranges (0.05) and the real misfit is large (chi^2/dof ~ 30); the refit's zeta_v then
  sits at its own range edge, which tests the verdicts for an estimate pinned at the edge away from zero.
- Correct (top-1): the diagnosis table's rank-1 effect is in the hidden effect's equivalence class and its
  verdict starts with "add". Classes: the slope force k_w u' + k_z u'^3 = {slope_spring, expansion_k4
  (its linear term k4 u'), expansion_k6 (its cubic term k6 u'^3)}; every other candidate is its own class.
  On "none": a false alarm is any "add" verdict or an "unexplained discrepancy" conclusion. A hidden effect
  concluded "no missing effect" is a missed detection, reported apart from a wrong identification.
- Baseline: a naive ranking from the same Jacobian at the same base optimum (``score_test.extended_problem``)
  without projecting out the base parameters' sensitivities: statistic ||r||^2 - min_b ||r + G b||^2 with
  the raw G (for one parameter (g.r)^2 / ||g||^2, the raw correlation with the residual), the same sign
  constraints and the same ordering (chi^2(k) p-value) as the score test: only the projection differs.
  Ranking accuracies (rank-1 in the hidden class, verdict ignored) of the diagnosis' final table, of its
  score test alone and of the baseline are printed side by side.
No timed assertions: times are reported (wall and CPU; the machine may be shared).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize, stats
from threadpoolctl import threadpool_limits

from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.identify import forward as fwd
from hybridtwin.identify.arrow_problem import Layout
from hybridtwin.identify import identification as idn
from hybridtwin.identify import lm
from hybridtwin.diagnose import score_test as st
from hybridtwin.identify import uncertainty as unc
from hybridtwin.model.candidates import builtin_candidates
from hybridtwin.identify.protocol import ProtocolOptions
from hybridtwin.model.variants import BUILTIN_VARIANTS, Variant
from hybridtwin.settings import diagnosis_settings

SIGMA = 8e-7  # m per real/imaginary part, the bundled records' (results/data/harmonics.tsv: 6-10e-7)
RUNS = [("r350_m25p9", 350.0, 25.9), ("r500_m25p9", 500.0, 25.9), ("r650_m25p9", 650.0, 25.9),
        ("r550_m14p8", 550.0, 14.8), ("r700_m14p8", 700.0, 14.8), ("r850_m14p8", 850.0, 14.8),
        ("r800_m0p0", 800.0, 0.0), ("r950_m0p0", 950.0, 0.0)]
GEOMETRIC = BUILTIN_VARIANTS["geometric"]  # the paper's Geometric model, as in config/config.yaml
TRUTH = {"k_b": 2411.3, "zeta_s": 0.024, "zeta_bup": 0.016, "q_x": 0.002, "q_y": 0.0015}

#: (hidden effect, strength, its parameter values); "weak" values give a first-order lam1 ~ 50 (docstring)
CASES: list[tuple[str, str, dict[str, float]]] = [
    ("slope_spring", "strong", {"k_w": 324.2, "k_z": 301.1}),  # the bundled data's (paper Table 5)
    ("slope_spring", "weak", {"k_w": 7.5, "k_z": 7.0}),
    ("cross_coupled_stiffness", "strong", {"k_xy": 100.0}),  # destabilising: stable up to ~350 N/m here
    ("cross_coupled_stiffness", "weak", {"k_xy": 1.3}),
    ("excitation_2x", "strong", {"f2_c": 0.1, "f2_s": -0.05}),
    ("excitation_2x", "weak", {"f2_c": 0.0025, "f2_s": -0.0018}),
    ("lower_bearing_compliance", "strong", {"dk_lo": -1000.0}),  # k 10 % softer
    ("lower_bearing_compliance", "weak", {"dk_lo": -40.0}),
    ("speed_damping", "strong", {"zeta_v": 0.05}),  # the top of its range
    ("speed_damping", "weak", {"zeta_v": 0.035}),
    ("upper_bearing_anisotropy", "strong", {"dk_up": 25.0}),
    ("upper_bearing_anisotropy", "weak", {"dk_up": 0.55}),
    ("moment_stiffness", "strong", {"k_rot": 30.0}),
    ("moment_stiffness", "weak", {"k_rot": 1.5}),
]
QUICK = {("slope_spring", "strong"), ("slope_spring", "weak"), ("lower_bearing_compliance", "strong")}

#: equivalence classes: candidates that stand for the same physics (the slope force and its two terms)
SLOPE = ("slope_spring", "expansion_k4", "expansion_k6")
CLASS = {name: ("slope force" if name in SLOPE else name) for name in builtin_candidates()}


class Unsolvable(RuntimeError):
    pass


# --- data and fits ----------------------------------------------------------------------------------------


def truth_response(effect: str | None, values: dict[str, float], harmonics: int) -> list[np.ndarray]:
    """Noise-free sensor harmonics (H, 2) of every run for the truth (geometric + the hidden effect)."""
    values = TRUTH | values
    spec = {"effects": GEOMETRIC["effects"] + ([effect] if effect else []),
            "unknown": {k: (v - 1.0, v + 1.0) for k, v in values.items()}}
    truth = Variant.from_spec("truth", spec)
    names = list(values)
    centre = np.array([values[n] for n in names])
    out = []
    for run, rpm, mass in RUNS:
        model = fwd.SolverModel(truth, run, rpm, mass, names, centre - 1.0, centre + 1.0, harmonics)
        M = model.evaluate(np.zeros((1, len(names))), jacobian=False)[0][0]  # x = 0: the middle = the values
        if not np.isfinite(M).all():
            raise Unsolvable(f"no periodic solution at {run} ({rpm:g} RPM)")
        out.append(M)
    return out


def measured(clean: list[np.ndarray], seed: int) -> list[idn.RunData]:
    rng = np.random.default_rng(seed)
    out = []
    for (run, rpm, mass), M in zip(RUNS, clean):
        noise = SIGMA * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
        out.append(idn.RunData(run, rpm, mass, "fit", M + noise, np.full(M.shape, SIGMA)))
    return out


def base_variant() -> Variant:
    return Variant.from_spec("geometric", GEOMETRIC)


def fit_base(data: list[idn.RunData], harmonics: int, seed: int) -> tuple[st.BaseFit, idn.Identification]:
    """The Geometric variant fitted with the full solver, shared bow: 3 random starts + the nominal values."""
    variant = base_variant()
    names = list(variant.unknown)
    lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
    models = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, names, lower, upper, harmonics)
              for d in data]
    layout = Layout.build(names, lower, upper, [d.run for d in data], [])
    nominal = np.zeros(layout.n)  # phases 0: set from the 1X data by the protocol
    for i, (p, _) in enumerate(layout.entries()):
        if p != "phase":
            nominal[i] = float(layout.normalise(p, variant.model.parameters[p].nominal))
    options = ProtocolOptions(trials=3, monte_carlo=0, seed=seed, lm=lm.LMOptions(max_iterations=60))
    fit = idn.identify(models, data, (), options, extra_starts=nominal[None])
    return st.BaseFit(variant, fit.layout, fit.theta, fit.data, harmonics), fit


def truth_base(clean: list[np.ndarray], harmonics: int) -> st.BaseFit:
    """The base at the truth (no hidden effect, phases 0): where the first-order lam1 is computed."""
    variant = base_variant()
    lower, upper = zip(*variant.unknown.values())
    layout = Layout.build(list(variant.unknown), lower, upper, [r[0] for r in RUNS], [])
    theta = np.array([0.0 if p == "phase" else float(layout.normalise(p, TRUTH[p])) for p, _ in layout.entries()])
    data = [idn.RunData(run, rpm, mass, "fit", M, np.full(M.shape, SIGMA)) for (run, rpm, mass), M in zip(RUNS, clean)]
    return st.BaseFit(variant, layout, theta, data, harmonics)


def first_order_lambda(scores: st.Scores, effect: str, values: dict[str, float]) -> float:
    """||G_p delta||^2 at the truth: the excess chi^2 the hidden effect leaves to first order."""
    score = next(s for s in scores.scores if s.candidate.name == effect)
    delta = np.array([2.0 * values[p.name] / (p.bounds[1] - p.bounds[0]) for p in score.candidate.parameters])
    return float(np.sum((score.projected @ delta) ** 2))


# --- the naive baseline ------------------------------------------------------------------------------------


def naive_ranking(base: st.BaseFit, candidates) -> list[tuple[str, float, float]]:
    """(name, statistic, p-value) by the raw correlation with the residual: the score test's algebra on the
    raw sensitivities G (the base's not projected out), same Jacobian, bounds and ordering."""
    problem, theta = st.extended_problem(base, candidates)
    ev = problem.evaluate(theta[None], base.X[None], jacobian=True)
    r = ev.r[0].reshape(-1)
    J = problem.dense_jacobian(ev)
    entries = problem.layout.entries()
    rows = []
    for c in candidates:
        cols = [entries.index((p.name, "all")) for p in c.parameters]
        G = J[:, cols]
        lower = np.where(theta[cols] <= -1.0 + unc.BOUND_TOLERANCE, 0.0, -np.inf)
        upper = np.where(theta[cols] >= 1.0 - unc.BOUND_TOLERANCE, 0.0, np.inf)
        b = optimize.lsq_linear(G, -r, bounds=(lower, upper), method="bvls").x if np.linalg.norm(G) else 0 * lower
        statistic = max(float(r @ r - np.sum((r + G @ b) ** 2)), 0.0)
        rows.append((c.name, statistic, float(stats.chi2.logsf(statistic, len(cols)))))
    rows.sort(key=lambda t: (t[2], -t[1]))
    return rows


# --- one case ----------------------------------------------------------------------------------------------


def short_verdict(verdict: str) -> str:
    if verdict.startswith("add"):
        return "add" + (" (part)" if "remains" in verdict else "") + (" (confounded)" if "confounded" in verdict
                                                                      else "")
    m = re.match(r"(confounded with|part of|contains) (\w+)", verdict)
    if m:
        return f"{m.group(1)} {m.group(2)}"
    return re.split(r"[:;(]", verdict)[0].replace("significant, not refitted", "signif., not refitted").strip()


def short_conclusion(conclusion: str) -> str:
    head = conclusion.split(":")[0]
    return head if head.startswith("add") else head.replace("unexplained discrepancy", "unexplained")


def outcome(effect: str, table: pd.DataFrame, conclusion: str) -> str:
    verdicts = table["verdict"].tolist()
    if effect == "none":
        alarm = any(v.startswith("add") for v in verdicts) or conclusion.startswith("unexplained")
        return "FALSE ALARM" if alarm else "ok"
    rank1, verdict = table.loc[0, "effect"], table.loc[0, "verdict"]
    if CLASS[rank1] == CLASS[effect] and verdict.startswith("add"):
        return "correct"
    if conclusion.startswith("no missing effect"):
        return "missed"
    if conclusion.startswith("unexplained"):
        return "unexplained"
    if verdict.startswith("add"):
        confounded = [n for n in CLASS if n in verdict.split("confounded with")[-1]] if "confounded" in verdict else []
        return "confounded" if any(CLASS[n] == CLASS[effect] for n in confounded) else "wrong"
    return "other"


def run_case(effect: str, strength: str, values: dict, seed: int, clean, harmonics: int, candidates,
             lam1: float) -> dict:
    hidden = effect if effect != "none" else None
    data = measured(clean, seed)
    t0 = time.perf_counter()
    base, fit = fit_base(data, harmonics, seed)
    base_s = time.perf_counter() - t0
    row = {"effect": effect, "strength": strength,
           "values": ", ".join(f"{k} {v:g}" for k, v in values.items()) or "-", "lam1": lam1, "seed": seed,
           "base_s": base_s, "base_status": fit.status}
    try:
        wall, cpu = time.perf_counter(), time.process_time()
        result = dg.diagnose(base, candidates, diagnosis_settings({}).options())
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    except Exception as error:  # a crash is a finding: record it, go on
        return row | {"chi2_dof": np.nan, "rank1": "-", "verdict": f"CRASH {type(error).__name__}: {error}",
                      "conclusion": "crash", "outcome": "crash", "rank1_ok": False, "score_ok": False,
                      "naive_ok": False, "naive_alarm": False, "diag_s": np.nan, "conclusion_full": str(error)}
    table, s = result.table, result.summary
    by_score = table.sort_values(["log10_p_value", "statistic"], ascending=[True, False], kind="stable")
    naive = naive_ranking(base, candidates)
    alpha_each = s["alpha_per_candidate"]
    return row | {
        "chi2_dof": s["base_chi2_dof"], "misfit": s["misfit"], "rank1": table.loc[0, "effect"],
        "verdict": short_verdict(table.loc[0, "verdict"]), "conclusion": short_conclusion(result.conclusion),
        "outcome": outcome(effect, table, result.conclusion),
        "n_add": int(sum(v.startswith("add") for v in table["verdict"])),
        "rank1_ok": hidden is not None and CLASS[table.loc[0, "effect"]] == CLASS[hidden],
        "score_rank1": by_score.iloc[0]["effect"],
        "score_ok": hidden is not None and CLASS[by_score.iloc[0]["effect"]] == CLASS[hidden],
        "naive_rank1": naive[0][0], "naive_ok": hidden is not None and CLASS[naive[0][0]] == CLASS[hidden],
        "naive_alarm": bool(np.exp(naive[0][2]) < alpha_each),
        "refits": len(s["refitted"]), "score_s": s["score_seconds"], "refit_s": s["refit_seconds"],
        "diag_s": wall, "diag_cpu_s": cpu, "conclusion_full": result.conclusion,
    }


# --- main --------------------------------------------------------------------------------------------------

COLUMNS = [("effect", 24, "s"), ("values", 24, "s"), ("lam1", 8, ".3g"), ("seed", 4, "d"), ("chi2_dof", 8, ".3g"),
           ("rank1", 24, "s"), ("verdict", 22, "s"), ("conclusion", 28, "s"), ("outcome", 11, "s"),
           ("naive_rank1", 24, "s"), ("refits", 6, "d"), ("base_s", 6, ".1f"), ("score_s", 7, ".1f"),
           ("refit_s", 7, ".1f"), ("diag_s", 7, ".1f")]


def line(row: dict | None) -> str:
    if row is None:
        return " ".join(f"{name:>{w}}" if fmt != "s" else f"{name:<{w}}" for name, w, fmt in COLUMNS)
    cells = []
    for name, w, fmt in COLUMNS:
        v = row.get(name, "")
        if fmt == "s":
            cells.append(f"{str(v)[:w]:<{w}}")
        elif isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v):
            cells.append(f"{v:>{w}{fmt}}")
        else:
            cells.append(f"{'-':>{w}}")
    return " ".join(cells)


def fraction(mask: pd.Series) -> str:
    n, k = len(mask), int(mask.sum())
    return f"{k}/{n} ({100 * k / n:.0f} %)" if n else "-"


def summary(df: pd.DataFrame) -> None:
    hidden, none = df[df["effect"] != "none"], df[df["effect"] == "none"]
    print("\nSummary")
    for label, part in (("strong", hidden[hidden["strength"] == "strong"]),
                        ("weak", hidden[hidden["strength"] == "weak"]), ("all hidden", hidden)):
        counts = part["outcome"].value_counts()
        detail = ", ".join(f"{k} {counts.get(k, 0)}" for k in ("correct", "missed", "unexplained", "wrong",
                                                                  "confounded", "other", "crash") if counts.get(k, 0))
        print(f"  top-1 accuracy, {label:<10}: {fraction(part['outcome'] == 'correct'):<14} [{detail}]")
    print(f"  false alarms on none      : {fraction(none['outcome'] != 'ok')}  (naive baseline with the same "
          f"Bonferroni threshold on its top statistic: {fraction(none['naive_alarm'].astype(bool))})")
    done = df[np.isfinite(df["diag_s"].astype(float))]
    print(f"  time per diagnosis (wall) : mean {done['diag_s'].mean():.1f} s, max {done['diag_s'].max():.1f} s "
          f"(score tests mean {done['score_s'].mean():.1f} s, refits mean {done['refit_s'].mean():.1f} s for "
          f"{done['refits'].mean():.1f} refits; CPU mean {done['diag_cpu_s'].mean():.1f} s); base fit mean "
          f"{df['base_s'].mean():.1f} s, max {df['base_s'].max():.1f} s")
    for name, part in (("hidden effects", hidden), ("none", none)):
        if len(part):
            print(f"  time per diagnosis, {name}: mean {part['diag_s'].mean():.1f} s, max {part['diag_s'].max():.1f} s")
    print("\n  ranking accuracy (rank-1 in the hidden effect's class), side by side with the naive baseline")
    rows = []
    for label, part in (("strong", hidden[hidden["strength"] == "strong"]),
                        ("weak", hidden[hidden["strength"] == "weak"]), ("all", hidden)):
        n = len(part)
        top1 = (part["outcome"] == "correct").mean() if n else np.nan
        naive = part["naive_ok"].astype(bool).mean() if n else np.nan
        rows.append({"cases": label, "n": n, "diagnosis top-1 (add)": top1,
                     "diagnosis rank-1": part["rank1_ok"].astype(bool).mean() if n else np.nan,
                     "score test rank-1": part["score_ok"].astype(bool).mean() if n else np.nan,
                     "naive rank-1": naive, "ratio top-1 / naive": top1 / naive if naive else np.inf})
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    wrong = hidden[~hidden["outcome"].isin(["correct", "missed"])]
    if len(wrong):
        print("\n  cases not correct and not missed (conclusions in full):")
        for r in wrong.itertuples():
            print(f"  - {r.effect} {r.strength} ({r.values}) seed {r.seed}: {r.outcome}; {r.conclusion_full}")
    alarms = none[none["outcome"] != "ok"]
    for r in alarms.itertuples():
        print(f"  - FALSE ALARM, none seed {r.seed}: {r.conclusion_full}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 cases + 2 none, one seed (a few minutes)")
    parser.add_argument("--strong-seeds", type=int, default=1, help="noise seeds per strong case")
    parser.add_argument("--weak-seeds", type=int, default=2, help="noise seeds per weak case")
    parser.add_argument("--none-seeds", type=int, default=6, help="noise seeds of the no-effect case")
    parser.add_argument("--harmonics", type=int, default=5)
    parser.add_argument("--out", type=Path, help="write the per-case table here (TSV)")
    args = parser.parse_args()
    cases = [c for c in CASES if not args.quick or (c[0], c[1]) in QUICK]
    seeds = {"strong": 1 if args.quick else args.strong_seeds, "weak": 1 if args.quick else args.weak_seeds,
             "none": 2 if args.quick else args.none_seeds}
    H = args.harmonics
    candidates = list(builtin_candidates().values())
    pd.set_option("display.width", 250)
    print(f"Hidden-effect detection, full solver: {len(RUNS)} runs "
          f"({', '.join(f'{rpm:g} RPM/{m:g} g' for _, rpm, m in RUNS)}), H = {H}, sigma {SIGMA:g} m, shared bow; "
          f"base: geometric {TRUTH}; {len(candidates)} built-in candidates")
    classes = {}
    for name, cls in CLASS.items():
        classes.setdefault(cls, []).append(name)
    print("equivalence classes: " + "; ".join(f"{k} = {{{', '.join(v)}}}" for k, v in classes.items() if len(v) > 1)
          + "; every other candidate its own class")
    with threadpool_limits(1):
        start = time.perf_counter()
        clean = {"none": truth_response(None, {}, H)}
        truth_scores = st.score_tests(truth_base(clean["none"], H), candidates)
        plan = [("none", "none", {}, s, 0.0) for s in range(1, seeds["none"] + 1)]
        print(f"\ntruths (solved for all {len(RUNS)} runs?) and first-order lam1 = ||G_p delta||^2 at the truth:")
        for effect, strength, values in cases:
            try:
                clean[(effect, strength)] = truth_response(effect, values, H)
            except Unsolvable as error:
                print(f"  {effect:<26} {strength:<6} {values}: UNSOLVABLE ({error}); case skipped")
                continue
            lam1 = first_order_lambda(truth_scores, effect, values)
            print(f"  {effect:<26} {strength:<6} {', '.join(f'{k} {v:g}' for k, v in values.items()):<26} "
                  f"solved, lam1 {lam1:.3g}")
            plan += [(effect, strength, values, s, lam1) for s in range(1, seeds[strength] + 1)]
        print(f"  ({time.perf_counter() - start:.0f} s)\n")
        print(line(None))
        rows = []
        for effect, strength, values, seed, lam1 in plan:
            key = "none" if effect == "none" else (effect, strength)
            row = run_case(effect, strength, values, seed, clean[key], H, candidates, lam1)
            rows.append(row)
            print(line(row), flush=True)
    df = pd.DataFrame(rows)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(args.out, sep="\t", index=False)
    summary(df)
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
