"""The boundary of labels of a label volume as a closed triangulated surface: a skull from a
segmentation (the labels of everything inside it, brain and CSF), and the fine surface of a
mesh made from a label volume (outputs/fine_surface.py).

Marching cubes (scikit-image) on the labels' mask at the 0.5 level, the mask padded by one
empty voxel so that the surface closes at the image's edge; the vertices mapped through the
image's affine to the scene's frame (the one a mesh made from the same volume has).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from skimage.measure import marching_cubes

from ..errors import InputError
from ..images.volumes import label_mask, read_volume
from ..surfaces.triangles import outward


def label_surface(path: str | Path, labels, scale: float, what: str = "[skull] label") -> tuple[np.ndarray, np.ndarray]:
    """(points (m), triangles with outward normals) of the boundary of the voxels whose label
    is one of ``labels`` (values or segment names; None: any label but 0) in the volume at
    ``path``, whose unit times ``scale`` is m."""
    volume = read_volume(path, "[mesh] file", layered=True)
    mask = label_mask(volume, labels, what)
    if not mask.any():
        wanted = ", ".join(map(str, labels)) if labels is not None else "other than 0"
        raise InputError(
            f"{what}: no voxel of '{Path(path).name}' has label {wanted}; "
            f"its labels: {', '.join(map(str, np.unique(volume.data)[:20]))}"
        )
    padded = np.pad(mask, 1).astype(np.float32)
    ijk, triangles, _, _ = marching_cubes(padded, 0.5)
    ijk -= 1.0  # the padding
    points = (ijk @ volume.affine[:3, :3].T + volume.affine[:3, 3]) * scale
    return points, outward(points, triangles.astype(np.int64))
