"""What the bundled brain scene (data/scenes/brain.toml) defines in the ICBM152 template's
frame, as things a registration can carry: each named [[fixed]] region as a mask on the
template's grid (the brain stem at the foramen magnum, the occipital pole), each [[septum]]
plane (the falx, the tentorium) as a triangulated sheet clipped to its region and the brain,
and the [probes]. One definition: a change to the bundled scene's anatomy is carried to
every patient prepared after it."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import SimpleITK as sitk
from scipy import ndimage

from ..images.frames import LPS_TO_RAS
from ..scene.body import FixedRegion
from ..scene.septum import SeptumSpec
from .carry import lps_to_index, voxel_centres_ras_m

BRAIN_SCENE = Path(__file__).resolve().parents[1] / "data" / "scenes" / "brain.toml"
SHEET_STEP = 2.0  # mm between a septum sheet's vertices
SHEET_MARGIN = 3  # voxels (mm) a sheet reaches past the brain, so it cuts the whole of it


@dataclass
class TemplateAnatomy:
    supports: dict[str, np.ndarray] = field(default_factory=dict)  # name -> bool [k, j, i], template grid
    septa: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # name -> (LPS mm, triangles)
    probes: dict[str, np.ndarray] = field(default_factory=dict)  # name -> LPS mm


def template_anatomy(template: sitk.Image, brain: np.ndarray) -> TemplateAnatomy:
    """The bundled scene's anatomy on the template (``brain``: its mask, [k, j, i])."""
    raw = tomllib.loads(BRAIN_SCENE.read_text())
    anatomy = TemplateAnatomy()
    centres = voxel_centres_ras_m(template, brain)
    for table in raw.get("fixed", []):
        region = FixedRegion(**table)
        if region.name is None or region.predicate is None:
            continue
        mask = np.zeros_like(brain)
        mask[brain] = region.predicate(centres.T)
        anatomy.supports[region.name] = mask
    reach = ndimage.binary_dilation(brain, iterations=SHEET_MARGIN)
    for table in raw.get("septum", []):
        spec = SeptumSpec(**{k: v for k, v in table.items() if k != "enabled"})
        if spec.normal is not None and spec.name:
            anatomy.septa[spec.name] = plane_sheet(spec, template, reach)
    anatomy.probes = {name: np.asarray(p, dtype=float) * 1e3 @ LPS_TO_RAS for name, p in raw.get("probes", {}).items()}
    return anatomy


def plane_sheet(spec: SeptumSpec, template: sitk.Image, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A septum plane as triangles (LPS mm) on a SHEET_STEP grid, those kept whose centroid is
    in the septum's region (``where``) and within ``reach`` (a mask on the template's grid)."""
    point = np.asarray(spec.point) * 1e3  # RAS mm
    normal = np.asarray(spec.normal) / np.linalg.norm(spec.normal)
    first = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(normal, first)
    steps = np.arange(-130.0, 130.0 + SHEET_STEP, SHEET_STEP)
    a, b = np.meshgrid(steps, steps, indexing="ij")
    vertices = point + a.reshape(-1, 1) * first + b.reshape(-1, 1) * second  # RAS mm
    n = len(steps)
    corner = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    triangles = np.concatenate(
        [np.stack([corner, corner + n, corner + 1], 1), np.stack([corner + 1, corner + n, corner + n + 1], 1)]
    )
    centroids = vertices[triangles].mean(axis=1)
    keep = _inside(reach, template, centroids @ LPS_TO_RAS)
    if spec.predicate is not None:
        keep &= spec.predicate((centroids * 1e-3).T)
    triangles = triangles[keep]
    used, triangles = np.unique(triangles, return_inverse=True)
    return vertices[used] @ LPS_TO_RAS, triangles.reshape(-1, 3)


def _inside(mask: np.ndarray, image: sitk.Image, lps: np.ndarray) -> np.ndarray:
    """Whether each point (LPS mm) lies in a voxel of ``mask`` ([k, j, i]) of ``image``'s grid."""
    ijk = np.rint(lps_to_index(image, lps)).astype(np.int64)
    shape = np.array(mask.shape[::-1])
    ok = np.all((ijk >= 0) & (ijk < shape), axis=1)
    out = np.zeros(len(lps), dtype=bool)
    out[ok] = mask[ijk[ok, 2], ijk[ok, 1], ijk[ok, 0]]
    return out
