"""Images in and out: NIfTI / NRRD volumes, Slicer markups, RAS and LPS, and the warp of a
pre-operative image by a run's displacement (with its ITK transform)."""
from .frames import lps_to_ras, ras_to_lps, read_markups, write_markups
from .volumes import Volume, is_volume, read_volume, write_like
from .warp import DeformedMesh, Warp, write_itk_transform

__all__ = ["DeformedMesh", "Volume", "Warp", "is_volume", "lps_to_ras", "ras_to_lps", "read_markups",
           "read_volume", "write_itk_transform", "write_like", "write_markups"]
