"""The only module that knows which DOLFINx it runs on (0.5.2 on Debian 12, 0.9.0 on Debian 13).

Everything else in the package calls these helpers and never branches on the version.
"""

from __future__ import annotations

import dolfinx
import dolfinx.fem.petsc  # noqa: F401  (0.9 does not import it with dolfinx.fem)
import dolfinx.geometry
import dolfinx.io
import numpy as np
import ufl
from dolfinx import fem

from .logs import quiet_compiler

quiet_compiler()  # the form compiler's gcc lines are not the user's business

DOLFINX_VERSION = dolfinx.__version__
_MAJOR_MINOR = tuple(int(p) for p in DOLFINX_VERSION.split(".")[:2])
MODERN = _MAJOR_MINOR >= (0, 8)  # functionspace(), basix.ufl, x.petsc_vec, bb_tree

# How long a process waits for another to finish compiling the same form (the form compiler's
# default is 10 s, after which the waiting process fails). Two processes compile the same form
# whenever they share an empty cache: the rank groups of an atlas under mpirun, a test suite's
# workers; a large form (the neo-Hookean P2 tangent) on a busy machine takes more than 10 s.
# The price: a compile killed midway leaves its lock, and the next process waits this long
# before the form compiler says to clear the cache.
JIT_WAIT_SECONDS = 300
_JIT = {"timeout": JIT_WAIT_SECONDS}


def vector_space(mesh, degree: int = 1):
    """Continuous Lagrange space of 3-vectors (displacement, velocity, acceleration)."""
    if MODERN:
        return fem.functionspace(mesh, ("Lagrange", degree, (mesh.geometry.dim,)), jit_options=_JIT)
    # (VectorFunctionSpace takes no JIT options: the element it makes, given to FunctionSpace)
    return fem.FunctionSpace(mesh, ufl.VectorElement("Lagrange", mesh.ufl_cell(), degree), jit_params=_JIT)


def scalar_space(mesh, family: str = "Lagrange", degree: int = 1):
    if MODERN:
        return fem.functionspace(mesh, (family, degree), jit_options=_JIT)
    return fem.FunctionSpace(mesh, (family, degree), jit_params=_JIT)


def cell_tensor_space(mesh):
    """Cell-wise constant (DG0) 3 x 3 tensors: the deformation gradient of each cell."""
    if MODERN:
        return fem.functionspace(mesh, ("DG", 0, (3, 3)), jit_options=_JIT)
    return fem.FunctionSpace(mesh, ufl.TensorElement("DG", mesh.ufl_cell(), 0), jit_params=_JIT)


def petsc_vec(f: fem.Function):
    """The PETSc vector that shares memory with a Function's values (owned + ghosts)."""
    return f.x.petsc_vec if MODERN else f.vector


def geometry_dofmap(mesh) -> np.ndarray:
    """(num_cells, nodes_per_cell) indices into mesh.geometry.x."""
    dm = mesh.geometry.dofmap
    if MODERN:
        return np.asarray(dm)
    return dm.array.reshape(-1, dm.offsets[1] - dm.offsets[0]) if len(dm.offsets) > 1 else np.zeros((0, 4), np.int32)


def element_degree(V) -> int:
    degree = V.ufl_element().degree  # a method in 0.5, a property in 0.9
    return int(degree() if callable(degree) else degree)


def dofmap_array(V) -> np.ndarray:
    """(num_cells, dofs_per_cell) block dof indices of a function space."""
    dm = V.dofmap.list
    if MODERN:
        return np.asarray(dm)
    return dm.array.reshape(-1, dm.offsets[1] - dm.offsets[0]) if len(dm.offsets) > 1 else np.zeros((0, 1), np.int32)


def tetra_domain():
    """The ufl.Mesh of an affine tetrahedral mesh in 3-D (equispaced nodes: see settled_mesh)."""
    if MODERN:
        import basix.ufl

        return ufl.Mesh(basix.ufl.element("Lagrange", "tetrahedron", 1, shape=(3,)))
    scalar = ufl.FiniteElement("Lagrange", ufl.tetrahedron, 1, variant="equispaced")
    return ufl.Mesh(ufl.VectorElement(scalar))


def settled_mesh(mesh):
    """The mesh with its coordinate element's Lagrange variant given once, here.

    Debian 12's FFCx 0.5 gives a coordinate element without a variant the variant
    "equispaced" *in place* when it compiles a form that misses the JIT cache. UFL Arguments
    fix their hash when made but compare by the current state, so Arguments made before such
    a compile and after it compare equal, hash differently, and a form mixing them fails
    ("Found different Arguments with same number and part") - on a cold cache only. Every
    mesh the package builds or reads passes through here, so no compile changes it later.
    (basix.ufl elements, DOLFINx 0.8+, carry their variant: nothing to do.)"""
    domain = mesh.ufl_domain()
    element = domain.ufl_coordinate_element()
    sub = getattr(element, "_sub_element", None)
    if sub is not None and getattr(sub, "variant", lambda: "")() is None:
        scalar = ufl.FiniteElement(
            sub.family(), sub.cell(), sub.degree(), quad_scheme=sub.quadrature_scheme(), variant="equispaced"
        )
        domain._ufl_coordinate_element = ufl.VectorElement(scalar, dim=element.value_shape()[0])
    return mesh


def create_mesh(comm, cells: np.ndarray, points: np.ndarray):
    """Distributed mesh from cells/points given on some ranks (others pass empty arrays)."""
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    return settled_mesh(dolfinx.mesh.create_mesh(comm, cells, points, tetra_domain()))


def read_xdmf_mesh(comm, path, name: str = "mesh"):
    """A mesh (and nothing else) from a DOLFINx XDMF file."""
    with dolfinx.io.XDMFFile(comm, str(path), "r") as f:
        return settled_mesh(f.read_mesh(name=name))


def gmsh_model_to_mesh(model, comm, rank: int = 0):
    """(mesh, cell_tags, facet_tags) from a gmsh model built on `rank`."""
    import dolfinx.io.gmshio as gmshio

    out = gmshio.model_to_mesh(model, comm, rank, gdim=3)
    return settled_mesh(out[0]), out[1], out[2]


def interpolation_points(V) -> np.ndarray:
    ip = V.element.interpolation_points
    return ip() if callable(ip) else ip


def expression(expr, V) -> fem.Expression:
    """A compiled UFL expression evaluated at V's interpolation points."""
    if MODERN:
        return fem.Expression(expr, interpolation_points(V), jit_options=_JIT)
    return fem.Expression(expr, interpolation_points(V), jit_params=_JIT)


def form(ufl_form):
    """fem.form, waiting for another process's compile of the same form (JIT_WAIT_SECONDS)."""
    if MODERN:
        return fem.form(ufl_form, jit_options=_JIT)
    return fem.form(ufl_form, jit_params=_JIT)


def colliding_cells(mesh, points: np.ndarray) -> list[int]:
    """For each point (N, 3), the index of one local cell containing it, or -1."""
    tdim = mesh.topology.dim
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if MODERN:
        tree = dolfinx.geometry.bb_tree(mesh, tdim)
        candidates = dolfinx.geometry.compute_collisions_points(tree, pts)
    else:
        tree = dolfinx.geometry.BoundingBoxTree(mesh, tdim)
        candidates = dolfinx.geometry.compute_collisions(tree, pts)
    cells = dolfinx.geometry.compute_colliding_cells(mesh, candidates, pts)
    found = []
    for i in range(pts.shape[0]):
        links = cells.links(i)
        found.append(int(links[0]) if len(links) else -1)
    return found


def write_meshtags(xdmf, tags, mesh) -> None:
    """XDMFFile.write_meshtags: 0.9 also wants the geometry."""
    if MODERN:
        xdmf.write_meshtags(tags, mesh.geometry)
    else:
        xdmf.write_meshtags(tags)
