"""The rigid skull as a distance field: phi(y) >= 0 where a brain point y may be, phi < 0 past
the skull, and grad phi (unit) pointing away from the skull wall.

Two shapes: a closed triangulated surface (phi = the distance to it, positive inside), or the
brain's own reference surface dilated by a gap (phi = gap - the signed distance to that
surface, positive inside the brain; exact for every point of the dilated body, whose
boundary is the set at distance gap). Distances are exact: the point-to-triangle distance to
the nearest triangle of the whole surface. A first bound is the distance to the triangle of a
near centroid (scipy's KD-tree); then only triangles that may be nearer are measured:
those in a leaf of a tree of bounding boxes within the bound, whose disk (in their plane,
about their centroid, holding them) is within it too. Triangles of any sizes and shapes, such
as a fine wall beside a floor of long strips, are measured alike. The side is that of the
nearest triangle's outward normal.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .triangles import closest_points_on_triangles

LEAF = 8  # triangles per leaf box (fewer: more boxes to test, more: more triangles to test)
FAR = 0.05  # a point farther than this fraction of the surface's size from it is "far" ...
FAR_CHUNK = 32  # ... and far points are measured this many at a time (their candidates: most triangles)
KD_EPS = 1.0  # the first bound's centroid need not be the nearest: within twice its distance is found far quicker


def _box_distance(y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The distance from each point y to its box [lo, hi] (rows paired; inf for an empty box,
    lo = inf, hi = -inf)."""
    d = np.maximum(np.maximum(lo - y, y - hi), 0.0)
    return np.sqrt(np.einsum("ni,ni->n", d, d))


class _BoxTree:
    """A complete binary tree of axis-aligned boxes over triangles (T, 3, 3), heap-ordered
    (node i has children 2i + 1 and 2i + 2): each node's triangles are split in halves by
    their centroids along the longest side of the centroids' extent; the 2^depth leaves hold
    LEAF slots each (-1: empty, where T is not LEAF times a power of 2)."""

    def __init__(self, tri: np.ndarray):
        self.depth = max(0, int(np.ceil(np.log2(max(len(tri) / LEAF, 1.0)))))
        order = np.full(2**self.depth * LEAF, -1)
        order[: len(tri)] = np.arange(len(tri))
        centroid = np.vstack([tri.mean(axis=1), np.full((1, 3), np.inf)])  # row -1: an empty slot
        for level in range(self.depth):  # sort each node's slots along its axis: halves are its children
            rows = order.reshape(2**level, -1)
            c = centroid[rows]
            valid = (rows >= 0)[..., None]
            extent = np.where(valid, c, -np.inf).max(axis=1) - np.where(valid, c, np.inf).min(axis=1)
            key = np.take_along_axis(c, np.argmax(extent, axis=1)[:, None, None], axis=2)[..., 0]
            order = np.take_along_axis(rows, np.argsort(key, axis=1, kind="stable"), axis=1).ravel()
        self.slots = order.reshape(-1, LEAF)
        lo = np.vstack([tri.min(axis=1), np.full((1, 3), np.inf)])[self.slots].min(axis=1)
        hi = np.vstack([tri.max(axis=1), np.full((1, 3), -np.inf)])[self.slots].max(axis=1)
        los, his = [lo], [hi]
        while len(lo) > 1:  # the parents' boxes, level by level up to the root
            lo, hi = lo.reshape(-1, 2, 3).min(axis=1), hi.reshape(-1, 2, 3).max(axis=1)
            los.append(lo)
            his.append(hi)
        self.lo, self.hi = np.vstack(los[::-1]), np.vstack(his[::-1])
        self.first_leaf = 2**self.depth - 1

    def within(self, y: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(points, leaves), sorted by point: every leaf whose box is within bound (per point)
        of the point, down from the root."""
        point, node = np.arange(len(y)), np.zeros(len(y), dtype=np.int64)
        for _ in range(self.depth):
            point, node = np.repeat(point, 2), (2 * node[:, None] + [1, 2]).ravel()
            keep = _box_distance(y[point], self.lo[node], self.hi[node]) <= bound[point]
            point, node = point[keep], node[keep]
        return point, node - self.first_leaf


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
        self._centroids = tri.mean(axis=1)
        self._radii = np.linalg.norm(tri - self._centroids[:, None], axis=2).max(axis=1)
        self._kd = cKDTree(self._centroids)
        self._tree = _BoxTree(tri)
        # round-off allowance of the bounds: no triangle tied for nearest is left out
        self._slack = 1e-12 * (1.0 + np.abs(tri).max(initial=0.0))
        self._size = float(np.ptp(tri.reshape(-1, 3), axis=0).max(initial=0.0))

    def _disk_distance(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """A lower bound of the distance from each point p to its triangle: to the disk in the
        triangle's plane, about its centroid, through its farthest vertex (to the ball, for a
        triangle of no area: its normal is NaN)."""
        v = p - self._centroids[triangle]
        squared = np.einsum("ni,ni->n", v, v)
        height = np.einsum("ni,ni->n", v, self.normals[triangle])
        across = np.sqrt(np.maximum(squared - height**2, 0.0))
        disk = np.sqrt(height**2 + np.maximum(across - self._radii[triangle], 0.0) ** 2)
        return np.where(np.isnan(disk), np.maximum(np.sqrt(squared) - self._radii[triangle], 0.0), disk)

    def distance(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(unsigned distance, side +1 outside / -1 inside, outward unit direction from the
        surface to y (the nearest triangle's normal where y is on the surface)) of every point;
        NaN for a point not finite or beyond 1e100 m (a diverged iterate)."""
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        finite = np.isfinite(y).all(axis=1) & (np.abs(y).max(axis=1, initial=0.0) < 1e100)  # (squares overflow)
        if not finite.all():  # a diverged iterate: NaN for it, so that its residual is not finite either
            out = (np.full(len(y), np.nan), np.full(len(y), np.nan), np.full((len(y), 3), np.nan))
            for whole, part in zip(out, self.distance(y[finite])):
                whole[finite] = part
            return out
        if len(y) == 0:
            return np.zeros(0), np.zeros(0), np.zeros((0, 3))
        _, first = self._kd.query(y, eps=KD_EPS)  # a bound: the triangle of a near centroid
        tri = self.triangles[first]
        bound = np.linalg.norm(closest_points_on_triangles(y, tri[:, 0], tri[:, 1], tri[:, 2]) - y, axis=1)
        bound = bound * (1 + 1e-9) + self._slack
        far = bound > FAR * self._size
        if not far.any():
            return self._nearest(y, first, bound)
        # a point far from the surface has most triangles within its bound: a few such points at
        # a time (a diverging iterate 1e6 m out took every triangle for each of 5262 nodes: 57
        # million pairs, the machine's memory)
        out = (np.empty(len(y)), np.empty(len(y)), np.empty((len(y), 3)))
        groups = [np.flatnonzero(~far)] + np.array_split(np.flatnonzero(far), -(-int(far.sum()) // FAR_CHUNK))
        for group in groups:
            if len(group):
                for whole, part in zip(out, self._nearest(y[group], first[group], bound[group])):
                    whole[group] = part
        return out

    def _nearest(
        self, y: np.ndarray, first: np.ndarray, bound: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """distance's answer for points y, each with a triangle ``first`` within ``bound``."""
        point, leaf = self._tree.within(y, bound)
        slots = self._tree.slots[leaf]
        full = slots >= 0
        point, triangle = np.repeat(point, LEAF)[full.ravel()], slots[full]
        keep = (self._disk_distance(y[point], triangle) <= bound[point]) | (triangle == first[point])
        point, triangle = point[keep], triangle[keep]  # still sorted by point; each has its first
        if len(point) == 0 or np.count_nonzero(np.r_[True, point[1:] != point[:-1]]) != len(y):  # (_with_first)
            point, triangle = _with_first(point, triangle, first)
        tri = self.triangles[triangle]
        q = closest_points_on_triangles(y[point], tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.linalg.norm(q - y[point], axis=1)
        starts = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
        best = np.minimum.reduceat(dist, starts)
        # the side: of the nearest triangle's plane; a point nearest to an edge or corner takes
        # the candidate whose plane it is farthest from (on a convex corner all say "outside");
        # of equals, the one it lies straightest over: next to a face's edge, the neighbour ties
        # to round-off, and the direction from its point on the edge would turn as if at one
        gap = y[point] - q
        offsets = np.einsum("ni,ni->n", gap, self.normals[triangle])
        # tied: equal to round-off. Relative to the distance near the surface; far from it
        # (a diverged iterate 1e11 m out) relative to the surface's size, or every face of a
        # small body would tie and the farthest plane's side win: "inside"
        slack = 1e-9 * np.minimum(best, self._size) + 1e-15 + 1e-14 * np.linalg.norm(y, axis=1)
        tied = dist <= best[point] + slack[point]
        aside = np.zeros(len(point))
        aside[tied] = np.linalg.norm(gap[tied] - offsets[tied, None] * self.normals[triangle[tied]], axis=1)
        strongest = np.lexsort((aside, -np.where(tied, np.abs(offsets), -1.0), point))[starts]
        side = np.where(offsets[strongest] >= 0, 1.0, -1.0)
        closest = q[strongest]
        on_surface = best <= 1e-12 * (1.0 + np.abs(y).max(initial=0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            direction = side[:, None] * (y - closest) / best[:, None]
        direction = np.where(on_surface[:, None], self.normals[triangle[strongest]], direction)
        return best, side, direction

    def phi(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(phi (n,), unit grad phi (n, 3)): the room left before the skull, and the direction
        that increases it (away from the wall)."""
        dist, side, outward_direction = self.distance(y)
        if self.gap is None:  # inside the skull surface: phi = +distance
            return -side * dist, -outward_direction
        return self.gap - side * dist, -outward_direction  # gap - the signed distance to the brain


def _with_first(point: np.ndarray, triangle: np.ndarray, first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The candidate pairs (sorted by point) with each point's first triangle added where the
    box tree left the point none: far from the surface (a diverged iterate, 1e8 m out) the
    box's distance and the bound round differently, and a point without candidates shifted
    every later point's distance onto its neighbour (a crash on two ranks: 642 distances for
    643 points)."""
    missing = np.setdiff1d(np.arange(len(first)), point)
    point, triangle = np.concatenate([point, missing]), np.concatenate([triangle, first[missing]])
    order = np.argsort(point, kind="stable")
    return point[order], triangle[order]
