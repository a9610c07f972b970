"""Turn a MeshSpec into a distributed DOLFINx mesh (coordinates in metres)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import compat
from ..scene import MeshSpec, SceneError
from .hexgrid import structured_box
from .shapes import gmsh_shape, read_msh


def mesh_from_arrays(comm, points: np.ndarray, tets: np.ndarray):
    """Distribute a tetrahedral mesh given in full on rank 0 (other ranks' inputs are ignored)."""
    if comm.rank != 0:
        points, tets = np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64)
    return compat.create_mesh(comm, tets, points)


def voxel_model_mesh(spec: MeshSpec, comm):
    """The embedding mesher for a scene's [mesh]: (mesh, VoxelModel on rank 0 or None)."""
    return voxelized_mesh(comm, spec.file, spec.voxel, spec.scale, spec.fill, spec.parts,
                          list(spec.labels) if spec.labels else None)


def voxelized_mesh(comm, input_file, voxel: float, scale: float, fill: float, parts: int, labels):
    """Voxel-mesh on rank 0 (errors raised on every rank), then distribute the tetrahedra."""
    from ..logs import get_logger
    from .voxelize import VoxelizeError, voxelize

    model, error = None, None
    if comm.rank == 0:
        try:
            model = voxelize(input_file, voxel, scale, fill, parts, labels)
            get_logger("meshing").info("voxel mesh of %s: %s", Path(input_file).name, model.report())
        except VoxelizeError as exc:
            error = str(exc)
    error = comm.bcast(error, root=0)
    if error:
        raise SceneError(f"[mesh] {error}")
    points, tets = (model.points, model.tets) if model is not None else (None, None)
    return mesh_from_arrays(comm, points, tets), model


def build_mesh(spec: MeshSpec, comm):
    if spec.shape == "box" and spec.cells is not None:
        points, tets = structured_box(spec.size, spec.cells, spec.origin) if comm.rank == 0 else (None, None)
        return mesh_from_arrays(comm, points, tets)
    if spec.shape is not None:
        return gmsh_shape(comm, spec.shape, spec.size, spec.origin, spec.h)
    path = Path(spec.file)
    if not path.is_file():
        raise SceneError(f"[mesh] file '{path}' not found")
    if spec.needs_voxels:
        return voxel_model_mesh(spec, comm)[0]
    try:
        if path.suffix == ".msh":
            mesh = read_msh(comm, str(path))
        elif path.suffix == ".xdmf":
            import dolfinx.io

            with dolfinx.io.XDMFFile(comm, str(path), "r") as f:
                mesh = f.read_mesh(name="mesh")
        else:
            raise SceneError(f"[mesh] file '{path.name}' must be .msh or .xdmf")
    except SceneError:
        raise
    except Exception as exc:  # corrupt or unreadable file: say which and why, no traceback
        raise SceneError(f"[mesh] file '{path.name}' could not be read as a tetrahedral mesh: {exc}") from None
    if mesh.topology.dim != 3:
        raise SceneError(f"[mesh] file '{path.name}' holds a {mesh.topology.dim}-D mesh; a volume (tetrahedra) is needed")
    mesh.geometry.x[:] *= spec.scale
    return mesh


def write_voxel_mesh(path: Path, comm, input_file: str, voxel: float, scale: float, fill: float = 0.5,
                     parts: int = 1, labels=None):
    """`brainshift mesh`: voxel-mesh a segmentation and write it as XDMF (metres), with the cell
    tags "voxel" (1 + the index of the voxel each tetrahedron came from). Returns the report."""
    import dolfinx.io
    import dolfinx.mesh

    mesh, model = voxelized_mesh(comm, input_file, voxel, scale, fill, parts, labels)
    tet_voxel = comm.bcast(model.tet_voxel if model else None, root=0)
    n_owned = mesh.topology.index_map(3).size_local
    original = np.asarray(mesh.topology.original_cell_index)[:n_owned]
    tags = dolfinx.mesh.meshtags(mesh, 3, np.arange(n_owned, dtype=np.int32),
                                 (tet_voxel[original] + 1).astype(np.int32))
    tags.name = "voxel"
    if comm.rank == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    with dolfinx.io.XDMFFile(comm, str(path), "w") as xdmf:
        xdmf.write_mesh(mesh)
        compat.write_meshtags(xdmf, tags, mesh)
    return comm.bcast(model.report() if model else None, root=0)
