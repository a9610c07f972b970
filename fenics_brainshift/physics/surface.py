"""The exterior surface of the cells present: its facets and what the fluid assembly needs."""

from __future__ import annotations

from dataclasses import dataclass

import basix
import numpy as np

from .. import compat
from ..meshing.facets import present_facet_counts


@dataclass
class SurfaceFacets:
    """The surface facets of the cells present, each held by the rank owning its cell, with what
    the assembly needs of each."""

    vertex_dofs: np.ndarray  # (F, 3) block dofs of V at the facet's vertices
    opposite_dofs: np.ndarray  # (F,) block dof at the cell's vertex opposite the facet
    edge_dofs: np.ndarray | None  # (F, 3) P2: dof of the edge opposite facet vertex k
    x_vertices: np.ndarray  # (F, 3, 3) reference coordinates
    x_opposite: np.ndarray  # (F, 3)


def surface_facets(V, present: np.ndarray | None = None) -> SurfaceFacets:
    """The surface of the cells present (all cells by default): facets with exactly one
    present cell next to them, each taken by the rank that owns that cell.

    The count is global (meshing.facets), so the surface is the same on any number of ranks;
    after a resection the cut faces join it."""
    mesh = V.mesh
    cells_present, counts = present_facet_counts(mesh, present)
    once = counts == 1  # (n, 4): facet k of the cell is on the surface
    cells = np.repeat(cells_present, 4)[once.ravel()]
    local = np.tile(np.arange(4), len(cells_present))[once.ravel()]  # facet k is opposite vertex k
    others = np.array([[v for v in range(4) if v != lf] for lf in range(4)])  # facet lf's vertices
    fv = others[local]  # (F, 3) local vertex numbers

    layout = V.dofmap.dof_layout
    vertex_local = np.array([layout.entity_dofs(0, v)[0] for v in range(4)])
    dofs = compat.dofmap_array(V)[cells]
    x = mesh.geometry.x
    geo = compat.geometry_dofmap(mesh)[cells]
    rows = np.arange(len(cells))[:, None]  # one row per surface facet
    edge_dofs = None
    if compat.element_degree(V) == 2:
        edges = basix.topology(basix.CellType.tetrahedron)[1]
        edge_of = {frozenset(e): layout.entity_dofs(1, i)[0] for i, e in enumerate(edges)}
        table = np.array(
            [[edge_of[frozenset(others[lf][[j for j in range(3) if j != k]])] for k in range(3)] for lf in range(4)]
        )
        edge_dofs = dofs[rows, table[local]]
    return SurfaceFacets(
        vertex_dofs=dofs[rows, vertex_local[fv]],
        opposite_dofs=dofs[rows[:, 0], vertex_local[local]],
        edge_dofs=edge_dofs,
        x_vertices=x[geo[rows, fv]],
        x_opposite=x[geo[rows[:, 0], local]],
    )


def gathered_outward_surface(facets, comm, u=None) -> tuple[np.ndarray, np.ndarray]:
    """The whole body surface on every rank, as (points, triangles) with outward normals:
    each facet's vertex order is turned so that its normal points away from the cell's
    opposite vertex. u: a displacement Function on the facets' space (the deformed surface)."""
    X, opposite = facets.x_vertices, facets.x_opposite
    if u is not None:
        values = u.x.array.reshape(-1, 3)
        X, opposite = X + values[facets.vertex_dofs], opposite + values[facets.opposite_dofs]
    normal = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    inward = np.einsum("ni,ni->n", normal, opposite - X[:, 0]) > 0
    X = np.where(inward[:, None, None], X[:, ::-1], X)
    X = np.concatenate(comm.allgather(X))
    return X.reshape(-1, 3), np.arange(3 * len(X)).reshape(-1, 3)
