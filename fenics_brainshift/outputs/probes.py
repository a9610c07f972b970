"""Named points where the displacement is sampled, in serial and under MPI alike."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from ..errors import InputError


class Probes:
    """Named points where the displacement is sampled, the same on every rank. A point just
    outside the mesh (a voxel model does not reach every anatomical landmark) is extrapolated
    from the nearest cell; one farther away than a cell's size is an error."""

    def __init__(self, mesh, points: dict[str, tuple[float, float, float]]):
        from .points import PointEvaluator

        self.names = list(points)
        coords = np.array([points[n] for n in self.names], dtype=np.float64).reshape(-1, 3)
        self.evaluator = PointEvaluator(mesh, coords)
        for i in self.evaluator.far_outside():
            raise InputError(
                f"[probes] {self.names[i]} = {list(coords[i])} lies outside the mesh, farther than a "
                f"cell from it: a frame slip (a markups file's coordinateSystem says LPS or RAS: do "
                f"its numbers agree?), a unit slip, or a point not on the body"
            )

    def values(self, f) -> np.ndarray:
        """(n_points, 3) values of a Function (ghosts must be up to date)."""
        return self.evaluator.values(f)

    def as_dict(self, values: np.ndarray) -> dict[str, list[float]]:
        return {n: [float(c) for c in v] for n, v in zip(self.names, values)}


class SurfaceAverages:
    """Area-weighted mean displacement over parts of the exterior surface, each given by a
    coordinate predicate that all vertices of a facet must satisfy (e.g. the cube's top face,
    as the paper's camera averaged the top surface's point cloud)."""

    def __init__(self, u, regions: dict):
        import dolfinx.mesh
        import ufl
        from dolfinx import fem

        from .. import compat

        mesh = u.function_space.mesh
        self.names = list(regions)
        self.comm = mesh.comm
        self.forms = []
        if not self.names:
            return
        mesh.topology.create_connectivity(2, 3)
        n_owned = mesh.topology.index_map(2).size_local
        for name in self.names:
            facets = dolfinx.mesh.locate_entities_boundary(mesh, 2, regions[name])
            if self.comm.allreduce(int(np.sum(facets < n_owned)), op=MPI.SUM) == 0:
                raise InputError(f'[surfaces] {name} = "{regions[name].text}" selects no boundary facet')
            tags = dolfinx.mesh.meshtags(
                mesh, 2, np.sort(facets).astype(np.int32), np.ones(len(facets), dtype=np.int32)
            )
            ds = ufl.Measure("ds", domain=mesh, subdomain_data=tags)(1)
            one = fem.Constant(mesh, 1.0)
            self.forms.append([compat.form(one * ds)] + [compat.form(u[i] * ds) for i in range(3)])

    def values(self) -> np.ndarray:
        """(n_regions, 3) mean displacement of each region (global)."""
        from dolfinx import fem

        out = np.zeros((len(self.names), 3))
        for k, forms in enumerate(self.forms):
            local = np.array([fem.assemble_scalar(f) for f in forms])
            area, *integrals = self.comm.allreduce(local, op=MPI.SUM)
            out[k] = np.array(integrals) / area
        return out

    def as_dict(self, values: np.ndarray) -> dict[str, list[float]]:
        return {n: [float(c) for c in v] for n, v in zip(self.names, values)}
