"""Loads a soft-tissue scene cannot have, refused before the solve with the unit slip named:
a stiffness in kPa where Pa belong (the body's weight alone would strain it a hundredfold: the
solve ended in NaN and "reduce [time] dt" in a quasi-static run), a CSF level in mm where
metres belong (85 "m" above a brain: 830 kPa of water pressure)."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from ..errors import InputError
from ..meshing.extent import body_diagonal
from ..scene import Scene

# the body's own weight over its stiffness, rho g H / E, above which a scene is a unit slip: soft
# tissue under gravity is 0.01-1 (the 5 mm brain 0.24, the gelatin cube 0.08); tests of the
# validity check use up to 33
WEIGHT_STRAIN = 50.0
# m: a level farther than this above or below the body is a unit slip (a skull's CSF is
# centimetres deep, a phantom's tank decimetres; a brain's 85 mm level in mm is 85 m)
LEVEL_REACH = 2.0


def heights(mesh, up: np.ndarray) -> tuple[float, float]:
    """The lowest and highest node of the body along ``up`` (m), on every rank."""
    h = mesh.geometry.x @ up
    comm = mesh.comm
    return (
        comm.allreduce(float(h.min(initial=np.inf)), op=MPI.MIN),
        comm.allreduce(float(h.max(initial=-np.inf)), op=MPI.MAX),
    )


def check_loads(scene: Scene, mesh) -> None:
    g = np.asarray(scene.gravity.vector, dtype=float)
    size = float(np.linalg.norm(g))
    if size == 0.0:
        return
    up = -g / size
    low, high = heights(mesh, up)
    mat = scene.material
    strain = mat.density * size * (high - low) / mat.E
    if strain > WEIGHT_STRAIN:
        raise InputError(
            f"[material] E = {mat.E:.4g} Pa (G = {mat.G:.4g} Pa): the body's weight alone would strain it "
            f"about {strain:.3g} (rho g H / E; soft tissue under gravity: 0.01-1): is it in kPa? moduli "
            f"are Pa (the brain: G = 2370)"
        )
    fluid = scene.fluid
    if fluid is None or fluid.level is None:
        return
    body = body_diagonal(mesh)
    for t, level in fluid.level.points:
        if level > high + LEVEL_REACH or level < low - LEVEL_REACH:
            where = (
                f"{level - high:.3g} m above the body's top"
                if level > high
                else f"{low - level:.3g} m below its bottom"
            )
            raise InputError(
                f"[fluid] level = {level:g} at t = {t:g} s is {where} (the body is {body:.3g} m across, "
                f"{low:.3g} to {high:.3g} m along up): levels are metres along up; is it in mm?"
            )
