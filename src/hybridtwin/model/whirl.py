"""The 1X whirl a machine's own linear model predicts: forward or backward, plane by plane (docs/data-checks.md,
"Backward whirl").

An unbalance response whirls forward (from +x towards +y, the sense of rotation) away from the critical speeds.
On supports stiffer along one axis than along the other (kxx != kyy: most horizontal machines on fluid-film
bearings) each critical speed splits in two, and between the two the unbalance response of a plane can whirl
backward: physics, not a wiring error. Whether it does depends on the machine, so the data check asks its
model.

``WhirlModel`` holds the variants a project declares (each a model of the machine with unknowns in ranges) and
answers, for a run's speed, which probe planes the models can make whirl backward. The response is that of the
linear part of eq. 29 at 1X,

    (K(Omega) + i Omega C(Omega) - Omega^2 M) X = F_1                  (eq. 29, the harmonic h = 1)

(K with its speed terms, C with the gyroscopic one, F_1 the variant's 1X forcing with an eccentric mass of
``m_e`` when its nominal one is 0; nonlinear bearing forces left out), read by the plane's two probes at their
angles (``probes.probe_readings``). A plane whirls backward where |p_x - i p_y| > |p_x + i p_y| (the backward
and forward circular components of the probes' 1X, x(t) = Re(X exp(i Omega t))). "Can": at the variant's
values (nominal and fixed), and at ``samples`` points drawn uniformly in its unknowns' ranges (seeded: the
answer never changes between calls), each at ``speeds`` speeds within +-``speed_margin`` of the run's: a model
whose unknowns are still to be fitted may put its split critical speeds anywhere in its ranges, and the check
must not reject a run that some model of the variant explains.

Computed once: the workflow's data check writes every answer it got (``whirl_table``, results/data/whirl.tsv) and
each run's preprocessing reads them (``RecordedWhirl``) instead of asking the model again.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from ..tables import WHIRL

from .probes import probe_readings
from .variants import Variant

Array = np.ndarray

#: the eccentric mass [kg] of a variant whose nominal m_e is 0 (the whirl's sense does not depend on its size:
#: the response is linear in the force, only the mass's own 10 g point mass changes M, negligibly)
DEFAULT_M_E = 0.01


@dataclass(frozen=True)
class PlaneWhirl:
    """The 1X whirl of one probe plane over a variant's models: its probes' names, and the forward and
    backward circular amplitudes [m] of each model (scenario) and speed, shape (S, n_speeds)."""

    probes: tuple[str, str]
    forward: Array
    backward: Array

    @property
    def backward_possible(self) -> bool:
        """Whether some model (and speed) whirls backward at this plane."""
        return bool(np.any(self.backward > self.forward))


@dataclass(frozen=True)
class WhirlModel:
    """The variants whose linear 1X response says where backward whirl is physics (module docstring)."""

    variants: Sequence[Variant]
    samples: int = 64
    speeds: int = 7
    speed_margin: float = 0.03
    seed: int = 0
    m_e: float = DEFAULT_M_E
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "variants", tuple(self.variants))
        if not self.variants:
            raise ValueError("WhirlModel: no variant to compute the whirl with")
        if not (self.samples >= 0 and self.speeds >= 1 and 0 <= self.speed_margin < 1):
            raise ValueError(f"WhirlModel: need samples >= 0, speeds >= 1, 0 <= speed_margin < 1, got "
                             f"{self.samples}, {self.speeds}, {self.speed_margin}")

    def planes(self, rpm: float) -> list[PlaneWhirl]:
        """Every variant's planes at ``rpm`` (a plane per x, y probe pair of its machine)."""
        key = round(float(rpm), 6)
        if key not in self._cache:
            with threadpool_limits(1):  # many small matrices: one thread each (threads contend, 15 times slower)
                self._cache[key] = [plane for variant in self.variants for plane in variant_whirl(
                    variant, rpm, self.samples, self.speeds, self.speed_margin, self.seed, self.m_e)]
        return self._cache[key]

    def backward_probes(self, rpm: float) -> set[tuple[str, str]]:
        """The (x probe, y probe) names of the planes some model of some variant makes whirl backward within
        +-speed_margin of ``rpm``."""
        return {plane.probes for plane in self.planes(rpm) if plane.backward_possible}

    def describe(self) -> str:
        """Which models the check asks, in a few words (for its messages)."""
        names = ", ".join(v.name for v in self.variants)
        return (f"the linear 1X response of variant(s) {names} over their unknowns' ranges, within "
                f"+-{100 * self.speed_margin:g} % of the run's speed")


def variant_values(variant: Variant, samples: int, seed: int = 0, m_e: float = DEFAULT_M_E) -> dict[str, Array]:
    """The variant's values (nominal and fixed) then ``samples`` points uniform in its unknowns' ranges, each
    parameter an array of 1 + samples values; an eccentric mass m_e of 0 (no 1X force) set to ``m_e``."""
    base = variant.values()
    if "m_e" in base and not float(base["m_e"]) > 0:
        base["m_e"] = np.asarray(m_e)
    rng = np.random.default_rng(seed)
    out = {k: np.full(1 + samples, float(v)) for k, v in base.items()}
    for name, (lo, hi) in variant.unknown.items():
        out[name][1:] = rng.uniform(lo, hi, samples)
    return out


def variant_whirl(variant: Variant, rpm: float, samples: int = 64, speeds: int = 9, speed_margin: float = 0.03,
                  seed: int = 0, m_e: float = DEFAULT_M_E) -> list[PlaneWhirl]:
    """The forward and backward 1X amplitudes at each x, y probe plane of ``variant``'s machine, for its models
    (``variant_values``) at ``speeds`` speeds within +-``speed_margin`` of ``rpm`` (module docstring)."""
    machine = variant.model.shaft
    sensors = list(getattr(machine, "sensors", ()))
    pairs = list(getattr(machine, "sensor_pairs", ()))
    if not pairs:
        return []
    values = variant_values(variant, samples, seed, m_e)
    S = 1 + samples
    grid = float(rpm) * (1.0 + np.linspace(-speed_margin, speed_margin, speeds))
    rest = variant.model.at_rest(values, S)  # the stages at rest once, then each speed
    X = np.empty((S, speeds, machine.n_dof), complex)
    for j, rpm_j in enumerate(grid):
        system = variant.model.system_at(rest, rpm_j)
        F = system.forcing.get(1)
        if F is None:
            return []
        Omega = system.Omega[:, None, None]
        Z = system.K + 1j * Omega * system.C - Omega**2 * system.M
        with np.errstate(all="ignore"):
            X[:, j] = np.linalg.solve(Z, np.asarray(F, complex)[..., None])[..., 0]
    X = X.reshape(S * speeds, machine.n_dof)
    out = []
    for ix, iy in pairs:
        px, py = sensors[ix], sensors[iy]
        x, y = X[:, machine.dof(f"u{px.node}")], X[:, machine.dof(f"v{px.node}")]
        p1, p2 = probe_readings(x, y, px.angle_deg, py.angle_deg)
        out.append(PlaneWhirl((px.name, py.name), (np.abs(p1 + 1j * p2) / 2).reshape(S, speeds),
                              (np.abs(p1 - 1j * p2) / 2).reshape(S, speeds)))
    return out


# --- computed once: check_data's answers, read by preprocess ------------------------------------------------------

WHIRL_COLUMNS = list(WHIRL.columns)


def whirl_table(model: WhirlModel | None) -> pd.DataFrame:
    """Every answer ``model`` gave (a row per speed asked and plane), for the runs' preprocessing to read instead of
    computing them again (``RecordedWhirl``); no row without a model."""
    rows = [] if model is None else [
        (rpm, plane.probes[0], plane.probes[1], plane.backward_possible, model.describe())
        for rpm, planes in model._cache.items() for plane in planes]
    return pd.DataFrame(rows, columns=WHIRL_COLUMNS)


class RecordedWhirl:
    """The whirl model's answers as the data check recorded them (``whirl_table``): ``backward_probes`` and
    ``describe`` as ``WhirlModel``'s, read, not computed again. A run's preprocessing asks at the run's refined
    speed, the one the check asked at (the same record, the same analysis: the same float); at a speed the check
    did not ask (a record changed since) the model is built and asked (``model``, a callable, called once)."""

    def __init__(self, table: pd.DataFrame, model: Callable[[], WhirlModel | None]):
        self._answers: dict[float, set[tuple[str, str]]] = {}
        for row in table.itertuples():
            probes = self._answers.setdefault(round(float(row.rpm), 6), set())
            if bool(row.backward_possible):
                probes.add((str(row.x_probe), str(row.y_probe)))
        self._description = str(table["model"].iloc[0]) if len(table) else None
        self._factory, self._model = model, None

    def _computed(self) -> WhirlModel | None:
        if self._model is None and self._factory is not None:
            self._model, self._factory = self._factory(), None
        return self._model

    def backward_probes(self, rpm: float) -> set[tuple[str, str]]:
        key = round(float(rpm), 6)
        if key in self._answers:
            return set(self._answers[key])
        model = self._computed()
        return set() if model is None else model.backward_probes(rpm)

    def describe(self) -> str:
        if self._description is not None:
            return self._description
        model = self._computed()
        return "" if model is None else model.describe()


def write_whirl(model: WhirlModel | None, path) -> None:
    """``whirl_table(model)`` at ``path`` (``WHIRL``)."""
    WHIRL.write(whirl_table(model), path)


def read_whirl(path, model: Callable[[], WhirlModel | None]) -> RecordedWhirl:
    """The answers ``write_whirl`` wrote, the model (built on first need) for a speed they lack."""
    return RecordedWhirl(WHIRL.read(path), model)
