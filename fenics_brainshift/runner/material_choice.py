"""[material] model = "auto": the linear model unless it is not valid for the scene.

A linear trial run (one factor, then a solve per step or settled state: a fraction of a
hyperelastic run) measures the largest principal strain; past the limit (outputs/validity.py),
or when the linear run finds no equilibrium, the scene is solved with the neo-Hookean model
instead. The choice and its reason go into the plan.
"""

from __future__ import annotations

import copy

from ..logs import get_logger
from ..outputs.validity import NONLINEAR_MODEL, STRAIN_LIMIT, in_doubt
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
    report = history.strain
    found = (
        f"a linear trial run's largest strain is {abs(report.strain):.1%} ({report.near}), "
        f"{report.volume_past_limit:.1%} of the volume past {STRAIN_LIMIT:.0%}"
    )
    if stopped is None and not in_doubt(report):
        return linear, f"linear: {found}"
    nonlinear = copy.deepcopy(scene)
    nonlinear.material.model = NONLINEAR_MODEL
    if stopped is not None:
        why = f"the linear trial run stopped ({stopped})"
    elif report.inverted:
        why = f"{found}; {report.inverted} cells inside out"
    else:
        why = found
    return nonlinear, f"{NONLINEAR_MODEL}: {why}"
