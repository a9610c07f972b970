"""Supports: homogeneous Dirichlet conditions on the nodes a condition selects."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import dolfinx.mesh
import numpy as np
from dolfinx import fem
from petsc4py import PETSc

from .. import compat
from ..errors import InputError


@dataclass(frozen=True)
class Support:
    """Nodes where ``select`` (coordinates (3, N) -> bool (N,)) holds are fixed along
    ``components`` (0, 1, 2 = x, y, z); ``label`` names it in messages."""

    label: str
    select: Callable[[np.ndarray], np.ndarray]
    components: tuple[int, ...] = (0, 1, 2)


def fixed_conditions(V, supports) -> list:
    """Dirichlet conditions on V, per support and axis.

    The condition is evaluated on the mesh's own vertex coordinates (and, for P2, an edge's
    dofs are fixed when both its vertices are), not on tabulated dof coordinates: those are
    recomputed cell by cell and round differently on different partitions, so a region whose
    bound falls on a grid plane would select different nodes for different rank counts.
    A support that selects no node, or every node, is bad input (a unit slip, most likely)."""
    mesh, comm = V.mesh, V.mesh.comm
    tdim = mesh.topology.dim
    dims = [0, 1] if compat.element_degree(V) == 2 else [0]
    for dim in dims:
        mesh.topology.create_connectivity(dim, tdim)
    vertices = mesh.topology.index_map(0)
    bcs = []
    for support in supports:
        entities = {dim: dolfinx.mesh.locate_entities(mesh, dim, support.select) for dim in dims}
        count = comm.allreduce(int(np.sum(entities[0] < vertices.size_local)))
        if count == 0:
            raise InputError(f"{support.label} selects no node of the mesh; check the coordinates (metres, mesh frame)")
        if count == vertices.size_global and len(support.components) == 3:
            raise InputError(
                f"{support.label} selects every node of the mesh, so nothing could move; check the "
                f"coordinates (metres, mesh frame: a bound in millimetres?)"
            )
        if len(support.components) == 3:
            dofs = np.unique(np.concatenate([fem.locate_dofs_topological(V, d, e) for d, e in entities.items()]))
            bcs.append(fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs.astype(np.int32), V))
        else:
            for i in support.components:
                dofs = np.unique(
                    np.concatenate([fem.locate_dofs_topological(V.sub(i), d, e) for d, e in entities.items()])
                )
                bcs.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs.astype(np.int32), V.sub(i)))
    if bcs and _all_dofs_fixed(V, bcs):
        raise InputError(
            "[[fixed]] the supports together hold every node in every direction, so nothing could "
            "move; check the coordinates (metres, mesh frame) and axes"
        )
    return bcs


def _all_dofs_fixed(V, bcs) -> bool:
    """Does the union of the conditions fix every dof of V (global)?"""
    bs = V.dofmap.index_map_bs
    n_owned = V.dofmap.index_map.size_local * bs
    fixed = np.zeros(n_owned, dtype=bool)
    for bc in bcs:
        dofs = np.asarray(bc.dof_indices()[0])
        fixed[dofs[dofs < n_owned]] = True
    return V.mesh.comm.allreduce(int(np.count_nonzero(~fixed))) == 0
