"""Triangulated surfaces as arrays: the closest point on a triangle, whether a surface is
closed, and its triangles turned so that their normals point out."""

from __future__ import annotations

import numpy as np


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The point of triangle (a, b, c) closest to p, for arrays of shape (..., 3) (Ericson,
    Real-Time Collision Detection, 5.1.5: the Voronoi regions of vertices, edges and face)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("...i,...i", ab, ap), np.einsum("...i,...i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("...i,...i", ab, bp), np.einsum("...i,...i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("...i,...i", ab, cp), np.einsum("...i,...i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        out = a + (vb / denom)[..., None] * ab + (vc / denom)[..., None] * ac  # the face
        t_ab, t_ac = d1 / (d1 - d3), d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # Ericson's tests in reverse order, so that the earlier ones win where regions touch:
    # vertex a, vertex b, edge ab, vertex c, edge ac, edge bc, face
    for region, point in (
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), lambda: b + t_bc[..., None] * (c - b)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), lambda: a + t_ac[..., None] * ac),
        ((d6 >= 0) & (d5 <= d6), lambda: c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), lambda: a + t_ab[..., None] * ab),
        ((d3 >= 0) & (d4 <= d3), lambda: b),
        ((d1 <= 0) & (d2 <= 0), lambda: a),
    ):
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(region[..., None], point(), out)
    return out


def closed_surface_problem(triangles: np.ndarray) -> str | None:
    """Why a triangulated surface is not closed (an edge not shared by exactly two
    triangles), or None."""
    t = np.asarray(triangles)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    open_edges = int(np.sum(counts == 1))
    if open_edges:
        return f"it has {open_edges} open edge(s) (edges of only one triangle)"
    if np.any(counts > 2):
        return f"{int(np.sum(counts > 2))} edge(s) are shared by more than two triangles"
    return None


def shell_problem(triangles: np.ndarray) -> str | None:
    """Why a closed surface is not one consistently oriented shell (a skull must be: a second
    shell inside it, or a triangle turned the wrong way, makes its distance field wrong), or
    None."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    t = np.asarray(triangles)
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    _, counts = np.unique(directed, axis=0, return_counts=True)
    if np.any(counts > 1):  # (an edge run the same way by both its triangles: one of them turned)
        return (
            f"its triangles are not consistently oriented ({int(np.sum(counts > 1))} edge(s) run the same way in "
            f"both their triangles); re-orient them (MeshLab: Re-Orient all faces coherently)"
        )
    n = int(t.max(initial=-1)) + 1
    adjacency = coo_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(n, n))
    used = np.zeros(n, dtype=bool)
    used[t.ravel()] = True
    _, label = connected_components(adjacency, directed=False)
    shells = len(np.unique(label[used]))
    if shells > 1:
        return (
            f"it is {shells} separate closed surfaces (an inner and an outer table?); give the inner skull's "
            f"surface alone (3D Slicer: Segment Editor, Islands, keep the largest or the selected island)"
        )
    return None


def outward(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles of a closed surface ordered so that their normals point out (flipped all
    together when the enclosed volume comes out negative)."""
    p = np.asarray(points)[triangles]
    volume = np.einsum("ni,ni->n", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return triangles if volume > 0 else triangles[:, ::-1]
