"""Distributed DOLFINx meshes (coordinates in metres) from grids, voxel models and files.

Each takes plain values; runner/build.py picks one from a scene's [mesh]. Big meshes are
refused before they are allocated (budget.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import compat, formats
from ..errors import InputError
from ..logs import get_logger
from ..units import LENGTH_UNITS
from .budget import require, run_bytes
from .extent import body_diagonal, size_problem
from .hexgrid import structured_box
from .shapes import read_msh
from .voxelize import VoxelizeError, voxelize

if TYPE_CHECKING:
    from collections.abc import Sequence

    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    from .voxelize import VoxelModel

log = get_logger("meshing")


def mesh_from_arrays(comm: MPI.Intracomm, points: np.ndarray, tets: np.ndarray) -> dmesh.Mesh:
    """Distribute a tetrahedral mesh given in full on rank 0 (other ranks' inputs are ignored)."""
    if comm.rank != 0:
        points, tets = np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64)
    return compat.create_mesh(comm, tets, points)


def box_mesh(
    comm: MPI.Intracomm,
    size: Sequence[float],
    cells: Sequence[int],
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    degree: int = 1,
) -> dmesh.Mesh:
    """A box of cells = [nx, ny, nz] hexahedra, five conforming tetrahedra each."""
    nodes = float(np.prod(np.asarray(cells, dtype=float) + 1))
    require(
        run_bytes(nodes, degree),
        f"[mesh] cells = {list(cells)} ({nodes:.3g} nodes)",
        "use fewer cells (the paper's cube has [25, 25, 12])",
    )
    points, tets = structured_box(size, cells, origin) if comm.rank == 0 else (None, None)
    return mesh_from_arrays(comm, points, tets)


def voxelized_mesh(
    comm: MPI.Intracomm,
    input_file: str | Path,
    voxel: float,
    scale: float,
    fill: float = 0.5,
    parts: int = 1,
    labels: Sequence | None = None,
    degree: int | None = 1,
) -> tuple[dmesh.Mesh, VoxelModel | None]:
    """Voxel-mesh on rank 0 (errors raised on every rank), then distribute the tetrahedra.
    Returns (mesh, VoxelModel on rank 0 or None). ``degree``: the run's element degree, to
    refuse a mesh the run could not hold (None: the mesh only)."""
    model, error = None, None
    if comm.rank == 0:
        try:
            model = voxelize(input_file, voxel, scale, fill, parts, labels)
            log.info("voxel mesh of %s: %s", Path(input_file).name, model.report())
            if degree is not None:
                require(
                    run_bytes(len(model.points), degree),
                    f"a run on {len(model.points)} nodes ({voxel * 1e3:g} mm voxels)",
                    "use larger voxels",
                )
        except InputError as exc:
            error = str(exc)
    error = comm.bcast(error, root=0)
    if error:
        raise VoxelizeError(error)
    points, tets = (model.points, model.tets) if model is not None else (None, None)
    return mesh_from_arrays(comm, points, tets), model


def read_mesh_file(comm: MPI.Intracomm, path: str | Path, scale: float = 1.0) -> dmesh.Mesh:
    """A tetrahedral mesh from .msh (gmsh) or .xdmf (DOLFINx/meshio), scaled to metres."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"[mesh] file '{path}' not found")
    if not formats.is_tetra_mesh(path):
        raise InputError(f"[mesh] file '{path.name}' must be .msh or .xdmf")
    try:
        if path.suffix == ".msh":
            mesh = read_msh(comm, str(path))
        elif _dolfinx_xdmf(comm, path):
            mesh = compat.read_xdmf_mesh(comm, path)
        else:  # meshio's XDMF (a grid of another name, cells by type)
            mesh = mesh_from_arrays(comm, *_meshio_tetrahedra(comm, path))
    except Exception as exc:  # corrupt or unreadable file: say which and why, no traceback
        raise InputError(f"[mesh] file '{path.name}' could not be read as a tetrahedral mesh: {exc}") from None
    if mesh.topology.dim != 3:
        raise InputError(
            f"[mesh] file '{path.name}' holds a {mesh.topology.dim}-D mesh; a volume (tetrahedra) is needed"
        )
    mesh.geometry.x[:] *= scale
    return mesh


def _dolfinx_xdmf(comm, path: Path) -> bool:
    """Does the XDMF file hold a grid named "mesh" (DOLFINx's and `brainshift mesh`'s)?"""
    found = None
    if comm.rank == 0:
        import xml.etree.ElementTree as ET

        found = any(grid.get("Name") == "mesh" for grid in ET.parse(path).getroot().iter("Grid"))
    return comm.bcast(found, root=0)


def _meshio_tetrahedra(comm, path: Path):
    """(points, tetrahedra) of an XDMF file meshio reads, on rank 0 (errors on every rank)."""
    points, tets, error = None, None, None
    if comm.rank == 0:
        import meshio

        try:
            data = meshio.read(str(path))
            blocks = [c.data for c in data.cells if c.type == "tetra"]
            if not blocks:
                error = "it holds no tetrahedra"
            else:
                points, tets = data.points[:, :3], np.concatenate(blocks)
        except Exception as exc:  # meshio says what it could not parse
            error = str(exc) or type(exc).__name__
    error = comm.bcast(error, root=0)
    if error:
        raise ValueError(error)
    return points, tets


def write_voxel_mesh(
    path: Path,
    comm: MPI.Intracomm,
    input_file: str,
    voxel: float,
    scale: float,
    fill: float = 0.5,
    parts: int = 1,
    labels: Sequence | None = None,
) -> str:
    """`brainshift mesh`: voxel-mesh a segmentation and write it as XDMF (metres), with the cell
    tags "voxel" (1 + the index of the voxel each tetrahedron came from). Returns the report.
    The caller checks that ``path``'s folder can be written before calling."""
    import dolfinx.io
    import dolfinx.mesh

    mesh, model = voxelized_mesh(comm, input_file, voxel, scale, fill, parts, labels, degree=None)
    problem = size_problem(body_diagonal(mesh), scale)
    if problem is not None:  # before writing: a mm file under --scale 1 is a 170 m brain
        what, unit = problem
        hint = (
            f"is it in {unit}? give --scale {LENGTH_UNITS[unit]:g}" if unit else "check --scale (input units to metres)"
        )
        raise InputError(f"mesh: {what} with --scale {scale:g}: {hint}")
    tet_voxel = comm.bcast(model.tet_voxel if model else None, root=0)
    n_owned = mesh.topology.index_map(3).size_local
    original = np.asarray(mesh.topology.original_cell_index)[:n_owned]
    tags = dolfinx.mesh.meshtags(
        mesh, 3, np.arange(n_owned, dtype=np.int32), (tet_voxel[original] + 1).astype(np.int32)
    )
    tags.name = "voxel"
    if comm.rank == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    with dolfinx.io.XDMFFile(comm, str(path), "w") as xdmf:
        xdmf.write_mesh(mesh)
        compat.write_meshtags(xdmf, tags, mesh)
    return comm.bcast(model.report() if model else None, root=0)
