"""[material] model = "auto": the linear model unless it is not valid for the scene.

A linear trial run (one factor, then a solve per step or settled state: a fraction of a
hyperelastic run) measures the largest principal strain; past the limit (outputs/validity.py),
or when the linear run finds no equilibrium, the scene is solved with the neo-Hookean model
instead. The choice and its reason go into the plan.
"""
from __future__ import annotations

import copy

from ..logs import get_logger
from ..outputs.validity import NONLINEAR_MODEL, STRAIN_LIMIT
from ..scene import Scene
from .loop import march
from .simulation import Simulation

log = get_logger("run")


def resolve_material(scene: Scene, comm) -> tuple[Scene, str]:
    """(the scene with a concrete material model, why) for model = "auto"; others unchanged."""
    if scene.material.model != "auto":
        return scene, ""
    linear = copy.deepcopy(scene)
    linear.material.model = "linear"
    trial = Simulation(linear, comm)
    trial.setup()
    history, stopped = march(trial)
    trial.destroy()
    strain = history.largest_strain
    if stopped is None and strain <= STRAIN_LIMIT and not history.inverted_cells:
        return linear, f"linear: a linear trial run's largest strain is {strain:.1%}, within {STRAIN_LIMIT:.0%}"
    nonlinear = copy.deepcopy(scene)
    nonlinear.material.model = NONLINEAR_MODEL
    why = (f"the linear trial run stopped ({stopped})" if stopped is not None
           else f"a linear trial run's largest strain is {strain:.1%}, past {STRAIN_LIMIT:.0%}")
    return nonlinear, f"{NONLINEAR_MODEL}: {why}"
