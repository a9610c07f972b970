"""A fine surface that follows the coarse model (the paper's Sim-intra-brain).

Every vertex of the fine surface is located once in a coarse tetrahedron; its displacement is
the finite-element displacement there (for P1, the barycentric interpolation of the four
corner values, as the paper interpolates the voxel nodes). Vertices just outside the coarse
mesh (a voxel model does not cover every bump of the surface) take the nearest cell and are
extrapolated with the same affine map, so an affine displacement is reproduced exactly
everywhere. Works under MPI: each vertex is evaluated by one rank, the result gathered.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import formats
from ..errors import InputError
from ..meshing.extent import body_diagonal
from ..meshing.label_surface import label_surface
from ..surfaces.files import read_surface, write_slicer_stl
from .points import PointEvaluator

# a fine surface with more of its vertices than this far outside the coarse mesh does not
# follow it (a thin gyrus the voxels miss is a few vertices, a unit slip all of them)
FAR_VERTICES = 0.01
SIZE_RANGE = (0.02, 5.0)  # the surface's bounding-box diagonal against the mesh's: a unit's 1000x or 100x
# is outside; a patch of the cortex (the craniotomy's, 0.2x) is inside
AREA_FRACTION = 0.1  # of the squared diagonal: a closed surface covers about 1x (a sphere pi/3)


class SurfaceEmbedding(PointEvaluator):
    """The fine surface's vertices located once in the coarse mesh (see the module note)."""

    @classmethod
    def of_scene(cls, mesh, points: np.ndarray, triangles: np.ndarray) -> SurfaceEmbedding:
        """The embedding of a scene's fine surface, checked first to be the body's closed
        surface in the mesh's unit (_check_size)."""
        _check_size(np.asarray(points), np.asarray(triangles, dtype=np.int64), body_diagonal(mesh))
        return cls(mesh, points, triangles)

    def __init__(self, mesh, points: np.ndarray, triangles: np.ndarray):
        super().__init__(mesh, points)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        far = self.far_outside()
        if len(far) > FAR_VERTICES * len(self.points):  # a surface of another object, unit or frame
            extent = np.ptp(self.points, axis=0) * 1e3
            raise InputError(
                f"[mesh] surface: {len(far)} of its {len(self.points)} vertices lie farther than two "
                f"cells from the mesh (the surface spans {extent[0]:.3g} x {extent[1]:.3g} x "
                f"{extent[2]:.3g} mm in [mesh] unit): is it in another unit or frame (RAS / LPS) than "
                f"the mesh, or of another object?"
            )

    def write(self, folder: Path, stem: str, u) -> None:
        """folder/stem.vtk (m, with the displacement as point data: ParaView, beside
        displacement.xdmf) and folder/stem.stl (mm, tagged RAS: 3D Slicer) of the deformed
        surface (rank 0 writes)."""
        import meshio

        d = self.values(u)  # (N, 3) displacement of the fine surface's vertices, on every rank
        if self.comm.rank == 0:
            mesh = meshio.Mesh(self.points + d, [("triangle", self.triangles)], point_data={"displacement": d})
            mesh.write(folder / f"{stem}.vtk")
            write_slicer_stl(folder / f"{stem}.stl", (self.points + d) * 1e3, self.triangles)
        self.comm.barrier()


def _check_size(points: np.ndarray, triangles: np.ndarray, body: float) -> None:
    """InputError for a fine surface of another size than the mesh (a surface in metres under
    [mesh] unit = "mm" lies near the origin, inside the mesh, 1000x too small: no vertex is
    far outside it) or of too little area for its size (slivers and degenerate triangles: not
    a closed surface)."""
    size = float(np.linalg.norm(np.ptp(points, axis=0))) if len(points) else 0.0
    corners = points[triangles] if len(triangles) else np.zeros((0, 3, 3))
    area = 0.5 * float(
        np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
    )
    if area < AREA_FRACTION * size**2:
        raise InputError(
            f"[mesh] surface: its triangles cover {area * 1e6:.3g} mm^2, where a closed surface "
            f"{size * 1e3:.3g} mm across covers about {size**2 * 1e6:.3g}: degenerate triangles, or "
            f"not the body's closed surface"
        )
    low, high = SIZE_RANGE
    if not low * body <= size <= high * body:
        ratio = size / body
        raise InputError(
            f"[mesh] surface: it is {size * 1e3:.3g} mm across (bounding-box diagonal), the mesh "
            f"{body * 1e3:.3g} mm ({ratio:.3g}x): is it in another unit than the mesh (mm or m: "
            f"[mesh] unit applies to both), or of another object?"
        )


def load_fine_surface(file: str | None, surface: str | None, scale: float, labels=None):
    """The fine surface (points in m, triangles) a mesh input implies: ``surface`` if given,
    else a surface ``file`` itself, else a marching-cubes surface of a label volume ``file``;
    None for gmsh shapes and tetrahedral files. ``scale``: the files' unit in m."""
    if surface is not None:
        return read_surface(Path(surface), scale)
    if file is not None and formats.is_surface(file):
        return read_surface(Path(file), scale)
    if file is not None and formats.is_label_volume(file):
        return label_surface(file, list(labels) if labels else None, scale, "[mesh] labels")
    return None
