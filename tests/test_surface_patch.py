"""atlas/surface_patch.py: a point-to-surface fit on the triangles near the points gives the
whole surface's nearest points, and a patch too small to hold them is caught, against brute
force over every triangle of a moved sphere."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from fenics_brainshift.atlas.surface_patch import MovingSurface
from fenics_brainshift.surfaces.triangles import closest_points_on_triangles

pytestmark = pytest.mark.usefixtures("serial_only")


def _sphere(n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """A sphere of radius 0.08 m, its n points on a Fibonacci spiral (triangles of even size):
    points (S, 3), triangles (T, 3) outward."""
    k = np.arange(n) + 0.5
    z, phi = 1 - 2 * k / n, np.pi * (1 + 5**0.5) * k
    points = 0.08 * np.c_[np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z]
    tri = ConvexHull(points).simplices
    a, b, c = (points[tri[:, i]] for i in range(3))
    inward = np.einsum("ni,ni->n", np.cross(b - a, c - a), a) < 0
    tri[inward] = tri[inward][:, [0, 2, 1]]
    return points, tri


def _brute(moved: np.ndarray, triangles: np.ndarray, y: np.ndarray) -> np.ndarray:
    a, b, c = (moved[triangles[:, i]] for i in range(3))
    return np.array(
        [np.linalg.norm(closest_points_on_triangles(np.broadcast_to(p, a.shape), a, b, c) - p, axis=1).min() for p in y]
    )


def _surface(seed: int = 0):
    points, triangles = _sphere()
    rng = np.random.default_rng(seed)
    z = points[:, 2:3] / 0.08
    modes = np.stack(  # a sag, a sideways shift, a bulge at the top: smooth, as a brain's modes are
        [np.c_[0 * z, 0 * z, -((z + 1) ** 2) * 4e-3], np.c_[5e-3 * (1 + z), 0 * z, 0 * z], points * (z > 0.5) * 0.1]
    ).astype(np.float32)
    reference = np.tensordot([0.5, 0.0, 0.0], modes.astype(float), axes=1)
    return MovingSurface(points, triangles, modes, reference), rng


def test_a_patch_fit_finds_the_whole_surfaces_nearest_points():
    surface, rng = _surface()
    c = np.array([0.8, 0.6, 0.3])
    moved = surface.points + np.tensordot(c, surface.modes.astype(float), axes=1)
    top = np.flatnonzero(surface.points[:, 2] > 0.06)
    y = moved[rng.choice(top, 12, replace=False)] + rng.normal(0.0, 1.5e-3, (12, 3))
    patch = surface.patch(y, np.abs(surface.prior_distances(y)) + 5e-3)
    assert len(patch.vertices) < len(surface.points) / 4  # a patch, not the surface
    distance = patch.rows.rows(c, y)[3]
    assert np.allclose(np.abs(distance), _brute(moved, surface.triangles, y), atol=1e-9)
    whole = surface.fits(patch, c, y, distance)
    assert whole is not None and np.allclose(whole, moved - surface.points, atol=1e-8)  # (float32 modes)
    assert np.allclose(np.abs(surface.distances(whole, y)), _brute(moved, surface.triangles, y), atol=1e-9)


def test_a_patch_that_misses_the_nearest_triangle_is_caught():
    surface, rng = _surface(1)
    c = np.array([0.5, 3.0, 0.0])  # 30 mm sideways at the top: the nearest triangles moved far from the prior's
    moved = surface.points + np.tensordot(c, surface.modes.astype(float), axes=1)
    top = np.flatnonzero(surface.points[:, 2] > 0.07)
    y = moved[rng.choice(top, 6, replace=False)]
    patch = surface.patch(y, np.full(len(y), 2e-3))
    distance = patch.rows.rows(c, y)[3]
    assert np.any(np.abs(distance) > _brute(moved, surface.triangles, y) + 1e-4)  # the patch alone is wrong ...
    assert surface.fits(patch, c, y, distance) is None  # ... and says so
    wide = surface.patch(y, np.full(len(y), 1.0))
    distance = wide.rows.rows(c, y)[3]
    assert surface.fits(wide, c, y, distance) is not None
