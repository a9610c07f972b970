"""The skull's distance query: the exact one (surfaces/skull.py) against the query it replaced
(the 16 triangles with the nearest centroids), timed in the same run on the same points.

    .venv/bin/python benchmarks/skull_distance.py     # writes benchmarks/results/skull_distance.md

Surfaces: the bundled brain surface (the gap and label skulls are of this kind), a dome closed
by a flat cap of slivers and a box with a floor of long strips (tests/test_skull_distance.py:
the surfaces where the old query was wrong). 20,000 points per set; each time the minimum of
7 interleaved repeats; "wrong" counts the points where the old query's distance or side
differs from the exact one.
"""

from __future__ import annotations

import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_skull_distance import capped_dome, strip_floor_box  # noqa: E402  (the tests' surfaces)

from fenics_brainshift.surfaces.files import read_surface  # noqa: E402
from fenics_brainshift.surfaces.skull import RigidSkull  # noqa: E402
from fenics_brainshift.surfaces.triangles import closest_points_on_triangles, outward  # noqa: E402

N, REPEATS = 20000, 7


class NearestCentroids(RigidSkull):
    """The old query, as the baseline: the 16 triangles whose centroids are nearest."""

    def __init__(self, points, triangles):
        super().__init__(points, triangles)
        self._centroids = cKDTree(self.triangles.mean(axis=1))

    def distance(self, y):
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        k = min(16, len(self.triangles))
        near = self._centroids.query(y, k=k)[1].reshape(len(y), k)
        tri = self.triangles[near]
        q = closest_points_on_triangles(y[:, None, :], tri[..., 0, :], tri[..., 1, :], tri[..., 2, :])
        dist = np.linalg.norm(q - y[:, None, :], axis=2)
        rows = np.arange(len(y))
        best = dist[rows, np.argmin(dist, axis=1)]
        offsets = np.einsum("nki,nki->nk", y[:, None, :] - q, self.normals[near])
        tied = dist <= best[:, None] * (1 + 1e-9) + 1e-15
        strongest = np.where(tied, np.abs(offsets), -1.0).argmax(axis=1)
        side = np.where(offsets[rows, strongest] >= 0, 1.0, -1.0)
        return best, side, None


def point_sets(points, rng) -> dict:
    """Points inside a closed surface: touching it, within 10 mm of it, anywhere."""
    centre = points.mean(axis=0)
    at = points[rng.integers(0, len(points), N)]
    inward = (centre - at) / np.linalg.norm(centre - at, axis=1)[:, None]
    return {
        "touching (0-0.1 mm in)": at + inward * rng.uniform(0, 1e-4, N)[:, None],
        "0-10 mm in": at + inward * rng.uniform(0, 0.01, N)[:, None],
        "anywhere inside": centre + (at - centre) * rng.uniform(0, 1, N)[:, None],
    }


def main() -> int:
    rng = np.random.default_rng(0)
    brain = read_surface(ROOT / "meshes" / "mni152_brain_surface.ply", 1e-3)
    surfaces = {
        "bundled brain surface": (brain[0], outward(*brain)),
        "dome with a capped floor": capped_dome(),
        "box with a floor of strips": strip_floor_box(),
    }
    rows = []
    for name, (points, triangles) in surfaces.items():
        exact, old = RigidSkull(points, triangles), NearestCentroids(points, triangles)
        for label, y in point_sets(points, rng).items():
            seconds = {"old": [], "exact": []}
            for _ in range(REPEATS):
                for key, skull in (("old", old), ("exact", exact)):
                    t0 = time.perf_counter()
                    d, side, _ = skull.distance(y)
                    seconds[key].append(time.perf_counter() - t0)
                    if key == "old":
                        d_old, side_old = d, side
                    else:
                        d_exact, side_exact = d, side
            wrong = int(np.sum((np.abs(d_old - d_exact) > 1e-12) | (side_old != side_exact)))
            t_old, t_exact = min(seconds["old"]), min(seconds["exact"])
            rows.append(
                (f"{name} ({len(triangles)} triangles)", label, t_old * 1e3, t_exact * 1e3, t_exact / t_old, wrong)
            )
            print(
                f"{rows[-1][0]:45s} {label:24s} old {t_old * 1e3:6.0f} ms  exact {t_exact * 1e3:6.0f} ms  "
                f"ratio {t_exact / t_old:.2f}  wrong {wrong}",
                flush=True,
            )
    lines = [
        "# The skull's distance query: exact against the 16 nearest centroids",
        "",
        f"`.venv/bin/python benchmarks/skull_distance.py`, {platform.processor() or platform.machine()}, one core; "
        f"{N} points a set, the minimum of {REPEATS} interleaved repeats.",
        "",
        "| surface | points | old (ms) | exact (ms) | exact / old | points the old query got wrong |",
        "|---|---|---:|---:|---:|---:|",
    ]
    lines += [f"| {s} | {p} | {a:.0f} | {b:.0f} | {r:.2f} | {w} |" for s, p, a, b, r, w in rows]
    out = ROOT / "benchmarks" / "results" / "skull_distance.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
