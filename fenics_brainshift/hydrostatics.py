"""The clipped hydrostatic pressure on the exterior surface, integrated exactly.

p = rho_f |g| max(level - x.up, 0) acts along -n. Its kink at the water line defeats any
fixed quadrature rule, so every exterior triangle is split exactly at the water line (the
paper's cases 1-4, eqs. 10-19) and only the wet part is integrated:

- ``"consistent"``: the exact integral of p N_i over the wet polygon for each basis function
  N_i of the facet (P1 or P2), by a quadrature rule exact for its cubic integrand on each wet
  sub-triangle;
- ``"paper"``: each wet sub-triangle's force rho_f |g| depth(centroid) area (-n), shared among
  the wet vertices by depth (eqs. 11-19); P1 only. Of two wet vertices, j1 is the deeper;
- ``"quadrature"``: the plain UFL surface form with max(., 0) (reference geometry only), kept
  to show why the exact rule exists.

The first two sum, over a closed surface, to rho_f |g| V_submerged along up (Archimedes) to
round-off. The work is vectorised over facets; dry facets are dropped before any of it.
Geometry may follow the displacement (``u``): then the current positions x + u are used, as
the paper does.
"""
from __future__ import annotations

from dataclasses import dataclass

import basix
import dolfinx.la
import dolfinx.mesh
import numpy as np
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from . import compat
from .meshing.facets import present_facet_counts

RULES = ("consistent", "paper", "quadrature")


# ----------------------------------------------------------------- reference quadrature
def _triangle_rule() -> tuple[np.ndarray, np.ndarray]:
    """Collapsed 3 x 3 Gauss rule on a triangle: barycentric points (9, 3) and weights summing
    to 1, exact for polynomials of total degree 4 (p N_i is at most cubic)."""
    g, w = np.polynomial.legendre.leggauss(3)
    g, w = (g + 1) / 2, w / 2
    xi, eta = np.meshgrid(g, g, indexing="ij")
    wx, wy = np.meshgrid(w, w, indexing="ij")
    x, y = xi.ravel(), (eta * (1 - xi)).ravel()
    weights = (wx * wy * (1 - xi)).ravel() * 2.0
    return np.column_stack([1 - x - y, x, y]), weights


QUAD_POINTS, QUAD_WEIGHTS = _triangle_rule()


# ----------------------------------------------------------------- the split, vectorised
def split_wet(depth: np.ndarray):
    """Split triangles at the water line, in barycentric coordinates.

    depth: (F, 3) depth below the surface at the vertices (> 0: wet).
    Returns (order, B, wet_count): ``order`` (F, 3) sorts each facet's vertices deepest first;
    ``B`` (F, 2, 3, 3) holds up to two wet sub-triangles, row a = barycentric coordinates (in
    the sorted vertex order) of sub-vertex a; unused sub-triangles are all zero.
      3 wet (case 1): (0, 1, 2)
      2 wet (case 2): (0, 1, P02) and (1, P12, P02)   [P02 on edge 0-2 at the water line]
      1 wet (case 3): (0, P01, P02)
      0 wet (case 4): nothing
    """
    order = np.argsort(-depth, axis=1, kind="stable")
    d = np.take_along_axis(depth, order, axis=1)
    wet = (d > 0).sum(axis=1)
    F = depth.shape[0]
    eye = np.eye(3)
    B = np.zeros((F, 2, 3, 3))

    def cut(i, j, rows):  # point on edge i-j where the depth is zero
        t = d[rows, i] / (d[rows, i] - d[rows, j])
        return (1 - t)[:, None] * eye[i] + t[:, None] * eye[j]

    c1, c2, c3 = wet == 3, wet == 2, wet == 1
    B[c1, 0] = eye
    if c2.any():
        p02, p12 = cut(0, 2, c2), cut(1, 2, c2)
        B[c2, 0, 0], B[c2, 0, 1], B[c2, 0, 2] = eye[0], eye[1], p02
        B[c2, 1, 0], B[c2, 1, 1], B[c2, 1, 2] = eye[1], p12, p02
    if c3.any():
        B[c3, 0, 0], B[c3, 0, 1], B[c3, 0, 2] = eye[0], cut(0, 1, c3), cut(0, 2, c3)
    return order, B, wet


def triangle_geometry(X: np.ndarray, X_opposite: np.ndarray):
    """Unit outward normals (F, 3) and areas (F,) of triangles X (F, 3, 3) on the surface of
    tetrahedra whose fourth vertex is X_opposite (F, 3)."""
    cross = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    n = cross / np.where(norm > 0, norm, 1.0)[:, None]
    inward = np.einsum("ij,ij->i", n, X_opposite - X[:, 0]) > 0
    n[inward] *= -1
    return n, 0.5 * norm


def consistent_loads(depth: np.ndarray, area: np.ndarray, degree: int, split=None):
    """Exact integrals of depth * N over the wet part, per facet and basis function (P1 in
    closed form, P2 by a rule exact for the cubic integrand).

    Returns (vertex (F, 3), edge (F, 3) or None) in the *sorted* order of split_wet; edge k is
    the edge opposite sorted vertex k. Multiply by rho_f |g| (-n) for the nodal forces.
    ``split``: split_wet(depth), when the caller has it already."""
    order, B, _ = split if split is not None else split_wet(depth)
    d = np.take_along_axis(depth, order, axis=1)
    sub_area = area[:, None] * np.abs(np.linalg.det(B))  # (F, 2)
    if degree == 1:
        # closed form: on a triangle of area A, the integral of the product of two linear
        # functions f, g with vertex values f_a, g_a is A/12 (sum_a f_a g_a + sum_a f_a sum_b g_b)
        dep = (B @ d[:, None, :, None])[..., 0]  # (F, 2, 3) depth at the sub-vertices
        lam_dep = (dep[:, :, None, :] @ B)[:, :, 0, :]  # sum_a lambda_k(a) depth(a)
        both = lam_dep + B.sum(axis=2) * dep.sum(axis=2)[..., None]
        return np.einsum("fs,fsk->fk", sub_area / 12.0, both), None
    lam = np.einsum("qa,fsak->fsqk", QUAD_POINTS, B)  # parent barycentrics at the points
    w = sub_area[:, :, None] * QUAD_WEIGHTS[None, None, :]  # (F, 2, Q)
    wp = w * np.einsum("fsqk,fk->fsq", lam, d)  # weight * depth at each point
    vertex = np.einsum("fsq,fsqk->fk", wp, lam * (2 * lam - 1))
    pairs = [(1, 2), (0, 2), (0, 1)]  # edge opposite sorted vertex k
    edge = np.stack([np.einsum("fsq,fsq->f", wp, 4 * lam[..., i] * lam[..., j]) for i, j in pairs], axis=1)
    return vertex, edge


def paper_loads(depth: np.ndarray, area: np.ndarray, split=None) -> np.ndarray:
    """The paper's nodal shares of depth * area (eqs. 11-19), sorted vertex order (F, 3)."""
    order, B, wet = split if split is not None else split_wet(depth)
    d = np.take_along_axis(depth, order, axis=1)
    sub_area = area[:, None] * np.abs(np.linalg.det(B))
    centroid_depth = np.einsum("fsak,fk->fs", B, d) / 3.0
    force = sub_area * centroid_depth  # (F, 2): depth-area of each wet sub-triangle
    shares = np.zeros((depth.shape[0], 2, 3))
    c1, c2, c3 = wet == 3, wet == 2, wet == 1
    shares[c1, 0] = d[c1] / d[c1].sum(axis=1, keepdims=True)  # eq. 13
    s = d[c2, 0] + d[c2, 1]
    shares[c2, 0, 0], shares[c2, 0, 1] = d[c2, 0] / s, d[c2, 1] / s  # eq. 16, 17
    shares[c2, 1, 1] = 1.0  # eq. 17: the second part goes to j2
    shares[c3, 0, 0] = 1.0  # eq. 19
    return np.einsum("fs,fsk->fk", force, shares)


def wet_integrals(depth: np.ndarray, area: np.ndarray, degree: int, rule: str = "consistent"):
    """The rule's nodal integrals of depth * N for facets with at least one wet vertex.

    Facets entirely under water (most of them) take closed forms; only those the water line
    cuts are split (split_wet), which is where the time went. The integrals of products of
    barycentrics, int l1^a l2^b l3^c = 2 A a! b! c! / (a + b + c + 2)!, give with D = sum d:
      P1:            vertex_k = A (d_k + D) / 12
      P2:            vertex_k = A (3 d_k - D) / 60,   edge_k (opposite vertex k) = A (2 D - d_k) / 15
      paper, case 1: vertex_k = A d_k / 3              (eq. 13: A D/3 shared as d_k / D)
    Returns (order, vertex, edge or None): row f of vertex/edge belongs to the facet's
    vertices in the order order[f] (the identity for whole facets, deepest first for cut ones)."""
    F = depth.shape[0]
    order = np.tile(np.arange(3), (F, 1))
    vertex = np.empty((F, 3))
    edge = np.empty((F, 3)) if degree == 2 and rule == "consistent" else None
    whole = (depth > 0).all(axis=1)
    d, A = depth[whole], area[whole, None]
    D = d.sum(axis=1, keepdims=True)
    if rule == "paper":
        vertex[whole] = A * d / 3.0
    elif degree == 1:
        vertex[whole] = A * (d + D) / 12.0
    else:
        vertex[whole] = A * (3.0 * d - D) / 60.0
        edge[whole] = A * (2.0 * D - d) / 15.0
    cut = ~whole
    if cut.any():
        split = split_wet(depth[cut])
        order[cut] = split[0]
        if rule == "paper":
            vertex[cut] = paper_loads(depth[cut], area[cut], split)
        else:
            vertex[cut], edge_cut = consistent_loads(depth[cut], area[cut], degree, split)
            if edge is not None:
                edge[cut] = edge_cut
    return order, vertex, edge


def _scatter_add(local: np.ndarray, dofs: np.ndarray, forces: np.ndarray) -> None:
    """local[dofs] += forces, summing repeats (np.add.at, but by bincount: several times faster)."""
    flat = dofs.ravel()
    for c in range(local.shape[1]):
        local[:, c] += np.bincount(flat, weights=forces[..., c].ravel(), minlength=local.shape[0])


# ----------------------------------------------------------------- the surface of a mesh
@dataclass
class SurfaceFacets:
    """The surface facets of the cells present, each held by the rank owning its cell, with what
    the assembly needs of each."""

    vertex_dofs: np.ndarray  # (F, 3) block dofs of V at the facet's vertices
    opposite_dofs: np.ndarray  # (F,) block dof at the cell's vertex opposite the facet
    edge_dofs: np.ndarray | None  # (F, 3) P2: dof of the edge opposite facet vertex k
    x_vertices: np.ndarray  # (F, 3, 3) reference coordinates
    x_opposite: np.ndarray  # (F, 3)


def surface_facets(V, present: np.ndarray | None = None) -> SurfaceFacets:
    """The surface of the cells present (all cells by default): facets with exactly one
    present cell next to them, each taken by the rank that owns that cell.

    The count is global (meshing.facets), so the surface is the same on any number of ranks;
    after a resection the cut faces join it."""
    mesh = V.mesh
    cells_present, counts = present_facet_counts(mesh, present)
    once = counts == 1  # (n, 4): facet k of the cell is on the surface
    cells = np.repeat(cells_present, 4)[once.ravel()]
    local = np.tile(np.arange(4), len(cells_present))[once.ravel()]  # facet k is opposite vertex k
    others = np.array([[v for v in range(4) if v != lf] for lf in range(4)])  # facet lf's vertices
    fv = others[local]  # (F, 3) local vertex numbers

    layout = V.dofmap.dof_layout
    vertex_local = np.array([layout.entity_dofs(0, v)[0] for v in range(4)])
    dofs = compat.dofmap_array(V)[cells]
    x = mesh.geometry.x
    geo = compat.geometry_dofmap(mesh)[cells]
    rows = np.arange(len(cells))[:, None]  # one row per surface facet
    edge_dofs = None
    if compat.element_degree(V) == 2:
        edges = basix.topology(basix.CellType.tetrahedron)[1]
        edge_of = {frozenset(e): layout.entity_dofs(1, i)[0] for i, e in enumerate(edges)}
        table = np.array([[edge_of[frozenset(others[lf][[j for j in range(3) if j != k]])]
                           for k in range(3)] for lf in range(4)])
        edge_dofs = dofs[rows, table[local]]
    return SurfaceFacets(
        vertex_dofs=dofs[rows, vertex_local[fv]],
        opposite_dofs=dofs[rows[:, 0], vertex_local[local]],
        edge_dofs=edge_dofs,
        x_vertices=x[geo[rows, fv]],
        x_opposite=x[geo[rows[:, 0], local]],
    )


# ----------------------------------------------------------------- the assembled load
class HydrostaticLoad:
    """Nodal fluid load on a vector space V, for any level and (optionally) displacement."""

    def __init__(self, V, rho_fluid: float, gravity, rule: str = "consistent", quadrature_degree: int = 4):
        if rule not in RULES:
            raise ValueError(f"rule must be one of {', '.join(RULES)} (got {rule!r})")
        self.V = V
        self.rule = rule
        self.degree = compat.element_degree(V)
        if rule == "paper" and self.degree != 1:
            raise ValueError("the paper's rule shares forces among triangle vertices: degree 1 only; "
                             "use rule = \"consistent\" with degree 2")
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
            from .loads import QuadratureFluidLoad

            self._quadrature = QuadratureFluidLoad(V, rho_fluid, g, quadrature_degree)
        self.force = np.zeros(3)
        self.submerged_volume = 0.0
        self.wet_facets = 0

    def set_present(self, present: np.ndarray) -> None:
        """After a resection: the load acts on the surface of the cells still present."""
        self.facets = surface_facets(self.V, present)
        self._reference = None
        if self._quadrature is not None:
            raise ValueError("the quadrature rule acts on the original surface only; use rule = \"consistent\" "
                             "with [[remove]]")

    def geometry(self, u=None):
        """Facet vertices and opposite vertices, moved by u (a Function on V) if given."""
        f = self.facets
        if u is None:
            return f.x_vertices, f.x_opposite
        values = u.x.array.reshape(-1, 3)
        return f.x_vertices + values[f.vertex_dofs], f.x_opposite + values[f.opposite_dofs]

    def _reference_surface(self):
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
        comes from _reference_surface. On x + u only facets that can be wet are moved: those
        whose lowest reference vertex is below the level plus the surface's greatest fall;
        their outward side is the reference one (a facet does not turn inside out)."""
        n, area, height, lowest, orientation, surface_dofs = self._reference_surface()
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

    def highest(self, u=None) -> float:
        """The greatest height (x.up) of the surface, global."""
        X, _ = self.geometry(u)
        local = float((X @ self.up).max()) if len(X) else -np.inf
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
                raise ValueError("the quadrature rule integrates on the reference geometry; "
                                 "use rule = \"consistent\" for follower loading")
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


def hydrostatic_load(V, level: float, rho_fluid: float, gravity, u=None, rule: str = "consistent") -> fem.Function:
    """The assembled nodal fluid load as a Function on V (see HydrostaticLoad)."""
    load = HydrostaticLoad(V, rho_fluid, gravity, rule)
    load.assemble(level, u)
    return load.as_function()
