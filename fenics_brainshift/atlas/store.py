"""An atlas on disk: ATLAS/atlas.h5 (the arrays) and ATLAS/atlas.json (the index a person
reads: the scene, the scenarios, the timings). Written by rank 0 through temporary files
renamed into place, so a killed build leaves no atlas that looks whole.

atlas.h5 (format 2):
  mesh/points (N, 3) m, mesh/tetrahedra (C, 4)
  modes/vertex (M, N, 3) float32, contiguous: the settled states of the family (first) and the
      swelling perturbation modes (last), m; mapped, not read (mode_file.py)
  boundary/vertices (B,), boundary/triangles (T, 3), boundary/modes (M, B, 3) and
      boundary/by_node (B, 3, M) float32: the modes at the mesh's boundary (boundary.py)
  modes/surface (M, S, 3) float32, surface/points (S, 3), surface/triangles: the fine surface
      (absent: the mesh's boundary)
  prior/vertex (N, 3), prior/surface (S, 3): the scene's own settled state
  regulariser/gram (M, M), regulariser/cross (M,), regulariser/prior_square: the mean over
      the vertices of |sum c_k u_k - u_prior|^2 = c.G.c - 2 c.h + p (m^2)
  skull/triangles (T, 3, 3), attribute gap: the skull the combination must respect
  checks/mode_crc32 (M,), checks/node_weights (M, 3), checks/node_sum (N,): what each piece of
      modes/vertex is checked against as it is read (mode_file.py); the group's attributes:
      the CRC-32 of every dataset read whole
"""

from __future__ import annotations

import hashlib
import json
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError
from . import mode_file
from .boundary import Boundary
from .mode_file import StoredModes, mode_crc, node_sums, node_weights

FORMAT = 2
STAGES = "stages"  # the folder of a resection's stages, each an atlas of its own


@dataclass
class Atlas:
    """The modes of an atlas at the mesh's vertices (m, RAS), the prior (the scene's own
    settled state), the Gram matrices the update solves with, the scenario of each mode, and
    optionally the fine surface's modes and the skull; info is atlas.json's record."""

    points: np.ndarray
    tetrahedra: np.ndarray
    vertex_modes: np.ndarray | StoredModes  # (M, N, 3) float32: an array (a build's), or read as asked (read())
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
    def boundary(self) -> Boundary:
        """The mesh's boundary and the modes there (read from atlas.h5, else made once)."""
        if "boundary" not in self.once:
            self.once["boundary"] = Boundary.of(self.points, self.tetrahedra, self.vertex_modes)
        return self.once["boundary"]

    def mesh_id(self) -> str:
        return mesh_id(self.points, self.tetrahedra)


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
    boundary = atlas.boundary
    # the HDF5 1.10 file format: its metadata checksummed, so damage there is an error HDF5 names, not
    # a crash in it (a flipped byte in the default format's metadata crashed or hung the reader); the
    # ids fixed-length strings, kept in the checksummed object header (a variable-length string lives
    # in the global heap, unchecked)
    with h5py.File(tmp, "w", libver=("v110", "v110")) as f:
        f.attrs["format"] = FORMAT
        f.attrs["mesh_id"] = np.bytes_(atlas.mesh_id())
        f.attrs["build_id"] = np.bytes_(build_id)
        f["mesh/points"], f["mesh/tetrahedra"] = atlas.points, atlas.tetrahedra
        # contiguous: chunked and compressed, the file is a fifth smaller and reads 5-17x slower
        # (benchmarks/results/atlas_storage.md), and only a contiguous array can be mapped
        _write_vertex_modes(f, atlas.vertex_modes)
        f["boundary/vertices"], f["boundary/triangles"] = boundary.vertices, boundary.triangles
        f["boundary/modes"], f["boundary/by_node"] = boundary.modes, boundary.by_node
        f["prior/vertex"] = atlas.prior_vertex
        f["regulariser/gram"], f["regulariser/cross"] = atlas.gram, atlas.cross
        f["regulariser"].attrs["prior_square"] = atlas.prior_square
        if atlas.surface_points is not None:
            f["surface/points"], f["surface/triangles"] = atlas.surface_points, atlas.surface_triangles
            surface = f.create_dataset("modes/surface", shape=atlas.surface_modes.shape, dtype=np.float32)
            for k in range(len(atlas.surface_modes)):  # (a mode at a time: no single-precision copy of all)
                surface[k] = atlas.surface_modes[k]
            f["prior/surface"] = atlas.prior_surface
        if atlas.skull_triangles is not None:
            f["skull/triangles"] = atlas.skull_triangles
            f["skull"].attrs["gap"] = np.nan if atlas.skull_gap is None else atlas.skull_gap
        for name, values in _read_whole(f).items():
            f["checks"].attrs[name] = _crc(values)
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


def _write_vertex_modes(f, modes) -> None:
    """modes/vertex in single precision, a mode at a time (no single-precision copy of all),
    and what each piece is checked against when read (mode_file.py)."""
    dataset = f.create_dataset("modes/vertex", shape=modes.shape, dtype=np.float32)
    weights, crc, sums = node_weights(len(modes)), np.zeros(len(modes), dtype=np.uint32), 0.0
    for k in range(len(modes)):
        mode = np.asarray(modes[k], dtype=np.float32)
        dataset[k], crc[k] = mode, mode_crc(mode)
        sums = sums + node_sums(mode[None], weights[k : k + 1])[0]
    f["checks/mode_crc32"], f["checks/node_weights"], f["checks/node_sum"] = crc, weights, sums


def _read_whole(f) -> dict[str, np.ndarray]:
    """What an update reads whole (every dataset but modes/vertex, and the groups' numbers),
    named as in checks' attributes ("mesh/points", "regulariser@prior_square")."""
    whole = {}

    def visit(name, item):
        if hasattr(item, "shape") and name != "modes/vertex" and not name.startswith("checks"):
            whole[name] = item[...]
        elif not hasattr(item, "shape") and name != "checks":
            whole.update({f"{name}@{key}": np.float64(value) for key, value in item.attrs.items()})

    f.visititems(visit)
    return whole


def _text(value) -> str:
    return value.decode("ascii") if isinstance(value, bytes) else str(value)


def _crc(values: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(values))


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
        # one open file for h5py and the map of the modes: the same file, though a build replace it meanwhile
        with open(h5, "rb") as handle, h5py.File(handle, "r") as f:
            if int(f.attrs["format"]) != FORMAT:
                raise InputError(
                    f"ATLAS: '{h5}' is of format {int(f.attrs['format'])}, this brainshift reads "
                    f"{FORMAT}: build it again"
                )
            stored_id, build_id = _text(f.attrs["mesh_id"]), _text(f.attrs.get("build_id", b""))
            whole, recorded = _read_whole(f), dict(f["checks"].attrs)
            modes = StoredModes(
                _mapped(f["modes/vertex"], handle),
                f["checks/mode_crc32"][...],
                f["checks/node_weights"][...],
                f["checks/node_sum"][...],
                str(folder),
            )
        atlas = Atlas(
            whole["mesh/points"],
            whole["mesh/tetrahedra"],
            modes,
            whole["prior/vertex"],
            whole["regulariser/gram"],
            whole["regulariser/cross"],
            float(whole["regulariser@prior_square"]),
            info["scenarios"],
        )
        if "surface/points" in whole:
            atlas.surface_points, atlas.surface_triangles = whole["surface/points"], whole["surface/triangles"]
            atlas.surface_modes, atlas.prior_surface = whole["modes/surface"], whole["prior/surface"]
        if "skull/triangles" in whole:
            gap = float(whole["skull@gap"])
            atlas.skull_triangles, atlas.skull_gap = whole["skull/triangles"], None if np.isnan(gap) else gap
        boundary = Boundary(*(whole[f"boundary/{name}"] for name in ("vertices", "triangles", "modes", "by_node")))
    except InputError:
        raise
    except Exception as exc:  # a truncated or foreign file (h5py, JSON, a missing dataset)
        raise InputError(f"ATLAS: '{folder}' cannot be read ({type(exc).__name__}: {exc}); build it again") from None
    atlas.info = {k: v for k, v in info.items() if k != "scenarios"}
    # damage first: a changed byte in the mesh is damage, not an index of another mesh
    changed = [name for name in whole if recorded.get(name) != _crc(whole[name])]
    changed += [name for name in recorded if name not in whole]  # (a group gone: the skull, the fine surface)
    problem = damage(atlas, boundary) or (
        changed and f"{changed[0]} is {'not what the build wrote (its CRC-32)' if changed[0] in whole else 'missing'}"
    )
    if problem:
        raise InputError(f"ATLAS: '{folder}' is damaged: {problem}; build it again (or copy it again)")
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
    atlas.once["boundary"] = boundary
    return atlas


def _mapped(dataset, handle):
    """A contiguous float32 dataset mapped (pages read as they are touched, mode_file.py); one
    stored otherwise (an atlas.h5 repacked with compression) is read whole."""
    offset = dataset.id.get_offset()
    if dataset.chunks is None and dataset.compression is None and dataset.dtype == "<f4" and offset is not None:
        return mode_file.mapped(handle, offset, dataset.shape)
    return dataset[...].astype(np.float32)


def damage(atlas: Atlas, boundary: Boundary) -> str | None:
    """What in an atlas's arrays read whole is not what a build writes, or None: every number
    finite, cells naming vertices there are, the stiffness's bounds ordered and positive, the
    regulariser symmetric and its prior square the prior's. (Whether each is what this build
    wrote: the CRC-32s; the modes/vertex pieces: as they are read, mode_file.py.)"""
    arrays = {
        "the prior": atlas.prior_vertex,
        "the regulariser": atlas.gram,
        "the regulariser's cross terms": atlas.cross,
        "the regulariser's prior square": np.array([atlas.prior_square]),
        "the mesh's points": atlas.points,
        "the boundary's modes": boundary.modes,
        "the boundary's modes by node": boundary.by_node,
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
        ("the boundary's triangles", boundary.triangles, 3, len(boundary.vertices)),
        ("the fine surface's triangles", atlas.surface_triangles, 3,
         0 if atlas.surface_points is None else len(atlas.surface_points)),
    ):  # fmt: skip
        if cells is None:
            continue
        if cells.ndim != 2 or cells.shape[1] != corners or not np.issubdtype(cells.dtype, np.integer):
            return f"{name} are not rows of {corners} vertex numbers"
        if len(cells) and not (0 <= cells.min() and cells.max() < count):
            return f"{name} name vertices {cells.min()} to {cells.max()}, past the {count} there are"
    n, m = len(atlas.points), len(atlas.vertex_modes)
    vertices = boundary.vertices
    if not (len(vertices) and np.issubdtype(vertices.dtype, np.integer) and 0 <= vertices.min() and vertices.max() < n):
        return "the boundary's vertices are not vertices of the mesh"
    if boundary.modes.shape != (m, len(vertices), 3) or boundary.by_node.shape != (len(vertices), 3, m):
        return "the boundary's modes are not one value a mode and boundary vertex"
    if atlas.surface_points is not None and (
        atlas.surface_modes is None or atlas.surface_modes.shape != (m, *atlas.surface_points.shape)
    ):
        return "the fine surface's modes are not one value a mode and surface point"
    stiffness = atlas.info.get("stiffness") or {}
    numbers = [stiffness.get(k) for k in ("lower", "G", "upper") if k in stiffness]
    if numbers and not (
        all(isinstance(v, (int, float)) and np.isfinite(v) for v in numbers)
        and 0 < min(numbers)
        and numbers == sorted(numbers)
    ):
        return f"atlas.json's stiffness {stiffness} is not 0 < lower <= G <= upper"
    if atlas.gram.shape != (m, m) or not np.array_equal(atlas.gram, atlas.gram.T) or atlas.cross.shape != (m,):
        return "the regulariser is not a symmetric matrix of one row a mode"
    prior = atlas.prior_vertex.ravel()
    if abs(atlas.prior_square - prior @ prior / n) > 1e-6 * max(prior @ prior / n, 1e-300):
        return "the regulariser's prior square and the prior disagree"
    return None
