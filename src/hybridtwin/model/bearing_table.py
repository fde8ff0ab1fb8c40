"""Speed-dependent bearings: the eight linear coefficients of a bearing (or seal) against speed, from a table
(docs/model.md, "Describing your machine", "Speed-dependent bearings").

A fluid-film bearing's or a seal's force on the shaft at its node, linearised about the running position, is

    [F_x, F_y] = -K(Omega) [x, y] - C(Omega) [x', y'],   K = [[kxx, kxy], [kyx, kyy]],  C = [[cxx, cxy], [cyx, cyy]]

(Friswell et al., Dynamics of Rotating Machines, 2010, sec. 5.5; ROSS's ``BearingElement``, whose K and C these
are, same signs and layout). ``BearingTable`` holds the coefficients at a list of speeds (``rpm``) and evaluates
them at any speed, vectorised over scenarios, by one of two rules (``interpolation``):

- ``linear`` (the default): piecewise linear between the table's speeds, constant beyond its ends (the table's
  first and last rows: a table says nothing outside its range, and a line continued would soon make a stiffness
  negative).
- ``ross``: ROSS 2.3.0's rule (``BearingElement._process_coefficient``), the same scipy calls on the speeds in
  rad/s: four rows or more, ``scipy.interpolate.UnivariateSpline(speeds, values)`` (a cubic smoothing spline with
  FITPACK's default smoothing s = number of rows, which does not quite pass through the rows where the values are
  small); three rows, the quadratic through them; two, the line; one, a constant. Beyond the table's ends ROSS
  *extrapolates* (the spline's end polynomial, the parabola, the line), and so does this rule. It is what
  ``ross_io.machine_from_ross`` gives a ROSS 2.3 bearing, so that our model and ROSS evaluate the same coefficients.
- ``pchip``: ROSS 3's rule (its ``BearingCoefficient``, ``interpolation="pchip"``, the default): the
  shape-preserving piecewise cubic Hermite interpolant (``scipy.interpolate.PchipInterpolator``) of the rows over
  rad/s, continued beyond the table's ends as a line with the end slopes; two rows, the line; one, a constant.
- ``linear_extrapolated``: ROSS 3's ``interpolation="linear"``: piecewise linear, continued beyond the ends as the
  end segments' lines (``scipy.interpolate.interp1d(..., fill_value="extrapolate")``).

``TableBearing`` is the effect ``bearing_table@<bearing>`` (``Machine.effects``): the coefficients at rest
(Omega = 0) in the stiffness at rest (so the first mode at rest sees the bearing), the change with speed in
``speed_stiffness``, and C(Omega) in ``damping``. It has no parameters: the table is the machine's.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .effect_base import Array, Context, Effect, LocalMatrix, Parameter

#: the eight coefficients, in the order of a table's columns: stiffness [N/m], then damping [N s/m]
COEFFICIENTS = ("kxx", "kxy", "kyx", "kyy", "cxx", "cxy", "cyx", "cyy")
#: the optional mass coefficients [kg] (a seal's or a squeeze film's added mass; ROSS's mxx ..), zero when not given
MASSES = ("mxx", "mxy", "myx", "myy")
COLUMNS = COEFFICIENTS + MASSES
INTERPOLATIONS = ("linear", "ross", "pchip", "linear_extrapolated")
#: (row, column) of each coefficient in the bearing's 2 x 2 block over (x, y)
_PLACE = {"xx": (0, 0), "xy": (0, 1), "yx": (1, 0), "yy": (1, 1)}


@dataclass(frozen=True)
class BearingTable:
    """The eight coefficients of a bearing at the speeds ``rpm`` (strictly increasing, >= 0): ``kxx`` .. ``kyy``
    [N/m], ``cxx`` .. ``cyy`` [N s/m], one value per speed; ``interpolation`` one of ``INTERPOLATIONS`` (module
    docstring). A problem raises ValueError naming the key."""

    rpm: tuple[float, ...]
    kxx: tuple[float, ...]
    kxy: tuple[float, ...]
    kyx: tuple[float, ...]
    kyy: tuple[float, ...]
    cxx: tuple[float, ...]
    cxy: tuple[float, ...]
    cyx: tuple[float, ...]
    cyy: tuple[float, ...]
    interpolation: str = "linear"
    mxx: tuple[float, ...] = ()
    mxy: tuple[float, ...] = ()
    myx: tuple[float, ...] = ()
    myy: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for key in MASSES:  # not given: zero at every speed
            if isinstance(getattr(self, key), (tuple, list)) and len(getattr(self, key)) == 0:
                rows = len(self.rpm) if isinstance(self.rpm, (tuple, list, np.ndarray)) else 0
                object.__setattr__(self, key, (0.0,) * rows)
        for key in ("rpm",) + COLUMNS:
            values = getattr(self, key)
            if isinstance(values, (str, bytes, Mapping)) or not isinstance(values, (Sequence, np.ndarray)):
                raise ValueError(f"{key}: must be a list of numbers, got {values!r}")
            if any(isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v)
                   for v in values):
                raise ValueError(f"{key}: must be a list of finite numbers, got {list(values)!r}")
            object.__setattr__(self, key, tuple(float(v) for v in values))
        n = len(self.rpm)
        if n == 0:
            raise ValueError("rpm: the table needs at least one speed")
        if self.rpm[0] < 0 or any(b <= a for a, b in zip(self.rpm, self.rpm[1:])):
            raise ValueError(f"rpm: speeds must be >= 0 and strictly increasing, got {list(self.rpm)}")
        for key in COLUMNS:
            if len(getattr(self, key)) != n:
                raise ValueError(f"{key}: has {len(getattr(self, key))} values, rpm has {n}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation: must be one of {', '.join(INTERPOLATIONS)}, got {self.interpolation!r}")

    @classmethod
    def from_mapping(cls, spec: Mapping) -> "BearingTable":
        """A table from its config form: ``rpm`` and any of the eight coefficients (lists as long as ``rpm``);
        as ROSS's BearingElement, kyy defaults to kxx and cyy to cxx, the others to 0; kxx is required.
        ``interpolation`` optional (default linear)."""
        if not isinstance(spec, Mapping):
            raise ValueError(f"must be a mapping (rpm, kxx, ...), got {spec!r}")
        stray = sorted(set(map(str, spec)) - {"rpm", "interpolation", *COLUMNS})
        if stray:
            raise ValueError(f"unknown key(s) {stray} (allowed: rpm, {', '.join(COLUMNS)}, interpolation)")
        missing = [k for k in ("rpm", "kxx") if k not in spec]
        if missing:
            raise ValueError(f"missing key(s) {missing}")
        rpm = spec["rpm"]
        n = len(rpm) if isinstance(rpm, Sequence) and not isinstance(rpm, (str, bytes)) else 0
        default = {"kyy": spec["kxx"], "cyy": spec.get("cxx", [0.0] * n), "myy": spec.get("mxx", [0.0] * n)}
        columns = {k: spec.get(k, default.get(k, [0.0] * n)) for k in COLUMNS}
        return cls(rpm, **columns, interpolation=str(spec.get("interpolation", "linear")))

    @property
    def has_mass(self) -> bool:
        """Whether any mass coefficient is nonzero."""
        return any(any(getattr(self, k)) for k in MASSES)

    def to_mapping(self) -> dict:
        """The config form (all eight columns, the four mass columns when one is nonzero; ``interpolation`` only
        when not linear)."""
        out = {"rpm": list(self.rpm)} | {k: list(getattr(self, k)) for k in COEFFICIENTS}
        out |= {k: list(getattr(self, k)) for k in MASSES} if self.has_mass else {}
        return out | ({"interpolation": self.interpolation} if self.interpolation != "linear" else {})

    @classmethod
    def constant(cls, kxx: float, kxy: float, kyx: float, kyy: float, cxx: float, cxy: float, cyx: float,
                 cyy: float, mxx: float = 0.0, mxy: float = 0.0, myx: float = 0.0, myy: float = 0.0
                 ) -> "BearingTable":
        """The same coefficients at every speed (a table of one row, at 0 RPM)."""
        values = dict(kxx=kxx, kxy=kxy, kyx=kyx, kyy=kyy, cxx=cxx, cxy=cxy, cyx=cyx, cyy=cyy, mxx=mxx, mxy=mxy,
                      myx=myx, myy=myy)
        return cls((0.0,), **{k: (v,) for k, v in values.items()})

    def _interpolants(self, make) -> dict:
        """Each column's interpolant over rad/s: a constant for a single row, else ``make(speeds, values)``."""
        speeds = np.asarray(self.rpm) * (2.0 * np.pi / 60.0)
        out = {}
        for key in COLUMNS:
            values = np.asarray(getattr(self, key))
            out[key] = (lambda omega, v=values[0]: np.full(np.shape(omega), v)) if len(values) == 1 else \
                make(speeds, values)
        return out

    @cached_property
    def _ross(self) -> dict:
        """ROSS 2.3.0's interpolants (``BearingElement._process_coefficient``) of each column over rad/s."""
        from scipy import interpolate  # here: at the top it costs the command line's start ~0.1 s (measured)

        def make(speeds, values):
            try:  # as ROSS: the smoothing spline, and where FITPACK refuses it (2 or 3 rows) the line or parabola
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    return interpolate.UnivariateSpline(speeds, values)
            except Exception:
                return interpolate.interp1d(speeds, values, kind=len(values) - 1, fill_value="extrapolate")
        return self._interpolants(make)

    @cached_property
    def _ross3(self) -> dict:
        """ROSS 3's interpolants (``bearing_seal_element._AxisInterpolator``) of each column over rad/s: PCHIP
        (``pchip``) or piecewise linear (``linear_extrapolated``), both continued linearly beyond the ends."""
        from scipy import interpolate  # here: at the top it costs the command line's start ~0.1 s (measured)

        def make(speeds, values):
            if len(values) == 2 or self.interpolation == "linear_extrapolated":
                return interpolate.interp1d(speeds, values, kind="linear", fill_value="extrapolate")
            return _pchip_extrapolated(speeds, values)
        return self._interpolants(make)

    def at(self, Omega: Array) -> dict[str, Array]:
        """Each coefficient at the speeds ``Omega`` [rad/s] (any shape), by ``interpolation``."""
        Omega = np.asarray(Omega, dtype=float)
        if self.interpolation != "linear":
            rule = self._ross if self.interpolation == "ross" else self._ross3
            return {k: np.asarray(f(Omega), dtype=float).reshape(Omega.shape) for k, f in rule.items()}
        rpm = Omega * (60.0 / (2.0 * np.pi))
        return {k: np.interp(rpm, self.rpm, getattr(self, k)) for k in COLUMNS}  # constant beyond the ends

    def matrices(self, Omega: Array) -> tuple[Array, Array]:
        """K and C over (x, y) at the speeds ``Omega`` [rad/s] (S,): two (S, 2, 2) arrays."""
        values = self.at(np.atleast_1d(Omega))
        K = np.zeros(np.shape(values["kxx"]) + (2, 2))
        C = np.zeros_like(K)
        for suffix, (i, j) in _PLACE.items():
            K[..., i, j] = values[f"k{suffix}"]
            C[..., i, j] = values[f"c{suffix}"]
        return K, C

    def mass_matrix(self, Omega: Array) -> Array:
        """The mass coefficients over (x, y) at the speeds ``Omega`` [rad/s] (S,): (S, 2, 2),
        [[mxx, mxy], [myx, myy]]."""
        values = self.at(np.atleast_1d(Omega))
        M = np.zeros(np.shape(values["mxx"]) + (2, 2))
        for suffix, (i, j) in _PLACE.items():
            M[..., i, j] = values[f"m{suffix}"]
        return M

    def describe(self) -> str:
        """One line: the speed range, kxx, kyy and cxx at its ends (a one-row table: its constant values)."""
        if len(self.rpm) == 1:
            return ("constant coefficients: " + ", ".join(f"{k} {getattr(self, k)[0]:g}" for k in COEFFICIENTS)
                    + " (N/m, N s/m)")
        lo, hi = self.rpm[0], self.rpm[-1]
        return (f"table of {len(self.rpm)} speeds {lo:g}..{hi:g} RPM ({self.interpolation}): kxx {self.kxx[0]:g}.."
                f"{self.kxx[-1]:g}, kyy {self.kyy[0]:g}..{self.kyy[-1]:g} N/m, cxx {self.cxx[0]:g}..{self.cxx[-1]:g} "
                "N s/m" + (f", mxx {self.mxx[0]:g}..{self.mxx[-1]:g} kg" if self.has_mass else ""))


@dataclass(eq=False)
class TableBearing(Effect):
    """The effect ``bearing_table@<bearing>``: the table's K(Omega) and C(Omega) at the bearing's node (u, v).

    K(0) is in the stiffness at rest (``stiffness``), K(Omega) - K(0) in ``speed_stiffness``, C(Omega) in
    ``damping``; the mass coefficients, when the table has them, M(0) in ``mass`` and M(Omega) - M(0) in
    ``speed_mass``; ``ctx.Omega`` per scenario. No parameters."""

    name: str = "bearing_table"
    bearing: str = ""
    node: int = 0
    table: BearingTable | None = None
    meaning: str = field(init=False)
    parameters: tuple[Parameter, ...] = ()
    _last: tuple[bytes, tuple[Array, Array]] | None = field(default=None, init=False, repr=False)
    _dofs: tuple[object, Array] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.table is None:
            raise ValueError(f"effect {self.name!r}: needs a BearingTable")
        self.meaning = (f"bearing {self.bearing or self.node} at node {self.node}: stiffness and damping "
                        f"(kxx..cyy) against speed from its {self.table.describe()}")

    def _block(self, ctx: Context, block: Array) -> LocalMatrix:
        """The block over (x, y) (broadcastable to (S, 2, 2)) at the node's (u, v) (their indices looked up once
        per shaft: a machine's lookup walks its segments)."""
        if self._dofs is None or self._dofs[0] is not ctx.shaft:
            self._dofs = (ctx.shaft, np.array([ctx.dof(f"u{self.node}"), ctx.dof(f"v{self.node}")]))
        return LocalMatrix(self._dofs[1], block)

    @cached_property
    def _at_rest(self) -> tuple[Array, Array | None]:
        """K(0) and M(0) (1, 2, 2) (M None without mass coefficients): every scenario's, interpolated once."""
        zero = np.zeros(1)
        return self.table.matrices(zero)[0], self.table.mass_matrix(zero) if self.table.has_mass else None

    def _at_speed(self, Omega: Array) -> tuple[Array, Array]:
        """K(Omega) and C(Omega) (S, 2, 2); the stiffness and damping hooks of one assembly ask for the same speeds:
        interpolated once for both."""
        key = np.asarray(Omega, float).tobytes()
        if self._last is None or self._last[0] != key:
            self._last = (key, self.table.matrices(Omega))
        return self._last[1]

    def stiffness(self, ctx: Context) -> LocalMatrix:
        return self._block(ctx, self._at_rest[0])

    def speed_stiffness(self, ctx: Context) -> LocalMatrix:
        return self._block(ctx, self._at_speed(ctx.Omega)[0] - self._at_rest[0])

    def damping(self, ctx: Context) -> LocalMatrix:
        return self._block(ctx, self._at_speed(ctx.Omega)[1])

    def mass(self, ctx: Context) -> LocalMatrix | None:
        if not self.table.has_mass:
            return None
        return self._block(ctx, self._at_rest[1])

    def speed_mass(self, ctx: Context) -> LocalMatrix | None:
        if not self.table.has_mass:
            return None
        return self._block(ctx, self.table.mass_matrix(ctx.Omega) - self._at_rest[1])


def _pchip_extrapolated(speeds: Array, values: Array):
    """PCHIP through the rows, beyond the ends the line with the end slope (ROSS 3's ``_AxisInterpolator``)."""
    from scipy import interpolate  # here: at the top it costs the command line's start ~0.1 s (measured)

    pchip = interpolate.PchipInterpolator(speeds, values, extrapolate=True)
    slope = pchip.derivative()
    lo, hi = speeds[0], speeds[-1]
    end_slopes = (float(slope(lo)), float(slope(hi)))

    def evaluate(omega):
        omega = np.asarray(omega, dtype=float)
        clipped = np.clip(omega, lo, hi)
        return pchip(clipped) + (omega - clipped) * np.where(omega < lo, end_slopes[0], end_slopes[1])

    return evaluate
