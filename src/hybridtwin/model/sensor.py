"""The sensors: displacement probes, each reading u_n(t) (direction x) or v_n(t) (direction y) at a node.

A plain ``Shaft`` (the VARM's structure) has two, named x and y, at node 1. A ``Machine`` has the sensors it
declares, in its order (``Machine.sensors``: plane by plane, x then y): ``sensor_names`` and ``sensor_dofs``
give every one of them (the channels of a record, docs/measurement-format.md), ``sensor_channels`` their
harmonics. The functions that show an orbit (``sensor_harmonics``; the command line's tables of a solved steady
state build on it) read one x, y pair: ``node`` defaults to the
structure's first probe plane, a ``Machine``'s ``sensor_node`` (the first node with both an x and a y probe),
node 1 for a plain ``Shaft``.

Conventions: amplitudes 0-peak, u(t) = Re(sum_h U_h exp(i h Omega t)), t = 0 when
the unbalance points to +x, the shaft turning from +x towards +y.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .effect_base import Array
from .shaft import Shaft


#: the channels of a record when no machine says otherwise: the VARM's sensors x and y
DEFAULT_CHANNELS = ("x", "y")

SENSOR_NODE = 1  # z = 0.085 m on the VARM
#: the channels of a plain Shaft (and of the VARM): x and y at SENSOR_NODE
DEFAULT_SENSORS = DEFAULT_CHANNELS  # a plain Shaft's (the VARM's) probes


def _is_machine(shaft) -> bool:
    return hasattr(type(shaft), "sensor_node")


def sensor_node(shaft: Shaft) -> int:
    """The node of the (first) x, y probe pair: a Machine's ``sensor_node``, SENSOR_NODE for a plain Shaft."""
    return shaft.sensor_node if _is_machine(shaft) else SENSOR_NODE


def sensor_names(shaft: Shaft) -> tuple[str, ...]:
    """The channel names, one per sensor in the machine's order: a Machine's sensors' names, ("x", "y") for a
    Shaft."""
    return tuple(s.name for s in shaft.sensors) if _is_machine(shaft) else DEFAULT_SENSORS


def sensor_dofs(shaft: Shaft, node: int | None = None) -> list[int]:
    """Global DOF indices read by the sensors: every sensor of a Machine in its order ([u1, v1] for a plain
    Shaft); with ``node``, the x, y pair [u_node, v_node] there."""
    if node is None and _is_machine(shaft):
        return shaft.sensor_dofs()
    return pair_dofs(shaft, node)


def pair_dofs(shaft: Shaft, node: int | None = None) -> list[int]:
    """[u_node, v_node]: the x, y pair at ``node``, by default the (first) probe pair's (``sensor_node``)."""
    node = sensor_node(shaft) if node is None else node
    return [shaft.dof(f"u{node}"), shaft.dof(f"v{node}")]


def sensor_channels(harmonics: Array, shaft: Shaft) -> Array:
    """Every sensor's harmonics (..., H+1, C) complex [m] from harmonics (..., H+1, n), channels in the order of
    ``sensor_names``."""
    return harmonics[..., sensor_dofs(shaft)]


def sensor_harmonics(harmonics: Array, shaft: Shaft, node: int | None = None) -> tuple[Array, Array]:
    """U_h, V_h at the (first) x, y probe pair's node from harmonics (..., H+1, n): each (..., H+1) complex [m]."""
    u, v = pair_dofs(shaft, node)
    return harmonics[..., u], harmonics[..., v]


def peak_displacement(harmonics: Array, shaft: Shaft, node: int | None = None, n_time: int = 64) -> Array:
    """Largest |displacement| over a period at any sensor (every sensor of a Machine; with ``node``, the x, y
    pair there), (...,) [m]; NaN stays NaN."""
    dofs = sensor_dofs(shaft, node)
    h = np.arange(harmonics.shape[-2])
    phase = np.exp(2j * np.pi * np.outer(np.arange(n_time) / n_time, h))  # (N, H+1)
    peaks = [np.abs((harmonics[..., dof][..., None, :] * phase).sum(-1).real).max(-1) for dof in dofs]
    return np.maximum.reduce(peaks) if len(peaks) > 1 else peaks[0]


def observable(harmonics: Array, shaft: Shaft, sensor_range_m: float, node: int | None = None) -> Array:
    """True where the steady state exists and stays inside the sensors' range at every sensor (what a rig can
    measure)."""
    peak = peak_displacement(harmonics, shaft, node)
    return np.isfinite(peak) & (peak <= sensor_range_m)


def machine_order(sensors: Sequence) -> list[int]:
    """The indexes of ``sensors`` (objects with ``node`` and ``direction``) in a machine's channel order: plane by
    plane (``sensor_pairs``: nodes in order of first appearance) its x probe, then its y probe; then the probes
    without a partner, as declared. Records, the model's sensor DOFs and every table of channels use this order."""
    items = list(sensors)
    paired = [i for pair in sensor_pairs(items) for i in pair]
    return paired + [i for i in range(len(items)) if i not in paired]


def sensor_pairs(sensors: Sequence) -> list[tuple[int, int]]:
    """(index of the x probe, index of the y probe) for each node of ``sensors`` (objects with ``node`` and
    ``direction``) with exactly one of each, in order of the nodes' first appearance: the orbits a record shows."""
    items = list(sensors)
    pairs = []
    for node in dict.fromkeys(item.node for item in items):
        xs = [i for i, item in enumerate(items) if item.node == node and item.direction == "x"]
        ys = [i for i, item in enumerate(items) if item.node == node and item.direction == "y"]
        if len(xs) == 1 and len(ys) == 1:
            pairs.append((xs[0], ys[0]))
    return pairs
