"""Benchmark of the harmonic-balance solver against brute-force time integration.

Draws Latin-hypercube scenarios of the Geometric model over its unknown ranges
(k_b, zeta_s, zeta_bup, q_x, q_y; the eccentric mass fixed) and, at each speed:

1. solves them all at once with the HB solver (``hybridtwin.solve``, H harmonics,
   direct start from the linear response) and reports the wall time per
   scenario (assembly of the systems + solve; target <= 1 ms), the convergence
   rate and the failures grouped by reason (``SteadyState.message`` with its
   numbers masked), with BLAS limited to 1 thread and with the default;
2. for a sample of converged scenarios, integrates eq. 29 in time from rest
   (``hybridtwin.solvers.transient``, Radau) until the node-1 response (x = u1, y = v1)
   agrees with the HB steady state to the target accuracy (max abs error over
   a period / max amplitude <= 1e-4, as in tests/test_transient.py), sustained
   over 3 periods, and reports the wall time that took and the ratio to the HB
   time per scenario (target >= 1000x). The reference for that check is HB
   with 11 harmonics, so that HB's own truncation error (also printed: HB(H)
   vs HB(11)) does not count against the time integration.

Usage (from the repository root, in the project's environment)::

    python benchmarks/solver_benchmark.py                    # 1000 scenarios at 450, 700, 900 RPM
    python benchmarks/solver_benchmark.py --scenarios 200 --rpm 700 --sample 3

Timings are wall-clock on the machine as it is; a loaded machine inflates them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from hybridtwin import solve
from hybridtwin.solvers import transient as tr
from hybridtwin.model.variants import builtin_variant

try:
    from threadpoolctl import threadpool_info, threadpool_limits
except ImportError:  # fall back to environment variables in a child process (see hb_timing_one_thread)
    threadpool_limits = threadpool_info = None

VARIANT = "geometric"
TARGET_MS = 1.0  # HB wall time per scenario
TARGET_RATIO = 1000.0  # time integration / HB, per scenario
TARGET_ERROR = 1e-4  # node-1 relative error that "the same accuracy" means
REFERENCE_H = 11  # harmonics of the HB reference the time integration is checked against
CONFIRM_PERIODS = 3  # the error must stay below the target this many periods in a row
SAMPLES_PER_PERIOD = 32
CHUNK_PERIODS = 4
ATOL_RELATIVE = 1e-5  # time integration: atol on displacements = this x the HB amplitude (see transient_to_accuracy)
_SHAFT = builtin_variant(VARIANT).model.shaft
NODE1 = [_SHAFT.dof("u1"), _SHAFT.dof("v1")]  # the sensors: x = u1, y = v1


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", type=int, default=1000, help="Latin-hypercube scenarios [%(default)s]")
    parser.add_argument("--rpm", type=float, nargs="+", default=[450.0, 700.0, 900.0], help="speeds [%(default)s]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the Latin hypercube and the sample [%(default)s]")
    parser.add_argument("--sample", type=int, default=10,
                        help="converged scenarios per speed timed by time integration [%(default)s]")
    parser.add_argument("--harmonics", type=int, default=5, help="HB harmonics H [%(default)s]")
    parser.add_argument("--eccentric-mass", type=float, default=0.0148, help="m_e [kg] [%(default)s]")
    parser.add_argument("--repeats", type=int, default=3, help="HB timing repeats (best of) [%(default)s]")
    parser.add_argument("--max-decay", type=float, default=12.0,
                        help="time integration gives up after this many decay times [%(default)s]")
    parser.add_argument("--hb-only-json", action="store_true", help=argparse.SUPPRESS)  # child process mode
    return parser.parse_args(argv)


# --- scenarios and HB ---------------------------------------------------------------------


def scenarios(n: int, seed: int, eccentric_mass: float) -> dict[str, np.ndarray]:
    """Latin-hypercube values of the variant's unknown parameters, plus the fixed m_e."""
    variant = builtin_variant(VARIANT)
    names = variant.unknown_names
    lo, hi = variant.bounds(names)
    unit = qmc.LatinHypercube(d=len(names), seed=seed).random(n)
    X = qmc.scale(unit, lo, hi)
    values = {k: X[:, i] for i, k in enumerate(names)}
    values["m_e"] = np.full(n, eccentric_mass)
    return values


def hb_once(values: dict[str, np.ndarray], rpm: float, H: int):
    """Assemble and solve all scenarios at one speed; returns (result, seconds)."""
    variant = builtin_variant(VARIANT)
    t0 = time.perf_counter()
    result = solve(variant.system(rpm, values), H)
    return result, time.perf_counter() - t0


def hb_best(values: dict[str, np.ndarray], rpm: float, H: int, repeats: int):
    """Best-of-``repeats`` wall time of hb_once (the first call also warms up)."""
    hb_once({k: v[:8] for k, v in values.items()}, rpm, H)
    best, result = math.inf, None
    for _ in range(repeats):
        result, seconds = hb_once(values, rpm, H)
        best = min(best, seconds)
    return result, best


def failure_reasons(messages: np.ndarray) -> Counter:
    """Failure messages with their numbers masked, counted."""
    return Counter(re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", str(m)) for m in messages)


def blas_threads() -> str:
    if threadpool_info is None:
        return os.environ.get("OPENBLAS_NUM_THREADS", "default")
    counts = {info.get("num_threads") for info in threadpool_info() if info.get("user_api") == "blas"}
    return ",".join(str(c) for c in sorted(counts)) or "?"


def hb_timing_one_thread(args: argparse.Namespace) -> dict[float, float]:
    """Seconds per speed for all scenarios with BLAS limited to one thread."""
    values = scenarios(args.scenarios, args.seed, args.eccentric_mass)
    if threadpool_limits is not None:
        with threadpool_limits(limits=1, user_api="blas"):
            return {rpm: hb_best(values, rpm, args.harmonics, args.repeats)[1] for rpm in args.rpm}
    # no threadpoolctl: a child process with the thread variables set before numpy is imported
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, __file__, "--hb-only-json", "--scenarios", str(args.scenarios), "--seed", str(args.seed),
           "--harmonics", str(args.harmonics), "--eccentric-mass", str(args.eccentric_mass),
           "--repeats", str(args.repeats), "--rpm", *map(str, args.rpm)]
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return {float(k): v for k, v in json.loads(out).items()}


# --- time integration to the same accuracy -------------------------------------------------


@dataclass
class Transient:
    """Time integration from rest of one scenario, until it matches the HB state."""

    reached: bool
    seconds: float  # wall time to reach the target (or spent, if not reached)
    periods: int  # forcing periods integrated until the target was reached (or in all)
    decay_times: float  # the same in decay times
    final_error: float  # node-1 error of the last period integrated
    hb_truncation: float  # HB(H) vs HB(REFERENCE_H) at node 1
    evaluations_per_period: float  # right-hand-side evaluations per forcing period
    note: str = ""  # why the target was not reached


class WallClock:
    """Records, at every right-hand-side call, the wall time at which t was first reached."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.wall: list[float] = []
        self.calls = 0
        self.start = time.perf_counter()

    def __call__(self, t: float) -> None:
        self.calls += 1
        if not self.t or t > self.t[-1]:
            self.t.append(t)
            self.wall.append(time.perf_counter() - self.start)

    def at(self, t: float) -> float:
        i = min(int(np.searchsorted(self.t, t)), len(self.t) - 1)
        return self.wall[i]


def transient_to_accuracy(system, reference: np.ndarray, hb: np.ndarray, max_decay: float) -> Transient:
    """Integrate one scenario from rest until node 1 matches ``reference`` harmonics (H+1, n).

    Chunks of CHUNK_PERIODS periods (state carried over), CONFIRM_PERIODS periods
    in a row below TARGET_ERROR; gives up after ``max_decay`` decay times.
    """
    first_order = tr.FirstOrder.from_system(system)
    T, Omega = first_order.period, first_order.Omega
    node1 = NODE1
    amplitude = np.abs(reference[:, 0::2]).sum(axis=0).max()  # largest translational amplitude [m]
    atol = ATOL_RELATIVE * amplitude
    max_periods = max(CONFIRM_PERIODS + 1, math.ceil(max_decay * tr.decay_time(system) / T))
    clock = WallClock()
    first_order.monitor = clock
    y = np.zeros(2 * system.n_dof)
    errors: list[float] = []
    done = 0
    reached_at = None
    tau = tr.decay_time(system)
    truncation = tr.relative_error(tr.fourier_series(reference, Omega, np.linspace(0, T, 65))[:, node1],
                                   tr.fourier_series(hb, Omega, np.linspace(0, T, 65))[:, node1])
    while done < max_periods and reached_at is None:
        n = min(CHUNK_PERIODS, max_periods - done)
        t_eval = (done + np.arange(n * SAMPLES_PER_PERIOD + 1) / SAMPLES_PER_PERIOD) * T
        try:
            t, Y = tr.run(first_order, y[: system.n_dof], y[system.n_dof:], (t_eval[0], t_eval[-1]), t_eval,
                          rtol=1e-8, atol=tr.state_tolerance(system.n_dof, atol))
        except RuntimeError:
            return Transient(False, clock.wall[-1], done, done * T / tau, math.inf, truncation,
                             clock.calls / max(done, 1), f"diverged in period {done + 1} (integrator failed)")
        ref = tr.fourier_series(reference, Omega, t)[:, node1]
        scale = np.abs(ref).max()
        for k in range(n):
            seg = slice(k * SAMPLES_PER_PERIOD, (k + 1) * SAMPLES_PER_PERIOD + 1)
            errors.append(float(np.abs(Y[seg][:, node1] - ref[seg]).max() / scale))
        y = Y[-1]
        done += n
        tail = errors[-CONFIRM_PERIODS:]
        if len(tail) == CONFIRM_PERIODS and max(tail) <= TARGET_ERROR:
            first_good = len(errors) - CONFIRM_PERIODS
            while first_good > 0 and errors[first_good - 1] <= TARGET_ERROR:
                first_good -= 1
            reached_at = first_good + 1  # periods integrated when the error first stayed below the target
    if reached_at is not None:
        return Transient(True, clock.at(reached_at * T), reached_at, reached_at * T / tau, errors[-1],
                         truncation, clock.calls / done)
    return Transient(False, clock.wall[-1], done, done * T / tau, errors[-1], truncation, clock.calls / done,
                     f"error still {errors[-1]:.1e} after {done} periods")


def orbit_check(system, reference: np.ndarray, n_decay: float = 5.0) -> str:
    """Does the time integration started ON the HB orbit stay on it for ``n_decay`` decay times?"""
    Omega = float(system.Omega[0])
    amplitude = np.abs(reference[:, 0::2]).sum(axis=0).max()
    try:
        periodic = tr.periodic_response(system, tr.harmonic_initial_state(reference, Omega), n_decay=n_decay,
                                        atol=ATOL_RELATIVE * amplitude)
    except RuntimeError:
        return "started on the HB orbit, the integration escapes"
    error = tr.relative_error(tr.fourier_series(reference, Omega, periodic.t)[:, NODE1], periodic.at(NODE1))
    verb = "stays on" if error <= 1e-3 else "leaves"
    return f"started on the HB orbit, it {verb} it: error {error:.0e} after {n_decay:g} decay times"


def sample_transients(values, rpm, hb_result, args, rng) -> list[tuple[int, Transient | str]]:
    """Time integration of a random sample of converged scenarios (index, outcome or reason skipped)."""
    converged = np.flatnonzero(hb_result.success)
    chosen = np.sort(rng.choice(converged, size=min(args.sample, converged.size), replace=False))
    sub = {k: v[chosen] for k, v in values.items()}
    variant = builtin_variant(VARIANT)
    system = variant.system(rpm, sub)
    reference = solve(system, REFERENCE_H)
    out = []
    for j, i in enumerate(chosen):
        hb = hb_result.harmonics[i]
        if not reference.success[j]:
            out.append((int(i), f"HB reference with H = {REFERENCE_H} failed: {reference.message[j]}"))
            continue
        ref = reference.harmonics[j]
        gap = np.abs(ref[: hb.shape[0], NODE1] - hb[:, NODE1]).max() / np.abs(ref[:, NODE1]).max()
        if gap > 1e-2:
            out.append((int(i), f"HB with H = {REFERENCE_H} found another branch (gap {gap:.1e})"))
            continue
        one = system.subset(np.array([j]))
        outcome = transient_to_accuracy(one, ref, hb, args.max_decay)
        if not outcome.reached:
            outcome.note += "; " + orbit_check(one, ref)
        out.append((int(i), outcome))
    return out


# --- report ------------------------------------------------------------------------------


def verdict(ok: bool) -> str:
    return "OK" if ok else "MISSED"


def report_speed(rpm, hb_result, seconds_default, seconds_one, transients, args) -> None:
    S = hb_result.n_scenarios
    ms_default, ms_one = 1e3 * seconds_default / S, 1e3 * seconds_one / S
    best_ms = min(ms_default, ms_one)
    print(f"\n=== {rpm:g} RPM: {S} scenarios, H = {args.harmonics}, m_e = {args.eccentric_mass:g} kg ===")
    print(f"HB time/scenario (assembly + solve), BLAS default ({blas_threads()} threads): {ms_default:.3f} ms")
    print(f"HB time/scenario (assembly + solve), BLAS 1 thread:{'':17s} {ms_one:.3f} ms")
    print(f"  -> time/scenario {best_ms:.3f} ms (target <= {TARGET_MS:g} ms) {verdict(best_ms <= TARGET_MS)}")
    rate = hb_result.success.mean()
    print(f"  -> convergence {100 * rate:.1f} % ({hb_result.success.sum()}/{S})")
    if (~hb_result.success).any():
        print("  failures by reason:")
        for reason, count in failure_reasons(hb_result.message[~hb_result.success]).most_common():
            print(f"    {count:5d}  {reason}")
    print(f"Time integration from rest to node-1 error <= {TARGET_ERROR:g} vs HB (sample of {len(transients)} "
          f"converged scenarios; Radau, rtol 1e-8, atol {ATOL_RELATIVE:g} x amplitude):")
    print(f"  {'scenario':>8s} {'HB(H) err':>9s} {'reached':>7s} {'periods':>7s} {'decay t.':>8s} "
          f"{'f-evals/T':>9s} {'TI time':>9s} {'final err':>9s} {'TI/HB':>9s}")
    ratios = []
    for i, outcome in transients:
        if isinstance(outcome, str):
            print(f"  {i:8d}  skipped: {outcome}")
            continue
        ratio = outcome.seconds / (best_ms * 1e-3)
        if outcome.reached:
            ratios.append(ratio)
        print(f"  {i:8d} {outcome.hb_truncation:9.1e} {'yes' if outcome.reached else 'NO':>7s} "
              f"{outcome.periods:7d} {outcome.decay_times:8.1f} {outcome.evaluations_per_period:9.0f} "
              f"{outcome.seconds:8.2f}s {outcome.final_error:9.1e} "
              + (f"{ratio:8.0f}x" if outcome.reached else f"{'-':>9s}  ({outcome.note})"))
    not_reached = [o for _, o in transients if not isinstance(o, str) and not o.reached]
    if ratios:
        worst = min(ratios)
        print(f"  -> speed ratio TI/HB per scenario: median {np.median(ratios):.0f}x, min {worst:.0f}x "
              f"(target >= {TARGET_RATIO:g}x) {verdict(worst >= TARGET_RATIO)}")
    if not_reached:
        print(f"  -> {len(not_reached)} sampled scenario(s) never reached the HB state from rest within "
              f"{args.max_decay:g} decay times (time spent: {sum(o.seconds for o in not_reached):.1f} s): the HB "
              "orbit is unstable (an integration started on it leaves it), or from rest the machine settles "
              "elsewhere (another orbit, a modulated response) or slowly (the orbit's own decay rate near the "
              "resonance is below the linear one), or escapes (the cubic bearing force of eq. 22 is unbounded)")


def summary_table(rows: list[tuple]) -> None:
    print("\n=== Summary (figure, value, target, verdict) ===")
    print(f"{'RPM':>5s}  {'HB ms/scenario':>15s}  {'convergence':>11s}  {'TI reached':>10s}  {'TI/HB median':>12s}  "
          f"{'TI/HB min':>10s}")
    for rpm, ms, rate, reached, med, worst in rows:
        med_s = f"{med:.0f}x" if med is not None else "-"
        worst_s = f"{worst:.0f}x" if worst is not None else "-"
        print(f"{rpm:5g}  {ms:9.3f} {verdict(ms <= TARGET_MS):>5s}  {100 * rate:10.1f}%  {reached:>10s}  {med_s:>12s}  "
              f"{worst_s:>6s} {verdict(worst is not None and worst >= TARGET_RATIO):>3s}")
    print(f"targets: HB <= {TARGET_MS:g} ms per scenario; TI/HB >= {TARGET_RATIO:g}x per scenario "
          f"(TI: time integration from rest to node-1 error <= {TARGET_ERROR:g}; 'TI reached': sampled scenarios "
          "where it got there, the ratios are over those)")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.hb_only_json:
        values = scenarios(args.scenarios, args.seed, args.eccentric_mass)
        print(json.dumps({rpm: hb_best(values, rpm, args.harmonics, args.repeats)[1] for rpm in args.rpm}))
        return
    started = time.perf_counter()
    print(f"solver benchmark: variant {VARIANT}, {args.scenarios} Latin-hypercube scenarios (seed {args.seed}), "
          f"speeds {args.rpm}, H = {args.harmonics}; {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}")
    if threadpool_limits is None:
        print("threadpoolctl not importable: the 1-thread HB timing runs in a child process with "
              "OMP_NUM_THREADS = OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = 1 set before numpy is imported")
    values = scenarios(args.scenarios, args.seed, args.eccentric_mass)
    variant = builtin_variant(VARIANT)
    print("unknown ranges: " + ", ".join(f"{k} in [{lo:g}, {hi:g}]" for k, (lo, hi) in variant.unknown.items()))
    one_thread = hb_timing_one_thread(args)
    rng = np.random.default_rng(args.seed)
    rows = []
    for rpm in args.rpm:
        result, seconds = hb_best(values, rpm, args.harmonics, args.repeats)
        transients = sample_transients(values, rpm, result, args, rng) if args.sample > 0 else []
        report_speed(rpm, result, seconds, one_thread[rpm], transients, args)
        ms = 1e3 * min(seconds, one_thread[rpm]) / args.scenarios
        ratios = [o.seconds / (ms * 1e-3) for _, o in transients if not isinstance(o, str) and o.reached]
        rows.append((rpm, ms, result.success.mean(), f"{len(ratios)}/{len(transients)}",
                     np.median(ratios) if ratios else None, min(ratios) if ratios else None))
    summary_table(rows)
    print(f"\nbenchmark wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
