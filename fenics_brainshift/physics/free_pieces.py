"""Pieces a resection cuts free: the present cells, joined through shared faces, that no
support holds.

A settled state cannot hold such a piece (K is singular on it: nothing resists its rigid
motion), where time stepping lets it fall with its mass. The components are found on rank 0
from every rank's cells and their faces' global numbers, so the answer is the same on any
number of ranks.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .. import compat


def unheld_cells(V, present: np.ndarray, fixed_blocks: np.ndarray) -> np.ndarray:
    """The owned cells (local indices) of present pieces that touch no fixed node (a block
    dof in ``fixed_blocks``, local). With no fixed node anywhere (a body the skull holds)
    every piece but the largest. Collective."""
    mesh = V.mesh
    topo = mesh.topology
    topo.create_entities(2)
    topo.create_connectivity(3, 2)
    n_owned = topo.index_map(3).size_local
    cells = np.flatnonzero(present[:n_owned])
    facets = topo.connectivity(3, 2).array.reshape(-1, 4)[cells]
    facets = topo.index_map(2).local_to_global(facets.ravel().astype(np.int32)).reshape(-1, 4)
    dofs = compat.dofmap_array(V)[cells]
    held = np.isin(dofs, fixed_blocks).any(axis=1)
    gathered = mesh.comm.gather((facets, held), root=0)
    free = None
    if mesh.comm.rank == 0:
        all_facets = np.concatenate([f for f, _ in gathered])
        all_held = np.concatenate([h for _, h in gathered])
        free = _free(all_facets, all_held)
        bounds = np.cumsum([0] + [len(h) for _, h in gathered])
        free = [free[bounds[r] : bounds[r + 1]] for r in range(mesh.comm.size)]
    mine = mesh.comm.scatter(free, root=0)
    return cells[mine]


def _free(facets: np.ndarray, held: np.ndarray) -> np.ndarray:
    """(n,) True for the cells of components (joined through shared facets) with no held cell;
    with none held anywhere, of every component but the largest."""
    n = len(facets)
    if n == 0:
        return np.zeros(0, dtype=bool)
    _, facet_index = np.unique(facets.ravel(), return_inverse=True)
    rows = np.repeat(np.arange(n), 4)
    cols = n + facet_index.ravel()
    size = n + int(facet_index.max()) + 1
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
    _, label = connected_components(graph, directed=False)
    label = label[:n]
    if held.any():
        return ~np.isin(label, np.unique(label[held]))
    largest = np.argmax(np.bincount(label))
    return label != largest
