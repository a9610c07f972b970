"""The tangent of the follower fluid load: how the nodal forces of the wet surface change
when its nodes move.

A wet facet's nodal forces f = -rho_f |g| int depth N n da depend on its three vertex
positions through the depth (the pressure grows as a vertex sinks), the facet's area and
normal (it stretches and turns) and, for a facet the water line cuts, through where the line
runs. The force kernel (wet_facets.py) is evaluated on moved copies of every facet that is
or may get wet, and the derivative is taken by central differences, vectorised over facets.
A whole facet's forces are cubic in its vertex positions, so the central difference is exact
to round-off there (its third derivative is constant); a cut facet's are smooth on either
side of a configuration change, and the difference is accurate to the step's square. The
blocks go into the matrix rows of the facet's nodes (vertex and, for P2, edge dofs) and the
columns of its vertices: the geometry is that of the vertices.
"""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from .wet_facets import wet_integrals

RELATIVE_STEP = 1e-6  # of a facet's longest edge


def facet_forces(X: np.ndarray, orientation: np.ndarray, level: float, up: np.ndarray, rho_g: float,
                 degree: int, rule: str) -> np.ndarray:
    """Nodal forces (F, 3 or 6 nodes, 3) of triangles X (F, 3, 3) under the clipped
    hydrostatic pressure, in the facets' own node order (vertices, then for P2 the edge
    opposite each vertex); ``orientation`` (+1/-1) makes the vertex order's normal outward."""
    cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    twice_area = np.linalg.norm(cross, axis=1)
    normals = cross * (orientation / np.where(twice_area > 0, twice_area, 1.0))[:, None]
    depth = level - X @ up
    order, vertex, edge = wet_integrals(depth, 0.5 * twice_area, degree, rule)
    nodes = [vertex] + ([edge] if edge is not None else [])
    out = []
    for values in nodes:  # back from the split's sorted order to the facet's own
        own = np.empty_like(values)
        np.put_along_axis(own, order, values, axis=1)
        out.append(-rho_g * own[:, :, None] * normals[:, None, :])
    return np.concatenate(out, axis=1)


def load_tangent_blocks(hydro, level: float, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row block dofs (F, n), column block dofs (F, 3), blocks (F, 3 n, 9)): d f / d x of every
    facet that may be wet, f its nodal forces and x its vertex positions."""
    n_ref, area, height, lowest, orientation, _ = hydro.reference_surface()
    facets = hydro.facets
    values = u.x.array.reshape(-1, 3)
    X = facets.x_vertices + values[facets.vertex_dofs]
    step = RELATIVE_STEP * np.linalg.norm(X - np.roll(X, 1, axis=1), axis=2).max(axis=1)
    near = np.flatnonzero(((level - X @ hydro.up) > -2.0 * step[:, None]).any(axis=1))
    X, h, orient = X[near], step[near], orientation[near]
    rows = facets.vertex_dofs[near]
    if facets.edge_dofs is not None and hydro.degree == 2 and hydro.rule == "consistent":
        rows = np.concatenate([rows, facets.edge_dofs[near]], axis=1)
    rho_g = hydro.rho_fluid * hydro.g_magnitude
    blocks = np.zeros((len(near), 3 * rows.shape[1], 9))
    for m in range(3):
        for c in range(3):
            plus, minus = X.copy(), X.copy()
            plus[:, m, c] += h
            minus[:, m, c] -= h
            difference = (facet_forces(plus, orient, level, hydro.up, rho_g, hydro.degree, hydro.rule)
                          - facet_forces(minus, orient, level, hydro.up, rho_g, hydro.degree, hydro.rule))
            blocks[:, :, 3 * m + c] = (difference / (2.0 * h[:, None, None])).reshape(len(near), -1)
    return rows, facets.vertex_dofs[near], blocks


def add_load_tangent(A: PETSc.Mat, hydro, level: float, u, scale: float = 1.0) -> None:
    """A += scale * d F_fluid / d u, in A's local block numbering (A is assembled after)."""
    rows, cols, blocks = load_tangent_blocks(hydro, level, u)
    if len(rows):  # one call for all facets (row-major (3 n) x 9 blocks per facet)
        A.setValuesBlockedLocalRCV(rows.astype(PETSc.IntType), cols.astype(PETSc.IntType),
                                   (scale * blocks).reshape(len(rows), -1), addv=PETSc.InsertMode.ADD_VALUES)
    A.assemble()
