"""The plots engineers read of a machine (matplotlib, no screen needed): the Campbell diagram, the mode shapes
and the operating deflected shape, for any model (a ``Machine``'s or the VARM's).

``campbell_figure(model, values, rpm)``: the whirl frequencies of any model's linear part (``model.campbell``)
against speed, forward and backward branches apart, the 1X-3X excitation lines, the crossings of the 1X line
(the critical speeds) and the run speeds marked; below them each branch's damping as its logarithmic decrement
(``log_decrement``: 2 pi zeta / sqrt(1 - zeta^2), the decay of a free vibration per cycle, ln(x_n / x_n+1)).

``undamped_modes(model, values, rpm)`` and ``mode_shape_figure``: the lowest modes of the model's linear part at
one speed without damping (stiffness with its speed terms, mass, gyroscopic coupling kept: it is not damping),
their deflection along the shaft between the nodes by the elements' cubic shape functions.

``operating_deflection(result, shaft)`` and ``ods_figure``: the amplitude of a harmonic of a steady state along
the whole shaft (the harmonic balance solves every DOF), the measured amplitude at the probes on top.

Bearings, disks, unbalance planes and probes of a ``Machine`` are marked on the shaft plots (``gid``
"bearing:<name>", "disk:<node>", "unbalance:<name>", "sensor:<name>").

Deflection along the shaft. A mode (or a harmonic) gives complex x- and y-plane deflections U(z), V(z): at
each z the point whirls on the ellipse Re((U, V) exp(i tau)). The shape drawn is the ellipse's semi-major
axis, sqrt((|U|^2 + |V|^2 + |U^2 + V^2|) / 2) (|U| for a planar or a circular whirl), signed by the direction
of the deflection at the instant the largest one peaks: a sign change is a nodal point.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import matplotlib.pyplot as plt  # no backend forced: Agg by itself without a display, or the caller's choice
import numpy as np
import pandas as pd

from ..model.model import Model, circular_modes, campbell
from ..solvers.solver import SteadyState

WHIRL_STYLE = {"forward": dict(color="C0", ls="-"), "backward": dict(color="C3", ls="--")}


def log_decrement(damping_ratio) -> np.ndarray:
    """The logarithmic decrement of a mode of damping ratio zeta: delta = 2 pi zeta / sqrt(1 - zeta^2) (ln of the
    ratio of two successive peaks of its free vibration; API 684's measure of stability, > 0 stable); +inf for
    zeta >= 1 (no oscillation to decay), negative for a growing mode."""
    zeta = np.asarray(damping_ratio, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(zeta < 1.0, 2 * np.pi * zeta / np.sqrt(np.maximum(1.0 - zeta**2, 0.0)), np.inf)


def branches(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (``model.campbell``) with a column ``branch``: the rank of each mode among the modes of its
    whirl sense at its speed (0 = the lowest forward mode, ...), and each mode's ``log_decrement``. Following a
    branch along speed keeps a forward and a backward mode apart where they cross."""
    out = table.sort_values(["rpm", "whirl", "frequency_hz"]).copy()
    out["branch"] = out.groupby(["rpm", "whirl"]).cumcount()
    if "damping_ratio" in out:
        out["log_decrement"] = log_decrement(out["damping_ratio"])
    return out.sort_values(["rpm", "mode"])


def critical_speeds(table: pd.DataFrame, harmonic: int = 1) -> pd.DataFrame:
    """Where a branch crosses the ``harmonic`` X line (frequency = harmonic rpm / 60), by linear
    interpolation between the table's speeds: columns whirl, branch, rpm, frequency_hz, and the branch's
    damping_ratio and log_decrement there (interpolated the same way; NaN for a table without damping)."""
    rows = []
    for (whirl, branch), group in branches(table).groupby(["whirl", "branch"]):
        group = group.sort_values("rpm")
        rpm, f = group["rpm"].to_numpy(), group["frequency_hz"].to_numpy()
        zeta = group["damping_ratio"].to_numpy(float) if "damping_ratio" in group else np.full(len(rpm), np.nan)
        gap = f - harmonic * rpm / 60.0
        for i in np.flatnonzero(np.sign(gap[:-1]) * np.sign(gap[1:]) < 0):
            t = gap[i] / (gap[i] - gap[i + 1])
            crossing = rpm[i] + t * (rpm[i + 1] - rpm[i])
            z = zeta[i] + t * (zeta[i + 1] - zeta[i])
            rows.append((whirl, int(branch), crossing, harmonic * crossing / 60.0, z, float(log_decrement(z))))
    columns = ["whirl", "branch", "rpm", "frequency_hz", "damping_ratio", "log_decrement"]
    return pd.DataFrame(rows, columns=columns).sort_values("rpm", ignore_index=True)


def _lowest_branches(table: pd.DataFrame, n_modes: int) -> pd.DataFrame:
    """The branches of the ``n_modes`` lowest modes at the lowest speed, followed over all speeds."""
    first = table[table["rpm"] == table["rpm"].min()].nsmallest(n_modes, "frequency_hz")
    counts = first["whirl"].value_counts()
    keep = table["branch"] < table["whirl"].map(counts).fillna(0)
    return table[keep]


def campbell_figure(model: Model, values: Mapping[str, float], rpm: Sequence[float], run_rpm: Sequence[float] = (),
                    n_modes: int = 6, harmonics: Sequence[int] = (1, 2, 3), title: str = "",
                    table: pd.DataFrame | None = None, operating: Sequence[float] | None = None) -> plt.Figure:
    """The Campbell diagram of ``model`` at parameter values ``values`` over the speeds ``rpm``.

    Whirl frequencies [Hz] of the branches of the ``n_modes`` lowest modes at the lowest speed, followed over
    the speeds (forward solid, backward dashed); the
    ``harmonics`` X lines; the critical speeds (1X crossings) as dots; the run speeds ``run_rpm`` as vertical
    lines; the operating speed range ``operating`` (min, max) [RPM] shaded. ``table``: a ``model.campbell`` table already computed (then ``values``, ``rpm`` and ``n_modes``
    are not used). Below, a second panel: each branch's logarithmic decrement against speed (the zero line is the
    stability limit). The figure's data stay readable: ``fig.campbell`` is the table with its branches and log
    decrements, ``fig.critical`` the crossings with their damping.
    """
    if table is None:  # twice the modes, so that a branch among the lowest is never cut off at high speed
        table = _lowest_branches(branches(campbell(model, values, rpm, 2 * n_modes)), n_modes)
    else:
        table = branches(table)
    if "log_decrement" not in table:  # a table without damping: the panel stays empty
        table = table.assign(log_decrement=np.nan)
    if table.empty:
        raise ValueError("Campbell diagram: the model has no oscillating mode at these speeds")
    fig, (ax, damping) = plt.subplots(2, 1, figsize=(8, 8), sharex=True, height_ratios=(2.2, 1))
    for (whirl, branch), group in table.groupby(["whirl", "branch"]):
        group = group.sort_values("rpm")
        ax.plot(group["rpm"], group["frequency_hz"], lw=1.5, **WHIRL_STYLE[whirl],
                label=f"{whirl} whirl" if branch == 0 else None, gid=f"{whirl}:{branch}")
        damping.plot(group["rpm"], group["log_decrement"], lw=1.3, **WHIRL_STYLE[whirl],
                     gid=f"log_decrement:{whirl}:{branch}")
        end = group.iloc[-1]
        damping.annotate(f"{branch + 1}{whirl[0].upper()}", (end["rpm"], end["log_decrement"]), fontsize=7,
                         xytext=(2, 0), textcoords="offset points", va="center", color=WHIRL_STYLE[whirl]["color"])
    speed = np.array([table["rpm"].min(), table["rpm"].max()])
    top = table["frequency_hz"].max() * 1.05
    for h in harmonics:
        ax.plot(speed, h * speed / 60.0, color="0.4", lw=1, ls=":", gid=f"{h}X")
        end = min(speed[1], top * 60.0 / h)
        ax.annotate(f"{h}X", (end, h * end / 60.0), fontsize=8, color="0.3", ha="right", va="bottom")
    critical = critical_speeds(table, 1)
    if len(critical):
        ax.plot(critical["rpm"], critical["frequency_hz"], "o", color="k", ms=5, mfc="none",
                label="critical speeds (1X)", gid="critical")
        for _, row in critical.iterrows():
            ax.annotate(f"{row['rpm']:.0f}", (row["rpm"], row["frequency_hz"]), textcoords="offset points",
                        xytext=(4, -10) if row["whirl"] == "backward" else (-8, 5), fontsize=7,
                        ha="left" if row["whirl"] == "backward" else "right")
    for i, r in enumerate(sorted(set(float(v) for v in run_rpm))):
        ax.axvline(r, color="C2", lw=0.8, alpha=0.6, label="run speeds" if i == 0 else None, gid=f"run:{r:g}")
    if operating is not None:
        for panel in (ax, damping):
            panel.axvspan(min(operating), max(operating), color="C2", alpha=0.12, zorder=0, gid="operating",
                          label="operating range" if panel is ax else None)
    ax.set_xlim(speed)
    ax.set_ylim(0, top)
    ax.set_ylabel("whirl frequency [Hz]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(title or f"Campbell diagram, {getattr(model.shaft, 'name', 'shaft')}")
    damping.axhline(0.0, color="k", lw=0.8, gid="stability limit")  # below: a mode that grows (unstable)
    for r in sorted(set(float(v) for v in run_rpm)):
        damping.axvline(r, color="C2", lw=0.8, alpha=0.6)
    finite = table["log_decrement"].to_numpy(float)
    finite = finite[np.isfinite(finite)]
    if finite.size:  # every branch's decrement in view, the zero line too
        lo, hi = min(finite.min(), 0.0), max(finite.max(), 0.0)
        pad = 0.08 * (hi - lo) or 0.1
        damping.set_ylim(lo - pad, hi + pad)
    damping.set_xlabel("speed [RPM]")
    damping.set_ylabel("log decrement")
    damping.grid(True, alpha=0.3)
    damping.set_title("damping: logarithmic decrement 2 pi zeta / sqrt(1 - zeta^2) of each branch (< 0: unstable)",
                      fontsize=8, loc="left")
    fig.tight_layout()
    fig.campbell, fig.critical = table, critical
    return fig


# --- mode shapes ------------------------------------------------------------------------------------------

#: two eigenvalues closer than this (relative) are one degenerate pair (the x and y planes of a rotor without
#: gyroscopic coupling); the same tolerance as ``model.circular_modes``
DEGENERATE_RTOL = 1e-7


@dataclass
class Modes:
    """Undamped modes at one speed: frequency_hz, whirl ("forward"/"backward"), whirl_index (as
    ``model.campbell``) and pair (True for both members of a degenerate pair: forward and backward combinations
    of one planar mode) per mode, lowest first; ``vectors`` (n_dof, n_modes) complex mode vectors."""

    rpm: float
    frequency_hz: np.ndarray
    whirl: np.ndarray
    whirl_index: np.ndarray
    pair: np.ndarray
    vectors: np.ndarray

    def table(self) -> pd.DataFrame:
        return pd.DataFrame({"rpm": self.rpm, "mode": np.arange(len(self.frequency_hz)),
                             "frequency_hz": self.frequency_hz, "whirl": self.whirl, "whirl_index": self.whirl_index,
                             "pair": self.pair})


def undamped_modes(model: Model, values: Mapping[str, float], rpm: float = 0.0, n_modes: int = 6) -> Modes:
    """The ``n_modes`` lowest modes of ``model``'s linear part at ``rpm`` with the damping left out.

    M q'' + Omega G q' + K q = 0: K with the speed terms and a polynomial bearing's degree-1 terms (as
    ``campbell``), G the model's ``gyroscopic`` effects (none: a real, planar problem whose x- and y-plane modes
    come in degenerate pairs, returned as their forward and backward circular combinations, ``pair`` True).
    The whirl frequencies are those of ``campbell`` with every damping set to zero.
    """
    from ..model.machine import Gyroscopic

    values = {k: np.asarray(v, dtype=float) for k, v in values.items()}
    system = model.system(values, [float(rpm)])
    M, K = system.M[0], system.K[0]
    gyroscopic = [e for e in model.effects if isinstance(e, Gyroscopic)]
    C = np.zeros_like(M)
    if gyroscopic:
        ctx = model.context(values, [float(rpm)])
        C = sum(e.damping(ctx)[0] for e in gyroscopic)
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    lam, vec = np.linalg.eig(np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]]))
    keep = np.flatnonzero(lam.imag > 1e-9 * np.abs(lam).max())
    keep = keep[np.argsort(lam.imag[keep])][:n_modes + 1]  # one more: a pair cut in two at the end is whole
    q = circular_modes(lam[keep], vec[:n, keep])
    x, y = np.arange(n // 2), np.arange(n // 2, n)
    w = lam[keep].imag
    close = np.abs(np.diff(w)) <= DEGENERATE_RTOL * np.abs(w[1:])
    pair = np.append(close, False) | np.insert(close, 0, False)
    index = np.array([-2.0 * np.sum(np.imag(np.conj(q[x, j]) * q[y, j])) / np.sum(np.abs(q[:, j]) ** 2)
                      for j in range(len(keep))])
    m = min(n_modes, len(keep))
    return Modes(float(rpm), w[:m] / (2 * np.pi), np.where(index[:m] >= 0, "forward", "backward"), index[:m],
                 pair[:m], q[:, :m])


def hermite(shaft, q: np.ndarray, plane: str = "x", per_element: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """The deflection of one plane along the shaft from DOF vector(s) ``q`` (n_dof,) or (n_dof, m), between the
    nodes by each element's cubic Hermite shape functions of its end deflections and slopes (the beam element's
    own interpolation): z [m] (per_element points per element, nodes included) and w (len(z),) or (len(z), m)."""
    nodes = shaft.translational(plane)
    w, slope = q[nodes], q[nodes + 1]
    z_nodes = np.asarray(shaft.z, float)
    s = np.linspace(0.0, 1.0, per_element + 1)[:-1]
    N1, N2, N3, N4 = 1 - 3 * s**2 + 2 * s**3, s - 2 * s**2 + s**3, 3 * s**2 - 2 * s**3, -s**2 + s**3
    zs, ws = [], []
    for e, h in enumerate(np.diff(z_nodes)):
        zs.append(z_nodes[e] + s * h)
        ws.append(np.multiply.outer(N1, w[e]) + np.multiply.outer(h * N2, slope[e])
                  + np.multiply.outer(N3, w[e + 1]) + np.multiply.outer(h * N4, slope[e + 1]))
    return np.append(np.concatenate(zs), z_nodes[-1]), np.concatenate(ws + [w[-1:]])


def deflection(U: np.ndarray, V: np.ndarray) -> np.ndarray:
    """The signed semi-major axis of the whirl ellipses Re((U, V) exp(i tau)) at each point (module docstring),
    for complex x- and y-plane deflections U, V (p,) [any unit]; the sign is + where the deflection at the
    instant the largest ellipse peaks points along that peak, - where against."""
    a = np.sqrt(0.5 * (np.abs(U) ** 2 + np.abs(V) ** 2 + np.abs(U**2 + V**2)))
    r = int(np.argmax(a))
    s = U[r] ** 2 + V[r] ** 2
    tau = -0.5 * np.angle(s) if abs(s) > 1e-9 * a[r] ** 2 else -np.angle(U[r] if abs(U[r]) >= abs(V[r]) else V[r])
    rotation = np.exp(1j * tau)
    peak = np.array([(U[r] * rotation).real, (V[r] * rotation).real])
    along = (U * rotation).real * peak[0] + (V * rotation).real * peak[1]
    return np.where(along < 0, -a, a)


def mode_shapes(shaft, modes: Modes, per_element: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """z [m] along the shaft and each mode's deflection (len(z), n_modes), the largest +1 (``deflection``)."""
    z, U = hermite(shaft, modes.vectors, "x", per_element)
    _, V = hermite(shaft, modes.vectors, "y", per_element)
    shapes = np.column_stack([deflection(U[:, j], V[:, j]) for j in range(U.shape[1])]) if U.shape[1] else U.real
    return z, shapes / np.maximum(np.abs(shapes).max(axis=0), 1e-300)


def mark_machine(ax: plt.Axes, shaft) -> None:
    """Bearings (triangles), disks (bars), unbalance planes (stars) and probes (diamonds) of a ``Machine`` on the
    shaft axis y = 0 of ``ax``, named; nothing for a plain ``Shaft``."""
    z = np.asarray(shaft.z, float)
    style = dict(textcoords="offset points", fontsize=7, ha="center")
    for bearing in getattr(shaft, "bearings", ()):
        ax.plot(z[bearing.node], 0.0, "^", color="k", ms=9, mfc="0.7", zorder=5, gid=f"bearing:{bearing.name}")
        ax.annotate(bearing.name, (z[bearing.node], 0.0), xytext=(0, -14), **style)
    for disk in getattr(shaft, "disks", ()):
        ax.axvline(z[disk.node], color="C1", lw=5, alpha=0.35, zorder=1, gid=f"disk:{disk.node}")
    for plane in getattr(shaft, "unbalance_planes", ()):
        ax.plot(z[plane.node], 0.0, "*", color="C3", ms=10, zorder=6, gid=f"unbalance:{plane.name}")
    probes: dict[int, list[str]] = {}
    for sensor in getattr(shaft, "sensors", ()):
        ax.plot(z[sensor.node], 0.0, "D", color="C2", ms=6, zorder=6, gid=f"sensor:{sensor.name}")
        probes.setdefault(sensor.node, []).append(sensor.name)
    for node, names in probes.items():  # one label per probe plane
        ax.annotate(", ".join(names), (z[node], 0.0), xytext=(0, 7), color="C2", **style)


def _whirl_label(modes: Modes, j: int) -> str:
    return "x and y planes alike" if modes.pair[j] else f"{modes.whirl[j]} whirl"


def mode_shape_figure(model: Model, values: Mapping[str, float], rpm: float = 0.0, n_modes: int = 4,
                      title: str = "", modes: Modes | None = None) -> plt.Figure:
    """The ``n_modes`` lowest distinct undamped modes at ``rpm`` (``undamped_modes``; of a degenerate pair the
    forward member only), one panel each: the deflection along the shaft (``mode_shapes``, largest +1), the
    nodes as dots, the machine's places marked. ``fig.modes``: the modes drawn (``Modes.table``), ``fig.shapes``:
    z [m] and the shapes."""
    modes = undamped_modes(model, values, rpm, 2 * n_modes) if modes is None else modes
    shown = [j for j in range(len(modes.frequency_hz)) if not (modes.pair[j] and j > 0 and modes.pair[j - 1]
                                                               and _same(modes, j - 1, j))][:n_modes]
    if not shown:
        raise ValueError("mode shapes: the model has no oscillating mode at this speed")
    picked = Modes(modes.rpm, modes.frequency_hz[shown], modes.whirl[shown], modes.whirl_index[shown],
                   modes.pair[shown], modes.vectors[:, shown])
    shaft = model.shaft
    per_element = 12
    z, shapes = mode_shapes(shaft, picked, per_element)
    at_nodes = shapes[::per_element]
    fig, axes = plt.subplots(len(shown), 1, figsize=(8, 1.9 * len(shown) + 0.8), sharex=True, squeeze=False)
    for k, ax in enumerate(axes[:, 0]):
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.plot(z, shapes[:, k], color="C0", lw=1.6, gid=f"mode:{k}")
        ax.plot(shaft.z, at_nodes[:, k], "o", color="C0", ms=3, gid=f"nodes:{k}")
        mark_machine(ax, shaft)
        ax.set_ylim(-1.3, 1.3)
        ax.set_ylabel("deflection")
        ax.set_title(f"mode {k + 1}: {picked.frequency_hz[k]:.4g} Hz, {_whirl_label(picked, k)}", fontsize=9,
                     loc="left")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("z along the shaft [m]")
    fig.suptitle(title or f"Undamped mode shapes at {rpm:g} RPM, {getattr(shaft, 'name', 'shaft')}", fontsize=10)
    fig.tight_layout()
    fig.modes, fig.shapes = picked.table(), (z, shapes)
    return fig


def _same(modes: Modes, i: int, j: int) -> bool:
    return abs(modes.frequency_hz[j] - modes.frequency_hz[i]) <= DEGENERATE_RTOL * modes.frequency_hz[j]


# --- operating deflected shape ----------------------------------------------------------------------------


def operating_deflection(result: SteadyState, shaft, scenario: int = 0, harmonic: int = 1,
                         per_element: int = 12) -> pd.DataFrame:
    """Harmonic ``harmonic`` of a steady state along the shaft (every DOF is solved): columns z_m, node (the
    node's index at a node, -1 between nodes), x_amplitude_m, x_phase_rad, y_amplitude_m, y_phase_rad (0-peak,
    u(t) = Re(U exp(i h Omega t))) and deflection_m (the signed semi-major axis, ``deflection``)."""
    Q = result.harmonics[scenario, harmonic]
    z, U = hermite(shaft, Q, "x", per_element)
    _, V = hermite(shaft, Q, "y", per_element)
    node = np.full(len(z), -1)
    node[::per_element] = np.arange(shaft.n_nodes)
    return pd.DataFrame({"z_m": z, "node": node, "x_amplitude_m": np.abs(U), "x_phase_rad": np.angle(U),
                         "y_amplitude_m": np.abs(V), "y_phase_rad": np.angle(V), "deflection_m": deflection(U, V)})


def ods_figure(runs: Sequence[tuple[str, SteadyState]], shaft,
               measured: Mapping[str, tuple[float, float]] | None = None, harmonic: int = 1,
               sensor_node: int | None = None, title: str = "") -> plt.Figure:
    """The operating deflected shape of each run: the ``harmonic`` X amplitude (0-peak) [mm] of x (solid) and y
    (dashed) along the shaft, one colour per run (``runs``: (label, steady state of one scenario)); ``measured``
    {label: (|X|, |Y|) [m]} at the probes' node ``sensor_node`` (default: the model's, ``sensor.sensor_node``) as
    markers on top. ``fig.ods``: {label: operating_deflection table}."""
    from ..model.sensor import sensor_node as probes

    node = probes(shaft) if sensor_node is None else sensor_node
    fig, ax = plt.subplots(figsize=(8, 4.5))
    tables = {}
    for i, (label, result) in enumerate(runs):
        table = operating_deflection(result, shaft, harmonic=harmonic)
        tables[label] = table
        colour = f"C{i % 10}"
        ax.plot(table.z_m, 1e3 * table.x_amplitude_m, color=colour, lw=1.5, label=f"{label} x", gid=f"x:{label}")
        ax.plot(table.z_m, 1e3 * table.y_amplitude_m, color=colour, lw=1.2, ls="--", label=f"{label} y",
                gid=f"y:{label}")
        if measured and label in measured:
            X, Y = measured[label]
            ax.plot(shaft.z[node], 1e3 * X, "o", color=colour, mfc="none", ms=8, label=f"{label} measured x",
                    gid=f"measured_x:{label}")
            ax.plot(shaft.z[node], 1e3 * Y, "s", color=colour, mfc="none", ms=7, label=f"{label} measured y",
                    gid=f"measured_y:{label}")
    mark_machine(ax, shaft)
    ax.set_xlabel("z along the shaft [m]")
    ax.set_ylabel(f"{harmonic}X amplitude, 0-peak [mm]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title or f"Operating deflected shape ({harmonic}X), {getattr(shaft, 'name', 'shaft')}")
    fig.tight_layout()
    fig.ods = tables
    return fig


# --- the report's machine figures -------------------------------------------------------------------------


def fitted_values(table: pd.DataFrame) -> dict[str, float]:
    """The parameter values of a parameter table (parameters.tsv, ``Identification.table``): each shared (or a
    per-run fit's physical) parameter's estimate, each per-run parameter's median over the runs; the phases
    left out."""
    rows = table[table["kind"].astype(str) != "nuisance"]
    return {str(name): float(np.median(group["value"].to_numpy(float)))
            for name, group in rows.groupby("parameter", sort=False)}


def report_speeds(run_rpm: Sequence[float], n_speeds: int = 121, margin: float = 1.25) -> np.ndarray:
    """The Campbell diagram's speeds [RPM]: 0 to ``margin`` times the fastest run, ``n_speeds`` of them."""
    return np.linspace(0.0, margin * float(np.max(run_rpm)), n_speeds)
