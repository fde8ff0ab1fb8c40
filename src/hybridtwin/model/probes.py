"""Probes at any angle: the two probe readings of a plane to the plane's x and y, and back
(docs/measurement-format.md, "Probe angles").

A probe's mounting angle a (``machine_parts.Sensor.angle_deg``) is measured in the rotor's cross-section from the
model's +x towards +y, the direction of rotation (the shaft turns from +x towards +y); the probe reads the
displacement's component along its axis, p = x cos a + y sin a. Two probes of one plane, at a1 and a2, read

    [p1, p2] = R [x, y],   R = [[cos a1, sin a1], [cos a2, sin a2]],

so [x, y] = R^-1 [p1, p2] (``plane_xy``) when the two axes are not collinear: |sin(a2 - a1)| >= sin(10 deg)
(``MIN_SEPARATION_DEG``; nearer, R^-1 multiplies the noise by more than 1 / sin(10 deg) = 5.8). The defaults,
0 deg for a probe of direction x and 90 deg for direction y, make R the identity: x = p1, y = p2, returned as
given (bit for bit). The relation is linear and real, so it holds alike for samples, for harmonics (complex,
each part) and for order vectors.

Noise: probes with independent noise sigma1, sigma2 give x, y with the covariance R^-1 diag(sigma1^2,
sigma2^2) R^-T: ``plane_xy`` returns sigma_x, sigma_y and their correlation rho (zero only when the probes
are orthogonal and, for unequal sigmas, aligned with x and y).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Array = np.ndarray

#: the two probes of a plane must stand at least this far from collinear: |sin(a2 - a1)| >= sin(10 deg)
MIN_SEPARATION_DEG = 10.0
#: the default angle of a probe of each direction [deg]
DEFAULT_ANGLE_DEG = {"x": 0.0, "y": 90.0}


class ProbeAngleError(ValueError):
    """Two probes of a plane whose angles cannot give the plane's x and y (collinear, or not finite)."""


def cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """(cos a, sin a) of an angle in degrees, exact (0, +-1) at multiples of 90 deg (np.cos(pi / 2) is 6e-17)."""
    a = float(angle_deg)
    if a % 90.0 == 0.0:
        quarter = int(a // 90.0) % 4
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[quarter]
    r = np.deg2rad(a)
    return float(np.cos(r)), float(np.sin(r))


def check_pair(angle1_deg: float, angle2_deg: float, names: tuple[str, str] = ("p1", "p2")) -> None:
    """Raise ``ProbeAngleError`` when two probes of a plane cannot give its x and y: an angle not finite, or the
    axes within MIN_SEPARATION_DEG of collinear (|sin(a2 - a1)| < sin(10 deg)). ``names``: the probes', for the
    message."""
    a1, a2 = float(angle1_deg), float(angle2_deg)
    if not (np.isfinite(a1) and np.isfinite(a2)):
        raise ProbeAngleError(f"probes {names[0]}, {names[1]}: angles {a1:g} and {a2:g} deg must be finite")
    c1, s1 = cos_sin_deg(a1)
    c2, s2 = cos_sin_deg(a2)
    separation = abs(c1 * s2 - s1 * c2)  # |sin(a2 - a1)|, the determinant of R
    if separation < np.sin(np.deg2rad(MIN_SEPARATION_DEG)):
        raise ProbeAngleError(
            f"probes {names[0]} at {a1:g} deg and {names[1]} at {a2:g} deg are (nearly) collinear: |sin(a2 - a1)| = "
            f"{separation:.3g} < sin({MIN_SEPARATION_DEG:g} deg); two probes of a plane must stand at least "
            f"{MIN_SEPARATION_DEG:g} deg from collinear (usually 90 deg apart) to give its x and y")


def rotation(angle1_deg: float, angle2_deg: float) -> Array:
    """R = [[cos a1, sin a1], [cos a2, sin a2]]: the probe readings [p1, p2] = R [x, y]."""
    return np.array([cos_sin_deg(angle1_deg), cos_sin_deg(angle2_deg)])


def is_default(angle1_deg: float, angle2_deg: float) -> bool:
    """Whether the two probes stand at the default 0 and 90 deg (R the identity)."""
    return float(angle1_deg) % 360.0 == 0.0 and float(angle2_deg) % 360.0 == 90.0


@dataclass(frozen=True)
class PlaneXY:
    """A plane's x and y from its two probes (``plane_xy``): x, y like the readings (samples, harmonics, ...);
    sigma_x, sigma_y: their 1-sigma noise (None when no probe sigmas were given); correlation: the correlation
    coefficient of the x and y noise it implies (0 for orthogonal probes of equal noise)."""

    x: Array
    y: Array
    sigma_x: Array | None
    sigma_y: Array | None
    correlation: Array | None


def plane_xy(p1, p2, angle1_deg: float, angle2_deg: float, sigma1=None, sigma2=None,
             names: tuple[str, str] = ("p1", "p2")) -> PlaneXY:
    """The plane's x and y from its probe readings: [x, y] = R^-1 [p1, p2] (module docstring).

    p1, p2: the two probes' readings, arrays of one shape (real samples or complex harmonics); angle1_deg,
    angle2_deg: their mounting angles (from +x towards +y); sigma1, sigma2: optional 1-sigma noise of each
    probe (scalars or arrays broadcasting with p1; for complex values, of each part), independent between the
    probes. Returns ``PlaneXY``: x, y, and with the sigmas the propagated sigma_x, sigma_y and the correlation
    rho = cov(x, y) / (sigma_x sigma_y) (zero where both sigmas are zero). At the default angles (0, 90) x and
    y are p1 and p2 themselves and the sigmas are passed through (correlation 0). Raises ``ProbeAngleError``
    for collinear probes (``check_pair``).
    """
    check_pair(angle1_deg, angle2_deg, names)
    p1, p2 = np.asarray(p1), np.asarray(p2)
    if p1.shape != p2.shape:
        raise ValueError(f"probes {names[0]}, {names[1]}: readings of shapes {p1.shape} and {p2.shape} differ")
    with_sigma = sigma1 is not None or sigma2 is not None
    if with_sigma and (sigma1 is None or sigma2 is None):
        raise ValueError(f"probes {names[0]}, {names[1]}: give both probes' sigmas or neither")
    if is_default(angle1_deg, angle2_deg):  # R = I: the readings themselves, bit for bit
        if not with_sigma:
            return PlaneXY(p1, p2, None, None, None)
        s1, s2 = np.asarray(sigma1, float), np.asarray(sigma2, float)
        return PlaneXY(p1, p2, s1, s2, np.zeros(np.broadcast(s1, s2).shape))
    inverse = np.linalg.inv(rotation(angle1_deg, angle2_deg))
    x = inverse[0, 0] * p1 + inverse[0, 1] * p2
    y = inverse[1, 0] * p1 + inverse[1, 1] * p2
    if not with_sigma:
        return PlaneXY(x, y, None, None, None)
    v1, v2 = np.asarray(sigma1, float) ** 2, np.asarray(sigma2, float) ** 2
    var_x = inverse[0, 0] ** 2 * v1 + inverse[0, 1] ** 2 * v2
    var_y = inverse[1, 0] ** 2 * v1 + inverse[1, 1] ** 2 * v2
    cov = inverse[0, 0] * inverse[1, 0] * v1 + inverse[0, 1] * inverse[1, 1] * v2
    scale = np.sqrt(var_x * var_y)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(scale > 0, cov / np.where(scale > 0, scale, 1.0), 0.0)
    return PlaneXY(x, y, np.sqrt(var_x), np.sqrt(var_y), rho)


def probe_readings(x, y, angle1_deg: float, angle2_deg: float) -> tuple[Array, Array]:
    """(p1, p2) = R [x, y]: what two probes at these angles read of the plane's x and y (the model's response
    projected onto the probes; at the default angles x and y themselves)."""
    x, y = np.asarray(x), np.asarray(y)
    if is_default(angle1_deg, angle2_deg):
        return x, y
    (c1, s1), (c2, s2) = cos_sin_deg(angle1_deg), cos_sin_deg(angle2_deg)
    return c1 * x + s1 * y, c2 * x + s2 * y
