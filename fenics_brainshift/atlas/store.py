"""An atlas on disk: ATLAS/atlas.h5 (the arrays) and ATLAS/atlas.json (the index a person
reads: the scene, the scenarios, the timings). Written by rank 0 through temporary files
renamed into place, so a killed build leaves no atlas that looks whole.

atlas.h5:
  mesh/points (N, 3) m, mesh/tetrahedra (C, 4), mesh/surface_vertices (B,)
  modes/vertex (M, N, 3) float32, modes/surface (M, S, 3) float32: the settled states of the
      family (first) and the swelling perturbation modes (last), m
  prior/vertex (N, 3), prior/surface (S, 3): the scene's own settled state
  regulariser/gram (M, M), regulariser/cross (M,), regulariser/prior_square: the mean over
      the vertices of |sum c_k u_k - u_prior|^2 = c.G.c - 2 c.h + p (m^2)
  surface/points (S, 3), surface/triangles: the fine surface (absent: the mesh's boundary)
  skull/triangles (T, 3, 3), attribute gap: the skull the combination must respect
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError

FORMAT = 1
STAGES = "stages"  # the folder of a resection's stages, each an atlas of its own


@dataclass
class Atlas:
    """The modes of an atlas at the mesh's vertices (m, RAS), the prior (the scene's own
    settled state), the Gram matrices the update solves with, the scenario of each mode, and
    optionally the fine surface's modes and the skull; info is atlas.json's record."""

    points: np.ndarray
    tetrahedra: np.ndarray
    vertex_modes: np.ndarray  # (M, N, 3)
    prior_vertex: np.ndarray
    gram: np.ndarray
    cross: np.ndarray
    prior_square: float
    scenarios: list[dict]  # per mode: {"kind": "family", "values": {...}} or {"kind": "swelling", ...}
    surface_points: np.ndarray | None = None
    surface_triangles: np.ndarray | None = None
    surface_modes: np.ndarray | None = None
    prior_surface: np.ndarray | None = None
    skull_triangles: np.ndarray | None = None  # (T, 3, 3) m
    skull_gap: float | None = None  # a gap skull: the brain's surface dilated by this (its triangles)
    info: dict = field(default_factory=dict)  # the rest of atlas.json
    # the resection's stages (atlas/resection.py), each an atlas of what is left: ATLAS/stages/K
    stages: list = field(default_factory=list, repr=False, compare=False)
    # what every update of this atlas needs and none changes (the point locator, the prior's
    # weights): made by the first update, in theatre before the measurements arrive
    once: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def family(self) -> np.ndarray:
        return np.array([s["kind"] == "family" for s in self.scenarios])

    @property
    def surface_vertices(self) -> np.ndarray:
        if "surface_vertices" not in self.once:
            self.once["surface_vertices"] = boundary_vertices(self.tetrahedra)
        return self.once["surface_vertices"]

    def mesh_id(self) -> str:
        return mesh_id(self.points, self.tetrahedra)


def boundary_vertices(tetrahedra: np.ndarray) -> np.ndarray:
    """The vertices on a mesh's boundary (of faces of one tetrahedron)."""
    faces = np.sort(tetrahedra[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    unique, counts = np.unique(faces, axis=0, return_counts=True)
    return np.unique(unique[counts == 1])


def mesh_id(points: np.ndarray, tetrahedra: np.ndarray) -> str:
    digest = hashlib.sha256(np.ascontiguousarray(points, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(tetrahedra, dtype=np.int64).tobytes())
    return digest.hexdigest()[:16]


def write(folder: Path, atlas: Atlas) -> str:
    """The atlas's files (its stages' first, in ATLAS/stages/K); returns its build's id."""
    import h5py

    folder.mkdir(parents=True, exist_ok=True)
    _remove_stages(folder)
    if atlas.stages:
        ids = [write(folder / STAGES / str(k), stage) for k, stage in enumerate(atlas.stages, 1)]
        for record, stage_id in zip(atlas.info["resection"]["stages"], ids):
            record["build_id"] = stage_id
    h5, index = folder / "atlas.h5", folder / "atlas.json"
    tmp = folder / ".atlas.h5.tmp"
    build_id = os.urandom(8).hex()  # in both files: an index of another build is told apart
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["mesh_id"] = atlas.mesh_id()
        f.attrs["build_id"] = build_id
        f["mesh/points"], f["mesh/tetrahedra"] = atlas.points, atlas.tetrahedra
        # contiguous: chunked and compressed, the file is a fifth smaller and reads 5-17x slower
        # (benchmarks/results/atlas_storage.md); a mode at a time (no single-precision copy of all)
        _write_modes(f, "modes/vertex", atlas.vertex_modes)
        f["prior/vertex"] = atlas.prior_vertex
        f["regulariser/gram"], f["regulariser/cross"] = atlas.gram, atlas.cross
        f["regulariser"].attrs["prior_square"] = atlas.prior_square
        if atlas.surface_points is not None:
            f["surface/points"], f["surface/triangles"] = atlas.surface_points, atlas.surface_triangles
            _write_modes(f, "modes/surface", atlas.surface_modes)
            f["prior/surface"] = atlas.prior_surface
        if atlas.skull_triangles is not None:
            f["skull/triangles"] = atlas.skull_triangles
            f["skull"].attrs["gap"] = np.nan if atlas.skull_gap is None else atlas.skull_gap
    info = {
        "format": FORMAT,
        "mesh_id": atlas.mesh_id(),
        "build_id": build_id,
        "modes": len(atlas.scenarios),
        "nodes": len(atlas.points),
        "cells": len(atlas.tetrahedra),
        **atlas.info,
        "scenarios": atlas.scenarios,
    }
    tmp_index = folder / ".atlas.json.tmp"
    tmp_index.write_text(json_text.dumps(info, indent=1) + "\n")
    os.replace(tmp, h5)
    os.replace(tmp_index, index)
    return build_id


def _write_modes(f, name: str, modes: np.ndarray) -> None:
    """Modes (M, n, 3) in single precision, one at a time."""
    dataset = f.create_dataset(name, shape=modes.shape, dtype=np.float32)
    for k in range(len(modes)):
        dataset[k] = modes[k]


def _remove_stages(folder: Path) -> None:
    """An earlier build's stage atlases (ATLAS/stages/K holding atlas.h5 or atlas.json, and the
    build's temporary files), and the stages folder if nothing else is left in it."""
    import shutil

    stages = folder / STAGES
    if not stages.is_dir():
        return
    for stage in stages.iterdir():
        names = {p.name for p in stage.iterdir()} if stage.is_dir() and stage.name.isdigit() else set()
        ours = {"atlas.h5", "atlas.json", ".atlas.h5.tmp", ".atlas.json.tmp"}
        if names and names <= ours | {STAGES}:
            shutil.rmtree(stage)
    if not any(stages.iterdir()):
        stages.rmdir()


def stage_count(atlas: Atlas) -> int:
    """How many resection stages the atlas holds (0: none)."""
    return len((atlas.info.get("resection") or {}).get("stages", []))


def read_stage(folder: str | Path, atlas: Atlas, number: int) -> Atlas:
    """Resection stage ``number`` (1, 2, ...) of the atlas read from ``folder``."""
    count = stage_count(atlas)
    if not 1 <= number <= count:
        have = (
            f"stages 1 to {count} (0: before the resection)"
            if count
            else "no resection stages (build them with brainshift atlas SCENE --resect REGION)"
        )
        raise InputError(f"--stage {number}: the atlas in '{folder}' has {have}")
    where = Path(folder) / STAGES / str(number)
    if not (where / "atlas.h5").is_file() or not (where / "atlas.json").is_file():
        raise InputError(
            f"ATLAS: '{folder}' names {count} resection stages but '{where}' holds no atlas (a build interrupted, "
            f"or the folder copied without it); build the atlas again with --resect"
        )
    stage = read(where)
    expected = atlas.info["resection"]["stages"][number - 1].get("build_id")
    if stage.info.get("build_id") != expected:
        raise InputError(
            f"ATLAS: '{folder}/{STAGES}/{number}' is not the stage its atlas.json names (another build's); "
            f"build it again"
        )
    return stage


def read(folder: str | Path) -> Atlas:
    """The atlas in a folder; one-line InputErrors for a folder that holds none, a damaged
    file, or an index and arrays of two different builds."""
    import h5py

    folder = Path(folder)
    h5, index = folder / "atlas.h5", folder / "atlas.json"
    if not h5.is_file() or not index.is_file():
        raise InputError(
            f"ATLAS: '{folder}' holds no atlas (atlas.h5 and atlas.json); build one with "
            f"brainshift atlas SCENE -o {folder}"
        )
    try:
        info = json.loads(index.read_text())
        with h5py.File(h5, "r") as f:
            if int(f.attrs["format"]) != FORMAT:
                raise InputError(
                    f"ATLAS: '{h5}' is of format {int(f.attrs['format'])}, this brainshift reads "
                    f"{FORMAT}: build it again"
                )
            stored_id, build_id = str(f.attrs["mesh_id"]), str(f.attrs.get("build_id", ""))
            atlas = Atlas(
                f["mesh/points"][...],
                f["mesh/tetrahedra"][...],
                f["modes/vertex"][...],
                f["prior/vertex"][...],
                f["regulariser/gram"][...],
                f["regulariser/cross"][...],
                float(f["regulariser"].attrs["prior_square"]),
                info["scenarios"],
            )
            if "surface" in f:
                atlas.surface_points, atlas.surface_triangles = f["surface/points"][...], f["surface/triangles"][...]
                atlas.surface_modes, atlas.prior_surface = f["modes/surface"][...], f["prior/surface"][...]
            if "skull" in f:
                gap = float(f["skull"].attrs["gap"])
                atlas.skull_triangles, atlas.skull_gap = f["skull/triangles"][...], None if np.isnan(gap) else gap
    except InputError:
        raise
    except Exception as exc:  # a truncated or foreign file (h5py, JSON, a missing dataset)
        raise InputError(f"ATLAS: '{folder}' cannot be read ({type(exc).__name__}: {exc}); build it again") from None
    atlas.info = {k: v for k, v in info.items() if k != "scenarios"}
    if info.get("mesh_id") != stored_id or atlas.mesh_id() != stored_id:
        raise InputError(
            f"ATLAS: atlas.json and atlas.h5 in '{folder}' are of different meshes (an atlas copied over "
            f"another?); build it again"
        )
    if info.get("build_id", "") != build_id:
        raise InputError(
            f"ATLAS: atlas.json and atlas.h5 in '{folder}' are of different builds (an index copied over "
            f"another, or a build interrupted between the two); build it again"
        )
    if len(atlas.scenarios) != len(atlas.vertex_modes) or atlas.vertex_modes.shape[1] != len(atlas.points):
        raise InputError(
            f"ATLAS: '{folder}': atlas.json names {len(atlas.scenarios)} modes, atlas.h5 holds "
            f"{len(atlas.vertex_modes)} over {atlas.vertex_modes.shape[1]} nodes; build it again"
        )
    problem = damage(atlas)
    if problem:
        raise InputError(f"ATLAS: '{folder}' is damaged: {problem}; build it again (or copy it again)")
    return atlas


def damage(atlas: Atlas) -> str | None:
    """What in an atlas's arrays is not what its build wrote, or None: every number finite, the
    stiffness's bounds ordered and positive, and the regulariser (its Gram matrix, cross terms
    and prior square) equal to what the modes and the prior give, checked in O(modes x nodes):
    the diagonal, the cross terms, and the Gram's action on two random weight vectors (a changed
    entry anywhere moves w.G.w), without the O(modes^2 x nodes) Gram itself."""
    arrays = {
        "the modes": atlas.vertex_modes,
        "the prior": atlas.prior_vertex,
        "the regulariser": atlas.gram,
        "the regulariser's cross terms": atlas.cross,
        "the regulariser's prior square": np.array([atlas.prior_square]),
        "the mesh's points": atlas.points,
        "the fine surface": atlas.surface_points,
        "the fine surface's modes": atlas.surface_modes,
        "the fine surface's prior": atlas.prior_surface,
        "the skull": atlas.skull_triangles,
    }
    for name, values in arrays.items():
        if values is not None and not np.all(np.isfinite(values)):
            bad = int(np.size(values) - np.count_nonzero(np.isfinite(values)))
            return f"{name} hold {bad} numbers that are not finite"
    for name, cells, corners, count in (
        ("the mesh's tetrahedra", atlas.tetrahedra, 4, len(atlas.points)),
        ("the fine surface's triangles", atlas.surface_triangles, 3,
         0 if atlas.surface_points is None else len(atlas.surface_points)),
    ):  # fmt: skip
        if cells is None:
            continue
        if cells.ndim != 2 or cells.shape[1] != corners or not np.issubdtype(cells.dtype, np.integer):
            return f"{name} are not rows of {corners} vertex numbers"
        if len(cells) and not (0 <= cells.min() and cells.max() < count):
            return f"{name} name vertices {cells.min()} to {cells.max()}, past the {count} there are"
    if atlas.surface_points is not None and (
        atlas.surface_modes is None or atlas.surface_modes.shape[1:] != atlas.surface_points.shape
    ):
        return "the fine surface's modes are not one value a surface point"
    stiffness = atlas.info.get("stiffness") or {}
    numbers = [stiffness.get(k) for k in ("lower", "G", "upper") if k in stiffness]
    if numbers and not (
        all(isinstance(v, (int, float)) and np.isfinite(v) for v in numbers)
        and 0 < min(numbers)
        and numbers == sorted(numbers)
    ):
        return f"atlas.json's stiffness {stiffness} is not 0 < lower <= G <= upper"
    n, m = len(atlas.points), len(atlas.vertex_modes)
    prior = atlas.prior_vertex.ravel().astype(np.float64)
    if atlas.gram.shape != (m, m) or not np.array_equal(atlas.gram, atlas.gram.T):
        return "the regulariser is not a symmetric matrix of one row a mode"
    weights = np.random.default_rng(0).standard_normal((2, m))
    squares, cross, combined = np.empty(m), np.empty(m), np.zeros((2, prior.size))
    for k in range(m):  # (a mode at a time in float64: no float64 copy of every mode)
        mode = atlas.vertex_modes[k].ravel().astype(np.float64)
        squares[k], cross[k] = mode @ mode / n, mode @ prior / n
        combined += weights[:, k : k + 1] * mode
    scale = max(float(squares.max(initial=0.0)), float(prior @ prior / n), 1e-300)
    if abs(atlas.prior_square - prior @ prior / n) > 1e-6 * scale:
        return "the regulariser's prior square and the prior disagree"
    if np.abs(np.diag(atlas.gram) - squares).max(initial=0.0) > 1e-6 * scale:
        return "the regulariser's diagonal and the modes disagree"
    if np.abs(atlas.cross - cross).max(initial=0.0) > 1e-6 * scale:
        return "the regulariser's cross terms and the modes disagree"
    actions = np.einsum("bi,ij,bj->b", weights, atlas.gram, weights)
    if np.abs(actions - np.einsum("bi,bi->b", combined, combined) / n).max() > 1e-6 * scale * m:
        return "the regulariser and the modes disagree"
    return None
