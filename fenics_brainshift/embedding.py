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
from mpi4py import MPI
from scipy.spatial import cKDTree

from . import compat


class PointEvaluator:
    """Values of a Function at fixed points, each point evaluated by one rank: in the cell
    that holds it, or, just outside the mesh, extrapolated from the nearest cell."""

    def __init__(self, mesh, points: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        self.comm = mesh.comm
        comm, n = self.comm, len(self.points)
        n_owned = mesh.topology.index_map(mesh.topology.dim).size_local
        cells = np.array(compat.colliding_cells(mesh, self.points), dtype=np.int64)
        cells[cells >= n_owned] = -1  # ghosts belong to the neighbour
        # inside: the lowest rank holding a containing cell evaluates the point
        found = np.array(comm.allgather(cells >= 0))
        owner = np.where(found.any(axis=0), found.argmax(axis=0), -1)
        # outside everywhere: the rank with the nearest cell midpoint extrapolates
        outside = np.flatnonzero(owner < 0)
        self._outside_mask = owner < 0
        self.outside = len(outside)
        self.outside_distance = np.zeros(0)
        if len(outside):
            geo = compat.geometry_dofmap(mesh)[:n_owned]
            corners = mesh.geometry.x[geo]
            midpoints = corners.mean(axis=1)
            distance = np.full(len(outside), np.inf)
            if len(midpoints):
                distance, nearest = cKDTree(midpoints).query(self.points[outside])
                cells[outside] = nearest
            distances = np.array(comm.allgather(distance))
            owner[outside] = distances.argmin(axis=0)
            self.outside_distance = distances.min(axis=0)
            local_h = float(np.linalg.norm(corners - midpoints[:, None], axis=2).max()) if len(corners) else 0.0
            self.cell_radius = comm.allreduce(local_h, op=MPI.MAX)
        self.mine = np.flatnonzero(owner == comm.rank)
        self.cells = cells[self.mine].astype(np.int32)
        self.n = n

    def far_outside(self) -> np.ndarray:
        """Indices of points farther from every cell than a cell's own size."""
        if not self.outside:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(self._outside_mask)[self.outside_distance > 2.0 * self.cell_radius]

    def values(self, u) -> np.ndarray:
        """(N, 3) values of u at the points, on every rank."""
        out = np.zeros((self.n, 3))
        if len(self.mine):
            out[self.mine] = u.eval(self.points[self.mine], self.cells).reshape(len(self.mine), -1)[:, :3]
        return self.comm.allreduce(out, op=MPI.SUM)


class SurfaceEmbedding(PointEvaluator):
    """The fine surface's vertices located once in the coarse mesh (see the module note)."""

    def __init__(self, mesh, points: np.ndarray, triangles: np.ndarray):
        super().__init__(mesh, points)
        self.triangles = np.asarray(triangles, dtype=np.int64)

    def displacement(self, u) -> np.ndarray:
        """(N, 3) displacement of the fine surface's vertices, on every rank."""
        return self.values(u)

    def write(self, folder: Path, stem: str, u) -> None:
        """folder/stem.vtk and folder/stem.stl of the deformed surface (rank 0 writes), with the
        displacement as point data in the VTK file."""
        import meshio

        d = self.displacement(u)
        if self.comm.rank == 0:
            mesh = meshio.Mesh(self.points + d, [("triangle", self.triangles)], point_data={"displacement": d})
            mesh.write(folder / f"{stem}.vtk")
            meshio.Mesh(self.points + d, [("triangle", self.triangles)]).write(folder / f"{stem}.stl", binary=True)
        self.comm.barrier()


def surface_of_label_volume(path: str | Path, scale: float, labels=None) -> tuple[np.ndarray, np.ndarray]:
    """A marching-cubes surface (m) of a label volume, for when no surface file is given."""
    import nibabel as nib
    from skimage.measure import marching_cubes

    image = nib.load(str(path))
    data = np.asanyarray(image.dataobj)
    inside = np.isin(data, labels) if labels else data > 0
    verts, faces, _, _ = marching_cubes(np.pad(inside.astype(np.float32), 1), level=0.5)
    A = image.affine
    return ((verts - 1.0) @ A[:3, :3].T + A[:3, 3]) * scale, faces


def load_fine_surface(spec) -> tuple[np.ndarray, np.ndarray] | None:
    """The fine surface a scene asks for: [mesh] surface, else a surface mesh file itself, else
    a marching-cubes surface of a label volume; None for gmsh shapes and tetrahedral files."""
    from .meshing.voxelize import LABEL_SUFFIXES, SURFACE_SUFFIXES, read_surface

    if spec.surface is not None:
        name = spec.surface
    elif spec.file is not None and str(spec.file).lower().endswith(SURFACE_SUFFIXES):
        name = spec.file
    elif spec.file is not None and str(spec.file).lower().endswith(LABEL_SUFFIXES):
        return surface_of_label_volume(spec.file, spec.scale, list(spec.labels) if spec.labels else None)
    else:
        return None
    return read_surface(Path(name), spec.scale)
