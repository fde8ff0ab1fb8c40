"""What a steady state costs as the machine grows (issue 53 item 3, the measurement before any condensation).

    python benchmarks/solver_cost_by_dof.py [--scenarios 16] [--harmonics 5] [--repeats 3]

Three machines, each with its model as the loop builds it, ``--scenarios`` scenarios spread over its speed range,
H = ``--harmonics``, one thread, CPU time (``time.process_time``), best of ``--repeats`` (the machine is shared):

- the VARM, variant ``geometric`` (11 nodes, 44 DOFs; nonlinear bearing forces at two nodes), 300-1100 RPM;
- the stepped rotor of examples/stepped_rotor, variant ``anisotropic_b`` (18 nodes, 72 DOFs; linear), 1000-6000 RPM;
- ROSS's ``compressor_example()`` through ``ross_io.machine_from_ross`` (56 nodes, 224 lateral DOFs, ROSS's 336 with
  the axial and torsional ones; 2 bearings and 12 seals as tables over speed, gyroscopic terms, an unbalance at the
  first impeller; linear), 2000-12000 RPM. Needs the ``ross`` extra (skipped without it);
- the same compressor with one nonlinear seal: ``radial_spring@Seal_7`` (a cubic spring k_b/l_i^2 u^3 + 2 k_b u at
  the middle seal, k_b 5e6 N/m, l_i 10 um: the response changes by up to 35 % against the compressor without it,
  Newton takes 1-3 iterations), sensitivities of m_e and k_b;
- that one again with its 16 scenarios at 4 speeds (4 unbalance angles each: runs that share their linear system),
  where the stability check's eigenproblems are solved once per speed.

Per scenario: the steady state (``solver.solve``, the stability check off), the sensitivities of the variant's
unknowns at it (``solver.sensitivity``; per parameter; the compressor's only parameter is the unbalance m_e) and the
stability check (``solver.assess_stability``: Floquet multipliers, exactly from the eigenvalues for a linear model).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import yaml
from threadpoolctl import threadpool_limits

from hybridtwin import config as cfg
from hybridtwin.model.model import Model
from hybridtwin.model.variants import builtin_variant
from hybridtwin.solvers.solver import assess_stability, sensitivity, solve

ROOT = Path(__file__).resolve().parents[1]


def _varm(S):
    variant = builtin_variant("geometric")
    values = {k: np.full(S, v, float) for k, v in variant.values({"m_e": 0.0148}).items()}
    return "VARM (geometric)", variant.model, values, np.linspace(300.0, 1100.0, S), variant.unknown_names


def _stepped(S):
    folder = ROOT / "examples" / "stepped_rotor" / "config"
    config = yaml.safe_load((folder / "config.yaml").read_text())
    variant = cfg.variant(config, "anisotropic_b", folder)
    values = {k: np.full(S, v, float) for k, v in variant.values({"m_e": 0.02}).items()}
    return "stepped rotor (anisotropic_b)", variant.model, values, np.linspace(1000.0, 6000.0, S), variant.unknown_names


def _compressor(S, seal: bool = False, shared: bool = False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import ross
    from hybridtwin.model.machine_parts import UnbalancePlane
    from hybridtwin.model.ross_io import machine_from_ross

    rotor = ross.compressor_example()
    machine = machine_from_ross(rotor, name="compressor",
                                unbalance_planes=[UnbalancePlane("impeller_1", rotor.disk_elements[0].n)])
    fx = machine.effects()
    model = Model([fx[f"bearing_table@{b.name}"] for b in machine.bearings] + [fx["gyroscopic"],
                  fx["unbalance@impeller_1"]] + ([fx["radial_spring@Seal_7"]] if seal else []), machine)
    values = {"m_e": np.full(S, 0.01), "r_me": np.full(S, 0.1), "angle_me": np.zeros(S)}
    rpm = np.linspace(2000.0, 12000.0, S)
    if not seal:
        return "ROSS compressor", model, values, rpm, ["m_e"]
    values |= {"k_b": np.full(S, 5e6), "l_i": np.full(S, 1e-5)}
    if not shared:
        return "ROSS compressor + nonlinear seal", model, values, rpm, ["m_e", "k_b"]
    values["angle_me"] = np.tile(np.arange(4) * np.pi / 2, -(-S // 4))[:S]
    return ("ROSS compressor + nonlinear seal, 4 speeds", model, values, np.repeat(np.linspace(2000.0, 12000.0, 4),
            -(-S // 4))[:S], ["m_e", "k_b"])


def _compressor_seal(S):
    return _compressor(S, seal=True)


def _compressor_seal_shared(S):
    return _compressor(S, seal=True, shared=True)


def best(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.process_time()
        function()
        times.append(time.process_time() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", type=int, default=16)
    parser.add_argument("--harmonics", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    S, H = args.scenarios, args.harmonics
    print("| machine | nodes | DOFs | nonlinear forces | solve [ms/scenario] | sensitivities [ms/scenario/parameter] | "
          "stability check [ms/scenario] |")
    print("|---|---|---|---|---|---|---|")
    for case in (_varm, _stepped, _compressor, _compressor_seal, _compressor_seal_shared):
        try:
            label, model, values, rpm, names = case(S)
        except ImportError as err:
            print(f"| {case.__name__[1:]}: skipped ({err}) |")
            continue
        with threadpool_limits(1):
            system = model.system(values, rpm)
            t_build = best(lambda: model.system(values, rpm), args.repeats)
            state = solve(system, H, stability=False)
            assert state.success.all(), label
            t_solve = best(lambda: solve(system, H, stability=False), args.repeats)
            lower, upper = np.array([model.parameters[n].bounds for n in names]).T
            steps = 1e-4 * np.where(upper > lower, upper - lower, np.abs(lower) + 1.0)

            def build(v):  # the perturbed assemblies come stacked (parameter, sign, scenario): the speeds tiled
                return model.system(v, np.tile(rpm, len(next(iter(v.values()))) // len(rpm)))

            t_sens = best(lambda: sensitivity(build, values, names, state, steps), args.repeats)
            t_stab = best(lambda: assess_stability(system, state), args.repeats)
        shaft = model.shaft
        newton = f"{state.iterations.min()}-{state.iterations.max()} Newton iterations, " if system.forces else ""
        print(f"| {label} | {shaft.n_nodes} | {shaft.n_dof} | {len(system.forces)} | {1e3 * t_solve / S:.2f} "
              f"({newton}+ {1e3 * t_build / S:.2f} assembly) | {1e3 * t_sens / S / len(names):.2f} "
              f"({len(names)} parameters) "
              f"| {1e3 * t_stab / S:.2f} |")


if __name__ == "__main__":
    main()
