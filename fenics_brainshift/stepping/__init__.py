"""Stepping: the state, Newmark / generalized-alpha time steps with the energy guard, the
quasi-static path, and the follower-load settle both share."""

from .dynamic import DynamicStepper
from .energy import EnergyBalance
from .integrators import TimeIntegrator, newmark_discrete_frequency
from .solves import Solves
from .state import State
from .static import StaticSolver

__all__ = [
    "DynamicStepper",
    "EnergyBalance",
    "Solves",
    "State",
    "StaticSolver",
    "TimeIntegrator",
    "newmark_discrete_frequency",
]
