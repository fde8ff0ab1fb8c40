"""The sensors: displacements x = u_n(t), y = v_n(t) at one node (node 1 on the VARM).

``node`` defaults to the structure's probe plane: a ``Machine``'s ``sensor_node`` (its one x, y pair),
node 1 for a plain ``Shaft``.

Conventions: amplitudes 0-peak, u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when
the unbalance points to +x, the shaft turning from +x towards +y.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .effect_base import Array
from .shaft import Shaft
from .solver import SteadyState

SENSOR_NODE = 1  # z = 0.085 m on the VARM


def sensor_node(shaft: Shaft) -> int:
    """The node of the x, y probes: a Machine's ``sensor_node``, SENSOR_NODE for a plain Shaft."""
    return shaft.sensor_node if hasattr(type(shaft), "sensor_node") else SENSOR_NODE


def sensor_dofs(shaft: Shaft, node: int | None = None) -> list[int]:
    """Global DOF indices [u_node, v_node] read by the sensors."""
    node = sensor_node(shaft) if node is None else node
    return [shaft.dof(f"u{node}"), shaft.dof(f"v{node}")]


def sensor_harmonics(harmonics: Array, shaft: Shaft, node: int | None = None) -> tuple[Array, Array]:
    """U_h, V_h at the sensor node from harmonics (..., H+1, n): each (..., H+1) complex [m]."""
    u, v = sensor_dofs(shaft, node)
    return harmonics[..., u], harmonics[..., v]


def harmonics_frame(result: SteadyState, shaft: Shaft, scenario: int = 0, node: int | None = None) -> pd.DataFrame:
    """One scenario's sensor harmonics as columns harmonic,u_re_m,u_im_m,v_re_m,v_im_m."""
    U, V = sensor_harmonics(result.harmonics, shaft, node)
    return pd.DataFrame({
        "harmonic": np.arange(result.H + 1),
        "u_re_m": U[scenario].real, "u_im_m": U[scenario].imag,
        "v_re_m": V[scenario].real, "v_im_m": V[scenario].imag,
    })


def time_series_frame(result: SteadyState, shaft: Shaft, t: Array, scenario: int = 0,
                      node: int | None = None) -> pd.DataFrame:
    """x_m, y_m at times ``t`` [s], evaluated from the Fourier series (not resampled)."""
    xy = result.time_series(t, sensor_dofs(shaft, node))[scenario]
    return pd.DataFrame({"time_s": t, "x_m": xy[:, 0], "y_m": xy[:, 1]})


def peak_displacement(harmonics: Array, shaft: Shaft, node: int | None = None, n_time: int = 64) -> Array:
    """Largest |x(t)| or |y(t)| over a period at the sensor, (...,) [m]; NaN stays NaN."""
    U, V = sensor_harmonics(harmonics, shaft, node)
    h = np.arange(U.shape[-1])
    phase = np.exp(2j * np.pi * np.outer(np.arange(n_time) / n_time, h))  # (N, H+1)
    x = np.abs((U[..., None, :] * phase).sum(-1).real).max(-1)
    y = np.abs((V[..., None, :] * phase).sum(-1).real).max(-1)
    return np.maximum(x, y)


def observable(harmonics: Array, shaft: Shaft, sensor_range_m: float, node: int | None = None) -> Array:
    """True where the steady state exists and stays inside the sensors' range (what a rig can measure)."""
    peak = peak_displacement(harmonics, shaft, node)
    return np.isfinite(peak) & (peak <= sensor_range_m)
