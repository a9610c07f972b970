"""Synthetic intra-operative measurements: a "true" scene's shift sampled at points of the
exposed cortex, with noise (demos/fit.py, benchmarks/fit.py); a true operation after a
resection (demos/update.py --resection, benchmarks/update_resection.py)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

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


@dataclass
class Resected:
    """A true operation after a resection, at the mesh's vertices (GlobalVertices' order):
    the displacement (m), the cells left and the cells removed."""

    points: np.ndarray
    displacement: np.ndarray
    present: np.ndarray  # (C1, 4) tetrahedra
    removed: np.ndarray  # (C2, 4)

    @property
    def wall(self) -> np.ndarray:
        """The vertices between the tissue left and the cavity."""
        return np.intersect1d(np.unique(self.removed), np.unique(self.present))

    @property
    def removed_ml(self) -> float:
        corners = self.points[self.removed]
        return float(np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])).sum() / 6.0 * 1e6)


def resected_truth(overrides: list[str], truth: dict[str, float], where: str, comm=MPI.COMM_WORLD) -> Resected:
    """The bundled brain's settled state with the true values and the cells whose centroid
    satisfies ``where`` removed (pieces cut free go with them), solved on its own; on rank 0."""
    from ..outputs.vertices import GlobalVertices
    from ..runner import Simulation
    from ..scene.body import Removal

    scene = dataclasses.replace(true_scene(overrides, truth), remove=(Removal(where=where),))
    sim = Simulation(scene, comm)
    sim.setup()
    sim.solve_to_settled(scene.settled_time)
    vertices = GlobalVertices(sim.model.mesh)
    u = vertices.values(sim.u)
    present = vertices.cell_values(sim.model.tissue.indicator)
    sim.destroy()
    if comm.rank != 0:
        return None
    return Resected(vertices.points, u, vertices.tetrahedra[present > 0.5], vertices.tetrahedra[present <= 0.5])
