"""Triangulated surfaces with numpy and scipy only (no DOLFINx): reading surface files in
RAS (files.py), triangles' closest points and orientation (triangles.py), inside/outside and
enclosed volume (inside.py), and the rigid skull's distance field (skull.py). The theatre
path (the update, the markups and surface readers) stands on this floor."""

from .files import SurfaceFileError, read_surface
from .skull import RigidSkull
from .triangles import closed_surface_problem, closest_points_on_triangles, outward

__all__ = [
    "RigidSkull",
    "SurfaceFileError",
    "closed_surface_problem",
    "closest_points_on_triangles",
    "outward",
    "read_surface",
]
