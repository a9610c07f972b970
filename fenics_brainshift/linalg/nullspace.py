"""The rigid-body near-nullspace that makes aggregation AMG work for elasticity."""

from __future__ import annotations

from typing import TYPE_CHECKING

import dolfinx.la
import numpy as np
from petsc4py import PETSc

if TYPE_CHECKING:
    from dolfinx import fem


def rigid_body_modes(V: fem.FunctionSpace) -> PETSc.NullSpace:
    """Three translations and three rotations of the dof coordinates of a vector space V,
    orthonormalised (modified Gram-Schmidt with global dot products: the same on any number
    of ranks)."""
    index_map = V.dofmap.index_map
    bs = V.dofmap.index_map_bs
    n_owned = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n_owned]
    basis = [dolfinx.la.create_petsc_vector(index_map, bs) for _ in range(6)]
    arrays = [np.zeros((n_owned, bs)) for _ in range(6)]
    for i in range(3):
        arrays[i][:, i] = 1.0
    arrays[3][:, 0], arrays[3][:, 1] = -x[:, 1], x[:, 0]
    arrays[4][:, 0], arrays[4][:, 2] = x[:, 2], -x[:, 0]
    arrays[5][:, 1], arrays[5][:, 2] = -x[:, 2], x[:, 1]
    for vec, arr in zip(basis, arrays):
        vec.array[:] = arr.ravel()
    for i, vi in enumerate(basis):
        for vj in basis[:i]:
            vi.axpy(-vi.dot(vj), vj)
        vi.normalize()
    return PETSc.NullSpace().create(vectors=basis, comm=V.mesh.comm)
