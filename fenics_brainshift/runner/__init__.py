"""The runner: from a scene to the model (build.py), the plan (plan.py), the Simulation a user can
drive (simulation.py), the one loop (loop.py) and what a run returns and writes (summary.py, driver.py)."""

from .build import build_model
from .driver import Result, run
from .plan import Plan, make_plan
from .simulation import Simulation

__all__ = ["Plan", "Result", "Simulation", "build_model", "make_plan", "run"]
