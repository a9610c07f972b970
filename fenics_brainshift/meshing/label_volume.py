"""Reading a label volume at points (for removals by label)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def labels_at(path: str | Path, points_m: np.ndarray, scale: float) -> np.ndarray:
    """The label of a NIfTI label volume at each point (m; the file's unit times ``scale`` is
    m); 0 outside the image."""
    import nibabel as nib

    try:
        image = nib.load(str(path))
        data = np.asanyarray(image.dataobj)
    except Exception as exc:  # nibabel's own message says what is wrong
        raise InputError(f"'{Path(path).name}' could not be read as NIfTI: {exc}") from None
    inverse = np.linalg.inv(image.affine)
    ijk = np.rint((points_m / scale) @ inverse[:3, :3].T + inverse[:3, 3]).astype(np.int64)
    inside = np.all((ijk >= 0) & (ijk < np.array(data.shape[:3])), axis=1)
    labels = np.zeros(len(points_m), dtype=np.int64)
    labels[inside] = data[tuple(ijk[inside].T)]
    return labels
