"""The state of a run: displacement, velocity and acceleration on the model's space."""

from __future__ import annotations

import numpy as np
from dolfinx import fem
from mpi4py import MPI


class State:
    """u, v, a as DOLFINx Functions on V, with global measures of them."""

    def __init__(self, V):
        self.V = V
        self.comm = V.mesh.comm
        self.u = fem.Function(V, name="displacement")
        self.v = fem.Function(V, name="velocity")
        self.a = fem.Function(V, name="acceleration")
        self.n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self.t = 0.0

    def owned(self, f: fem.Function) -> np.ndarray:
        return f.x.array[: self.n_owned]

    def norm(self, f: fem.Function) -> float:
        """The global 2-norm of a Function's owned values. Not PETSc's Vec.norm(): PETSc caches
        norms until a PETSc operation changes the vector, and u, v, a change through numpy."""
        owned = self.owned(f)
        return float(np.sqrt(self.comm.allreduce(float(owned @ owned), op=MPI.SUM)))

    def max_displacement(self) -> float:
        """The largest |u| at a node (m), global."""
        local = self.owned(self.u).reshape(-1, 3)
        local_max = float(np.max(np.linalg.norm(local, axis=1))) if local.size else 0.0
        return self.comm.allreduce(local_max, op=MPI.MAX)

    def snapshot(self) -> tuple:
        return self.t, self.u.x.array.copy(), self.v.x.array.copy(), self.a.x.array.copy()

    def restore(self, snapshot: tuple) -> None:
        self.t, u, v, a = snapshot
        for f, values in zip((self.u, self.v, self.a), (u, v, a)):
            f.x.array[:] = values
