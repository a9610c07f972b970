"""The skull contact's pressure distribution and nodal reactions (physics/contact.py), not only
their total: the total holds for any converged answer whatever area each node is given.
The nodal reactions hold for any converged answer too (equilibrium fixes them); the pressure,
each node's force over its share of the surface, is what a wrong area changes, and the
pressure checks are the ones that catch it.

References made here, not by the package: each surface node's area is a third of every
boundary triangle of the mesh it is a corner of, found from the tetrahedra's coordinates
(gathered from every rank); the reactions under gravity come from the linear-elastic
residual K u - f assembled with UFL forms written here.
"""

from __future__ import annotations

import meshio
import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from mpi4py import MPI
from petsc4py import PETSc

from fenics_brainshift import compat
from fenics_brainshift.runner import Simulation
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM

pytestmark = pytest.mark.mpi

EPS = 1e-9
G = 9.81


def _box_surface(lo, hi, path) -> str:
    """A closed box surface (12 triangles, outward), written by rank 0."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    P = np.array(
        [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0], [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
    )
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]]
    tris = [[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads]
    if COMM.rank == 0:
        meshio.write(str(path), meshio.Mesh(P, [("triangle", np.array(tris))]), binary=True)
    COMM.barrier()
    return str(path)


def _boundary_triangles(mesh) -> np.ndarray:
    """(T, 3, 3) coordinates of the mesh's boundary triangles, on every rank: the faces of
    the (gathered) tetrahedra that belong to one tetrahedron only."""
    n_owned = mesh.topology.index_map(mesh.topology.dim).size_local
    tets = mesh.geometry.x[compat.geometry_dofmap(mesh)[:n_owned]]  # (c, 4, 3)
    tets = np.concatenate(COMM.allgather(tets))
    size = np.abs(tets).max()
    points, ids = np.unique(np.round(tets.reshape(-1, 3) / (1e-9 * size)).astype(np.int64), axis=0, return_inverse=True)
    ids = ids.reshape(-1, 4)
    faces = np.concatenate([ids[:, [0, 1, 2]], ids[:, [0, 1, 3]], ids[:, [0, 2, 3]], ids[:, [1, 2, 3]]])
    unique, count = np.unique(np.sort(faces, axis=1), axis=0, return_counts=True)
    xyz = tets.reshape(-1, 3)[np.unique(ids.ravel(), return_index=True)[1]]  # a coordinate per id
    return xyz[unique[count == 1]]


def _shares(triangles: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Each node's area share: a third of every triangle it is a corner of (m^2)."""
    area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    share = np.zeros(len(nodes))
    for corner in range(3):
        hit = np.linalg.norm(nodes[:, None, :] - triangles[None, :, corner, :], axis=2) < 1e-9
        share += hit @ area / 3.0
    return share


def _max(value: float) -> float:
    return COMM.allreduce(float(value), op=MPI.MAX)


def _owned(sim):
    V = sim.model.V
    n = V.dofmap.index_map.size_local
    return V.tabulate_dof_coordinates()[:n], n


def test_a_buoyant_column_presses_the_skull_roof_with_the_uniform_closed_form_pressure(shared_tmp):
    """A weightless column (rollers on its four sides, nothing holding it vertically) fully
    submerged: the buoyancy rho_f g H per unit area presses its top face on the skull's roof
    at z = H. Every load is a uniform pressure on a horizontal face, so the answer is the
    homogeneous uniaxial strain state exactly, on this mesh too: the contact pressure is
    rho_f g H at every top node, and each node's reaction is that pressure times its share of
    the top face. On the hexahedra cut into five tetrahedra those shares are not equal (a
    node on two cut diagonals has twice the share of one on none), and a node of the top's
    rim has side area too, so a contact giving every node the same area is caught."""
    W, H, RHO_F, LEVEL = 0.04, 0.02, 1000.0, 0.05
    roof = _box_surface((-0.1, -0.1, -0.2), (0.15, 0.15, H), shared_tmp / "roof.stl")
    data = {
        "mesh": {"shape": "box", "size": [W, W, H], "cells": [4, 4, 2]},
        "material": {"E": 729.0, "nu": 0.48, "density": 1e-9},  # weightless next to the fluid
        "gravity": {"vector": [0.0, 0.0, -G]},
        "fluid": {"density": RHO_F, "level": LEVEL, "follower": False},
        "fixed": [
            {"where": f"x < {EPS} or x > {W - EPS}", "axes": "x"},
            {"where": f"y < {EPS} or y > {W - EPS}", "axes": "y"},
        ],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "skull": {"file": roof, "tolerance": 1e-7},
    }
    sim = Simulation(scene_from_dict(data), COMM)
    sim.solve_to_settled(0.0)
    contact = sim.static.contact
    report = contact.report(sim.u)
    p_exact = RHO_F * G * H
    assert report["force_N"][2] == pytest.approx(-p_exact * W * W, rel=1e-6)
    assert report["max_penetration_m"] <= 1e-7

    X, n = _owned(sim)
    pressure = contact.nodal_pressure(sim.u)
    force = contact.assemble(sim.u).array_r.reshape(-1, 3).copy()
    triangles = _boundary_triangles(sim.model.mesh)
    on_top = np.all(np.abs(triangles[:, :, 2] - H) < EPS, axis=1)
    top = np.abs(X[:, 2] - H) < EPS
    rim = top & ((X[:, 0] < EPS) | (X[:, 0] > W - EPS) | (X[:, 1] < EPS) | (X[:, 1] > W - EPS))
    inner = top & ~rim
    top_share = _shares(triangles[on_top], X)
    full_share = _shares(triangles, X)
    assert COMM.allreduce(int(top.sum())) == 25 and COMM.allreduce(int(inner.sum())) == 9
    # the hand shares on the top are unequal (2:1 between inner nodes, less on the rim):
    # a contact with equal areas cannot meet the checks below
    assert _max(top_share[inner].max(initial=0.0)) == pytest.approx(2.0 * -_max(-top_share[inner].min(initial=1.0)))
    # each node's reaction: the closed-form pressure times its share of the top face
    error = np.abs(force[top, 2] + p_exact * top_share[top]) / (p_exact * top_share[top])
    assert _max(error.max(initial=0.0)) < 1e-3, "reaction != rho_f g H x tributary area"
    assert _max(np.abs(force[~top]).max(initial=0.0)) < 1e-9 * p_exact * W * W  # nothing else touches
    # the contact pressure: uniform rho_f g H across the top's inner nodes
    error = np.abs(pressure[inner] / p_exact - 1.0)
    assert _max(error.max(initial=0.0)) < 1e-3, "contact pressure not the uniform rho_f g H"
    # and on every node (the rim's share counts its side area too): force / that share
    error = np.abs(pressure[top] * full_share[top] / np.linalg.norm(force[top], axis=1) - 1.0)
    assert _max(error.max(initial=0.0)) < 1e-9, "pressure x tributary area != the node's force"
    assert _max(np.abs(pressure[~top]).max(initial=0.0)) == 0.0


def test_under_gravity_each_floor_node_carries_its_reaction_and_its_pressure_times_area(shared_tmp):
    """A block standing on a rigid floor under its weight (rollers on two faces, laterally
    free): on tetrahedra the floor's reactions are not uniform, so the reference is the
    settled state's own residual, K u - rho g assembled here. At every floor node the
    contact's force is that reaction, and its pressure times the node's area is it too."""
    L, H, E, NU, RHO = 0.05, 0.025, 729.0, 0.48, 1048.0
    floor = _box_surface((-0.1, -0.1, 0.0), (0.15, 0.15, 0.2), shared_tmp / "floor.stl")
    data = {
        "mesh": {"shape": "box", "size": [L, L, H], "cells": [4, 4, 2]},
        "material": {"E": E, "nu": NU, "density": RHO},
        "gravity": {"vector": [0.0, 0.0, -G]},
        "fixed": [{"where": f"x < {EPS}", "axes": "x"}, {"where": f"y < {EPS}", "axes": "y"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "skull": {"file": floor, "tolerance": 1e-7},
    }
    sim = Simulation(scene_from_dict(data), COMM)
    sim.solve_to_settled(0.0)
    contact = sim.static.contact
    V, u = sim.model.V, sim.u
    v = ufl.TestFunction(V)
    mu, lmbda = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
    eps = ufl.sym(ufl.grad(u))
    sigma = 2 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(3)
    g = fem.Constant(V.mesh, np.array([0.0, 0.0, -G], dtype=PETSc.ScalarType))
    b = assemble_vector(fem.form(ufl.inner(sigma, ufl.sym(ufl.grad(v))) * ufl.dx - RHO * ufl.inner(g, v) * ufl.dx))
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    reaction = b.array_r.reshape(-1, 3)[:, 2].copy()  # K u - f: the floor's push on each node (N, up)

    X, n = _owned(sim)
    force = contact.assemble(u).array_r.reshape(-1, 3)[:, 2].copy()
    pressure = contact.nodal_pressure(u)
    share = _shares(_boundary_triangles(sim.model.mesh), X)
    bottom = np.abs(X[:, 2]) < EPS
    weight = RHO * G * L * L * H
    assert COMM.allreduce(float(reaction[bottom].sum())) == pytest.approx(weight, rel=1e-6)
    assert _max(np.abs(reaction[~bottom]).max(initial=0.0)) < 1e-6 * weight  # the residual is an equilibrium
    assert -_max(-reaction[bottom].min(initial=np.inf)) > 0.0  # every floor node pressed
    scale = _max(reaction[bottom].max(initial=0.0))
    assert _max(np.abs(force[bottom] - reaction[bottom]).max(initial=0.0)) < 1e-3 * scale
    assert _max(np.abs(pressure[bottom] * share[bottom] - reaction[bottom]).max(initial=0.0)) < 1e-3 * scale, (
        "pressure x tributary area != the node's reaction"
    )
    # summed over the floor, pressure times area is the weight
    assert COMM.allreduce(float(np.sum(pressure[bottom] * share[bottom]))) == pytest.approx(weight, rel=1e-6)
