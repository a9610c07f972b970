"""The skull's distance field (surfaces/skull.py) is exact on closed surfaces whose triangles
differ in size and shape: a fine wall beside a floor of long strips (a decimated scan), a dome
closed by a flat cap of long slivers. Distances and sides are checked against the box's
closed form, against every triangle at once (brute force), and against the winding number
(the solid angle the surface subtends: 1 inside, 0 outside), which knows nothing of nearest
triangles."""

from __future__ import annotations

import numpy as np
import pytest

from fenics_brainshift.data import MESHES
from fenics_brainshift.surfaces.files import read_surface
from fenics_brainshift.surfaces.skull import RigidSkull
from fenics_brainshift.surfaces.triangles import closed_surface_problem, closest_points_on_triangles, outward

W, D, H = 0.15, 0.15, 0.10  # a skull-sized box, m


def lattice_box(xs, ys, zs) -> tuple[np.ndarray, np.ndarray]:
    """The boundary of the box xs x ys x zs (sorted coordinates) triangulated on that lattice:
    every face a structured grid, so faces meeting at an edge share its vertices (conforming)."""
    index: dict = {}
    axes = (xs, ys, zs)
    triangles = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for end in (0, len(axes[a]) - 1):
            for i in range(len(axes[b]) - 1):
                for j in range(len(axes[c]) - 1):
                    quad = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = [0.0, 0.0, 0.0]
                        p[a], p[b], p[c] = axes[a][end], axes[b][i + di], axes[c][j + dj]
                        quad.append(index.setdefault(tuple(p), len(index)))
                    quad = quad if end else quad[::-1]  # b x c is +a: out of the far face
                    triangles += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    points = np.array(sorted(index, key=index.get), dtype=float)
    triangles = np.array(triangles)
    return points, outward(points, triangles)


def strip_floor_box() -> tuple[np.ndarray, np.ndarray]:
    """Walls y = 0 and y = D meshed finely (40 x 40 cells); the floor, the top and the walls
    x = 0, x = W are strips D long, 3.75 or 2.5 mm wide (a 40-fold size ratio)."""
    return lattice_box(np.linspace(0.0, W, 41), [0.0, D], np.linspace(0.0, H, 41))


def capped_dome(radius: float = 0.08, rings: int = 16, segments: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The upper half of a sphere (rings x segments, a fan at the pole) closed at the equator by
    a flat cap: a fan of long slivers from the centre (80 mm by 8 mm at the rim)."""
    theta = np.linspace(0.0, 0.5 * np.pi, rings + 1)[1:]  # from the pole's first ring to the equator
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = (
        np.stack(
            [
                np.outer(np.sin(theta), np.cos(phi)),
                np.outer(np.sin(theta), np.sin(phi)),
                np.outer(np.cos(theta), np.ones_like(phi)),
            ],
            axis=-1,
        ).reshape(-1, 3)
        * radius
    )
    pole, centre = len(ring), len(ring) + 1
    points = np.vstack([ring, [[0.0, 0.0, radius], [0.0, 0.0, 0.0]]])
    k = np.arange(segments)
    at = lambda r, s: r * segments + s % segments  # noqa: E731
    triangles = [np.stack([np.full(segments, pole), at(0, k), at(0, k + 1)], axis=1)]
    for r in range(rings - 1):
        triangles += [
            np.stack([at(r, k), at(r + 1, k), at(r + 1, k + 1)], axis=1),
            np.stack([at(r, k), at(r + 1, k + 1), at(r, k + 1)], axis=1),
        ]
    triangles.append(np.stack([np.full(segments, centre), at(rings - 1, k + 1), at(rings - 1, k)], axis=1))
    triangles = np.concatenate(triangles)
    return points, outward(points, triangles)


def brute_force(points, triangles, y) -> np.ndarray:
    """The distance from each point y to the nearest of all the triangles."""
    tri = points[triangles]
    best = np.full(len(y), np.inf)
    for start in range(0, len(tri), 500):
        t = tri[start : start + 500]
        q = closest_points_on_triangles(y[:, None], t[None, :, 0], t[None, :, 1], t[None, :, 2])
        best = np.minimum(best, np.linalg.norm(q - y[:, None], axis=2).min(axis=1))
    return best


def winding_number(points, triangles, y) -> np.ndarray:
    """The solid angle the closed surface subtends at each point y over 4 pi (Van Oosterom and
    Strackee's formula for each triangle): 1 inside, 0 outside."""
    tri = points[triangles]
    out = np.zeros(len(y))
    for start in range(0, len(y), 100):
        a, b, c = (tri[None, :, i] - y[start : start + 100, None] for i in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
        dot = lambda u, v: np.einsum("nti,nti->nt", u, v)  # noqa: E731
        omega = 2 * np.arctan2(dot(a, np.cross(b, c)), la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la)
        out[start : start + 100] = omega.sum(axis=1) / (4 * np.pi)
    return out


def test_the_surfaces_are_closed_conforming_and_strongly_non_uniform():
    for points, triangles in (strip_floor_box(), capped_dome()):
        assert closed_surface_problem(triangles) is None
        directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
        assert len(np.unique(directed, axis=0)) == len(directed)  # each edge once each way: oriented
        tri = points[triangles]
        size = np.linalg.norm(tri - tri.mean(axis=1)[:, None], axis=2).max(axis=1)
        assert size.max() > 8 * np.median(size)


def test_a_box_with_a_floor_of_strips_against_its_closed_form_and_brute_force():
    """Points anywhere in and around the box, among them 3 mm past the floor next to the fine
    walls (where the 16 nearest centroids are all the walls')."""
    points, triangles = strip_floor_box()
    rng = np.random.default_rng(26)
    lo, hi = np.zeros(3), np.array([W, D, H])
    y = rng.uniform(lo - 0.01, hi + 0.01, size=(1500, 3))
    y[:500] = rng.uniform([0.0, 0.0, -0.003], [W, D, -0.003], size=(500, 3))  # 3 mm past the floor
    y[:250, 1] = rng.uniform(0.0, 0.03, 250)  # ... within 3 cm of the wall y = 0
    distance, side, direction = RigidSkull(points, triangles).distance(y)
    outside = np.any((y < lo) | (y > hi), axis=1)
    clamped = np.clip(y, lo, hi)
    exact = np.where(outside, np.linalg.norm(y - clamped, axis=1), np.minimum(y - lo, hi - y).min(axis=1))
    np.testing.assert_allclose(distance[:500], 0.003, rtol=0, atol=1e-12)
    np.testing.assert_allclose(distance, exact, rtol=0, atol=1e-12)
    np.testing.assert_allclose(distance, brute_force(points, triangles, y), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(side, np.where(outside, 1.0, -1.0))
    # outside, the direction is from the box's nearest point (a face, edge or corner) to y
    np.testing.assert_allclose(direction[outside], ((y - clamped) / exact[:, None])[outside], atol=1e-9)


def test_a_dome_closed_by_a_flat_cap_of_slivers_against_brute_force_and_the_winding_number():
    points, triangles = capped_dome()
    rng = np.random.default_rng(14)
    y = rng.uniform([-0.09, -0.09, -0.01], [0.09, 0.09, 0.09], size=(1200, 3))
    r = rng.uniform(0.06, 0.085, 400)  # 3 mm past the cap, most of them near the rim
    a = rng.uniform(0.0, 2 * np.pi, 400)
    y[:400] = np.stack([r * np.cos(a), r * np.sin(a), np.full(400, -0.003)], axis=1)
    distance, side, _ = RigidSkull(points, triangles).distance(y)
    np.testing.assert_allclose(distance, brute_force(points, triangles, y), rtol=0, atol=1e-15)
    w = winding_number(points, triangles, y)
    assert np.all(np.abs(w - np.round(w)) < 1e-6)  # no point on the surface
    np.testing.assert_array_equal(side, np.where(w > 0.5, -1.0, 1.0))
    under_cap = np.hypot(y[:400, 0], y[:400, 1]) < 0.08 * np.cos(np.pi / 64)  # under the cap itself
    np.testing.assert_allclose(distance[:400][under_cap], 0.003, rtol=0, atol=1e-12)


def test_the_bundled_brain_surface_against_brute_force():
    """A real, folded surface (the bundled brain's, 29652 triangles) at points inside, near
    it and outside."""
    points, triangles = read_surface(MESHES / "mni152_brain_surface.ply", 1e-3)
    triangles = outward(points, triangles)
    rng = np.random.default_rng(5)
    centre = points.mean(axis=0)
    y = centre + (points[rng.integers(0, len(points), 300)] - centre) * rng.uniform(0.0, 1.1, 300)[:, None]
    distance, side, _ = RigidSkull(points, triangles).distance(y)
    np.testing.assert_allclose(distance, brute_force(points, triangles, y), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(side, np.where(winding_number(points, triangles, y) > 0.5, -1.0, 1.0))


@pytest.mark.parametrize("n", [1, 7, 8, 9, 100])
def test_any_number_of_triangles(n):
    """Leaves are only partly filled where the count is not 8 times a power of 2: a triangle
    fan's distances still agree with brute force (an open surface: the distance only)."""
    rng = np.random.default_rng(n)
    points = rng.normal(size=(n + 2, 3))
    triangles = np.stack([np.zeros(n, int), np.arange(1, n + 1), np.arange(2, n + 2)], axis=1)
    y = rng.normal(size=(200, 3))
    np.testing.assert_allclose(
        RigidSkull(points, triangles).distance(y)[0], brute_force(points, triangles, y), rtol=0, atol=1e-15
    )


def test_over_a_face_next_to_its_edge_the_direction_is_the_face_normal():
    """Points over one of two coplanar triangles, next to the edge they share, whose ends are
    single-precision values (an STL's): the neighbour ties to round-off and its nearest point
    lies on the edge, which turns the direction by (distance aside) / (height) and puts a
    convex edge's turning into the contact's tangent (Newton went linear on a floor). Every
    direction is the plane's normal, to round-off."""
    corners = np.array([[-0.1, -0.1, 0.0], [0.15, -0.1, 0.0], [0.15, 0.15, 0.0], [-0.1, 0.15, 0.0]], np.float32)
    floor = np.vstack([corners, corners + [0.0, 0.0, 0.2]]).astype(float)
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]]
    triangles = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    rng = np.random.default_rng(2)
    t = rng.uniform(0.0, 0.05, 400)
    y = np.stack([t, t + rng.uniform(-1e-12, 1e-12, 400), -rng.uniform(1e-5, 2e-4, 400)], axis=1)  # past the floor
    _, side, direction = RigidSkull(floor, triangles).distance(y)
    assert np.all(side == 1.0)
    np.testing.assert_allclose(direction, np.tile([0.0, 0.0, -1.0], (400, 1)), rtol=0, atol=1e-10)


@pytest.mark.parametrize("far", [1e3, 1e8, 1.25e11])
def test_a_point_far_outside_is_outside(far):
    """A diverged iterate (a body free to translate, 1e11 m out) is past the skull, not inside:
    every face of a small body is nearly as far, and a tie to within the distance's 1e-9 made
    the farthest face's plane decide (it said inside: the run reported no contact)."""
    points, triangles = lattice_box(*(np.linspace(0.0, s, 4) for s in (W, D, H)))
    skull = RigidSkull(points, triangles)
    rng = np.random.default_rng(7)
    directions = rng.normal(size=(50, 3))
    y = np.array([W, D, H]) / 2 + far * directions / np.linalg.norm(directions, axis=1)[:, None]
    _, side, _ = skull.distance(y)
    assert np.all(side == 1.0)
    assert np.all(winding_number(points, triangles, y) < 0.5)


def test_a_point_the_box_tree_leaves_without_candidates_keeps_its_own_distance(monkeypatch):
    """Far out the box tree's rounding can leave a point no candidate triangle (seen on two
    ranks: 642 distances for 643 points, a crash): it then takes its first triangle's
    distance, and every other point keeps its own (against brute force)."""
    from fenics_brainshift.surfaces import skull as skull_module

    points, triangles = strip_floor_box()
    skull = RigidSkull(points, triangles)
    y = np.random.default_rng(3).uniform(-0.05, 0.2, size=(40, 3))
    within = skull_module._BoxTree.within
    dropped = 17

    def losing_one(tree, y_, bound):
        point, leaf = within(tree, y_, bound)  # (`dropped` read when called)
        return point[point != dropped], leaf[point != dropped]

    monkeypatch.setattr(skull_module._BoxTree, "within", losing_one)
    distance, side, _ = skull.distance(y)
    assert distance.shape == (40,) and np.isfinite(distance).all()
    others = np.arange(40) != dropped
    np.testing.assert_allclose(distance[others], brute_force(points, triangles, y)[others], rtol=0, atol=1e-15)
    assert distance[dropped] >= brute_force(points, triangles, y[[dropped]])[0] - 1e-15
    dropped = 0  # a single point left without candidates (no candidate pair at all)
    alone, _, _ = skull.distance(y[:1])
    assert alone.shape == (1,) and alone[0] >= brute_force(points, triangles, y[:1])[0] - 1e-15


def test_far_points_are_measured_a_few_at_a_time():
    """A diverging iterate 1e6 m out has nearly every triangle within its first bound: 5262
    such nodes against the resection's 10k-triangle gap skull asked for 57 million candidate
    pairs (1.3 GB an array; the run was killed for memory). Far points go a few at a time:
    the same distances as brute force, mixed with near ones, in a small part of that memory."""
    import tracemalloc

    points, triangles = read_surface(MESHES / "mni152_brain_surface.ply", 1e-3)
    triangles = outward(points, triangles)
    skull = RigidSkull(points, triangles)
    rng = np.random.default_rng(11)
    directions = rng.normal(size=(400, 3))
    far = points.mean(axis=0) + 1e6 * directions / np.linalg.norm(directions, axis=1)[:, None]
    near = points[rng.integers(0, len(points), 100)] + rng.normal(scale=1e-3, size=(100, 3))
    y = np.vstack([far[:200], near, far[200:]])
    tracemalloc.start()
    distance, side, _ = skull.distance(y)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    check = np.r_[0:5, 200:300, 495:500]
    np.testing.assert_allclose(distance[check], brute_force(points, triangles, y[check]), rtol=1e-12, atol=1e-15)
    assert np.all(side[:200] == 1.0) and np.all(side[300:] == 1.0)
    # measured (tracemalloc): 30 MB a few at a time, 285 MB all at once (and it grows with the points)
    assert peak < 100e6, f"{peak / 1e6:.0f} MB"


def test_a_point_beyond_any_body_is_not_a_number_not_a_crash():
    """A diverging iterate 1e160 m out squared past float range and raised an IndexError (a
    traceback instead of the run's "no longer finite" guard): it is NaN, as an infinite one."""
    points, triangles = lattice_box(*(np.linspace(0.0, s, 4) for s in (W, D, H)))
    distance, side, direction = RigidSkull(points, triangles).distance(
        np.array([[1e160, 0.0, 0.0], [W / 2, D / 2, H / 2], [np.inf, 0.0, 0.0]])
    )
    assert np.isnan(distance[[0, 2]]).all() and np.isnan(direction[[0, 2]]).all()
    assert distance[1] == pytest.approx(min(W, D, H) / 2) and side[1] == -1.0
