"""A label array written as a 3D Slicer segmentation (.seg.nrrd): one layer, each segment a
label value with its name and colour, the grid in LPS as Slicer writes it; readable by
Slicer's Segment Editor and by this project's volume reader (segments by name)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import SimpleITK as sitk

COLOURS = {"brain": (0.95, 0.8, 0.7), "tumour": (0.9, 0.2, 0.2)}  # others: a palette by order
PALETTE = ((0.3, 0.6, 0.9), (0.4, 0.8, 0.4), (0.9, 0.7, 0.2), (0.6, 0.4, 0.8))


def write_segmentation(path: Path, labels_kji: np.ndarray, grid: sitk.Image, names: dict[int, str]) -> Path:
    """``labels_kji``: the label array in SimpleITK's order on ``grid``; ``names``: value -> name."""
    import nrrd

    data = np.ascontiguousarray(np.transpose(labels_kji, (2, 1, 0)))  # [i, j, k]
    direction = np.array(grid.GetDirection()).reshape(3, 3)
    header = {
        "type": "uint8",
        "space": "left-posterior-superior",
        "space directions": (direction * np.array(grid.GetSpacing())).T,
        "space origin": np.array(grid.GetOrigin()),
        "kinds": ["domain"] * 3,
        "encoding": "gzip",
        "Segmentation_MasterRepresentation": "Binary labelmap",
        "Segmentation_ContainedRepresentationNames": "Binary labelmap|",
        "Segmentation_ReferenceImageExtentOffset": "0 0 0",
    }
    for n, (value, name) in enumerate(sorted(names.items())):
        colour = COLOURS.get(name, PALETTE[n % len(PALETTE)])
        where = np.argwhere(data == value)
        extent = np.ravel(np.stack([where.min(0), where.max(0)], 1)) if len(where) else np.zeros(6, int)
        header.update(
            {
                f"Segment{n}_ID": name,
                f"Segment{n}_Name": name,
                f"Segment{n}_LabelValue": str(value),
                f"Segment{n}_Layer": "0",
                f"Segment{n}_Color": " ".join(f"{c:g}" for c in colour),
                f"Segment{n}_Extent": " ".join(str(int(v)) for v in extent),
                f"Segment{n}_Tags": "|",
            }
        )
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.nrrd")
    nrrd.write(str(tmp), data.astype(np.uint8), header, index_order="F")
    os.replace(tmp, path)
    return path
