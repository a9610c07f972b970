"""Where to measure next: the point of the exposed cortex whose measurement would most reduce
the uncertainty of the displacement at the targets.

The update's weights are Gaussian on the fit's face, covariance Sigma (atlas/posterior.py). A
touch of the cortex at vertex v measures the distance to the moved surface along its normal n:
one more row a = n . U_v (the modes at v), with the noise's variance s^2. After it the
covariance would be Sigma - Sigma a a' Sigma / (s^2 + a' Sigma a) whatever the touch reads
(a linear Gaussian model's posterior covariance does not depend on the value measured), so
the targets' summed variance tr(T Sigma T') falls by |T Sigma a|^2 / (s^2 + a' Sigma a), T
the modes at the targets. Every candidate's reduction is one product with T Sigma; the best
is suggested, with the targets' RMS spread before and as expected after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..atlas import posterior
from ..atlas.prepared import locator, moving_surface

EXPOSED_RADIUS = 35e-3  # m around the craniotomy's centre: the cortex a pointer can touch
FACING_UP = 0.3  # the outward normal's cosine with "up" (against gravity) of a touchable vertex
SPACING = 2e-3  # m: candidates thinned to one per cell of this size


@dataclass
class Suggestion:
    position: np.ndarray  # (3,) m, on the updated surface
    vertex: int  # of the surface the update measures against
    spread: float  # m: the targets' RMS spread now
    expected: float  # m: ... and as expected after a touch there

    @property
    def reduction(self) -> float:
        return 1.0 - self.expected / self.spread if self.spread > 0 else 0.0


def exposed_cortex(atlas, centre: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, their outward normals): the surface's vertices a pointer can touch, within
    EXPOSED_RADIUS of the craniotomy's centre, facing up at the prior's state, thinned to one
    per SPACING cell."""
    surface = moving_surface(atlas)
    at = surface.at_reference
    normals = vertex_normals(at, surface.triangles)
    near = np.flatnonzero((np.linalg.norm(at - centre, axis=1) < EXPOSED_RADIUS) & (normals @ up > FACING_UP))
    if len(near):
        _, first = np.unique(np.floor(at[near] / SPACING).astype(np.int64), axis=0, return_index=True)
        near = near[np.sort(first)]
    return near, normals[near]


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit outward normals at the vertices (the triangles' area-weighted)."""
    a, b, c = (points[triangles[:, i]] for i in range(3))
    face = np.cross(b - a, c - a)
    corners = triangles.ravel()
    normals = np.stack(
        [np.bincount(corners, np.repeat(face[:, d], 3), minlength=len(points)) for d in range(3)], axis=1
    )  # (a sum per vertex: bincount, much faster than np.add.at)
    return normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]


def suggest(atlas, result, targets: np.ndarray, candidates, noise: float) -> Suggestion | None:
    """The candidate vertex whose touch would most reduce the spread at the targets (m, (n, 3)),
    from an update's result (its problem and weights); candidates: exposed_cortex's (vertices,
    normals). None when the weights are fixed."""
    candidates, normals = candidates
    if result.problem is None or not len(candidates) or not len(targets):
        return None
    problem, c = result.problem, result.weights
    free, sigma, dimension = posterior.covariance(problem, result.alpha, c)
    if not dimension:
        return None
    sigma = 0.5 * (sigma + sigma.T) * posterior.scale(problem, c, dimension)
    index, weight, _ = locator(atlas).weights(targets)
    modes = atlas.vertex_modes
    T = np.einsum("nj,mnjd->ndm", weight, modes[:, index, :].astype(np.float64)).reshape(-1, len(modes))[:, free]
    surface = moving_surface(atlas)
    moved = surface.points[candidates] + surface.displacement_at(candidates, c)
    a = np.einsum("vd,vdm->vm", normals, surface.by_vertex[candidates].astype(np.float64))[:, free]
    B = T @ sigma  # (3 targets, free)
    before = float(np.sum(B * T))
    gain = np.sum((a @ B.T) ** 2, axis=1) / (noise**2 + np.einsum("vf,fg,vg->v", a, sigma, a))
    best = int(np.argmax(gain))
    n = len(targets)
    return Suggestion(
        moved[best],
        int(candidates[best]),
        float(np.sqrt(max(before, 0.0) / n)),
        float(np.sqrt(max(before - gain[best], 0.0) / n)),
    )
