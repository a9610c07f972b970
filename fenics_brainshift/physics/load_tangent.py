"""The tangent of the follower fluid load: how the nodal forces of the wet surface change
when its nodes move.

A wet facet's nodal forces f = -rho_f |g| int depth N n da depend on its three vertex
positions through the depth (the pressure grows as a vertex sinks), the facet's area and
normal (it stretches and turns) and, for a facet the water line cuts, through where the line
runs. The force kernel (wet_facets.py) is evaluated on moved copies of every facet that is
or may get wet, and the derivative is taken by forward differences, vectorised over facets:
ten evaluations of the kernel, not the eighteen of central differences, accurate to the step
(RELATIVE_STEP of the facet, about 1e-6 of the derivative) plus round-off: far inside what
Newton's tangent needs; a cut facet's forces are smooth on either side of a configuration
change. The paper's rule keeps central differences (its shares jump where two vertices are
level). A P1 facet wholly under water (most of them) takes its derivative in closed form
(_whole_p1_blocks): the kernel's differences were half of a Newton iteration's tangent in an
atlas with the skull. The
blocks go into the matrix rows of the facet's nodes (vertex and, for P2, edge dofs) and the
columns of its vertices: the geometry is that of the vertices.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from .wet_facets import wet_integrals

RELATIVE_STEP = 1e-6  # of a facet's longest edge


def facet_forces(
    X: np.ndarray, orientation: np.ndarray, level: float, up: np.ndarray, rho_g: float, degree: int, rule: str
) -> np.ndarray:
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
    whole = ((level - X @ hydro.up) > 0).all(axis=1)
    if hydro.degree == 1 and hydro.rule == "consistent":  # closed form under water, differences at the line
        blocks[whole] = _whole_p1_blocks(X[whole], orient[whole], level, hydro.up, rho_g)
    else:
        whole[:] = False
    cut = np.flatnonzero(~whole)
    if len(cut):
        X, h, orient = X[cut], h[cut], orient[cut]
        # the paper's rule shares a facet's load by its vertices' depth order, which jumps where
        # two are level (a horizontal edge; a voxel mesh at rest has many): central differences'
        # spikes there are equal and opposite and cancel between neighbouring facets, forward
        # ones do not (Newton took 15 iterations instead of 5 with forward differences)
        central = hydro.rule != "consistent"
        here = None if central else facet_forces(X, orient, level, hydro.up, rho_g, hydro.degree, hydro.rule)
        for m in range(3):
            for c in range(3):
                plus = X.copy()
                plus[:, m, c] += h
                difference = facet_forces(plus, orient, level, hydro.up, rho_g, hydro.degree, hydro.rule)
                if central:
                    minus = X.copy()
                    minus[:, m, c] -= h
                    difference = (
                        difference - facet_forces(minus, orient, level, hydro.up, rho_g, hydro.degree, hydro.rule)
                    ) / 2.0
                else:
                    difference = difference - here
                blocks[cut, :, 3 * m + c] = (difference / h[:, None, None]).reshape(len(cut), -1)
    return rows, facets.vertex_dofs[near], blocks


def _whole_p1_blocks(X: np.ndarray, orientation: np.ndarray, level: float, up: np.ndarray, rho_g: float) -> np.ndarray:
    """d f / d x (F, 9, 9) of P1 facets wholly under water, in closed form: f_k = -rho g
    (d_k + D) / 24 o (x1 - x0) x (x2 - x0) (wet_integrals: A (d_k + D) / 12 times the normal,
    A n = o cross / 2; d the vertices' depths, D their sum, o the orientation), so
    d f_k / d x_m = -rho g o / 24 [cross (x) (-up) (1 + [k = m]) + (d_k + D) [e_m]x], the
    cross product's derivative in vertex m the skew matrix of the edge opposite it,
    e_0 = x2 - x1, e_1 = x0 - x2, e_2 = x1 - x0."""
    cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    depth = level - X @ up
    weight = depth + depth.sum(axis=1, keepdims=True)  # (F, 3): d_k + D
    edges = np.stack([X[:, 2] - X[:, 1], X[:, 0] - X[:, 2], X[:, 1] - X[:, 0]], axis=1)  # (F, 3, 3)
    skew = np.zeros(edges.shape[:2] + (3, 3))  # skew[f, m] @ v = e_m x v
    skew[..., 0, 1], skew[..., 0, 2] = -edges[..., 2], edges[..., 1]
    skew[..., 1, 0], skew[..., 1, 2] = edges[..., 2], -edges[..., 0]
    skew[..., 2, 0], skew[..., 2, 1] = -edges[..., 1], edges[..., 0]
    depth_part = -np.einsum("fi,c->fic", cross, up)[:, None, :, None, :] * (1.0 + np.eye(3))[None, :, None, :, None]
    turn_part = weight[:, :, None, None, None] * skew.transpose(0, 2, 1, 3)[:, None]  # (F, k, i, m, c)
    blocks = (-rho_g / 24.0) * orientation[:, None, None, None, None] * (depth_part + turn_part)
    return blocks.reshape(len(X), 9, 9)


def add_load_tangent(A: PETSc.Mat, hydro, level: float, u, scale: float = 1.0) -> None:
    """A += scale * d F_fluid / d u, in A's local block numbering (A is assembled after)."""
    rows, cols, blocks = load_tangent_blocks(hydro, level, u)
    if len(rows):  # one call for all facets (row-major (3 n) x 9 blocks per facet)
        A.setValuesBlockedLocalRCV(
            rows.astype(PETSc.IntType),
            cols.astype(PETSc.IntType),
            (scale * blocks).reshape(len(rows), -1),
            addv=PETSc.InsertMode.ADD_VALUES,
        )
    A.assemble()
