"""hybridtwin: hybrid twins of rotating machines (docs/method.md).

The package reads like the method, a subpackage per stage, each importing only from the stages before it:
``model`` (shaft, machine, effects, variants, sensors) -> ``solvers`` (harmonic balance, continuation, stability,
time integration) -> ``offline`` (scenarios, snapshots, POD, sPGD libraries) -> ``data`` (records, checks, order
analysis) -> ``rig`` (the virtual rig) -> ``identify`` -> ``diagnose`` -> ``report``; ``config`` (the workflow's
settings) and ``cli`` (the ``hybridtwin`` command) on top. The names a user's script needs are importable from here."""

from .model.effect_base import Context, Effect, Parameter, Params, PolynomialBearing, Term
from .model.effects import builtin_effects
from .model.machine import Machine
from .model.model import LocalForce, Model, System, rpm_to_rad_s
from .model.shaft import Shaft
from .model.variants import Variant, builtin_variant
from .solvers.continuation import Sweep, solve_sweep
from .solvers.solver import SteadyState, solve, solve_variant

__all__ = [
    "Context", "Effect", "LocalForce", "Machine", "Model", "Parameter", "Params", "PolynomialBearing", "Shaft",
    "SteadyState", "Sweep", "System", "Term", "Variant", "builtin_effects", "builtin_variant", "rpm_to_rad_s",
    "solve", "solve_sweep", "solve_variant",
]
