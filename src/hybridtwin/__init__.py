"""hybridtwin: hybrid twins of rotating machines (VARM reference model, HMH solver, ...)."""

from .effect_base import Context, Effect, Parameter, Params, PolynomialBearing, Term
from .model import LocalForce, Model, System, rpm_to_rad_s
from .shaft import Shaft
from .continuation import Sweep, solve_sweep
from .solver import SteadyState, solve

__all__ = [
    "Context", "Effect", "LocalForce", "Model", "Parameter", "Params", "PolynomialBearing", "Shaft",
    "SteadyState", "Sweep", "System", "Term", "rpm_to_rad_s", "solve", "solve_sweep",
]
