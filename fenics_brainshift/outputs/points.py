"""Values of a Function at fixed points, the same on any number of ranks."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from .. import compat


class PointEvaluator:
    """Values of a Function at fixed points, each point evaluated by one rank: in the cell
    that holds it, or, just outside the mesh, extrapolated from the nearest cell."""

    def __init__(self, mesh, points: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        self.comm = mesh.comm
        comm, n = self.comm, len(self.points)
        n_owned = mesh.topology.index_map(mesh.topology.dim).size_local
        cells = np.array(compat.colliding_cells(mesh, self.points), dtype=np.int64)
        cells[cells >= n_owned] = -1  # ghosts belong to the neighbour
        # inside: the lowest rank holding a containing cell evaluates the point
        found = np.array(comm.allgather(cells >= 0))
        owner = np.where(found.any(axis=0), found.argmax(axis=0), -1)
        # outside everywhere: the rank with the nearest cell midpoint extrapolates
        outside = np.flatnonzero(owner < 0)
        self._outside_mask = owner < 0
        self.outside = len(outside)
        self.outside_distance = np.zeros(0)
        if len(outside):
            geo = compat.geometry_dofmap(mesh)[:n_owned]
            corners = mesh.geometry.x[geo]
            midpoints = corners.mean(axis=1)
            distance = np.full(len(outside), np.inf)
            if len(midpoints):
                distance, nearest = cKDTree(midpoints).query(self.points[outside])
                cells[outside] = nearest
            distances = np.array(comm.allgather(distance))
            owner[outside] = distances.argmin(axis=0)
            self.outside_distance = distances.min(axis=0)
            local_h = float(np.linalg.norm(corners - midpoints[:, None], axis=2).max()) if len(corners) else 0.0
            self.cell_radius = comm.allreduce(local_h, op=MPI.MAX)
        self.mine = np.flatnonzero(owner == comm.rank)
        self.cells = cells[self.mine].astype(np.int32)
        self.n = n

    @property
    def inside(self) -> np.ndarray:
        """Which points lie in a cell of the mesh (bool, N)."""
        return ~self._outside_mask

    def far_outside(self) -> np.ndarray:
        """Indices of points farther from every cell than a cell's own size."""
        if not self.outside:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(self._outside_mask)[self.outside_distance > 2.0 * self.cell_radius]

    def values(self, u) -> np.ndarray:
        """(N, 3) values of u at the points, on every rank."""
        out = np.zeros((self.n, 3))
        if len(self.mine):
            out[self.mine] = u.eval(self.points[self.mine], self.cells).reshape(len(self.mine), -1)[:, :3]
        return self.comm.allreduce(out, op=MPI.SUM)
