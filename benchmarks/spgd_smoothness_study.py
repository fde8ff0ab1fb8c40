"""Why the sPGD trails a Gaussian process on the Geometric libraries (issue 3): a kink in the bow force.

    python benchmarks/spgd_smoothness_study.py [--rpm 350] [--mass-g 25.9] [--fit] [--n 1000]

The bow force is m_el q Phi_1 Omega^2 (eq. 30) with Phi_1 "scaled so that its entry of largest magnitude is
+1" (docs/model.md). Which node holds that entry changes with k_b (node 4 below about 2775 N/m, node 5
above, for the default shaft): the scaling max |Phi_1| has a kink there, and so does every response to the bow,
as a function of k_b. A polynomial (Chebyshev) factor converges only algebraically across a kink, a local
kernel (the GP's Matern) does not care. The study shows it three ways:

1. where the largest entry of Phi_1 moves, over the k_b range;
2. the Chebyshev coefficients |c_n| / max |U| of the sensor's 1X response along each parameter through the
   centre of the box (full solver at 41 Chebyshev points): fast (exponential) decay in a smooth direction,
   slow decay in k_b; the same with Phi_1 scaled by its node-5 entry instead (smooth in k_b, "node-5 scaling",
   the node of the unbalance mass), where the slow decay is gone;
3. with --fit: one sPGD (config offline.spgd, as with offline.pieces: none; the workflow's default splits the
   library at the kink instead) and the benchmark's GP (ARD Matern 5/2) fitted on the
   same Latin-hypercube scenarios (the workflow's splits and sizes: n, 20 % validation, 200 test), with each
   scaling: median and p95 relative sensor error on the test scenarios and their ratio. Needs scikit-learn
   (pip install -e '.[bench]') and a few minutes.

The scaling is the model's definition, not a numerical choice, so changing it is a model decision (it changes
what q_x, q_y mean by up to a few per cent); this script only measures what it costs the library.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from numpy.polynomial import chebyshev
from threadpoolctl import threadpool_limits

from hybridtwin import config as cfg
from hybridtwin.offline.library import build_library, relative_sensor_error
from hybridtwin.model.model import Model
from hybridtwin.offline.pod import pod, to_features
from hybridtwin.offline.scenarios import sample_scenarios
from hybridtwin.model.sensor import observable, sensor_dofs
from hybridtwin.model.variants import Variant, builtin_variant
from hybridtwin.solvers.solver import solve_variant

ROOT = Path(__file__).resolve().parents[1]
UNBALANCE_NODE = 5  # the node nearest z_me, where the eccentric mass sits


class NodeScaledBowModel(Model):
    """The same model with Phi_1 scaled by its entry at the unbalance node (smooth in every parameter)."""

    def context(self, values, rpm):
        ctx = super().context(values, rpm)
        ctx.Phi_1 = ctx.Phi_1 / ctx.Phi_1[:, UNBALANCE_NODE : UNBALANCE_NODE + 1]
        return ctx


def with_scaling(variant: Variant, scaling: str) -> Variant:
    if scaling == "max":
        return variant
    model = NodeScaledBowModel(variant.model.effects, variant.model.shaft)
    return Variant(variant.name, model, dict(variant.unknown), dict(variant.fixed), variant.description)


def peak_node(variant: Variant, k_b: np.ndarray) -> np.ndarray:
    values = variant.values({"k_b": k_b})
    values = {k: np.broadcast_to(v, k_b.shape) for k, v in values.items()}
    phi = variant.model.context(values, 0.0).Phi_1
    return np.argmax(np.abs(phi), axis=1)


def chebyshev_decay(variant: Variant, rpm: float, mass_g: float, degree: int = 20, points: int = 41) -> pd.DataFrame:
    """|c_n| / max |U_1x| along each unknown through the box centre, n = 0, 2, ..., degree."""
    x = np.cos(np.pi * (np.arange(points) + 0.5) / points)
    names = variant.unknown_names
    lo, hi = variant.bounds(names)
    rows = []
    for j, name in enumerate(names):
        values = np.tile((lo + hi) / 2, (points, 1))
        values[:, j] = lo[j] + (x + 1) / 2 * (hi[j] - lo[j])
        overrides = {k: values[:, i] for i, k in enumerate(names)} | {"m_e": np.full(points, mass_g * 1e-3)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = solve_variant(variant, rpm, overrides, harmonics=5)
        u = result.harmonics[:, 1, sensor_dofs(variant.model.shaft)[0]]
        c = chebyshev.chebfit(x, np.c_[u.real, u.imag], degree)
        decay = np.abs(c).max(axis=1) / np.abs(u).max()
        rows.append({"parameter": name, **{f"n={n}": decay[n] for n in range(0, degree + 1, 2)}})
    return pd.DataFrame(rows)


def surrogate_errors(variant: Variant, rpm: float, mass_g: float, n: int, seed: int, spgd: dict) -> dict:
    """sPGD and GP on the same scenarios (workflow splits), relative sensor error on the test ones."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    table = sample_scenarios(variant, n, seed)
    names = variant.unknown_names
    values = table[names].to_numpy()
    overrides = {k: values[:, i] for i, k in enumerate(names)} | {"m_e": np.full(len(table), mass_g * 1e-3)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = solve_variant(variant, rpm, overrides, harmonics=5)
    shaft = variant.model.shaft
    usable = result.success & observable(result.harmonics, shaft, 14e-3)
    split = table["split"].to_numpy()
    train, test = usable & (split == "train"), usable & (split == "test")
    basis = pod(to_features(result.harmonics[train]))
    lo, hi = variant.bounds(names)
    start = time.perf_counter()
    library = build_library("study", basis, result.harmonics, values, split, usable, names, lo, hi,
                            sensor_dofs(shaft), **spgd)
    fit_s = time.perf_counter() - start
    reference = result.harmonics[test][:, :, sensor_dofs(shaft)]
    spgd_error = relative_sensor_error(library.sensor(values[test]), reference)
    x = library.normalise(values)
    alpha = basis.project(to_features(np.nan_to_num(result.harmonics)))
    kernel = (ConstantKernel(1.0, (1e-4, 1e12)) * Matern(np.ones(len(names)), (1e-2, 1e5), nu=2.5)
              + WhiteKernel(1e-6, (1e-14, 1e-1)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gp = GaussianProcessRegressor(kernel, normalize_y=True, random_state=0).fit(x[train], alpha[train])
    gp_sensor = library._to_sensor(gp.predict(x[test]) @ library._sensor_modes.T)
    gp_error = relative_sensor_error(gp_sensor, reference)
    return {"n_train": int(train.sum()), "n_test": int(test.sum()), "terms": library.model.n_terms,
            "sPGD_med_pct": 100 * np.median(spgd_error), "sPGD_p95_pct": 100 * np.percentile(spgd_error, 95),
            "GP_med_pct": 100 * np.median(gp_error), "GP_p95_pct": 100 * np.percentile(gp_error, 95),
            "ratio_med": np.median(spgd_error) / np.median(gp_error),
            "ratio_p95": np.percentile(spgd_error, 95) / np.percentile(gp_error, 95), "sPGD_fit_s": fit_s}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variant", default="geometric", help="a built-in variant [%(default)s]")
    parser.add_argument("--rpm", type=float, default=350.0)
    parser.add_argument("--mass-g", type=float, default=25.9)
    parser.add_argument("--fit", action="store_true", help="also fit sPGD and GP with each scaling (minutes)")
    parser.add_argument("--n", type=int, default=1000, help="scenarios for --fit (n_s) [%(default)s]")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--config", default=str(ROOT / "config" / "config.yaml"),
                        help="offline.spgd options from this config [%(default)s]")
    args = parser.parse_args(argv)
    variant = builtin_variant(args.variant)
    if "k_b" not in variant.unknown:
        sys.exit(f"spgd_smoothness_study: variant {args.variant!r} has no unknown k_b")
    spgd = cfg.spgd_for(yaml.safe_load(Path(args.config).read_text()), args.variant)
    pd.set_option("display.width", 200)
    with threadpool_limits(1):
        k_b = np.linspace(*variant.unknown["k_b"], 301)
        node = peak_node(variant, k_b)
        switches = k_b[1:][np.diff(node) != 0]
        print(f"1. largest |Phi_1| entry: node {node[0]} at k_b = {k_b[0]:g} N/m, node {node[-1]} at {k_b[-1]:g} N/m; "
              f"it moves at k_b = {', '.join(f'{s:.0f}' for s in switches) or 'nowhere'} N/m")
        for scaling in ("max", "node"):
            label = "as specified (max |Phi_1| = 1)" if scaling == "max" else f"node-{UNBALANCE_NODE} scaling"
            decay = chebyshev_decay(with_scaling(variant, scaling), args.rpm, args.mass_g)
            print(f"\n2. {args.rpm:g} RPM, {args.mass_g:g} g, {label}: Chebyshev |c_n| / max |U_1x| along each "
                  f"parameter through the box centre")
            print(decay.to_string(index=False, float_format=lambda v: f"{v:.0e}"))
        if args.fit:
            rows = []
            for scaling in ("max", "node"):
                rows.append({"scaling": scaling, **surrogate_errors(with_scaling(variant, scaling), args.rpm,
                                                                    args.mass_g, args.n, args.seed, spgd)})
            print(f"\n3. sPGD (config offline.spgd) vs GP on the same {args.n} + 200 scenarios, relative sensor error "
                  f"on the test ones")
            print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
