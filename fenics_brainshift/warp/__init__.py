"""The predicted intra-operative image: a pre-operative volume warped by a run's last
displacement (warp.py, exact inversion of the P1 field), the deformed mesh it follows
(deformed.py) and the same map as an ITK transform for 3D Slicer (itk_transform.py)."""

from .deformed import DeformedMesh
from .itk_transform import write_itk_transform
from .warp import Warp, check_size

__all__ = ["DeformedMesh", "Warp", "check_size", "write_itk_transform"]
