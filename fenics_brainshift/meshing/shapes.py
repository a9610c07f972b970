"""Unstructured meshes with gmsh (built or read on rank 0, then distributed)."""

from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np

from .. import compat
from .budget import require, run_bytes

if TYPE_CHECKING:
    from collections.abc import Sequence

    from dolfinx import mesh as dmesh
    from mpi4py import MPI


@contextmanager
def gmsh_session():
    """gmsh initialised for the block and finalised after, unless the caller already runs it.
    (gmsh 4.8 on Debian 12 cannot say whether it is initialised; then we start our own.)"""
    import gmsh

    probe = getattr(gmsh, "isInitialized", None) or getattr(gmsh, "is_initialized", None)
    started = not (probe() if probe else False)
    if started:
        gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        yield gmsh
    finally:
        if started:
            gmsh.finalize()


def gmsh_shape(
    comm: MPI.Intracomm, shape: str, size: Sequence[float], origin: Sequence[float], h: float, degree: int = 1
) -> dmesh.Mesh:
    """A tetrahedral mesh of a box (size = extents, origin = corner) or an ellipsoid
    (size = semi-axes, origin = centre) with element size h."""
    volume = float(np.prod(size)) * (4.0 / 3.0 * np.pi if shape == "ellipsoid" else 1.0)
    nodes = 1.5 * volume / h**3  # about what gmsh makes for a tetrahedral mesh of edge h
    require(
        run_bytes(nodes, degree),
        f"[mesh] h = {h:g} m for a {shape} of {volume * 1e6:.3g} ml (about {nodes:.3g} nodes)",
        "[mesh] h is in metres: use a larger element size",
    )
    with gmsh_session() as gmsh:
        model = gmsh.model
        if comm.rank == 0:
            model.add(f"brainshift_{shape}")
            if shape == "box":
                tag = model.occ.addBox(*origin, *size)
            else:
                tag = model.occ.addSphere(*origin, 1.0)
                model.occ.dilate([(3, tag)], *origin, *size)
            model.occ.synchronize()
            model.addPhysicalGroup(3, [tag], 1)
            gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h)
            gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
            model.mesh.generate(3)
        mesh, _, _ = compat.gmsh_model_to_mesh(model, comm, 0)
        if comm.rank == 0:
            model.remove()
    return mesh


def read_msh(comm, path: str):
    """A gmsh .msh file's volume mesh. (DOLFINx 0.5.2's own read_from_msh is broken:
    NameError 'msh'; opening the file in gmsh and converting the model works in 0.5 and 0.9.)"""
    with gmsh_session() as gmsh:
        error = None
        if comm.rank == 0:
            try:
                gmsh.open(path)
                volumes = gmsh.model.getEntities(3)
                if not volumes:
                    error = "it holds no volume (tetrahedra), only a surface or nothing"
                elif not gmsh.model.getPhysicalGroups(3):  # model_to_mesh reads physical volumes
                    for _, tag in volumes:
                        gmsh.model.addPhysicalGroup(3, [tag])
            except Exception as exc:  # gmsh says what it could not parse
                error = str(exc) or type(exc).__name__
        error = comm.bcast(error, root=0)  # every rank raises, none waits for the others
        if error:
            raise ValueError(error)
        mesh, _, _ = compat.gmsh_model_to_mesh(gmsh.model, comm, 0)
        if comm.rank == 0:
            gmsh.model.remove()
    return mesh
