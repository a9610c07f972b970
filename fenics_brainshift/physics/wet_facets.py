"""Integrals of the clipped hydrostatic pressure over surface triangles, exact at the water line.

p = rho_f |g| max(level - x.up, 0) has a kink at the water line that defeats any fixed
quadrature rule, so every triangle is split exactly there (the paper's cases 1-4, eqs.
10-19) and only the wet part is integrated:

- ``"consistent"``: the exact integral of depth * N_i over the wet polygon for each basis
  function N_i of the facet (P1 in closed form, P2 by a rule exact for its cubic integrand);
- ``"paper"``: each wet sub-triangle's depth-area shared among the wet vertices by depth
  (eqs. 11-19); P1 only.

Pure numpy, vectorised over facets; multiply by rho_f |g| (-n) for nodal forces.
"""

from __future__ import annotations

import numpy as np


# ----------------------------------------------------------------- reference quadrature
def _triangle_rule() -> tuple[np.ndarray, np.ndarray]:
    """Collapsed 3 x 3 Gauss rule on a triangle: barycentric points (9, 3) and weights summing
    to 1, exact for polynomials of total degree 4 (p N_i is at most cubic)."""
    g, w = np.polynomial.legendre.leggauss(3)
    g, w = (g + 1) / 2, w / 2
    xi, eta = np.meshgrid(g, g, indexing="ij")
    wx, wy = np.meshgrid(w, w, indexing="ij")
    x, y = xi.ravel(), (eta * (1 - xi)).ravel()
    weights = (wx * wy * (1 - xi)).ravel() * 2.0
    return np.column_stack([1 - x - y, x, y]), weights


QUAD_POINTS, QUAD_WEIGHTS = _triangle_rule()


# ----------------------------------------------------------------- the split, vectorised
def split_wet(depth: np.ndarray):
    """Split triangles at the water line, in barycentric coordinates.

    depth: (F, 3) depth below the surface at the vertices (> 0: wet).
    Returns (order, B, wet_count): ``order`` (F, 3) sorts each facet's vertices deepest first;
    ``B`` (F, 2, 3, 3) holds up to two wet sub-triangles, row a = barycentric coordinates (in
    the sorted vertex order) of sub-vertex a; unused sub-triangles are all zero.
      3 wet (case 1): (0, 1, 2)
      2 wet (case 2): (0, 1, P02) and (1, P12, P02)   [P02 on edge 0-2 at the water line]
      1 wet (case 3): (0, P01, P02)
      0 wet (case 4): nothing
    """
    order = np.argsort(-depth, axis=1, kind="stable")
    d = np.take_along_axis(depth, order, axis=1)
    wet = (d > 0).sum(axis=1)
    F = depth.shape[0]
    eye = np.eye(3)
    B = np.zeros((F, 2, 3, 3))

    def cut(i, j, rows):  # point on edge i-j where the depth is zero
        t = d[rows, i] / (d[rows, i] - d[rows, j])
        return (1 - t)[:, None] * eye[i] + t[:, None] * eye[j]

    c1, c2, c3 = wet == 3, wet == 2, wet == 1
    B[c1, 0] = eye
    if c2.any():
        p02, p12 = cut(0, 2, c2), cut(1, 2, c2)
        B[c2, 0, 0], B[c2, 0, 1], B[c2, 0, 2] = eye[0], eye[1], p02
        B[c2, 1, 0], B[c2, 1, 1], B[c2, 1, 2] = eye[1], p12, p02
    if c3.any():
        B[c3, 0, 0], B[c3, 0, 1], B[c3, 0, 2] = eye[0], cut(0, 1, c3), cut(0, 2, c3)
    return order, B, wet


def triangle_geometry(X: np.ndarray, X_opposite: np.ndarray):
    """Unit outward normals (F, 3) and areas (F,) of triangles X (F, 3, 3) on the surface of
    tetrahedra whose fourth vertex is X_opposite (F, 3)."""
    cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    n = cross / np.where(norm > 0, norm, 1.0)[:, None]
    inward = np.einsum("ij,ij->i", n, X_opposite - X[:, 0]) > 0
    n[inward] *= -1
    return n, 0.5 * norm


def consistent_loads(depth: np.ndarray, area: np.ndarray, degree: int, split=None):
    """Exact integrals of depth * N over the wet part, per facet and basis function (P1 in
    closed form, P2 by a rule exact for the cubic integrand).

    Returns (vertex (F, 3), edge (F, 3) or None) in the *sorted* order of split_wet; edge k is
    the edge opposite sorted vertex k. Multiply by rho_f |g| (-n) for the nodal forces.
    ``split``: split_wet(depth), when the caller has it already."""
    order, B, _ = split if split is not None else split_wet(depth)
    d = np.take_along_axis(depth, order, axis=1)
    sub_area = area[:, None] * np.abs(np.linalg.det(B))  # (F, 2)
    if degree == 1:
        # closed form: on a triangle of area A, the integral of the product of two linear
        # functions f, g with vertex values f_a, g_a is A/12 (sum_a f_a g_a + sum_a f_a sum_b g_b)
        dep = (B @ d[:, None, :, None])[..., 0]  # (F, 2, 3) depth at the sub-vertices
        lam_dep = (dep[:, :, None, :] @ B)[:, :, 0, :]  # sum_a lambda_k(a) depth(a)
        both = lam_dep + B.sum(axis=2) * dep.sum(axis=2)[..., None]
        return np.einsum("fs,fsk->fk", sub_area / 12.0, both), None
    lam = np.einsum("qa,fsak->fsqk", QUAD_POINTS, B)  # parent barycentrics at the points
    w = sub_area[:, :, None] * QUAD_WEIGHTS[None, None, :]  # (F, 2, Q)
    wp = w * np.einsum("fsqk,fk->fsq", lam, d)  # weight * depth at each point
    vertex = np.einsum("fsq,fsqk->fk", wp, lam * (2 * lam - 1))
    pairs = [(1, 2), (0, 2), (0, 1)]  # edge opposite sorted vertex k
    edge = np.stack([np.einsum("fsq,fsq->f", wp, 4 * lam[..., i] * lam[..., j]) for i, j in pairs], axis=1)
    return vertex, edge


def paper_loads(depth: np.ndarray, area: np.ndarray, split=None) -> np.ndarray:
    """The paper's nodal shares of depth * area (eqs. 11-19), sorted vertex order (F, 3)."""
    order, B, wet = split if split is not None else split_wet(depth)
    d = np.take_along_axis(depth, order, axis=1)
    sub_area = area[:, None] * np.abs(np.linalg.det(B))
    centroid_depth = np.einsum("fsak,fk->fs", B, d) / 3.0
    force = sub_area * centroid_depth  # (F, 2): depth-area of each wet sub-triangle
    shares = np.zeros((depth.shape[0], 2, 3))
    c1, c2, c3 = wet == 3, wet == 2, wet == 1
    shares[c1, 0] = d[c1] / d[c1].sum(axis=1, keepdims=True)  # eq. 13
    s = d[c2, 0] + d[c2, 1]
    shares[c2, 0, 0], shares[c2, 0, 1] = d[c2, 0] / s, d[c2, 1] / s  # eq. 16, 17
    shares[c2, 1, 1] = 1.0  # eq. 17: the second part goes to j2
    shares[c3, 0, 0] = 1.0  # eq. 19
    return np.einsum("fs,fsk->fk", force, shares)


def wet_integrals(depth: np.ndarray, area: np.ndarray, degree: int, rule: str = "consistent"):
    """The rule's nodal integrals of depth * N for facets with at least one wet vertex.

    Facets entirely under water (most of them) take closed forms; only those the water line
    cuts are split (split_wet), which is where the time went. The integrals of products of
    barycentrics, int l1^a l2^b l3^c = 2 A a! b! c! / (a + b + c + 2)!, give with D = sum d:
      P1:            vertex_k = A (d_k + D) / 12
      P2:            vertex_k = A (3 d_k - D) / 60,   edge_k (opposite vertex k) = A (2 D - d_k) / 15
      paper, case 1: vertex_k = A d_k / 3              (eq. 13: A D/3 shared as d_k / D)
    Returns (order, vertex, edge or None): row f of vertex/edge belongs to the facet's
    vertices in the order order[f] (the identity for whole facets, deepest first for cut ones)."""
    F = depth.shape[0]
    order = np.tile(np.arange(3), (F, 1))
    vertex = np.empty((F, 3))
    edge = np.empty((F, 3)) if degree == 2 and rule == "consistent" else None
    whole = (depth > 0).all(axis=1)
    d, A = depth[whole], area[whole, None]
    D = d.sum(axis=1, keepdims=True)
    if rule == "paper":
        vertex[whole] = A * d / 3.0
    elif degree == 1:
        vertex[whole] = A * (d + D) / 12.0
    else:
        vertex[whole] = A * (3.0 * d - D) / 60.0
        edge[whole] = A * (2.0 * D - d) / 15.0
    cut = ~whole
    if cut.any():
        split = split_wet(depth[cut])
        order[cut] = split[0]
        if rule == "paper":
            vertex[cut] = paper_loads(depth[cut], area[cut], split)
        else:
            vertex[cut], edge_cut = consistent_loads(depth[cut], area[cut], degree, split)
            if edge is not None:
                edge[cut] = edge_cut
    return order, vertex, edge
