"""Synthetic intra-operative measurements: a "true" scene's shift sampled at points of the
exposed cortex, with noise (demos/fit.py, benchmarks/fit.py)."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from ..outputs.points import PointEvaluator
from ..physics.surface import gathered_outward_surface
from ..scene import load_scene
from .parameters import rotated_gravity


def true_scene(overrides: list[str], truth: dict[str, float]):
    """The bundled brain (settled states) with the true values in the scene itself."""
    g = rotated_gravity(load_scene("brain", overrides).gravity.vector, truth)
    sets = ["time.mode=quasi-static", f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]"]
    sets += [f"{name}={value}" for name, value in truth.items() if not name.startswith("gravity.")]
    return load_scene("brain", overrides + sets)


def measurements(
    overrides: list[str], truth: dict[str, float], count: int, noise: float, seed: int, comm=MPI.COMM_WORLD
) -> tuple[np.ndarray, np.ndarray]:
    """(pre, intra) (count, 3) m: surface points of the exposed (anterior, y > 30 mm) cortex
    before the true shift, and after it with Gaussian noise (m per axis)."""
    from ..runner import Simulation

    scene = true_scene(overrides, truth)
    sim = Simulation(scene, comm)
    sim.setup()
    sim.solve_to_settled(scene.settled_time)
    surface, _ = gathered_outward_surface(sim.model.fluid.hydro.facets, comm)
    surface = np.unique(surface, axis=0)
    exposed = surface[surface[:, 1] > 0.03]
    rng = np.random.default_rng(seed)
    pre = exposed[rng.choice(len(exposed), count, replace=False)]
    intra = pre + PointEvaluator(sim.model.mesh, pre).values(sim.u) + rng.normal(scale=noise, size=pre.shape)
    sim.destroy()
    return pre, intra
