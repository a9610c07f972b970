"""The surface points are measured against, as a point-to-surface update needs it: only the
part near the measured points moves with the weights.

A patient's fine surface has tens of thousands of vertices, and each round of the iterated
closest point moved all of them (every mode, every vertex) and rebuilt a tree of them, though
20 touches of a pointer only ever see the few hundred triangles under them. The surface is
kept once per atlas at the prior's state (its tree, its triangles by vertex); an update takes
the triangles within a radius of its points there, fits on those, and checks at the fitted
weights that no triangle left out could be nearer than the one found (else it takes a wider
patch and fits again), so the answer is the whole surface's (to the tolerance of the nearest
point's search, locate.SurfaceLocator).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..surfaces.triangles import closest_points_on_triangles
from .locate import SurfaceLocator
from .rows import SurfaceRows

PATCH_MARGIN = 3e-3  # m beyond each point's distance to the prior's surface (and an edge): the first patch
PATCH_TRIES = 4  # the radius doubles at most this many times before the whole surface is taken


class MovingSurface:
    """A triangulated surface (S vertices at rest, their modes (M, S, 3), float32 as stored)
    and its state at reference weights c_ref (the prior's)."""

    def __init__(
        self, points: np.ndarray, triangles: np.ndarray, modes: np.ndarray, reference: np.ndarray, by_vertex=None
    ):
        self.points, self.triangles, self.modes = points, np.asarray(triangles), modes
        self.reference = reference  # (S, 3) displacement at the prior's state
        self.at_reference = points + reference
        self.prior_locator = SurfaceLocator(self.at_reference, self.triangles)  # (its tree: of these positions)
        self._tree = cKDTree(self.at_reference)
        # two layouts: by mode (a combination of the few weights not 0 reads only their rows) and
        # by vertex (a patch's modes are then a few contiguous blocks: gathered from the first
        # layout they were most of a small update's time)
        self._flat = modes.reshape(len(modes), -1)
        self.by_vertex = np.ascontiguousarray(modes.transpose(1, 2, 0) if by_vertex is None else by_vertex)  # (S, 3, M)
        order = np.argsort(self.triangles.ravel(), kind="stable")
        self._owner = order // 3  # triangles sorted by corner, and where each vertex's begin
        self._start = np.searchsorted(self.triangles.ravel()[order], np.arange(len(points) + 1))
        corners = self.at_reference[self.triangles]
        self.longest_edge = float(np.sqrt(np.max(np.sum((corners - np.roll(corners, 1, axis=1)) ** 2, axis=2))))

    def displacement(self, c: np.ndarray) -> np.ndarray:
        """(S, 3) at weights c, over the weights that are not 0 (float32 products: 1e-7 of a shift)."""
        used = np.flatnonzero(c)
        if 4 * len(used) > len(c):  # (most of them: gathering the rows would copy most of the modes)
            return (c.astype(self._flat.dtype) @ self._flat).reshape(-1, 3).astype(np.float64)
        return (c[used].astype(self._flat.dtype) @ self._flat[used]).reshape(-1, 3).astype(np.float64)

    def displacement_at(self, vertices: np.ndarray, c: np.ndarray) -> np.ndarray:
        """(n, 3) at these vertices only, at weights c."""
        return self.by_vertex[vertices].astype(np.float64) @ c

    def distances(self, displacement: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """Signed distances (+ outside) of points to the whole surface moved by a displacement (S, 3)."""
        moved = self.points + displacement
        return SurfaceLocator(moved, self.triangles).nearest(moved, measured)[3]

    def prior_distances(self, measured: np.ndarray) -> np.ndarray:
        """Signed distances (+ outside) of points to the surface at the prior's state."""
        return self.prior_locator.nearest(self.at_reference, measured)[3]

    def patch(self, measured: np.ndarray, radius: np.ndarray) -> Patch:
        """The triangles with a corner within radius (n,) plus the longest edge of each point at
        the prior's state (so at least the triangle nearest each point there)."""
        hits = self._tree.query_ball_point(measured, radius + self.longest_edge)
        near = np.zeros(len(self.points), dtype=bool)
        for h in hits:
            near[h] = True
        chosen = np.flatnonzero(near[self.triangles].any(axis=1))
        vertices, local = np.unique(self.triangles[chosen], return_inverse=True)
        modes = self.by_vertex[vertices].astype(np.float64)
        return Patch(vertices, chosen, SurfaceRows(self.points[vertices], local.reshape(-1, 3), modes))

    def fits(self, patch: Patch, c: np.ndarray, measured: np.ndarray, distances: np.ndarray) -> np.ndarray | None:
        """The whole surface's displacement (S, 3) at weights c if no triangle outside the patch
        comes nearer a point than its distance found on the patch, else None. Each corner has
        moved from the prior's state by at most the largest shift of any, and a triangle's points
        lie within its longest edge of a corner: only triangles with a corner that near at the
        prior's state (the tree of those) can come nearer, and only those outside the patch are
        measured."""
        displacement = self.displacement(c)
        shift = float(np.sqrt(np.max(np.sum((displacement - self.reference) ** 2, axis=1), initial=0.0)))
        reach = np.abs(distances) + self.longest_edge + 3 * shift  # (an edge at c: at most the longest + 2 shifts)
        near = self._tree.query_ball_point(measured, reach)
        outside = np.ones(len(self.triangles), dtype=bool)
        outside[patch.triangles] = False
        moved = self.points + displacement
        for y, d, corners in zip(measured, distances, near):
            tri = self._around(np.asarray(corners, dtype=np.int64))
            tri = tri[outside[tri]]
            if not len(tri):
                continue
            a, b, e = (moved[self.triangles[tri, i]] for i in range(3))
            q = closest_points_on_triangles(np.broadcast_to(y, a.shape), a, b, e)
            if np.min(np.linalg.norm(q - y, axis=1)) < abs(d) * (1 - 1e-9):
                return None
        return displacement

    def _around(self, vertices: np.ndarray) -> np.ndarray:
        """The triangles with a corner among these vertices (each once)."""
        counts = self._start[vertices + 1] - self._start[vertices]
        first = np.repeat(self._start[vertices], counts)
        offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return np.unique(self._owner[first + offset])


class Patch:
    """The triangles of a MovingSurface near some points: their indices, their corners' and
    the point-to-surface rows over them (SurfaceRows, numbered locally)."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, rows: SurfaceRows):
        self.vertices, self.triangles, self.rows = vertices, triangles, rows
