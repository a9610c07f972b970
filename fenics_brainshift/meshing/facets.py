"""How many cells that are present touch each facet: the topology behind a surface that
changes when cells are removed."""

from __future__ import annotations

import dolfinx.la
import numpy as np
from petsc4py import PETSc


def present_facet_counts(mesh, present: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(owned present cells, (n, 4) global count of present cells at each of their facets).

    Owned present cells add 1 to each of their facets through the facet index map; ghost
    counts are summed onto the owners and sent back. No ghost cells are needed, so the answer
    is the same for any ghost mode and number of ranks. Facet k of a cell is opposite its
    vertex k (the DOLFINx/basix reference numbering). Collective."""
    topo = mesh.topology
    tdim = topo.dim
    topo.create_entities(tdim - 1)
    topo.create_connectivity(tdim, tdim - 1)
    n_owned = topo.index_map(tdim).size_local
    owned = np.ones(n_owned, dtype=bool) if present is None else np.asarray(present[:n_owned], dtype=bool)
    cells = np.flatnonzero(owned)
    c2f = topo.connectivity(tdim, tdim - 1).array.reshape(-1, 4)[cells]
    counts = dolfinx.la.create_petsc_vector(topo.index_map(tdim - 1), 1)
    with counts.localForm() as lf:
        local = np.zeros(lf.getLocalSize())
        np.add.at(local, c2f.ravel(), 1.0)
        lf.array[:] = local
    counts.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    counts.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    with counts.localForm() as lf:
        result = lf.array_r[c2f].astype(np.int64)
    counts.destroy()
    return cells, result
