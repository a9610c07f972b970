"""The patient's inner skull for `[skull] file`: a closed surface --gap mm out from the brain
and from the voxel mesh `brainshift run` builds of it (whose corners stand up to half a
voxel's diagonal past the brain's surface: the contact acts on the mesh's nodes).

Marching cubes of the distance to their union, on a grid that divides the mesh's voxel (so
every node of the mesh is a grid point, and the distance there is exact: on a grid that was
not, nodes stood 0.3 mm from a 3 mm skull), smoothed by a Gaussian first: the distance to a
union of voxels has creases where two voxels' offsets meet, marching cubes facets them, and
the contact's normal jumps across each facet's edge; Newton chattered there without end (a
synthetic patient's settled state at 5 mm). The smoothing pulls the surface in at the mesh's
corners; the level is raised where that would leave a node within MIN_CLEARANCE of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import SimpleITK as sitk
from scipy import ndimage

from ..images.frames import LPS_TO_RAS
from .carry import lps_to_index

GRID = 1.5  # mm: the grid's spacing at most (the largest divisor of the voxel no larger)
SMOOTHING = 1.5  # mm: the Gaussian the distance is smoothed by
MIN_CLEARANCE = 1.0  # mm: no mesh node nearer the skull than this (of a gap of 0.5-10 mm: its half, if less)


def inner_skull(
    segmentation: Path, labels: list[str], brain: np.ndarray, patient: sitk.Image, voxel: float, gap: float
) -> tuple[np.ndarray, np.ndarray]:
    """(points RAS mm, triangles) of the inner skull around the brain (``brain``, a mask on
    ``patient``'s grid) and the voxel mesh of ``voxel`` mm of ``segmentation``'s ``labels``."""
    from skimage.measure import marching_cubes

    from ..meshing.voxelize import voxelize
    from ..surfaces.triangles import closed_surface_problem

    model = voxelize(segmentation, voxel * 1e-3, 1e-3, 0.5, 1, labels)
    kept = np.zeros(model.voxels.max(axis=0) + 1, dtype=bool)
    kept[tuple(model.voxels.T)] = True
    per_voxel = int(np.ceil(voxel / GRID))  # grid steps per voxel
    step = voxel / per_voxel
    pad = int(np.ceil(3 * gap / voxel)) + 1  # voxels of room around the mesh for the offset
    cells = np.pad(kept, pad).repeat(per_voxel, 0).repeat(per_voxel, 1).repeat(per_voxel, 2)
    # a grid point is the mesh's if any of the eight grid cells around it is: nodes included
    padded = np.pad(cells, 1)
    body = np.zeros(np.array(cells.shape) + 1, dtype=bool)
    for shift in np.ndindex(2, 2, 2):
        body |= padded[tuple(slice(s, s + n + 1) for s, n in zip(shift, cells.shape))]
    origin = model.origin * 1e3 - pad * voxel  # RAS mm of grid point (0, 0, 0)
    axes = [origin[d] + step * np.arange(body.shape[d]) for d in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    ijk = np.rint(lps_to_index(patient, grid @ LPS_TO_RAS)).astype(np.int64)
    inside_image = np.all((ijk >= 0) & (ijk < np.array(patient.GetSize())), axis=1)
    flat = body.reshape(-1)
    flat[inside_image] |= brain[ijk[inside_image, 2], ijk[inside_image, 1], ijk[inside_image, 0]]
    distance = ndimage.gaussian_filter(ndimage.distance_transform_edt(~body, sampling=step), SMOOTHING / step)
    nodes = body & ~ndimage.binary_erosion(body)  # the union's boundary points, the mesh's outer nodes among them
    clearance = min(MIN_CLEARANCE, 0.5 * gap)
    level = max(gap, float(distance[nodes].max()) + clearance)
    # just off the grid's exact distances, so that no vertex falls on a grid point: those make
    # zero-area triangles, and the STL's holes
    level += 1e-3 * step * np.pi
    distance = distance.astype(np.float32)
    points, triangles, _, _ = marching_cubes(
        np.pad(distance, 1, constant_values=distance.max()), level, allow_degenerate=False
    )
    points = origin + (points - 1.0) * step
    problem = closed_surface_problem(triangles)
    if problem:  # not the user's input: say so plainly
        raise RuntimeError(f"prepare: the inner skull's surface came out open ({problem})")
    return points, triangles.astype(np.int64)
