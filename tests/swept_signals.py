"""Closed-form swept records for the order-tracking tests and benchmarks: a known, non-linear speed profile
theta(t), order vectors that vary with speed (a damped resonance, a constant runout), white noise, keyphasor
marks on the sample grid."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

TWO_PI = 2 * np.pi


@dataclass
class Sweep:
    """rpm(t) = r0 + (r1 - r0) t / T + bow sin(pi t / T): monotone for |bow| < |r1 - r0| / pi."""

    r0: float = 300.0
    r1: float = 1000.0
    duration_s: float = 60.0
    bow: float = 60.0

    def rpm(self, t):
        return self.r0 + (self.r1 - self.r0) * t / self.duration_s + self.bow * np.sin(np.pi * t / self.duration_s)

    def theta(self, t):
        """The shaft angle [rad], the closed-form integral of rpm(t) * 2 pi / 60 from t = 0."""
        T = self.duration_s
        turns = (self.r0 * t + (self.r1 - self.r0) * t**2 / (2 * T)
                 + self.bow * T / np.pi * (1 - np.cos(np.pi * t / T))) / 60.0
        return TWO_PI * turns

    def time_of_turn(self, k):
        """The instants where theta = 2 pi k (bisection: theta is monotone)."""
        k = np.asarray(k, float)
        lo, hi = np.zeros_like(k), np.full_like(k, self.duration_s)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = self.theta(mid) < TWO_PI * k
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return 0.5 * (lo + hi)


@dataclass
class Response:
    """Order vectors of a channel pair x, y as functions of speed: 1X a damped resonance (forward whirl, y = -i x)
    plus a runout, 2X a constant runout (x and y each their own), h >= 3 zero."""

    amplitude_m: float = 20e-6   # the 1X's static-deflection scale A: U1 = A r^2 / (1 - r^2 + 2 i zeta r)
    critical_rpm: float = 650.0
    zeta: float = 0.08
    runout_1x_m: tuple = (3e-6 + 2e-6j, -1e-6 + 2.5e-6j)  # x, y
    runout_2x_m: tuple = (1.5e-6 - 1e-6j, 0.5e-6 + 1e-6j)
    offset_m: tuple = (40e-6, -25e-6)
    drift_m_per_s: tuple = (0.2e-6, -0.1e-6)

    def dynamic_1x(self, rpm):
        r = np.asarray(rpm, float) / self.critical_rpm
        x = self.amplitude_m * r**2 / (1 - r**2 + 2j * self.zeta * r)
        return x, -1j * x

    def vector(self, rpm, h):
        """(U_x, U_y) of harmonic h at these speeds (complex, 0-peak)."""
        rpm = np.asarray(rpm, float)
        if h == 1:
            dx, dy = self.dynamic_1x(rpm)
            return dx + self.runout_1x_m[0], dy + self.runout_1x_m[1]
        if h == 2:
            return np.full(rpm.shape, self.runout_2x_m[0]), np.full(rpm.shape, self.runout_2x_m[1])
        return np.zeros(rpm.shape, complex), np.zeros(rpm.shape, complex)


@dataclass
class SweptRecord:
    """What the order tracker reads (the attributes of records.Record it uses) and the truth."""

    path: Path
    time_s: np.ndarray
    channels: dict
    keyphasor: np.ndarray | None
    sweep: Sweep
    response: Response
    noise_m: float
    extra: dict = field(default_factory=dict)

    def line(self, index):
        return np.asarray(index) + 2


def swept_record(sweep: Sweep | None = None, response: Response | None = None, fs: float = 5000.0,
                 noise_m: float = 5e-6, seed: int = 0, harmonics: int = 2, shift: float | None = None,
                 path: str = "swept.csv") -> SweptRecord:
    """Samples at t0 + n / fs (t0 a random fraction of a step unless ``shift``), x and y from ``response`` along
    ``sweep`` plus offset, drift and white noise; the keyphasor True on the sample nearest each whole turn (the
    sample where the mark passes, docs/measurement-format.md)."""
    sweep, response = sweep or Sweep(), response or Response()
    rng = np.random.default_rng(seed)
    t0 = (rng.uniform(0, 1) if shift is None else shift) / fs
    t = t0 + np.arange(int(sweep.duration_s * fs - 1)) / fs
    theta, rpm = sweep.theta(t), sweep.rpm(t)
    out = []
    for i in range(2):
        u = response.offset_m[i] + response.drift_m_per_s[i] * t
        for h in range(1, harmonics + 1):
            u = u + (response.vector(rpm, h)[i] * np.exp(1j * h * theta)).real
        out.append(u + noise_m * rng.standard_normal(t.size))
    turns = np.floor(theta / TWO_PI)
    keyphasor = np.zeros(t.size, bool)
    after = np.flatnonzero(turns[1:] > turns[:-1]) + 1  # first sample at or after each whole turn
    turn_time = sweep.time_of_turn(turns[after])
    nearest = np.where(t[after] - turn_time > 0.5 / fs, after - 1, after)  # the sample nearer the turn
    keyphasor[nearest[nearest > 0]] = True
    return SweptRecord(Path(path), t, {"x": out[0], "y": out[1]}, keyphasor, sweep, response, noise_m)
