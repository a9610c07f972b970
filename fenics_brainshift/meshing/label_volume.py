"""Reading a label volume at points (for removals by label)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..images.volumes import label_mask, read_volume


def labels_at(path: str | Path, points_m: np.ndarray, scale: float, label=None) -> np.ndarray:
    """The label of a label volume (NIfTI or NRRD) at each point (m; the file's unit times
    ``scale`` is m): of the voxel the point lies in (a point on a face between voxels takes
    the one above it, a node on the image's outer face the edge voxel); 0 outside the image.
    With ``label`` (a value or a segment name): whether each point lies in it."""
    volume = read_volume(path, "[mesh] file", layered=True)
    data = volume.data if label is None else label_mask(volume, [label], "label")
    inverse = np.linalg.inv(volume.affine)
    continuous = (points_m / scale) @ inverse[:3, :3].T + inverse[:3, 3]
    shape = np.array(data.shape[:3])
    on_edge = np.all((continuous >= -0.5 - 1e-9) & (continuous <= shape - 0.5 + 1e-9), axis=1)
    ijk = np.clip(np.floor(continuous + 0.5), 0, shape - 1).astype(np.int64)
    inside = on_edge
    labels = np.zeros(len(points_m), dtype=data.dtype if label is not None else np.int64)
    labels[inside] = data[tuple(ijk[inside].T)]
    return labels
