"""Triangulated surfaces without DOLFINx (numpy, scipy, and meshio, nibabel or VTK for the
files): reading surface files in RAS and writing the STL 3D Slicer reads (files.py),
triangles' closest points and orientation (triangles.py), inside/outside and enclosed volume
(inside.py), and the rigid skull's distance field (skull.py). The theatre path (the update,
the markups and surface readers) stands on this floor."""

from .files import SurfaceFileError, read_surface, write_slicer_stl
from .skull import RigidSkull
from .triangles import closed_surface_problem, closest_points_on_triangles, outward

__all__ = [
    "RigidSkull",
    "SurfaceFileError",
    "closed_surface_problem",
    "closest_points_on_triangles",
    "outward",
    "read_surface",
    "write_slicer_stl",
]
