"""The dural septa as surfaces on the mesh: which nodes lie on each, and its normal there.

A septum (the falx cerebri, the tentorium) is a rigid membrane fixed to the skull: the tissue
slides along it and does not cross it. On a mesh with a fissure the tissue on each side
touches it: the nodes within ``reach`` of the surface. On a mesh that runs through it (a
voxel mesh of the whole brain) the septum is the layer of nodes nearest to it: of every mesh
edge it crosses, the end nearer to it, and every node on it. Those nodes move along it only
(constraints.py holds their normal component); a P2 edge's middle node is on it when both
its ends are, as a support holds it.

Which nodes is decided from the mesh's vertex coordinates, edge by edge, and the ranks'
choices are summed to the owners and sent back to the ghosts, so that a node is on a septum
on any number of ranks exactly when it is in serial.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import dolfinx.la
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from .. import compat
from ..errors import InputError
from ..surfaces.skull import RigidSkull

# the reference tetrahedron's edges in DOLFINx's order: P2's dof 4 + e sits on edge e
TETRA_EDGES = ((2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1))
ON_SURFACE = 1e-9  # a node this close to a septum (relative to the mesh's size) lies on it
# over a surface: the way from a point to its nearest point within 26 degrees of that face's
# normal (beyond a sheet's free edge it turns towards the edge; at a curved surface's triangle
# edges it stays within half the angle between the faces)
OVER = 0.9


@dataclass(frozen=True)
class Septum:
    """``side``: points (N, 3) -> (signed distance (N,) m, unit normal (N, 3), over (N,): the
    point's nearest point on the septum is inside a face, not on its rim); ``region``:
    points -> bool (N,), the part of space it spans (None: everywhere); ``reach``: None for
    the nearest layer of nodes, else every node within that distance (m) of it; ``name``
    names it in messages ([[septum]] NAME) and in the summary."""

    name: str
    side: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    region: Callable[[np.ndarray], np.ndarray] | None = None
    reach: float | None = None

    @classmethod
    def plane(cls, name: str, point, normal, region=None, reach=None) -> Septum:
        p = np.asarray(point, dtype=float)
        n = np.asarray(normal, dtype=float)
        n = n / np.abs(n).max()  # first: the square of 1e200 overflows, of 1e-170 underflows
        n = n / np.linalg.norm(n)
        return cls(
            name,
            lambda x: ((np.asarray(x) - p) @ n, np.broadcast_to(n, np.shape(x)), np.ones(len(x), dtype=bool)),
            region,
            reach,
        )

    @classmethod
    def surface(cls, name: str, points, triangles, region=None, reach=None) -> Septum:
        """A triangulated surface (points m, triangles): the side of each point is that of
        the nearest triangle's normal (surfaces/skull.py's exact distances). A point whose
        nearest point lies on an open surface's rim (beyond a falx's free edge) is not over it:
        the sign flips across the surface's extended plane there, which crosses no tissue."""
        skull = RigidSkull(points, triangles)

        def side(x):
            dist, sign, direction = skull.distance(x)
            closest = np.asarray(x) - (sign * dist)[:, None] * direction
            _, _, normal = skull.distance(closest)  # on the surface: its triangle's normal
            over = (dist <= ON_SURFACE * skull_size) | (np.abs(np.einsum("ni,ni->n", direction, normal)) > OVER)
            return sign * dist, normal, over

        skull_size = float(np.ptp(np.asarray(points, dtype=float), axis=0).max())
        return cls(name, side, region, reach)


def septum_nodes(V, septum: Septum) -> tuple[np.ndarray, np.ndarray]:
    """(block dofs (n,), unit normals (n, 3)) of the local nodes (owned and ghosts) on the
    septum; InputError when it holds no node of the mesh (on any rank)."""
    mesh = V.mesh
    geo = compat.geometry_dofmap(mesh)
    dofs = compat.dofmap_array(V)
    n_blocks = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
    corners = dofs[:, :4]
    X = np.zeros((n_blocks, 3))
    X[corners.ravel()] = mesh.geometry.x[geo[:, :4].ravel()]
    vertex = np.zeros(n_blocks, dtype=bool)
    vertex[corners.ravel()] = True
    distance, over = np.zeros(n_blocks), np.zeros(n_blocks, dtype=bool)
    distance[vertex], _, over[vertex] = septum.side(X[vertex])
    size = mesh.comm.allreduce(float(np.ptp(X[vertex], axis=0).max(initial=0.0)) if vertex.any() else 0.0, op=MPI.MAX)
    marked = np.zeros(n_blocks)
    if septum.reach is not None:
        marked[vertex & over & (np.abs(distance) <= septum.reach)] = 1.0
    else:
        marked[vertex & (np.abs(distance) <= ON_SURFACE * size)] = 1.0
        for a, b in TETRA_EDGES:
            da, db = distance[corners[:, a]], distance[corners[:, b]]
            crossed = (da * db < 0.0) & over[corners[:, a]] & over[corners[:, b]]
            nearer = np.where(np.abs(da) <= np.abs(db), corners[:, a], corners[:, b])
            marked[nearer[crossed]] = 1.0
    if septum.region is not None and vertex.any():
        inside = np.zeros(n_blocks, dtype=bool)
        inside[vertex] = np.asarray(septum.region(X[vertex].T), dtype=bool)
        marked[~inside] = 0.0
    marked = _summed_over_ranks(V, marked) > 0.0
    if compat.element_degree(V) == 2:  # an edge's middle node: on it when both ends are
        for e, (a, b) in enumerate(TETRA_EDGES):
            middle = dofs[:, 4 + e]
            both = marked[corners[:, a]] & marked[corners[:, b]]
            X[middle] = 0.5 * (X[corners[:, a]] + X[corners[:, b]])
            marked[middle[both]] = True
    nodes = np.flatnonzero(marked).astype(np.int32)
    owned = V.dofmap.index_map.size_local
    if mesh.comm.allreduce(int(np.count_nonzero(nodes < owned))) == 0:
        raise InputError(
            f"[[septum]] {septum.name} holds no node of the mesh; check its position and region (metres, mesh frame)"
        )
    normal = septum.side(X[nodes])[1] if len(nodes) else np.zeros((0, 3))
    return nodes, np.asarray(normal, dtype=float).reshape(-1, 3)


def _summed_over_ranks(V, values: np.ndarray) -> np.ndarray:
    """Per block dof (owned and ghosts): the sum of every rank's value for that node."""
    vector = dolfinx.la.create_petsc_vector(V.dofmap.index_map, 1)
    with vector.localForm() as local:
        local.array[:] = values
    vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    with vector.localForm() as local:
        out = local.array.copy()
    vector.destroy()
    return out
