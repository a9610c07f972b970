"""Images in and out: NIfTI / NRRD volumes, DICOM-SEG, Slicer markups, RAS and LPS, and a
tetrahedral mesh laid on a voxel grid (rasterize.py)."""

from .frames import lps_to_ras, ras_to_lps, read_markups, write_markups
from .volumes import Volume, is_volume, read_volume, write_like

__all__ = [
    "Volume",
    "is_volume",
    "lps_to_ras",
    "ras_to_lps",
    "read_markups",
    "read_volume",
    "write_like",
    "write_markups",
]
