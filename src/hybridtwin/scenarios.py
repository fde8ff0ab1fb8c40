"""Operating points and parameter scenarios to solve (the stage after the solver).

``solve_operating_points`` solves a run plan (rpm, eccentric mass) for one set
of parameter values the way a rig is driven: per eccentric mass, a run-up
through its speeds by continuation, so that near the resonance the branch is
the one a run-up reaches, and every point says which branch it is on.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from .sensor import sensor_harmonics
from .solver import solve_sweep
from .variants import Variant


def solve_operating_points(variant: Variant, points: pd.DataFrame, overrides: Mapping[str, float] | None = None,
                           harmonics: int = 5, step_rpm: float = 50.0, start_rpm: float = 300.0) -> pd.DataFrame:
    """Sensor harmonics at every (rpm, eccentric_mass_g) row of ``points``, by run-up per mass.

    Returns ``points`` with, per harmonic h (1..H), columns U{h}_re_m, U{h}_im_m,
    V{h}_re_m, V{h}_im_m, plus success, branch and message. Each mass's run-up
    starts at ``start_rpm`` (or its lowest speed if lower); speeds between the
    plan's points (spaced at most ``step_rpm``) are solved for continuation only.
    """
    for column in ("rpm", "eccentric_mass_g"):
        if column not in points:
            raise ValueError(f"operating points need a column {column!r} (have {list(points.columns)})")
    out = points.copy()
    columns: dict[str, np.ndarray] = {}
    status = {k: np.empty(len(points), dtype=object) for k in ("success", "branch", "message")}
    for mass_g, group in points.groupby("eccentric_mass_g", sort=True):
        values = variant.values({**(overrides or {}), "m_e": float(mass_g) * 1e-3})
        speeds = _with_intermediate(np.unique(np.append(group["rpm"].to_numpy(float), start_rpm)), step_rpm)
        sweep = solve_sweep(lambda rpm, rows: variant.model.system(values, rpm), speeds, 1,
                            harmonics=harmonics, direction="up")
        by_rpm = dict(zip(sweep.rpm, sweep.results))
        for pos, rpm in zip(np.flatnonzero(points.index.isin(group.index)), group["rpm"].to_numpy(float)):
            result = by_rpm[rpm]
            U, V = sensor_harmonics(result, variant.model.shaft)
            for h in range(1, harmonics + 1):
                for name, value in ((f"U{h}", U[0, h]), (f"V{h}", V[0, h])):
                    columns.setdefault(f"{name}_re_m", np.full(len(points), np.nan))[pos] = value.real
                    columns.setdefault(f"{name}_im_m", np.full(len(points), np.nan))[pos] = value.imag
            status["success"][pos] = bool(result.success[0])
            status["branch"][pos] = result.branch[0]
            status["message"][pos] = result.message[0]
    for name, values in {**columns, **status}.items():
        out[name] = values
    out["success"] = out["success"].astype(bool)
    return out


def _with_intermediate(speeds: np.ndarray, step: float) -> np.ndarray:
    """The sorted speeds plus evenly spaced intermediate ones so no gap exceeds ``step``."""
    if speeds.size < 2:
        return speeds
    parts = [np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)[:-1] for a, b in zip(speeds[:-1], speeds[1:])]
    return np.concatenate(parts + [speeds[-1:]])
