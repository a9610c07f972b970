"""Pieces a resection cuts free: the present cells, joined through shared faces, whose
supports do not hold all six rigid motions.

A settled state cannot hold such a piece (K is singular on it: nothing resists its rigid
motion), where time stepping lets it fall with its mass. A piece pinned at one fixed node, or
at fixed nodes on a line, still turns: it is free too. The components are found on rank 0
from every rank's cells, their faces' global numbers and the fixed degrees of freedom in
them, so the answer is the same on any number of ranks.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .. import compat

RANK_TOL = 1e-10  # a held direction this small against the largest holds nothing


def unheld_cells(V, present: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """The owned cells (local indices) of present pieces their fixed degrees of freedom
    (``fixed``: local unrolled indices) do not hold against every rigid motion. With no fixed
    degree of freedom anywhere (a body the skull holds) every piece but the largest.
    Collective."""
    mesh = V.mesh
    topo = mesh.topology
    topo.create_entities(2)
    topo.create_connectivity(3, 2)
    n_owned = topo.index_map(3).size_local
    cells = np.flatnonzero(present[:n_owned])
    facets = topo.connectivity(3, 2).array.reshape(-1, 4)[cells]
    facets = topo.index_map(2).local_to_global(facets.ravel().astype(np.int32)).reshape(-1, 4)
    bs = V.dofmap.index_map_bs
    blocks = compat.dofmap_array(V)[cells]
    unrolled = blocks[:, :, None] * bs + np.arange(bs)
    cell, node, axis = np.nonzero(np.isin(unrolled, fixed))
    X = V.tabulate_dof_coordinates()
    holds = (cell, X[blocks[cell, node]], axis)
    supported = mesh.comm.allreduce(len(fixed)) > 0  # (before the cut too: a body the skull alone holds has none)
    gathered = mesh.comm.gather((facets, holds), root=0)
    free = None
    if mesh.comm.rank == 0:
        offsets = np.cumsum([0] + [len(f) for f, _ in gathered])
        all_facets = np.concatenate([f for f, _ in gathered])
        where = np.concatenate([h[0] + offsets[r] for r, (_, h) in enumerate(gathered)])
        points = np.concatenate([h[1] for _, h in gathered]).reshape(-1, 3)
        axes = np.concatenate([h[2] for _, h in gathered])
        free = _free(all_facets, where, points, axes, supported)
        free = [free[offsets[r] : offsets[r + 1]] for r in range(mesh.comm.size)]
    mine = mesh.comm.scatter(free, root=0)
    return cells[mine]


def _free(facets: np.ndarray, cell: np.ndarray, points: np.ndarray, axes: np.ndarray, supported: bool) -> np.ndarray:
    """(n,) True for the cells of components (joined through shared facets) that the held
    directions in them (a fixed component `axes` at `points`, in cell `cell`) leave free to
    move rigidly; in a body without supports (supported False), of every component but the
    largest."""
    n = len(facets)
    if n == 0:
        return np.zeros(0, dtype=bool)
    _, facet_index = np.unique(facets.ravel(), return_inverse=True)
    rows = np.repeat(np.arange(n), 4)
    size = n + int(facet_index.max()) + 1
    graph = coo_matrix((np.ones(len(rows)), (rows, n + facet_index.ravel())), shape=(size, size))
    _, label = connected_components(graph, directed=False)
    label = label[:n]
    if not supported:
        return label != np.argmax(np.bincount(label))
    held = [c for c in np.unique(label[cell]) if _holds_all(points[label[cell] == c], axes[label[cell] == c])]
    return ~np.isin(label, held)


def _holds_all(points: np.ndarray, axes: np.ndarray) -> bool:
    """Whether fixed components (axis a at a point x) hold the six rigid motions t + w x x:
    each holds d . t + (x - c) x d . w (d = e_a), and together they must span all six."""
    d = np.eye(3)[axes]
    centre = points.mean(axis=0)
    scale = max(float(np.abs(points - centre).max()), 1e-300)
    g = np.hstack([d, np.cross((points - centre) / scale, d)])
    values = np.linalg.eigvalsh(g.T @ g)
    return bool(values[-1] > 0 and values[0] > RANK_TOL * values[-1])
