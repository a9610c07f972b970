"""Where points are in the atlas's mesh, without DOLFINx: the tetrahedron that holds each
point and its barycentric coordinates (a point just outside the mesh, as cortex points lie
outside a voxel model's staircase, takes the nearest candidate cell and is extrapolated with
its affine map, as the fine surface is); and the point of a triangulated surface nearest to
each point, with its triangle and barycentric coordinates."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..surfaces.triangles import closest_points_on_triangles

CANDIDATES = 24  # nearest cell centroids tried per point


def barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, 4) barycentric coordinates of points (n, 3) in tetrahedra (n, 4, 3)."""
    edges = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)  # columns v_i - v_0
    lam = np.linalg.solve(edges, (points - corners[:, 0])[..., None])[..., 0]
    return np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)


class MeshLocator:
    def __init__(self, points: np.ndarray, tetrahedra: np.ndarray):
        self.points, self.tetrahedra = points, tetrahedra
        corners = points[tetrahedra]
        self._centroids = corners.mean(axis=1)
        self._tree = cKDTree(self._centroids)
        self.cell_size = float(np.median(np.linalg.norm(corners - self._centroids[:, None], axis=2).max(axis=1)))

    def locate(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cell (n,), barycentric (n, 4), distance outside the mesh (n,), 0 inside) of points."""
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        k = min(CANDIDATES, len(self._centroids))
        distance, near = self._tree.query(y, k=k)
        distance, near = distance.reshape(len(y), k), near.reshape(len(y), k)
        lam = barycentric(np.repeat(y, k, axis=0), self.points[self.tetrahedra[near.ravel()]]).reshape(len(y), k, 4)
        worst = lam.min(axis=2)  # >= 0 inside the cell
        best = worst.argmax(axis=1)
        cell = near[np.arange(len(y)), best]
        inside = worst[np.arange(len(y)), best] >= -1e-9
        outside = np.zeros(len(y))
        if not inside.all():  # the nearest centroid's cell extrapolates (its distance measures how far out)
            # centroids as near to a nanometre tie (a voxel's tetrahedra lie symmetric about its
            # centre): the lowest cell number wins, not the tree's order, which round-off in
            # the points (another partition's) can turn
            key = np.round(distance[~inside] * 1e9) * (len(self._centroids) + 1.0) + near[~inside]
            cell[~inside] = near[~inside][np.arange(len(key)), key.argmin(axis=1)]
            outside[~inside] = np.linalg.norm(y[~inside] - self._centroids[cell[~inside]], axis=1)
        lam = barycentric(y, self.points[self.tetrahedra[cell]])
        return cell, lam, outside

    def weights(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertex indices (n, 4), their weights (n, 4), distance outside): the values at y
        of a vertex field f are sum_j w_j f[index_j]."""
        cell, lam, outside = self.locate(y)
        return self.tetrahedra[cell], lam, outside


class SurfaceLocator:
    """Nearest points on a triangulated surface, through the triangles around its nearest
    vertices (exact where the triangles are small beside the points' distance to it)."""

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        self.triangles = np.asarray(triangles)
        self._tree, self._tree_of = cKDTree(points), np.asarray(points)
        order = np.argsort(self.triangles.ravel(), kind="stable")
        self._owner = order // 3  # triangles sorted by vertex
        self._start = np.searchsorted(self.triangles.ravel()[order], np.arange(len(points) + 1))

    def nearest(self, moved: np.ndarray, y: np.ndarray, k: int = 4):
        """(triangle (n,), barycentric (n, 3), the signed distance's gradient (n, 3; the outward
        normal at a face), signed distance (n, + outside)) of each point y to the surface whose vertices
        are at `moved`; the
        triangles tried are those around the k moved vertices nearest to y."""
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        if moved is not self._tree_of:  # (a tree of the moved vertices: they moved farther than they are apart)
            self._tree, self._tree_of = cKDTree(moved), moved
        _, near = self._tree.query(y, k=k)
        near = np.asarray(near).reshape(len(y), k).ravel()
        counts = self._start[near + 1] - self._start[near]
        point = np.repeat(np.repeat(np.arange(len(y)), k), counts)
        first = np.repeat(self._start[near], counts)
        offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        tri = self._owner[first + offset]
        corners = moved[self.triangles[tri]]
        q = closest_points_on_triangles(y[point], corners[:, 0], corners[:, 1], corners[:, 2])
        dist = np.linalg.norm(q - y[point], axis=1)
        order = np.lexsort((dist, point))  # by point, nearest first
        starts = np.flatnonzero(np.r_[True, np.diff(point[order]) != 0])
        pick = order[starts]
        triangle, closest, best = tri[pick], q[pick], dist[pick]
        a, b, c = (moved[self.triangles[triangle]][:, i] for i in range(3))
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        e1, e2, r = b - a, c - a, closest - a  # the closest point's coordinates in its triangle
        d11, d12, d22 = (np.einsum("ni,ni->n", u, v) for u, v in ((e1, e1), (e1, e2), (e2, e2)))
        r1, r2 = np.einsum("ni,ni->n", r, e1), np.einsum("ni,ni->n", r, e2)
        det = d11 * d22 - d12**2
        s, t = (d22 * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
        bary = np.stack([1.0 - s - t, s, t], axis=1)
        side = np.where(np.einsum("ni,ni->n", y - closest, normal) >= 0, 1.0, -1.0)
        # the signed distance's gradient: along y - closest off the surface (at an edge or a
        # corner that is not the face's normal), the normal on it
        off = best > 1e-9
        direction = normal.copy()
        direction[off] = side[off, None] * (y[off] - closest[off]) / best[off, None]
        return triangle, bary, direction, side * best
