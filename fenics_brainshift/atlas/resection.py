"""An atlas's resection stages: the tumour (a region of cells) taken out in stages along the
surgical approach, from the craniotomy inwards, each stage with its own family of settled
states on what is left.

The approach runs down from the upper side (against gravity: a craniotomy is made on top,
and `brainshift prepare` warns of one on the lower half), so stage k of n removes the
region's cells whose centroid lies above the height that leaves (n - k) / n of the region's
cells, the deepest last; the cut stages are nested. The cavity left is open to the fluid as
every outer surface is: the scene's level applies in it too (a level above the cavity's
floor is a cavity filled to that level, as surgeons fill it with saline; one below it an
empty cavity whose walls are free), so the atlas's levels span both. Pieces a stage cuts
free of every support are taken out with it (runner/simulation.py).

The stage's surface, the one points on the brain are measured against, is the fine surface
where tissue remains and the cavity's wall: the faces between a present and a removed cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..scene.body import Removal

DEFAULT_STAGES = 3
MAX_STAGES = 10


@dataclass(frozen=True)
class Resection:
    """What `brainshift atlas --resect` asks: the region (a [[remove]]'s where or label; its
    `at` unused) and the number of stages."""

    region: Removal
    stages: int = DEFAULT_STAGES
    given_as: str = "--resect"

    def describe(self) -> str:
        return self.region.describe()


def parse_resect(text: str | None, scene_removals, stages: int | None) -> Resection | None:
    """The resection from --resect (label=N, label=NAME, or a condition on x, y, z) or else
    from the scene's [[remove]] (one region); None when neither is given."""
    if stages is not None and not 1 <= stages <= MAX_STAGES:
        raise InputError(f"--stages {stages}: give 1 to {MAX_STAGES} stages of the resection")
    if text is None and not scene_removals:
        if stages is not None:
            raise InputError("--stages: no resection to stage; give --resect REGION (or a [[remove]] in the scene)")
        return None
    if text is not None and scene_removals:
        raise InputError(
            "--resect: the scene has a [[remove]] already; give the resection once (the scene's, or --resect with "
            "the [[remove]] taken out)"
        )
    count = DEFAULT_STAGES if stages is None else stages
    if text is None:
        if len(scene_removals) > 1:
            raise InputError(
                f"atlas: the scene has {len(scene_removals)} [[remove]]s; an atlas stages one region (the tumour): "
                f"give it once, or as --resect"
            )
        return Resection(scene_removals[0], count, "[[remove]]")
    text = text.strip()
    key, sep, value = text.partition("=")
    if sep and key.strip() == "label":
        value = value.strip().strip("'\"")
        label: int | str = int(value) if value.lstrip("-").isdigit() else value
        if not value:
            raise InputError("--resect label=: give a label value or a segment's name (label=2, label=tumour)")
        try:
            return Resection(Removal(label=label), count)
        except InputError as exc:
            raise InputError(f"--resect {text}: {exc}") from None
    try:
        return Resection(Removal(where=text), count)
    except InputError as exc:
        raise InputError(
            f"--resect {text!r}: {str(exc).removeprefix('[[remove]] where: ')}; give label=N or a condition on the "
            f'cell centroid, e.g. "(x-0.02)**2 + y**2 + (z-0.03)**2 < 0.01**2" (metres)'
        ) from None


class StagedRegion:
    """The region's cells in bands along up, cut by stage: cut k (0-based) removes what lies
    above the k-th threshold. The thresholds are found once from every rank's region cells,
    told apart by their centroids (ghosts counted once), so they are the same on any ranks."""

    def __init__(self, select, up: np.ndarray, stages: int, comm, describe: str):
        self.select, self.stages, self.comm, self.describe = select, stages, comm, describe
        self.up = np.asarray(up, dtype=float) / np.linalg.norm(up)
        self.thresholds: np.ndarray | None = None
        self.cells = 0  # of the region, of the whole mesh
        self.total = 0

    def cuts(self) -> list:
        """The stages' cuts (physics.resection.Cut), made only when asked (Simulation.cut_now):
        `at` is never due."""
        from ..physics.resection import Cut  # (DOLFINx: not for the update's theatre path)

        return [
            Cut(math.inf, f"resection stage {k + 1} of {self.stages} ({self.describe})", self._band(k))
            for k in range(self.stages)
        ]

    def _band(self, k: int):
        def select(centroids: np.ndarray) -> np.ndarray:
            try:
                inside = np.asarray(self.select(centroids), dtype=bool)
            except InputError as exc:  # (a label the scene's label volume does not have, say)
                raise InputError(f"--resect {self.describe}: {exc}") from None
            if self.thresholds is None:  # (collective: Tissue asks every cut on every rank, in order)
                self.thresholds = self._find_thresholds(centroids, inside)
            return inside & (centroids @ self.up >= self.thresholds[k])

        return select

    def _find_thresholds(self, centroids: np.ndarray, inside: np.ndarray) -> np.ndarray:
        keys = np.round(centroids * 1e9).astype(np.int64)
        gathered = self.comm.allgather((keys[inside], keys))
        region = np.unique(np.concatenate([g[0] for g in gathered]), axis=0)
        self.total = len(np.unique(np.concatenate([g[1] for g in gathered]), axis=0))
        self.cells = len(region)
        if self.cells == 0:
            raise InputError(
                f"--resect {self.describe}: selects no cell of the mesh; check the region (metres, the scene's frame, "
                f"cell centroids; a label of the scene's label volume)"
            )
        if self.cells >= self.total:
            raise InputError(f"--resect {self.describe}: selects every cell of the mesh; give the tumour alone")
        if self.cells < self.stages:
            raise InputError(
                f"--resect {self.describe}: {self.cells} cell(s), fewer than the {self.stages} stages; give fewer "
                f"--stages or a finer mesh"
            )
        heights = np.sort(region.astype(float) @ self.up * 1e-9)[::-1]  # highest first
        # stage k takes the highest (k + 1) / n of the region's cells: its threshold is that cell's height
        ends = [int(round((k + 1) * self.cells / self.stages)) - 1 for k in range(self.stages)]
        thresholds = heights[ends] - 1e-8  # (10 nm below: the keys are rounded to 1 nm)
        thresholds[-1] = -np.inf  # (the last stage takes the whole region)
        # cells of one height go to one stage: each stage must still take some
        if np.any(np.diff(thresholds) >= 0) or (self.stages > 1 and heights[-1] >= thresholds[-2]):
            raise InputError(
                f"--resect {self.describe}: the region is too thin along up to cut in {self.stages} stages "
                f"(its cells lie at too few heights); give fewer --stages"
            )
        return thresholds


def stage_surface(
    points: np.ndarray, tetrahedra: np.ndarray, present: np.ndarray, fine: tuple | None
) -> tuple[np.ndarray, np.ndarray]:
    """(points (S, 3), triangles (T, 3)): the surface of a stage's tissue that points are measured
    against: the fine surface's triangles whose corners lie in present cells (or the mesh's own
    boundary without a fine surface) and the cavity's wall, each face between a present and a
    removed cell, turned outward from the tissue (into the cavity)."""
    from .locate import MeshLocator

    faces, opposite = _faces(tetrahedra)
    key = np.sort(faces, axis=2).reshape(-1, 3)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    cell = np.repeat(np.arange(len(tetrahedra)), 4)
    present_at = np.zeros(len(counts), dtype=np.int64)
    np.add.at(present_at, inverse, present[cell])
    own = present[cell]
    wall = own & (counts[inverse] == 2) & (present_at[inverse] == 1)  # a present cell's face on a removed one
    triangles = [_outward(points, faces.reshape(-1, 3)[wall], opposite.reshape(-1)[wall])]
    kept_points = [points]
    if fine is None:  # the present cells' outer faces (a face of one cell) stand for the fine surface
        outer = own & (counts[inverse] == 1)
        triangles.append(_outward(points, faces.reshape(-1, 3)[outer], opposite.reshape(-1)[outer]))
    else:
        fine_points, fine_triangles = fine
        # a point inside the mesh is in tissue if a present cell holds it (one on a face between a
        # present and a removed cell is: which of the two a locator finds is round-off's choice);
        # one outside the voxels (the fine surface is smoother) if its nearest cell is present
        cell_of, _, outside = MeshLocator(points, tetrahedra).locate(fine_points)
        in_tissue = present[cell_of]
        inside = outside == 0
        _, _, off_present = MeshLocator(points, tetrahedra[present]).locate(fine_points[inside])
        in_tissue[inside] = off_present == 0
        kept = fine_triangles[in_tissue[fine_triangles].all(axis=1)]
        triangles.append(kept + len(points))
        kept_points.append(fine_points)
    all_points = np.concatenate(kept_points)
    all_triangles = np.concatenate(triangles)
    used, compact = np.unique(all_triangles, return_inverse=True)
    return all_points[used], compact.reshape(-1, 3)


def _faces(tetrahedra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, 4, 3) each cell's faces (face k opposite vertex k) and (C, 4) that vertex."""
    order = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    return tetrahedra[:, order], tetrahedra


def _outward(points: np.ndarray, faces: np.ndarray, opposite: np.ndarray) -> np.ndarray:
    """The faces with their corners ordered so the normal points away from the opposite vertex."""
    a, b, c = (points[faces[:, i]] for i in range(3))
    normal = np.cross(b - a, c - a)
    inward = np.einsum("ij,ij->i", normal, points[opposite] - a) > 0
    out = faces.copy()
    out[inward] = out[inward][:, [0, 2, 1]]
    return out
