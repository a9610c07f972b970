"""Meshes from a scene's [mesh] section: structured grids, gmsh shapes, files."""
from .build import build_mesh, mesh_from_arrays

__all__ = ["build_mesh", "mesh_from_arrays"]
