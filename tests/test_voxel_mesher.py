"""The embedding mesher and the fine surface that follows the coarse model."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from mpi4py import MPI

from fenics_brainshift import compat
from fenics_brainshift.cli import main
from fenics_brainshift.data import scene_path
from fenics_brainshift.meshing.voxelize import largest_parts, voxelize
from fenics_brainshift.runner.build import mesh_from_spec as build_mesh
from fenics_brainshift.scene import MeshSpec

from conftest import COMM, ROOT, mpirun, subprocess_env

R = 30.0  # mm


def _sphere_mask(shape=(80, 80, 80), centres=((40, 40, 40),), radii=(R,)):
    idx = np.indices(shape).transpose(1, 2, 3, 0) + 0.5
    mask = np.zeros(shape, bool)
    for c, r in zip(centres, radii):
        mask |= np.linalg.norm(idx - np.asarray(c), axis=-1) <= r
    return mask


def _nifti(path, mask, voxel_mm=1.0):
    import nibabel as nib

    affine = np.diag([voxel_mm] * 3 + [1.0])
    nib.save(nib.Nifti1Image(mask.astype(np.uint8), affine), str(path))
    return path


def _surface(path, mask, drop=0):
    """Marching-cubes surface of a mask (mm), optionally with `drop` triangles punched out."""
    import meshio
    from skimage.measure import marching_cubes

    verts, faces, _, _ = marching_cubes(np.pad(mask.astype(np.float32), 1), level=0.5)
    verts = verts - 1.0 + 0.5  # voxel centres at i + 0.5 mm, as in _nifti's affine
    if drop:
        rng = np.random.default_rng(3)
        faces = np.delete(faces, rng.choice(len(faces), drop, replace=False), axis=0)
    meshio.Mesh(verts, [("triangle", faces)]).write(path)
    return path


def _conforming(model) -> None:
    t = model.tets
    faces = np.sort(t[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2  # every interior face shared by exactly two tetrahedra
    # the boundary is the voxels' exposed faces, two triangles each
    v = {tuple(x) for x in model.voxels}
    exposed = sum(
        (tuple(np.add(x, d)) not in v)
        for x in v
        for d in [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    )
    assert (counts == 1).sum() == 2 * exposed
    p = model.points[t]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6
    assert vol.min() > 0 and vol.sum() == pytest.approx(model.volume_m3, rel=1e-12)


@pytest.mark.parametrize("voxel_mm", [4.0, 6.0])
def test_sphere_label_volume(tmp_path, voxel_mm, serial_only):
    path = _nifti(tmp_path / "sphere.nii.gz", _sphere_mask())
    exact = 4 / 3 * np.pi * (R * 1e-3) ** 3
    area = 4 * np.pi * (R * 1e-3) ** 2
    h = voxel_mm * 1e-3
    half = voxelize(path, h, fill=0.5)
    touch = voxelize(path, h, fill=0.0)
    assert half.input_volume_m3 == pytest.approx(exact, rel=0.01)
    # fill 0.5: errors cancel on average; bounded by the boundary layer
    assert abs(half.volume_m3 - half.input_volume_m3) <= 0.25 * area * h
    # fill 0 (the paper's rule): a superset, at most one voxel diagonal thicker
    assert half.input_volume_m3 < touch.volume_m3 <= half.input_volume_m3 + area * h * np.sqrt(3)
    _conforming(half)
    assert half.dropped_parts == 0


@pytest.mark.parametrize("slice_mm", [6.5, 10.0])
def test_a_series_of_thick_slices_meshes_whole(tmp_path, slice_mm, serial_only):
    """A clinical 2-D series (1 x 1 mm in plane, slices 6.5 or 10 mm apart) of a sphere, meshed
    at 5 mm: every 5 mm layer holds tissue (counted by image voxel centres alone, the layers
    between two slices were empty and the sphere fell apart into slabs: 380 of 1619 ml of a
    real 6.5 mm glioma series, its brain-stem support lost); the volume within the boundary
    layer of the sphere's, one part, conforming."""
    import nibabel as nib

    radius = 40.0  # mm
    nz = int(2 * radius / slice_mm) + 3
    centre = np.array([50.0, 50.0, nz * slice_mm / 2])
    xyz = np.indices((100, 100, nz)).transpose(1, 2, 3, 0) * [1.0, 1.0, slice_mm] + [0.5, 0.5, slice_mm / 2]
    mask = np.linalg.norm(xyz - centre, axis=-1) <= radius
    path = tmp_path / "slices.nii.gz"
    nib.save(nib.Nifti1Image(mask.astype(np.uint8), np.diag([1.0, 1.0, slice_mm, 1.0])), str(path))
    model = voxelize(path, 0.005, fill=0.5)
    exact = 4 / 3 * np.pi * (radius * 1e-3) ** 3
    assert model.input_volume_m3 == pytest.approx(exact, rel=0.05)  # (the slices' own staircase)
    assert abs(model.volume_m3 - model.input_volume_m3) <= 0.25 * 4 * np.pi * (radius * 1e-3) ** 2 * 0.005
    assert model.dropped_parts == 0
    _conforming(model)


def test_box_aligned_with_the_voxels_is_exact(tmp_path, serial_only):
    mask = np.zeros((40, 40, 40), bool)
    mask[5:25, 10:30, 0:15] = True  # 20 x 20 x 15 mm
    model = voxelize(_nifti(tmp_path / "box.nii", mask), 0.005, fill=0.5)
    assert model.volume_m3 == pytest.approx(20 * 20 * 15e-9, rel=1e-12)
    assert len(model.voxels) == 4 * 4 * 3
    _conforming(model)


def test_surface_with_a_hole_and_bad_triangles(tmp_path, serial_only):
    mask = _sphere_mask()
    closed = voxelize(_surface(tmp_path / "closed.stl", mask), 0.005)
    holed = voxelize(_surface(tmp_path / "holed.stl", mask, drop=40), 0.005)
    exact = 4 / 3 * np.pi * (R * 1e-3) ** 3
    assert closed.volume_m3 == pytest.approx(exact, rel=0.05)
    # 40 triangles punched out change at most a few voxels (the three-ray vote)
    assert abs(len(holed.voxels) - len(closed.voxels)) <= 0.02 * len(closed.voxels)
    _conforming(holed)


def test_gifti_surface(tmp_path, serial_only):
    import meshio
    import nibabel as nib

    stl = _surface(tmp_path / "s.stl", _sphere_mask())
    m = meshio.read(stl)
    gii = nib.gifti.GiftiImage(
        darrays=[
            nib.gifti.GiftiDataArray(m.points.astype(np.float32), intent="NIFTI_INTENT_POINTSET"),
            nib.gifti.GiftiDataArray(m.cells_dict["triangle"].astype(np.int32), intent="NIFTI_INTENT_TRIANGLE"),
        ]
    )
    nib.save(gii, str(tmp_path / "s.gii"))
    a, b = voxelize(stl, 0.005), voxelize(tmp_path / "s.gii", 0.005)
    assert len(a.voxels) == len(b.voxels) and a.volume_m3 == b.volume_m3


def test_two_blobs_keep_the_largest_or_both(tmp_path, serial_only):
    mask = _sphere_mask(centres=((25, 40, 40), (62, 40, 40)), radii=(18, 10))
    path = _nifti(tmp_path / "blobs.nii.gz", mask)
    one = voxelize(path, 0.004)
    both = voxelize(path, 0.004, parts=2)
    assert one.dropped_parts == 1 and both.dropped_parts == 0
    assert one.volume_m3 == pytest.approx(4 / 3 * np.pi * 0.018**3, rel=0.15)
    assert both.volume_m3 > one.volume_m3
    kept, dropped = largest_parts(np.isin(np.indices((5, 1, 1))[0], [0, 1, 3]), 1)
    assert kept.ravel().tolist() == [True, True, False, False, False] and dropped == 1


def test_pinches_are_closed():
    from fenics_brainshift.meshing.voxelize import close_pinches

    corner = np.zeros((3, 3, 3), bool)
    corner[0, 0, 0] = corner[1, 1, 1] = True  # touching at one corner only
    assert close_pinches(corner)[:2, :2, :2].all() and close_pinches(corner).sum() == 8
    edge = np.zeros((3, 3, 3), bool)
    edge[0, 0, 1] = edge[1, 1, 1] = True  # along an edge only: both blocks holding that edge fill
    closed = close_pinches(edge)
    assert closed.sum() == 12 and closed[:2, :2, :].all()
    assert (close_pinches(closed) == closed).all()
    solid = np.ones((3, 3, 3), bool)
    solid[1, 1, 1] = False  # a cavity is not a pinch
    assert (close_pinches(solid) == solid).all()


@pytest.mark.mpi
@pytest.mark.parametrize("shape", ["sphere", "pinched"])
def test_same_mesh_on_one_and_two_ranks(tmp_path_factory, shape):
    """Voxels touching only at an edge or corner would be split apart on a rank boundary:
    the mesher closes such pinches, so the mesh is the same for any rank count."""
    folder = tmp_path_factory.mktemp("nifti") if COMM.rank == 0 else None
    folder = COMM.bcast(str(folder) if folder else None, root=0)
    path = f"{folder}/{shape}.nii.gz"
    if COMM.rank == 0:
        mask = _sphere_mask()
        if shape == "pinched":  # staircases of blocks meeting along edges and at corners
            mask = np.zeros((60, 60, 60), bool)
            for k in range(6):
                mask[10 * k : 10 * k + 10, 10 * k : 10 * k + 10, 0:10] = True
                mask[10 * k : 10 * k + 10, 0:10, 10 * k : 10 * k + 10] = True
        _nifti(path, mask)
    COMM.barrier()
    serial = voxelize(path, 0.005)
    mesh = build_mesh(MeshSpec(file=path, voxel=0.005, unit="mm"), COMM)
    _conforming(serial)
    assert mesh.topology.index_map(0).size_global == len(serial.points)
    assert mesh.topology.index_map(3).size_global == len(serial.tets)
    import ufl
    from dolfinx import fem

    vol = COMM.allreduce(fem.assemble_scalar(fem.form(fem.Constant(mesh, 1.0) * ufl.dx(domain=mesh))))
    assert vol == pytest.approx(serial.volume_m3, rel=1e-12)


@pytest.mark.mpi
def test_embedding_reproduces_any_affine_displacement_exactly():
    """Fine-surface points inside and just outside the coarse voxel mesh."""
    from dolfinx import fem

    from fenics_brainshift.meshing import mesh_from_arrays
    from fenics_brainshift.meshing.hexgrid import voxel_mesh
    from fenics_brainshift.outputs.fine_surface import SurfaceEmbedding

    mask = np.ones((3, 3, 2), bool)
    mask[0, 0, 1] = False
    pts, tets = voxel_mesh(mask, (0.01, 0.01, 0.01))
    mesh = mesh_from_arrays(COMM, pts, tets)
    rng = np.random.default_rng(11)
    fine = rng.uniform([-0.002, -0.002, -0.002], [0.032, 0.032, 0.022], size=(400, 3))  # some outside
    embedding = SurfaceEmbedding(mesh, fine, np.zeros((0, 3), int))
    assert embedding.outside > 0
    A = np.array([[0.01, -0.02, 0.003], [0.005, 0.02, -0.01], [-0.004, 0.001, 0.03]])
    b = np.array([1e-3, -2e-3, 5e-4])
    V = compat.vector_space(mesh, 1)
    u = fem.Function(V)
    u.interpolate(lambda x: (A @ x) + b[:, None])
    got = embedding.values(u)
    np.testing.assert_allclose(got, fine @ A.T + b, atol=1e-14)


def test_mesh_command(tmp_path, capsys, serial_only):
    from dolfinx.io import XDMFFile

    path = _nifti(tmp_path / "sphere.nii.gz", _sphere_mask())
    out = tmp_path / "m" / "sphere.xdmf"
    assert main(["mesh", str(path), "--voxel", "6", "-o", str(out)]) == 0
    assert "tetrahedra from" in capsys.readouterr().out
    serial = voxelize(path, 0.006)
    with XDMFFile(MPI.COMM_SELF, str(out), "r") as f:
        mesh = f.read_mesh(name="mesh")
        tags = f.read_meshtags(mesh, name="voxel")
    assert mesh.geometry.x.max() < 0.1  # metres
    assert len(tags.values) == len(serial.tets)
    assert tags.values.min() == 1 and tags.values.max() == len(serial.voxels)
    assert np.all(np.bincount(tags.values)[1:] == 5)  # five tetrahedra per voxel
    assert main(["mesh", str(tmp_path / "none.nii"), "-o", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["mesh", str(path), "--voxel", "-1"]) == 2
    assert "--voxel and --scale must be > 0" in capsys.readouterr().err


def test_brain_demo_serial_and_mpi(tmp_path, serial_only):
    """The bundled brain at 10 mm voxels, quasi-static: same shift on 1 and 2 ranks, the
    deformed fine surface written, the frontal pole sinking along gravity."""
    results = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        cmd = [
            sys.executable,
            str(ROOT / "demos" / "brain.py"),
            "--quasi-static",
            "--out",
            str(out),
            "--set",
            "mesh.voxel=0.010",
            "--set",
            "fixed.0.where=y < -0.095",
        ]
        cmd = (mpirun() + cmd) if ranks > 1 else cmd
        proc = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env(), cwd=ROOT, timeout=900)
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert "frontal pole moves" in proc.stdout
        results[ranks] = json.loads((out / "summary.json").read_text())
        for name in ("surface_final.stl", "surface_final.vtk", "frontal_pole.png", "displacement.xdmf"):
            assert (out / name).is_file(), name
    a, b = (np.array(results[r]["probes"]["frontal_pole"]) for r in (1, 2))
    assert a[1] < -1e-3  # sinks towards posterior (supine)
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9)
    import meshio

    surface = meshio.read(tmp_path / "r1" / "surface_final.vtk")
    assert len(surface.points) == 14828 and "displacement" in surface.point_data
    assert results[1]["frame"] == "RAS"  # a mesh from an image: pictures mark the anatomy


@pytest.mark.mpi
def test_fixed_region_on_a_grid_plane_selects_the_same_nodes_on_any_rank_count():
    """demos/brain.toml's `y < -0.0985` falls exactly on a plane of 5 mm voxel nodes. Dof
    coordinates tabulated cell by cell round differently per partition; the supports are
    chosen on the mesh's own vertex coordinates, so they match the input points exactly."""
    from fenics_brainshift.physics.supports import fixed_conditions
    from fenics_brainshift.runner.build import supports
    from fenics_brainshift.scene import load_scene

    scene = load_scene(scene_path("brain"), ["time.mode=quasi-static"])
    model = voxelize(scene.mesh.file, scene.mesh.voxel)
    mesh = build_mesh(scene.mesh, COMM)
    V = compat.vector_space(mesh, 1)
    bcs = fixed_conditions(V, supports(scene))
    import dolfinx.la
    from dolfinx.fem.petsc import set_bc

    for bc, region in zip(bcs, scene.fixed):
        ones = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        ones.set(1.0)
        set_bc(ones, [bc])  # fixed entries become 0
        zeros = COMM.allreduce(int(np.sum(ones.array_r == 0.0)), op=MPI.SUM)
        assert zeros == 3 * int(region.predicate(model.points.T).sum())
