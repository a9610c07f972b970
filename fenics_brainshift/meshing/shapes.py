"""Unstructured meshes of simple shapes with gmsh (built on rank 0, then distributed)."""
from __future__ import annotations

from .. import compat


def gmsh_shape(comm, shape: str, size, origin, h: float):
    """A tetrahedral mesh of a box (size = extents, origin = corner) or an ellipsoid
    (size = semi-axes, origin = centre) with element size h."""
    import gmsh

    initialised_here = not gmsh.isInitialized()
    if initialised_here:
        gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    model = gmsh.model
    try:
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
    finally:
        if comm.rank == 0:
            model.remove()
        if initialised_here:
            gmsh.finalize()
    return mesh
