"""Meshes: the paper's structured grids, gmsh shapes, and files in other units."""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem

from fenics_brainshift.errors import InputError
from fenics_brainshift.meshing.hexgrid import structured_box
from fenics_brainshift.runner.build import mesh_from_spec as build_mesh
from fenics_brainshift.scene import MeshSpec

from conftest import COMM


def _volume(mesh) -> float:
    one = fem.Constant(mesh, 1.0)
    return COMM.allreduce(fem.assemble_scalar(fem.form(one * ufl.dx(domain=mesh))))


@pytest.mark.parametrize(
    "cells, nodes, elements",
    [
        ((16, 16, 9), 2890, 11520),
        ((20, 20, 10), 4851, 20000),
        ((25, 25, 12), 8788, 37500),
        ((30, 30, 15), 15376, 67500),
    ],
)
def test_paper_cube_grids_have_the_papers_counts_and_conform(cells, nodes, elements):
    points, tets = structured_box((0.05, 0.05, 0.025), cells)
    assert (len(points), len(tets)) == (nodes, elements)
    p = points[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6
    assert vol.min() > 0 and vol.sum() == pytest.approx(0.05 * 0.05 * 0.025, rel=1e-12)
    # conforming: every face is shared by two tetrahedra, or lies on the box surface
    faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    unique, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2
    boundary = unique[counts == 1]
    on_surface = np.zeros(len(boundary), bool)
    for axis, extent in enumerate((0.05, 0.05, 0.025)):
        c = points[boundary][:, :, axis]
        on_surface |= np.all(np.isclose(c, 0.0), axis=1) | np.all(np.isclose(c, extent), axis=1)
    assert on_surface.all()
    nx, ny, nz = cells
    assert len(boundary) == 4 * (nx * ny + ny * nz + nx * nz)  # two triangles per boundary quad


@pytest.mark.mpi
def test_distributed_structured_box_volume():
    mesh = build_mesh(MeshSpec(shape="box", size=(0.05, 0.05, 0.025), cells=(6, 6, 3)), COMM)
    assert _volume(mesh) == pytest.approx(0.05 * 0.05 * 0.025, rel=1e-12)
    assert mesh.topology.index_map(0).size_global == 7 * 7 * 4


@pytest.mark.mpi
def test_gmsh_ellipsoid_and_box():
    a, b, c = 0.07, 0.085, 0.06
    mesh = build_mesh(MeshSpec(shape="ellipsoid", size=(a, b, c), h=0.015), COMM)
    # a polyhedron inscribed in the ellipsoid: a little smaller
    assert _volume(mesh) == pytest.approx(4 / 3 * np.pi * a * b * c, rel=0.05)
    box = build_mesh(MeshSpec(shape="box", size=(0.02, 0.03, 0.01), origin=(0.1, 0, 0), h=0.005), COMM)
    assert _volume(box) == pytest.approx(0.02 * 0.03 * 0.01, rel=1e-10)
    assert box.geometry.x[:, 0].min() >= 0.1 - 1e-12


def test_mesh_files_in_millimetres(tmp_path, serial_only):
    import gmsh
    from dolfinx.io import XDMFFile

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("mm")
    tag = gmsh.model.occ.addBox(0, 0, 0, 50, 50, 25)  # millimetres
    gmsh.model.occ.synchronize()
    gmsh.model.addPhysicalGroup(3, [tag], 1)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", 12.0)
    gmsh.model.mesh.generate(3)
    gmsh.write(str(tmp_path / "block.msh"))
    gmsh.finalize()
    mesh = build_mesh(MeshSpec(file=str(tmp_path / "block.msh"), unit="mm"), COMM)
    assert _volume(mesh) == pytest.approx(0.05 * 0.05 * 0.025, rel=1e-10)
    # the same through XDMF
    with XDMFFile(COMM, str(tmp_path / "block.xdmf"), "w") as f:
        f.write_mesh(build_mesh(MeshSpec(file=str(tmp_path / "block.msh"), unit="m"), COMM))
    again = build_mesh(MeshSpec(file=str(tmp_path / "block.xdmf"), unit="mm"), COMM)
    assert _volume(again) == pytest.approx(0.05 * 0.05 * 0.025, rel=1e-10)
    # meshio's XDMF (another grid name, cells by type) reads too: the same block, in mm
    import meshio

    points, tets = structured_box((50.0, 50.0, 25.0), (2, 2, 1))
    meshio.write(tmp_path / "meshio.xdmf", meshio.Mesh(points, [("tetra", tets)]))
    third = build_mesh(MeshSpec(file=str(tmp_path / "meshio.xdmf"), unit="mm"), COMM)
    assert _volume(third) == pytest.approx(0.05 * 0.05 * 0.025, rel=1e-12)
    meshio.write(tmp_path / "triangles.xdmf", meshio.Mesh(points, [("triangle", tets[:, :3])]))
    with pytest.raises(
        InputError, match=r"'triangles.xdmf' could not be read as a tetrahedral mesh: it holds no tetra"
    ):
        build_mesh(MeshSpec(file=str(tmp_path / "triangles.xdmf")), COMM)
    # a corrupt file is a named error, not a traceback
    (tmp_path / "bad.msh").write_text("this is not gmsh")
    with pytest.raises(InputError, match=r"\[mesh\] file 'bad.msh' could not be read"):
        build_mesh(MeshSpec(file=str(tmp_path / "bad.msh")), COMM)


def test_material_from_shear_modulus():
    from fenics_brainshift.scene import Material

    m = Material(G=2370.0, nu=0.4925, density=1036.0)
    assert m.E == pytest.approx(7.07e3, rel=1e-3)  # the paper's Table II
    assert m.mu == pytest.approx(2370.0)
