"""A slow-roll compensated band's model (forward.SolverModel with slow_roll_harmonics): the model's own response at
slow roll subtracted from those harmonics, as the data's runout was. Checked against the same solver evaluated
plainly at both speeds (an independent path: two separate models, no batching), and for what it means physically:
an unbalance response (growing as Omega^2) has no slow-roll part, a 2X force of constant amplitude has its static
deflection."""

from __future__ import annotations

import numpy as np
import yaml

from hybridtwin import config as cfg
from hybridtwin.identify import forward as fwd

H = 3


def variant():
    config = yaml.safe_load(open(cfg.CONFIG_FILE))
    geometric = config["variants"]["geometric"]
    config["variants"]["g2x"] = {"description": "geometric + a 2X force", "effects": geometric["effects"] +
                                 ["excitation_2x"], "unknown": geometric["unknown"] | {"f2_c": [-0.2, 0.2],
                                                                                       "f2_s": [-0.2, 0.2]}}
    return cfg.variant(config, "g2x")


def models(v, rpm, mass, compensated):
    names = list(v.unknown)
    lower, upper = (np.array(x, float) for x in zip(*v.unknown.values()))
    return fwd.SolverModel(v, "b", rpm, mass, names, lower, upper, H, slow_roll_harmonics=compensated)


def test_compensated_is_the_band_minus_its_slow_roll_response():
    v = variant()
    x = np.array([[0.1, 0.2, -0.3, -0.5, -0.6, 0.5, -0.25], [0.0, 0.0, 0.0, -0.4, -0.5, -0.3, 0.4]])
    band, plain, slow = models(v, 250.0, 14.8, (1, 2)), models(v, 250.0, 14.8, ()), models(v, fwd.SLOW_ROLL_RPM,
                                                                                          14.8, ())
    M, dM = band.evaluate(x)
    P, dP = plain.evaluate(x)
    S, dS = slow.evaluate(x)
    scale = np.abs(P).max()
    # the same solver at the same points: equal to round-off (1e-9 of the response, the solver's tolerance)
    assert np.allclose(M[:, :2], P[:, :2] - S[:, :2], atol=1e-9 * scale, rtol=0)
    assert np.allclose(M[:, 2], P[:, 2], atol=1e-12 * scale, rtol=0)  # 3X not compensated
    assert np.allclose(dM[:, :2], dP[:, :2] - dS[:, :2], atol=1e-7 * np.abs(dP).max(), rtol=0)
    # batched with another band (evaluate_runs): the same numbers
    other = models(v, 400.0, 25.9, (1, 2))
    (Mb, _), _ = fwd.evaluate_runs([models(v, 250.0, 14.8, (1, 2)), other], [x, x])
    assert np.allclose(Mb, M, atol=1e-9 * scale, rtol=0)
    # physics: the unbalance and bow (Omega^2 forces) scale as (3 / 250)^2 = 1.4e-4 between the two speeds (divided
    # by the band's dynamic amplification 1 / (1 - (250 / 960)^2) = 1.07: within 0.5-1.5 of it); the 2X force's
    # static deflection is most of the band's 2X at 250 RPM (2 Omega below the first critical speed, ~960 RPM)
    one = np.abs(S[:, 0]) / np.abs(P[:, 0]) / (fwd.SLOW_ROLL_RPM / 250.0) ** 2
    assert np.all((one > 0.5) & (one < 1.5)), one
    ratio = np.abs(S[:, 1]) / np.abs(P[:, 1])
    assert np.all((ratio > 0.5) & (ratio < 1.0)), ratio


def test_the_bands_of_one_record_share_one_slow_roll_solve():
    """Two bands of one record (same mass, same parameters) need one 3-RPM state: it is solved once per evaluation,
    and both bands get the same numbers as when evaluated alone."""
    v = variant()
    x = np.array([[0.1, 0.2, -0.3, -0.5, -0.6, 0.5, -0.25]])
    a, b = models(v, 250.0, 14.8, (1, 2)), models(v, 300.0, 14.8, (1, 2))
    (Ma, _), (Mb, _) = fwd.evaluate_runs([a, b], [x, x])
    assert a.reference.n_solves + b.reference.n_solves == 1
    alone_a, alone_b = models(v, 250.0, 14.8, (1, 2)).evaluate(x)[0], models(v, 300.0, 14.8, (1, 2)).evaluate(x)[0]
    scale = np.abs(alone_a).max()
    # batched or alone, the same solver to its tolerance (1e-9 of the response)
    assert np.allclose(Ma, alone_a, atol=1e-9 * scale, rtol=0) and np.allclose(Mb, alone_b, atol=1e-9 * scale, rtol=0)
