"""Named points where the displacement is sampled, in serial and under MPI alike."""
from __future__ import annotations

import numpy as np
from mpi4py import MPI

from . import compat
from .scene import SceneError


class Probes:
    """Each point is evaluated by exactly one rank (the lowest that holds a containing cell)
    and the values are summed over ranks, so every rank sees the same global answer."""

    def __init__(self, mesh, points: dict[str, tuple[float, float, float]]):
        self.names = list(points)
        self.points = np.array([points[n] for n in self.names], dtype=np.float64).reshape(-1, 3)
        comm = mesh.comm
        cells = compat.colliding_cells(mesh, self.points) if self.names else []
        found = np.array([c >= 0 for c in cells], dtype=bool)
        first_rank = np.array(comm.allgather(found)).reshape(comm.size, -1)
        owner = np.where(first_rank.any(axis=0), first_rank.argmax(axis=0), -1)
        for name, o, p in zip(self.names, owner, self.points):
            if o < 0:
                raise SceneError(f"[probes] {name} = {list(p)} lies outside the mesh")
        self.mine = np.flatnonzero(owner == comm.rank)
        self.cells = np.array(cells, dtype=np.int32)[self.mine] if len(self.mine) else np.zeros(0, np.int32)
        self.comm = comm

    def values(self, f) -> np.ndarray:
        """(n_points, 3) values of a Function (ghosts must be up to date)."""
        out = np.zeros((len(self.names), 3))
        if len(self.mine):
            out[self.mine] = f.eval(self.points[self.mine], self.cells).reshape(len(self.mine), -1)
        return self.comm.allreduce(out, op=MPI.SUM)

    def as_dict(self, values: np.ndarray) -> dict[str, list[float]]:
        return {n: [float(c) for c in v] for n, v in zip(self.names, values)}
