"""A timing stand-in for an atlas at a finer resolution than can be built here: the modes of an
atlas carried onto its scene's mesh at a finer voxel (P1: each fine node's value from the coarse
cell holding it), with the fine mesh's own regulariser, boundary and gap skull. The update's time
depends on the number of points, modes and nodes, not on what the modes hold, so the update of
this atlas costs what the update of the real one would. Not an atlas to update anybody with:
its modes are the coarse atlas's, not the finer mesh's settled states (the 2 mm default atlas
takes about a day on one rank here: benchmarks/results/resolution.md).

    python benchmarks/finer_standin.py --atlas ATLAS --voxel 0.002 -o STANDIN

ATLAS: an atlas of a bundled scene or a prepared one (atlas.json's "scene" and "set"); STANDIN's
atlas.json says what it is ("standin_of": the coarse atlas's build, "standin_voxel"). Then time
it as any atlas: `python benchmarks/update_command.py --atlas STANDIN`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mpi4py import MPI  # noqa: E402

from fenics_brainshift import load_scene  # noqa: E402
from fenics_brainshift.atlas import store  # noqa: E402
from fenics_brainshift.atlas.boundary import boundary_triangles  # noqa: E402
from fenics_brainshift.atlas.locate import MeshLocator  # noqa: E402
from fenics_brainshift.outputs.vertices import GlobalVertices  # noqa: E402
from fenics_brainshift.runner.build import build_mesh  # noqa: E402


def carried(coarse: store.Atlas, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(modes (M, n, 3) float32, prior (n, 3)) of the coarse atlas at these points (P1)."""
    index, weight, _ = MeshLocator(coarse.points, coarse.tetrahedra).weights(points)
    modes = np.empty((len(coarse.vertex_modes), len(points), 3), dtype=np.float32)
    for k in range(len(modes)):  # (a mode at a time: the coarse modes stay mapped)
        modes[k] = np.einsum("nj,njd->nd", weight, coarse.vertex_modes[k].astype(np.float64)[index])
    return modes, np.einsum("nj,njd->nd", weight, coarse.prior_vertex[index])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", type=Path, required=True)
    parser.add_argument("--voxel", type=float, required=True, help="m: the finer mesh's voxel")
    parser.add_argument("-o", "--out", type=Path, required=True)
    options = parser.parse_args()
    start = time.perf_counter()
    coarse = store.read(options.atlas)
    sets = [s for s in coarse.info.get("set", []) if not s.startswith("mesh.voxel=")]
    sets.append(f"mesh.voxel={options.voxel:g}")
    scene = load_scene(coarse.info["scene"], [*sets, "time.mode=quasi-static"])  # (as the atlas loads it)
    vertices = GlobalVertices(build_mesh(scene, MPI.COMM_SELF))
    points, tetrahedra = vertices.points, vertices.tetrahedra
    modes, prior = carried(coarse, points)
    flat, n = modes.reshape(len(modes), -1), len(points)
    gram = np.zeros((len(modes), len(modes)))
    for begin in range(0, flat.shape[1], 1 << 18):  # (float64 a block of columns at a time)
        block = flat[:, begin : begin + (1 << 18)].astype(np.float64)
        gram += block @ block.T / n
    atlas = store.Atlas(
        points,
        tetrahedra,
        modes,
        prior,
        gram,
        np.array([m.astype(np.float64) @ prior.ravel() for m in flat]) / n,
        float(prior.ravel() @ prior.ravel() / n),
        coarse.scenarios,
    )
    if coarse.surface_points is not None:  # (the same fine surface: its modes are the coarse atlas's)
        atlas.surface_points, atlas.surface_triangles = coarse.surface_points, coarse.surface_triangles
        atlas.surface_modes, atlas.prior_surface = np.asarray(coarse.surface_modes), coarse.prior_surface
    if coarse.skull_triangles is not None:
        gap = scene.skull.gap if scene.skull is not None else coarse.skull_gap
        on, triangles = boundary_triangles(points, tetrahedra)
        atlas.skull_triangles, atlas.skull_gap = points[on][triangles], gap
    written_by_store = ("format", "mesh_id", "build_id", "modes", "nodes", "cells")
    atlas.info = {
        **{k: v for k, v in coarse.info.items() if k not in written_by_store},
        "set": sets,
        "standin_of": coarse.info.get("build_id"),
        "standin_voxel": options.voxel,
        "standin_note": "the coarse atlas's modes carried onto the finer mesh (P1): for timing, not for updates",
    }
    store.write(options.out, atlas)
    print(
        json.dumps(
            {
                "nodes": n,
                "cells": len(tetrahedra),
                "modes": len(modes),
                "boundary": len(atlas.boundary.vertices),
                "atlas_h5_mb": round((options.out / "atlas.h5").stat().st_size / 1e6),
                "seconds": round(time.perf_counter() - start, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
