"""Which files the package reads, by suffix: the one table every reader and check uses."""

from __future__ import annotations

from pathlib import Path

TETRA_SUFFIXES = (".msh", ".xdmf")  # tetrahedral meshes, read as they are
LABEL_SUFFIXES = (".nii", ".nii.gz", ".nrrd")  # label volumes (NIfTI, NRRD, Slicer .seg.nrrd), voxel-meshed
SURFACE_SUFFIXES = (".stl", ".obj", ".ply", ".vtk", ".vtp", ".vtu", ".off", ".gii")  # surfaces, voxel-meshed

MESH_HELP = (
    "use .msh, .xdmf, a label volume (.nii, .nii.gz, .nrrd, .seg.nrrd) or a surface "
    "(.stl, .obj, .ply, .vtk, .vtp, .gii)"
)


def _name(path: str | Path) -> str:
    return str(path).lower()


def is_tetra_mesh(path: str | Path) -> bool:
    return _name(path).endswith(TETRA_SUFFIXES)


def is_label_volume(path: str | Path) -> bool:
    return _name(path).endswith(LABEL_SUFFIXES)


def is_surface(path: str | Path) -> bool:
    return _name(path).endswith(SURFACE_SUFFIXES)


def is_voxelizable(path: str | Path) -> bool:
    return is_label_volume(path) or is_surface(path)


def is_mesh_input(path: str | Path) -> bool:
    return is_tetra_mesh(path) or is_voxelizable(path)
