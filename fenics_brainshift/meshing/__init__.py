"""Meshes: structured grids, gmsh shapes, mesh files and the voxel mesher (the paper's
"embedding" method), each from plain values, with memory checked before allocation."""

from .build import box_mesh, mesh_from_arrays, read_mesh_file, voxelized_mesh, write_voxel_mesh
from .shapes import gmsh_shape

__all__ = ["box_mesh", "gmsh_shape", "mesh_from_arrays", "read_mesh_file", "voxelized_mesh", "write_voxel_mesh"]
