"""The clipped hydrostatic pressure on the exterior surface, assembled exactly.

The wet-facet integrals (wet_facets.py) of every surface triangle with a wet vertex are
scattered into a nodal load vector on V. The "consistent" and "paper" rules sum, over a closed
surface, to rho_f |g| V_submerged along up (Archimedes) to round-off; "quadrature" is the
plain UFL surface form (pressure_quadrature.py), kept to show why the exact rule exists.
Geometry may follow the displacement (``u``): then the current positions x + u are used, as
the paper does. Dry facets are dropped before any arithmetic.
"""

from __future__ import annotations

import dolfinx.la
import numpy as np
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from .. import compat
from .pressure_quadrature import QuadratureFluidLoad
from .surface import surface_facets
from .wet_facets import triangle_geometry, wet_integrals

RULES = ("consistent", "paper", "quadrature")


def _scatter_add(local: np.ndarray, dofs: np.ndarray, forces: np.ndarray) -> None:
    """local[dofs] += forces, summing repeats (np.add.at, but by bincount: several times faster)."""
    flat = dofs.ravel()
    for c in range(local.shape[1]):
        local[:, c] += np.bincount(flat, weights=forces[..., c].ravel(), minlength=local.shape[0])


class HydrostaticLoad:
    """Nodal fluid load on a vector space V, for any level and (optionally) displacement."""

    def __init__(self, V, rho_fluid: float, gravity, rule: str = "consistent", quadrature_degree: int = 4):
        if rule not in RULES:
            raise ValueError(f"rule must be one of {', '.join(RULES)} (got {rule!r})")
        self.V = V
        self.rule = rule
        self.degree = compat.element_degree(V)
        if rule == "paper" and self.degree != 1:
            raise ValueError(
                "the paper's rule shares forces among triangle vertices: degree 1 only; "
                'use rule = "consistent" with degree 2'
            )
        g = np.asarray(gravity, dtype=float)
        self.g_magnitude = float(np.linalg.norm(g))
        self.up = -g / self.g_magnitude
        self.rho_fluid = float(rho_fluid)
        self.comm = V.mesh.comm
        self.vector = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self.facets = surface_facets(V)
        self._reference = None  # normals, areas, heights of the reference surface, once needed
        self._quadrature = None
        if rule == "quadrature":
            self._quadrature = QuadratureFluidLoad(V, rho_fluid, g, quadrature_degree)
        self.force = np.zeros(3)
        self.submerged_volume = 0.0
        self.wet_facets = 0

    def set_gravity(self, gravity) -> None:
        """Another gravity vector (a head pose): up and |g| change, the reference heights too."""
        if self._quadrature is not None:
            raise ValueError('the quadrature rule keeps its gravity; use rule = "consistent"')
        g = np.asarray(gravity, dtype=float)
        self.g_magnitude = float(np.linalg.norm(g))
        self.up = -g / self.g_magnitude
        self._reference = None

    def set_present(self, present: np.ndarray) -> None:
        """After a resection: the load acts on the surface of the cells still present."""
        self.facets = surface_facets(self.V, present)
        self._reference = None
        if self._quadrature is not None:
            raise ValueError(
                'the quadrature rule acts on the original surface only; use rule = "consistent" with [[remove]]'
            )

    def geometry(self, u=None):
        """Facet vertices and opposite vertices, moved by u (a Function on V) if given."""
        f = self.facets
        if u is None:
            return f.x_vertices, f.x_opposite
        values = u.x.array.reshape(-1, 3)
        return f.x_vertices + values[f.vertex_dofs], f.x_opposite + values[f.opposite_dofs]

    def reference_surface(self):
        """Normals, areas, vertex heights, each facet's lowest height, outward orientation
        (+1/-1 on the vertex order's cross product) and the vertex dofs of the reference
        surface, computed once."""
        if self._reference is None:
            X, X_opp = self.geometry()
            n, area = triangle_geometry(X, X_opp)
            cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
            orientation = np.where(np.einsum("ij,ij->i", cross, n) < 0.0, -1.0, 1.0)
            height = X @ self.up
            self._reference = (n, area, height, height.min(axis=1), orientation, np.unique(self.facets.vertex_dofs))
        return self._reference

    def _wet_triangles(self, level: float, u=None):
        """(indices, unit outward normals, areas, vertex depths) of the facets with a wet
        vertex; dry facets cost nothing more. On the reference geometry (u None) all of it
        comes from reference_surface. On x + u only facets that can be wet are moved: those
        whose lowest reference vertex is below the level plus the surface's greatest fall;
        their outward side is the reference one (a facet does not turn inside out)."""
        n, area, height, lowest, orientation, surface_dofs = self.reference_surface()
        if u is None:
            wet = np.flatnonzero((height < level).any(axis=1))
            return wet, n[wet], area[wet], level - height[wet]
        values = u.x.array.reshape(-1, 3)
        sink = float(-(values[surface_dofs] @ self.up).min(initial=0.0))  # the surface's greatest fall
        near = np.flatnonzero(lowest < level + sink)
        X = self.facets.x_vertices[near] + values[self.facets.vertex_dofs[near]]
        depth = level - X @ self.up
        wet = np.flatnonzero((depth > 0).any(axis=1))
        X = X[wet]
        cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
        twice_area = np.linalg.norm(cross, axis=1)
        normals = cross * (orientation[near[wet]] / np.where(twice_area > 0, twice_area, 1.0))[:, None]
        return near[wet], normals, 0.5 * twice_area, depth[wet]

    def highest(self, u=None, up: float = 1.0) -> float:
        """The greatest height (x.up) of the surface, global; up = -1: minus the lowest."""
        X, _ = self.geometry(u)
        local = float((up * (X @ self.up)).max()) if len(X) else -np.inf
        return self.comm.allreduce(local, op=MPI.MAX)

    def volume_below(self, level: float, u=None) -> float:
        """Volume of the body below the level (global), from the surface alone:
        V = sum over wet sub-triangles of area * depth(centroid) * (-n.up) (divergence theorem)."""
        _, n, area, depth = self._wet_triangles(level, u)
        _, vertex, _ = wet_integrals(depth, area, 1, "paper")
        local = float(np.sum(vertex.sum(axis=1) * -(n @ self.up)))
        return self.comm.allreduce(local, op=MPI.SUM)

    def assemble(self, level: float, u=None) -> PETSc.Vec:
        """The assembled nodal load (owned entries summed over ranks, ghosts updated)."""
        if self._quadrature is not None:
            if u is not None:
                raise ValueError(
                    "the quadrature rule integrates on the reference geometry; "
                    'use rule = "consistent" for follower loading'
                )
            vec = self._quadrature.assemble(level)
            vec.copy(self.vector)
            self._totals_from_vector(level)
            return self.vector
        wet, n, area, depth = self._wet_triangles(level, u)
        order, vertex, edge = wet_integrals(depth, area, self.degree, self.rule)
        rho_g = self.rho_fluid * self.g_magnitude
        local = np.zeros((self.V.dofmap.index_map.size_local + self.V.dofmap.index_map.num_ghosts, 3))
        vertex_dofs = np.take_along_axis(self.facets.vertex_dofs[wet], order, axis=1)
        _scatter_add(local, vertex_dofs, -rho_g * vertex[:, :, None] * n[:, None, :])  # (F, 3 nodes, 3 components)
        if edge is not None:
            # the edge opposite ordered vertex k is the edge opposite original vertex order[k]
            edge_dofs = np.take_along_axis(self.facets.edge_dofs[wet], order, axis=1)
            _scatter_add(local, edge_dofs, -rho_g * edge[:, :, None] * n[:, None, :])
        with self.vector.localForm() as lf:
            lf.array[:] = local.ravel()
        self.vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self.wet_facets = self.comm.allreduce(len(wet), op=MPI.SUM)
        self._totals_from_vector(level)
        return self.vector

    def _totals_from_vector(self, level: float) -> None:
        """Resultant force (N) and the submerged volume it implies: F.up = rho_f |g| V_sub."""
        owned = self.vector.getArray(readonly=True).reshape(-1, 3).sum(axis=0)
        self.force = self.comm.allreduce(owned, op=MPI.SUM)
        self.submerged_volume = float(self.force @ self.up) / (self.rho_fluid * self.g_magnitude)

    def as_function(self, name: str = "fluid_load") -> fem.Function:
        f = fem.Function(self.V, name=name)
        with self.vector.localForm() as lf:
            f.x.array[:] = lf.array_r
        return f


def hydrostatic_load(
    V: fem.FunctionSpace,
    level: float,
    rho_fluid: float,
    gravity: np.ndarray,
    u: fem.Function | None = None,
    rule: str = "consistent",
) -> fem.Function:
    """The assembled nodal fluid load as a Function on V (see HydrostaticLoad)."""
    load = HydrostaticLoad(V, rho_fluid, gravity, rule)
    load.assemble(level, u)
    return load.as_function()
