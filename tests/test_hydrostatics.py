"""The exact clipped hydrostatic load: Archimedes to round-off, the paper's cases by hand,
the same vector on 1 and 2 ranks, and the quadrature reference's error."""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI
from scipy import integrate
from scipy.spatial import ConvexHull, QhullError

from fenics_brainshift import compat
from fenics_brainshift.meshing import mesh_from_arrays
from fenics_brainshift.meshing.hexgrid import voxel_mesh
from fenics_brainshift.physics.hydrostatic import HydrostaticLoad
from fenics_brainshift.physics.wet_facets import consistent_loads, paper_loads, split_wet, wet_integrals
from fenics_brainshift.runner.build import mesh_from_spec as build_mesh
from fenics_brainshift.scene import MeshSpec

from conftest import COMM

RHO, G = 1000.0, 9.81


# ------------------------------------------------------------ an independent submerged volume
def clipped_volume(points: np.ndarray, up: np.ndarray, level: float) -> float:
    """Volume of a tetrahedron below the plane x.up = level, by the convex hull of the
    vertices below and the edge crossings (independent of the surface code)."""
    h = points @ up - level
    below = [p for p, hh in zip(points, h) if hh <= 0]
    for i in range(4):
        for j in range(i + 1, 4):
            if (h[i] < 0 < h[j]) or (h[j] < 0 < h[i]):
                t = h[i] / (h[i] - h[j])
                below.append(points[i] + t * (points[j] - points[i]))
    if len(below) < 4:
        return 0.0
    try:
        return ConvexHull(np.array(below)).volume
    except QhullError:  # flat: nothing below but a face
        return 0.0


def submerged_volume(mesh, up, level) -> float:
    n_owned = mesh.topology.index_map(3).size_local
    geo = compat.geometry_dofmap(mesh)[:n_owned]
    x = mesh.geometry.x
    local = sum(clipped_volume(x[c], up, level) for c in geo)
    return mesh.comm.allreduce(local, op=MPI.SUM)


def total_volume(mesh) -> float:
    return submerged_volume(mesh, np.array([0.0, 0.0, 1.0]), 1e9)


# ------------------------------------------------------------ the meshes
def staircase(comm):
    """Voxels of a staircase with an overhang and a hole through it: a closed, non-convex
    surface with many coplanar facets."""
    mask = np.zeros((4, 3, 3), bool)
    mask[:, :, 0] = True
    mask[1:, :, 1] = True
    mask[2:, :2, 2] = True
    mask[1, 1, 0] = False  # a pocket under the step
    pts, tets = voxel_mesh(mask, (0.01, 0.01, 0.01))
    return mesh_from_arrays(comm, pts, tets)


MESHES = {
    "box": lambda comm: build_mesh(MeshSpec(shape="box", size=(0.03, 0.02, 0.01), cells=(3, 2, 2)), comm),
    "ellipsoid": lambda comm: build_mesh(MeshSpec(shape="ellipsoid", size=(0.03, 0.02, 0.015), h=0.008), comm),
    "staircase": staircase,
}


def _directions(seed: int, count: int):
    rng = np.random.default_rng(seed)
    dirs = [np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])]
    for _ in range(count):
        v = rng.normal(size=3)
        dirs.append(v / np.linalg.norm(v))
    return dirs


def _levels(mesh, up, seed):
    x = mesh.geometry.x
    heights = COMM.allgather(x @ up)
    heights = np.concatenate(heights)
    lo, hi = heights.min(), heights.max()
    rng = np.random.default_rng(seed)
    through_vertex = float(np.sort(heights)[len(heights) // 2])  # exactly through vertices
    return [lo - 0.01, hi + 0.01, through_vertex, *rng.uniform(lo, hi, 3)]


@pytest.mark.mpi
@pytest.mark.parametrize("name", list(MESHES))
@pytest.mark.parametrize("degree, rule", [(1, "consistent"), (1, "paper"), (2, "consistent")])
def test_archimedes_exactly(name, degree, rule):
    mesh = MESHES[name](COMM)
    V = compat.vector_space(mesh, degree)
    vol = total_volume(mesh)
    for k, direction in enumerate(_directions(seed=7, count=3)):
        gravity = G * direction
        up = -direction
        load = HydrostaticLoad(V, RHO, gravity, rule)
        for level in _levels(mesh, up, seed=k):
            load.assemble(level)
            expected = RHO * G * submerged_volume(mesh, up, level) * up
            assert np.abs(load.force - expected).max() <= 1e-12 * RHO * G * vol, (level, load.force, expected)
            assert load.submerged_volume == pytest.approx(expected @ up / (RHO * G), abs=1e-12 * vol)


@pytest.mark.mpi
def test_edges_and_faces_exactly_on_the_water_line():
    """Axis-aligned gravity with the level on a grid plane: whole faces at zero depth."""
    mesh = MESHES["staircase"](COMM)
    V = compat.vector_space(mesh, 1)
    for rule in ("consistent", "paper"):
        load = HydrostaticLoad(V, RHO, (0.0, 0.0, -G), rule)
        for level in (0.0, 0.01, 0.02, 0.03, 0.015):
            load.assemble(level)
            expected = RHO * G * submerged_volume(mesh, np.array([0, 0, 1.0]), level)
            assert load.force[2] == pytest.approx(expected, abs=1e-12)
            assert np.abs(load.force[:2]).max() < 1e-14


def test_quadrature_rule_error_falls_with_refinement():
    """The plain UFL form misses the kink at the water line; its Archimedes error shrinks
    with refinement but is far from round-off."""
    direction = np.array([0.3, -0.2, -1.0])
    direction /= np.linalg.norm(direction)
    errors = []
    for n in (2, 4, 8):
        mesh = build_mesh(MeshSpec(shape="box", size=(0.02, 0.02, 0.02), cells=(n, n, n)), MPI.COMM_SELF)
        V = compat.vector_space(mesh, 1)
        level = 0.0123
        quad = HydrostaticLoad(V, RHO, G * direction, "quadrature", quadrature_degree=2)
        exact = HydrostaticLoad(V, RHO, G * direction, "consistent")
        quad.assemble(level)
        exact.assemble(level)
        errors.append(np.linalg.norm(quad.force - exact.force) / np.linalg.norm(exact.force))
    assert errors[0] > 1e-6
    assert errors[2] < errors[1] < errors[0]


# ------------------------------------------------------------ one triangle, by hand
# The triangle (0,0,0), (0,1,0), (0,0,1) in the plane x = 0; up = z; rho g = 1.
TRI = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _unsort(values, depth):
    order, _, _ = split_wet(depth)
    out = np.zeros_like(values)
    np.put_along_axis(out, order, values, axis=1)
    return out


def _loads(level):
    depth = (level - TRI[:, 2])[None, :]
    area = np.array([0.5])
    return _unsort(paper_loads(depth, area), depth)[0], _unsort(consistent_loads(depth, area, 1)[0], depth)[0]


def test_case1_all_wet():
    paper, consistent = _loads(2.0)  # depths 2, 2, 1; force = area * centroid depth = 5/6
    np.testing.assert_allclose(paper, [1 / 3, 1 / 3, 1 / 6], rtol=1e-14)  # eq. 13: by depth
    np.testing.assert_allclose(consistent, [7 / 24, 7 / 24, 1 / 4], rtol=1e-14)  # A/12 (sum d + d_i)


def test_case2_two_wet():
    paper, consistent = _loads(0.5)  # depths .5, .5, -.5; wet part: a trapezoid of 5/48
    np.testing.assert_allclose(paper, [1 / 24, 1 / 16, 0.0], rtol=1e-14)  # eqs. 14-17
    np.testing.assert_allclose(consistent, [17 / 384, 17 / 384, 1 / 64], rtol=1e-14)
    assert paper.sum() == pytest.approx(5 / 48, rel=1e-14)


def test_case3_one_wet():
    tri = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    depth = (0.5 - tri[:, 2])[None, :]
    paper = _unsort(paper_loads(depth, np.array([0.5])), depth)[0]
    consistent = _unsort(consistent_loads(depth, np.array([0.5]), 1)[0], depth)[0]
    np.testing.assert_allclose(paper, [0.0, 0.0, 1 / 48], atol=1e-16)  # eqs. 18-19
    # consistent against an independent 2-D integral over the wet region z < 1/2, 0 < y < z:
    # in (y, z) the vertices are (0,1), (1,1), (0,0), so N1 = z - y, N2 = y, N3 = 1 - z
    shapes = [lambda y, z: z - y, lambda y, z: y, lambda y, z: 1 - z]
    for i, N in enumerate(shapes):
        ref, _ = integrate.dblquad(lambda y, z: (0.5 - z) * N(y, z), 0, 0.5, 0, lambda z: z, epsabs=1e-14, epsrel=1e-14)
        assert consistent[i] == pytest.approx(ref, abs=1e-12)


def test_case4_dry():
    paper, consistent = _loads(-0.1)
    assert not paper.any() and not consistent.any()


def test_p2_consistent_against_independent_integrals():
    depth = (0.5 - TRI[:, 2])[None, :]
    vertex, edge = consistent_loads(depth, np.array([0.5]), 2)
    order, _, _ = split_wet(depth)
    assert order[0].tolist() == [0, 1, 2]  # depths .5, .5, -.5: already sorted
    # (y, z) coordinates: l0 = 1 - y - z, l1 = y, l2 = z; wet region z < 1/2, 0 < y < 1 - z
    lam = [lambda y, z: 1 - y - z, lambda y, z: y, lambda y, z: z]

    def wet_integral(f):
        return integrate.dblquad(
            lambda y, z: (0.5 - z) * f(y, z), 0, 0.5, 0, lambda z: 1 - z, epsabs=1e-14, epsrel=1e-14
        )[0]

    for k in range(3):
        ref = wet_integral(lambda y, z: lam[k](y, z) * (2 * lam[k](y, z) - 1))
        assert vertex[0, k] == pytest.approx(ref, abs=1e-12)
        i, j = [m for m in range(3) if m != k]
        ref = wet_integral(lambda y, z: 4 * lam[i](y, z) * lam[j](y, z))
        assert edge[0, k] == pytest.approx(ref, abs=1e-12)


@pytest.mark.parametrize("degree, rule", [(1, "consistent"), (2, "consistent"), (1, "paper")])
def test_closed_forms_for_whole_facets_equal_the_split_rule(degree, rule):
    """wet_integrals takes closed forms for facets wholly under water and splits only the cut
    ones; on random facets (whole, cut in both ways) it must equal the split rule for all."""
    rng = np.random.default_rng(7)
    depth = rng.uniform(-1.0, 2.0, (400, 3))
    depth[:100] = rng.uniform(0.1, 2.0, (100, 3))  # a quarter wholly wet
    depth = depth[(depth > 0).any(axis=1)]
    area = rng.uniform(0.1, 1.0, len(depth))
    order, vertex, edge = wet_integrals(depth, area, degree, rule)
    split = split_wet(depth)
    if rule == "paper":
        ref_vertex, ref_edge = paper_loads(depth, area, split), None
    else:
        ref_vertex, ref_edge = consistent_loads(depth, area, degree, split)
    for got, ref in ((vertex, ref_vertex), (edge, ref_edge)):
        if ref is None:
            assert got is None
            continue
        back, back_ref = np.empty_like(got), np.empty_like(ref)  # into the facets' own vertex order
        np.put_along_axis(back, order, got, axis=1)
        np.put_along_axis(back_ref, split[0], ref, axis=1)
        np.testing.assert_allclose(back, back_ref, rtol=1e-12, atol=1e-14)
    whole = (depth > 0).all(axis=1)
    assert whole.sum() >= 100 and (order[whole] == [0, 1, 2]).all()


# ------------------------------------------------------------ parallel and follower geometry
@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_same_vector_on_one_and_many_ranks(degree):
    direction = np.array([0.2, 0.5, -1.0]) / np.linalg.norm([0.2, 0.5, -1.0])

    def gathered(comm):
        mesh = build_mesh(MeshSpec(shape="box", size=(0.02, 0.03, 0.01), cells=(4, 3, 2)), comm)
        V = compat.vector_space(mesh, degree)
        load = HydrostaticLoad(V, RHO, G * direction, "consistent")
        vec = load.assemble(0.004)
        n = V.dofmap.index_map.size_local
        x = V.tabulate_dof_coordinates()[:n]
        values = vec.getArray(readonly=True).reshape(-1, 3)
        rows = np.concatenate([np.round(x, 12), values], axis=1)
        rows = np.concatenate(comm.allgather(rows))
        return rows[np.lexsort(rows[:, :3].T[::-1])]

    serial, parallel = gathered(MPI.COMM_SELF), gathered(COMM)
    np.testing.assert_allclose(parallel[:, :3], serial[:, :3], atol=1e-12)
    np.testing.assert_allclose(parallel[:, 3:], serial[:, 3:], atol=1e-14 * np.abs(serial[:, 3:]).max())


@pytest.mark.mpi
def test_follower_geometry_translation_equals_lower_level():
    from dolfinx import fem

    mesh = MESHES["ellipsoid"](COMM)
    V = compat.vector_space(mesh, 1)
    direction = np.array([0.0, -0.6, -0.8])
    load = HydrostaticLoad(V, RHO, G * direction, "consistent")
    shift = np.array([0.001, 0.002, -0.003])
    u = fem.Function(V)
    u.x.array[:] = np.tile(shift, u.x.array.size // 3)
    moved = load.assemble(0.0, u).copy()
    reference = load.assemble(0.0 + shift @ direction).copy()  # up . shift = -direction . shift
    assert np.abs(moved.array_r - reference.array_r).max() < 1e-15 * RHO * G


@pytest.mark.mpi
def test_hydrostatic_load_function_api():
    from fenics_brainshift.physics.hydrostatic import hydrostatic_load

    mesh = MESHES["box"](COMM)
    V = compat.vector_space(mesh, 1)
    f = hydrostatic_load(V, 0.004, RHO, (0.0, 0.0, -G))
    n = V.dofmap.index_map.size_local * 3
    total = COMM.allreduce(f.x.array[:n].reshape(-1, 3).sum(axis=0), op=MPI.SUM)
    assert total[2] == pytest.approx(RHO * G * 0.03 * 0.02 * 0.004, rel=1e-12)
    with pytest.raises(ValueError, match="rule must be one of"):
        hydrostatic_load(V, 0.004, RHO, (0.0, 0.0, -G), rule="exact")


@pytest.mark.mpi
@pytest.mark.parametrize("thickness", [1e-4, 1e-6])
def test_archimedes_on_sliver_facets(thickness):
    """A plate 30 x 20 mm and 0.1 or 0.001 mm thick: its side triangles have aspect ratios of
    1e-2 and 1e-4 and the water line crosses them at grazing angles. The resultant stays exact
    up to the round-off of the large, nearly cancelling top and bottom forces."""
    mesh = build_mesh(MeshSpec(shape="box", size=(0.03, 0.02, thickness), cells=(3, 2, 1)), COMM)
    V = compat.vector_space(mesh, 1)
    vol = total_volume(mesh)
    for k, direction in enumerate(_directions(seed=3, count=3)):
        up = -direction
        for rule in ("consistent", "paper"):
            load = HydrostaticLoad(V, RHO, G * direction, rule)
            for level in _levels(mesh, up, seed=k):
                load.assemble(level)
                expected = RHO * G * submerged_volume(mesh, up, level) * up
                # the scale of the cancelling face forces: rho g (depth range) (face area)
                scale = RHO * G * 0.04 * 0.03 * 0.02
                assert np.abs(load.force - expected).max() <= 1e-13 * scale + 1e-9 * RHO * G * vol


@pytest.mark.mpi
@pytest.mark.parametrize("rule, tolerance", [("consistent", 1e-5), ("paper", 5e-3)])
def test_the_follower_loads_tangent_is_the_derivative_of_the_assembled_load(rule, tolerance):
    """Newton's follower tangent (load_tangent.py: a closed form for the facets under water,
    the facet kernel's differences at the water line) times a direction equals the central
    difference of the fluid load assembled on the moved surface (hydrostatic.py, the load a run
    applies), at a state whose water line cuts the side facets; on 1 or 2 ranks. The paper's
    rule, whose shares jump where two vertices are level, to a looser tolerance (its forward
    differences were 886 times off)."""
    from fenics_brainshift.physics.load_tangent import add_load_tangent
    from fenics_brainshift.runner import Simulation
    from fenics_brainshift.scene import scene_from_dict

    scene = scene_from_dict(
        {
            "mesh": {"shape": "box", "size": [0.05, 0.05, 0.025], "cells": [5, 5, 3]},
            "material": {"E": 729.0, "nu": 0.45, "density": 1048.0},
            "fixed": [{"where": "z < 1e-9"}],
            "fluid": {"density": 975.0, "level": 0.017, "follower": True, "rule": rule},
            "time": {"mode": "quasi-static"},
        }
    )
    sim = Simulation(scene, COMM)
    model = sim.model
    x = model.V.tabulate_dof_coordinates().reshape(-1, 3)  # (block dofs: one row a node)
    shape = np.column_stack([np.sin(80 * x[:, 1]), np.cos(60 * x[:, 0]), x[:, 0] * x[:, 2] * 400])
    u = sim.u
    u.x.array[:] = (1.5e-3 * shape).ravel()  # the body moved by up to 1.5 mm, its facets turned
    direction = u.copy()
    direction.x.array[:] = (np.column_stack([np.cos(50 * x[:, 2]), x[:, 1] * 30, np.sin(70 * x[:, 0])])).ravel()

    def load(step: float) -> np.ndarray:
        moved = u.copy()
        moved.x.array[:] = u.x.array + step * direction.x.array
        out = compat.petsc_vec(moved).duplicate()
        model.load_into(0.0, out, moved)
        return out.array_r.copy()

    eps = 1e-7
    expected = (load(eps) - load(-eps)) / (2 * eps)
    A = model.assemble(model.stiffness_form(), with_bcs=False)
    A.zeroEntries()
    add_load_tangent(A, model.fluid.hydro, model.fluid.level, u)
    product = A.createVecLeft()
    A.mult(compat.petsc_vec(direction), product)
    size = COMM.allreduce(float(np.abs(expected).max()), op=MPI.MAX)
    assert size > 1e-3  # (the load turns and deepens with the surface: the check is not vacuous)
    error = COMM.allreduce(float(np.abs(product.array_r - expected).max()), op=MPI.MAX)
    assert error <= tolerance * size
