"""The mesh's vertices and tetrahedra in one order on every number of ranks, and a
displacement's values there, gathered to rank 0: what an atlas stores.

The order is the vertices' coordinates sorted (x, then y, then z), and the tetrahedra's by
their sorted vertex numbers, which no partition changes, so an atlas built on 2 ranks is the
one built on 1. A P2 displacement is stored by
its vertex values (its P1 interpolant, as displacement.xdmf holds it)."""

from __future__ import annotations

import numpy as np
from dolfinx import fem

from .. import compat


class GlobalVertices:
    def __init__(self, mesh):
        self.comm = mesh.comm
        self.W = compat.vector_space(mesh, 1)
        self._w = fem.Function(self.W)
        index_map = self.W.dofmap.index_map
        owned = index_map.size_local
        coordinates = self.W.tabulate_dof_coordinates()[:owned]
        start = index_map.local_range[0]
        ghosts = np.asarray(index_map.ghosts, dtype=np.int64)
        self._global = np.concatenate([start + np.arange(owned), ghosts])  # of every local dof
        n_cells = mesh.topology.index_map(3).size_local
        cells = self._global[compat.dofmap_array(self.W)[:n_cells]]
        gathered = self.comm.gather((start + np.arange(owned), coordinates, cells), root=0)
        self._owned = owned
        if self.comm.rank == 0:
            ids = np.concatenate([g[0] for g in gathered])
            points = np.concatenate([g[1] for g in gathered])
            # x first, then y, then z, on coordinates rounded to a nanometre: a partition's
            # round-off must not reorder points of one x
            order = np.lexsort(np.round(points * 1e9).T[::-1])
            position = np.empty(len(ids), dtype=np.int64)
            position[ids[order]] = np.arange(len(ids))  # global dof id -> stored row
            self._position = position
            self.points = points[order]
            tetrahedra = position[np.concatenate([g[2] for g in gathered])]
            # the cells in one order too (by their sorted vertices): a point outside every cell
            # (a fine surface's, beyond the voxels) then takes the same nearest cell on any ranks
            self.cell_order = np.lexsort(np.sort(tetrahedra, axis=1).T[::-1])  # gathered cell -> stored row
            self.tetrahedra = tetrahedra[self.cell_order]
        else:
            self._position = self.points = self.tetrahedra = self.cell_order = None
        # the stored row of each owned dof block (for loads placed at stored vertices)
        position = self.comm.bcast(self._position, root=0)
        self.owned_rows = position[self._global[:owned]]

    def values(self, u) -> np.ndarray | None:
        """(N, 3) vertex values of u in the stored order, on rank 0 (None elsewhere)."""
        self._w.interpolate(u)
        mine = (self._global[: self._owned], self._w.x.array.reshape(-1, 3)[: self._owned].copy())
        gathered = self.comm.gather(mine, root=0)
        if self.comm.rank != 0:
            return None
        out = np.empty((len(self.points), 3))
        for ids, values in gathered:
            out[self._position[ids]] = values
        return out

    def cell_values(self, f) -> np.ndarray | None:
        """(C,) a DG0 function's values (the tissue indicator) in the stored cells' order, on
        rank 0 (None elsewhere)."""
        owned = f.function_space.mesh.topology.index_map(3).size_local
        dofs = compat.dofmap_array(f.function_space)[:owned, 0]
        parts = self.comm.gather(f.x.array[dofs].copy(), root=0)
        return np.concatenate(parts)[self.cell_order] if parts is not None else None

    def place(self, rows: np.ndarray, vectors: np.ndarray, b) -> None:
        """b (a PETSc vector on the P1 space) <- the vectors (n, 3) at the stored rows (the
        same on every rank; each rank sets the entries it owns)."""
        b.set(0.0)
        mine = np.flatnonzero(np.isin(self.owned_rows, rows))
        if len(mine):
            where = {r: i for i, r in enumerate(rows)}
            b.array.reshape(-1, 3)[mine] = vectors[[where[r] for r in self.owned_rows[mine]]]
