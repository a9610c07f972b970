"""The rigid skull as a distance field: phi(y) >= 0 where a brain point y may be, phi < 0 past
the skull, and grad phi (unit) pointing away from the skull wall.

Two shapes: a closed triangulated surface (phi = the distance to it, positive inside), or the
brain's own reference surface dilated by a gap (phi = gap - the signed distance to that
surface, positive inside the brain; exact for every point of the dilated body, whose
boundary is the set at distance gap). Distances are exact point-to-triangle distances to the
nearest of the triangles whose centroids scipy's KD-tree finds closest (CANDIDATES of them);
the side is that of the nearest triangle's outward normal.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

CANDIDATES = 16  # triangles checked per point: their centroids are the nearest ones


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
            ((d1 <= 0) & (d2 <= 0), lambda: a)):
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(region[..., None], point(), out)
    return out


class RigidSkull:
    """phi and its gradient for points y (n, 3); see the module's docstring."""

    def __init__(self, points: np.ndarray, triangles: np.ndarray, gap: float | None = None):
        """points, triangles: the surface with outward normals (right-hand order); gap: None
        for a skull surface, else the dilation of the brain's surface they describe."""
        self.triangles = np.asarray(points, dtype=float)[np.asarray(triangles)]  # (T, 3, 3)
        tri = self.triangles
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normals = normals / np.linalg.norm(normals, axis=1)[:, None]
        self.gap = gap
        self._tree = cKDTree(tri.mean(axis=1))

    def distance(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(unsigned distance, side +1 outside / -1 inside, outward unit direction from the
        surface to y (the nearest triangle's normal where y is on the surface)) of every point."""
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        k = min(CANDIDATES, len(self.triangles))
        _, near = self._tree.query(y, k=k)
        near = near.reshape(len(y), k)
        tri = self.triangles[near]  # (n, k, 3, 3)
        q = closest_points_on_triangles(y[:, None, :], tri[..., 0, :], tri[..., 1, :], tri[..., 2, :])
        dist = np.linalg.norm(q - y[:, None, :], axis=2)
        rows = np.arange(len(y))
        best = dist[rows, np.argmin(dist, axis=1)]
        # the side: of the nearest triangle's plane; a point nearest to an edge or corner takes
        # the candidate whose plane it is farthest from (on a convex corner all say "outside")
        offsets = np.einsum("nki,nki->nk", y[:, None, :] - q, self.normals[near])
        tied = dist <= best[:, None] * (1 + 1e-9) + 1e-15
        strongest = np.where(tied, np.abs(offsets), -1.0).argmax(axis=1)
        side = np.where(offsets[rows, strongest] >= 0, 1.0, -1.0)
        closest = q[rows, strongest]
        on_surface = best <= 1e-12 * (1.0 + np.abs(y).max(initial=0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            direction = side[:, None] * (y - closest) / best[:, None]
        direction = np.where(on_surface[:, None], self.normals[near[rows, strongest]], direction)
        return best, side, direction

    def phi(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(phi (n,), unit grad phi (n, 3)): the room left before the skull, and the direction
        that increases it (away from the wall)."""
        dist, side, outward_direction = self.distance(y)
        if self.gap is None:  # inside the skull surface: phi = +distance
            return -side * dist, -outward_direction
        return self.gap - side * dist, -outward_direction  # gap - the signed distance to the brain


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


def outward(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles of a closed surface ordered so that their normals point out (flipped all
    together when the enclosed volume comes out negative)."""
    p = np.asarray(points)[triangles]
    volume = np.einsum("ni,ni->n", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return triangles if volume > 0 else triangles[:, ::-1]


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
