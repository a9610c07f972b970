"""Files 3D Slicer reads and writes: RAS and LPS, NIfTI and NRRD grids, segmentations by name,
markups as probes. References: SimpleITK's own reading of the grids, hand-written values."""

from __future__ import annotations

import json

import nibabel as nib
import nrrd
import numpy as np
import pytest
import SimpleITK
from test_warp import _oblique_affine, _smooth_image

from fenics_brainshift.images import read_markups, read_volume, write_like, write_markups


def test_markups_round_trip_and_the_lps_convention(tmp_path):
    ras = np.array([[10.0, -20.0, 30.0], [-1.5, 2.5, -3.5]])
    path = write_markups(tmp_path / "points.mrk.json", ["a", "b"], ras)
    document = json.loads(path.read_text())
    markup = document["markups"][0]
    assert markup["coordinateSystem"] == "LPS"
    assert markup["controlPoints"][0]["position"] == [-10.0, 20.0, 30.0]  # L = -R, P = -A
    labels, back = read_markups(path)
    assert labels == ["a", "b"] and np.array_equal(back, ras)
    markup["coordinateSystem"] = "RAS"  # a file in RAS is read as it is
    (tmp_path / "ras.mrk.json").write_text(json.dumps(document))
    assert np.array_equal(read_markups(tmp_path / "ras.mrk.json")[1], ras * [-1, -1, 1])


@pytest.mark.parametrize("suffix", [".nii.gz", ".nrrd"])
def test_our_grid_is_itks_grid_and_survives_a_round_trip(tmp_path, suffix):
    """Voxel index -> RAS (ours) equals SimpleITK's index -> LPS with x, y negated, for an oblique,
    anisotropic NIfTI, and for the NRRD written from it (LPS, as Slicer writes); the data too."""
    affine = _oblique_affine()
    data = _smooth_image((12, 10, 8)).astype(np.float32)
    nii = tmp_path / "pre.nii.gz"
    nib.save(nib.Nifti1Image(data, affine), str(nii))
    volume = read_volume(nii)
    path = write_like(volume, volume.data, tmp_path / f"copy{suffix}")
    copy = read_volume(path)
    np.testing.assert_allclose(copy.affine, affine, atol=1e-5)
    assert np.array_equal(copy.data, data)
    image = SimpleITK.ReadImage(str(path))
    for ijk in ([0, 0, 0], [11, 0, 3], [5, 9, 7]):
        lps = np.array(image.TransformIndexToPhysicalPoint(ijk))
        np.testing.assert_allclose(copy.index_to_ras(np.array(ijk, float)), lps * [-1, -1, 1], atol=1e-4)
    assert np.array_equal(SimpleITK.GetArrayFromImage(image).transpose(2, 1, 0), data)


def test_segmentation_nrrd_names_its_segments(tmp_path):
    labels = _segmentation(tmp_path / "brain.seg.nrrd")
    volume = read_volume(tmp_path / "brain.seg.nrrd")
    assert volume.segments == {1: "brain", 2: "tumour"}
    assert np.array_equal(volume.data, labels)
    np.testing.assert_allclose(volume.index_to_ras(np.zeros(3)), [-10.0, -20.0, -5.0])  # LPS origin -> RAS


def _segmentation(path):
    labels = np.zeros((20, 16, 12), dtype=np.uint8)
    labels[2:12, 2:12, 2:10] = 1
    labels[12:18, 4:10, 3:9] = 2
    header = {
        "space": "left-posterior-superior",
        "space directions": np.diag([2.0, 2.0, 2.0]),
        "space origin": [10.0, 20.0, -5.0],
        "kinds": ["domain"] * 3,
        "Segment0_Name": "brain",
        "Segment0_LabelValue": "1",
        "Segment1_Name": "tumour",
        "Segment1_LabelValue": "2",
    }
    nrrd.write(str(path), labels, header)
    return labels


def test_a_segmentation_is_meshed_by_segment_name(tmp_path, serial_only):
    """`brainshift mesh x.seg.nrrd --labels tumour` meshes that segment: 6 x 6 x 6 voxels of 2 mm
    (1728 mm3) at 2 mm, in RAS (LPS origin negated)."""
    from fenics_brainshift.cli import main

    _segmentation(tmp_path / "head.seg.nrrd")
    assert (
        main(
            [
                "mesh",
                str(tmp_path / "head.seg.nrrd"),
                "--voxel",
                "2",
                "--labels",
                "tumour",
                "-o",
                str(tmp_path / "tumour.xdmf"),
            ]
        )
        == 0
    )
    from dolfinx.io import XDMFFile
    from mpi4py import MPI

    from fenics_brainshift import compat

    with XDMFFile(MPI.COMM_SELF, str(tmp_path / "tumour.xdmf"), "r") as f:
        mesh = f.read_mesh(name="mesh")
    points = mesh.geometry.x
    corners = points[compat.geometry_dofmap(mesh)]
    volume = (
        np.abs(
            np.einsum(
                "ij,ij->i",
                np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                corners[:, 3] - corners[:, 0],
            )
        ).sum()
        / 6
    )
    assert volume == pytest.approx(6 * 6 * 6 * 8e-9, rel=1e-9)
    # voxel 12 along i lies at L = 10 + 24 mm, i.e. x = -34 mm (RAS); its lower face half a voxel before
    assert points[:, 0].max() == pytest.approx(-0.034 + 0.001, abs=1e-9)


def test_a_removal_finds_its_segment_by_name(tmp_path):
    """[[remove]] label = "tumour": the points in that segment's voxels (RAS m), not others."""
    from fenics_brainshift.meshing.label_volume import labels_at

    _segmentation(tmp_path / "head.seg.nrrd")
    # voxel (i, j, k) has its centre at LPS (10 + 2i, 20 + 2j, -5 + 2k) mm, RAS (-L, -P, S)
    centre = lambda i, j, k: np.array([-(10 + 2 * i), -(20 + 2 * j), -5 + 2 * k]) * 1e-3  # noqa: E731
    points = np.array([centre(14, 6, 5), centre(5, 5, 5), centre(0, 0, 0)])
    assert labels_at(tmp_path / "head.seg.nrrd", points, 1e-3, "tumour").tolist() == [True, False, False]
    assert labels_at(tmp_path / "head.seg.nrrd", points, 1e-3).tolist() == [2, 1, 0]


def test_an_unknown_segment_name_is_one_line(tmp_path, capsys, serial_only):
    from fenics_brainshift.cli import main

    _segmentation(tmp_path / "head.seg.nrrd")
    assert (
        main(
            [
                "mesh",
                str(tmp_path / "head.seg.nrrd"),
                "--voxel",
                "2",
                "--labels",
                "lesion",
                "-o",
                str(tmp_path / "x.xdmf"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert "no segment 'lesion'" in err and "'brain', 'tumour'" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.xdmf").exists()


def test_markups_are_probes_and_come_back_moved(tmp_path):
    """[probes] markups: every point of a Slicer point list is a probe (mm -> m); the run writes
    probes_final.mrk.json with each point plus its displacement (summary.json), in LPS."""
    import tomllib

    from fenics_brainshift import run
    from fenics_brainshift.scene.toml import scene_from_dict

    points_mm = np.array([[25.0, 25.0, 25.0], [10.0, 40.0, 20.0]])  # in the cube (50 x 50 x 25 mm)
    write_markups(tmp_path / "landmarks.mrk.json", ["top", "side"], points_mm)
    data = tomllib.loads(_cube_toml().read_text())
    data["probes"] = {"markups": "landmarks.mrk.json"}
    data["mesh"]["cells"] = [10, 10, 5]
    data["time"] = {"mode": "quasi-static"}
    data["output"] = {"pictures": False}
    scene = scene_from_dict(data, tmp_path)
    assert set(scene.probes) == {"top", "side"}
    np.testing.assert_allclose(scene.probes["side"], [0.010, 0.040, 0.020])
    result = run(scene, tmp_path / "out")
    labels, moved = read_markups(tmp_path / "out" / "probes_final.mrk.json")
    assert labels == ["top", "side"]
    u_mm = np.array([result.summary["probes"][k] for k in labels]) * 1e3
    np.testing.assert_allclose(moved, points_mm + u_mm, atol=1e-9)
    assert np.abs(u_mm).max() > 0.5  # the cube sags by millimetres


def _cube_toml():
    from fenics_brainshift.data import scene_path

    return scene_path("cube")


def _layered_segmentation(path):
    """A segmentation as Slicer writes one whose segments overlap: a 4D .seg.nrrd of layers
    (kinds list, domain x 3; the list axis has no space direction), each segment its layer and
    label value. The brain (layer 0, value 1) holds the tumour (layer 1, value 1); the skull
    shell is layer 0, value 2."""
    layers = np.zeros((2, 20, 16, 12), dtype=np.uint8)
    layers[0, 1:19, 1:15, 1:11] = 2  # the skull, a shell one voxel thick around ...
    layers[0, 2:18, 2:14, 2:10] = 1  # ... the brain: 16 x 12 x 8 voxels
    layers[1, 6:10, 6:10, 4:8] = 1  # the tumour, inside the brain: 4 x 4 x 4
    directions = np.full((4, 3), np.nan)
    directions[1:] = np.diag([2.0, 2.0, 2.0])
    header = {
        "space": "left-posterior-superior",
        "space directions": directions,
        "space origin": [10.0, 20.0, -5.0],
        "kinds": ["list", "domain", "domain", "domain"],
    }
    for n, (name, layer, value) in enumerate((("skull", 0, 2), ("brain", 0, 1), ("tumour", 1, 1))):
        header.update(
            {
                f"Segment{n}_Name": name,
                f"Segment{n}_Layer": str(layer),
                f"Segment{n}_LabelValue": str(value),
                f"Segment{n}_ID": f"Segment_{n}",
            }
        )
    nrrd.write(str(path), layers, header)


@pytest.mark.parametrize("segment, voxels", [("brain", 16 * 12 * 8), ("tumour", 4 * 4 * 4)])
def test_a_layered_segmentation_is_meshed_by_segment_name(tmp_path, segment, voxels, serial_only):
    """Overlapping segments (a tumour inside the brain) are read from their layer and label
    value, as Slicer reads them: the brain keeps the tumour's voxels, the tumour is its own."""
    from fenics_brainshift.cli import main

    _layered_segmentation(tmp_path / "head.seg.nrrd")
    out = tmp_path / f"{segment}.xdmf"
    assert main(["mesh", str(tmp_path / "head.seg.nrrd"), "--voxel", "2", "--labels", segment, "-o", str(out)]) == 0
    assert _mesh_volume(out) == pytest.approx(voxels * 8e-9, rel=1e-9)


def test_a_segmentation_of_several_segments_needs_labels(tmp_path, capsys, serial_only):
    """No labels chosen: a brain, a tumour and a skull would be meshed as one body (+ the skull's
    volume); refused, the segments listed; a plain label map of the same voxels still meshes."""
    from fenics_brainshift.cli import main

    _layered_segmentation(tmp_path / "head.seg.nrrd")
    assert main(["mesh", str(tmp_path / "head.seg.nrrd"), "--voxel", "2", "-o", str(tmp_path / "x.xdmf")]) == 2
    err = capsys.readouterr().err.strip()
    assert "3 segments (skull, brain, tumour)" in err and "labels" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.xdmf").exists()
    _segmentation(tmp_path / "flat.seg.nrrd")  # two segments, side by side
    assert main(["mesh", str(tmp_path / "flat.seg.nrrd"), "--voxel", "2", "-o", str(tmp_path / "y.xdmf")]) == 2
    assert "2 segments (brain, tumour)" in capsys.readouterr().err


def test_a_value_that_is_several_layers_segments_needs_the_name(tmp_path, capsys, serial_only):
    """`--labels 1` on the layered file took label 1 of every layer, the brain and the tumour
    inside it, with exit 0; Slicer numbers each layer from 1, so a value names a segment only
    within its layer: refused, naming both. A value one segment has (the skull's 2) meshes."""
    from fenics_brainshift.cli import main

    _layered_segmentation(tmp_path / "head.seg.nrrd")
    assert (
        main(["mesh", str(tmp_path / "head.seg.nrrd"), "--voxel", "2", "--labels", "1", "-o", str(tmp_path / "x.xdmf")])
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert "label 1 of 'head.seg.nrrd' is each of the segments 'brain', 'tumour'" in err, err
    assert len(err.splitlines()) == 1 and not (tmp_path / "x.xdmf").exists()
    assert (
        main(
            [
                "mesh",
                str(tmp_path / "head.seg.nrrd"),
                "--voxel",
                "2",
                "--labels",
                "2",
                "-o",
                str(tmp_path / "skull.xdmf"),
            ]
        )
        == 0
    )


def test_warp_refuses_a_layered_segmentation_in_one_line(tmp_path):
    _layered_segmentation(tmp_path / "head.seg.nrrd")
    with pytest.raises(Exception, match="overlapping segments .2 layers.; export the segments needed as a labelmap"):
        read_volume(tmp_path / "head.seg.nrrd", "warp: --image")


def _mesh_volume(path) -> float:
    from dolfinx.io import XDMFFile
    from mpi4py import MPI

    from fenics_brainshift import compat

    with XDMFFile(MPI.COMM_SELF, str(path), "r") as f:
        mesh = f.read_mesh(name="mesh")
    corners = mesh.geometry.x[compat.geometry_dofmap(mesh)]
    return float(
        np.abs(
            np.einsum(
                "ij,ij->i",
                np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                corners[:, 3] - corners[:, 0],
            )
        ).sum()
        / 6
    )


def _read_model_as_slicer_does(path) -> np.ndarray:
    """Points (mm, RAS) of a binary STL by 3D Slicer's rule (vtkMRMLModelStorageNode): the
    frame is the header's SPACE= tag, LPS when there is none (flip x and y); millimetres."""
    raw = path.read_bytes()
    header = raw[:80].decode("ascii", "replace")
    count = int(np.frombuffer(raw[80:84], "<u4")[0])
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    vertices = np.frombuffer(raw[84 : 84 + count * record.itemsize], record)["vertices"].reshape(-1, 3).astype(float)
    return vertices if "SPACE=RAS" in header else vertices * [-1.0, -1.0, 1.0]


def test_a_run_writes_its_surface_as_slicer_reads_it(tmp_path):
    """surface_final.stl: read by Slicer's rule it lies where the run put it, in RAS mm (it was
    in metres with no tag: 1000x too small and mirrored in x and y); the .vtk stays in metres for
    ParaView, and both carry the same deformed surface."""
    import meshio

    from fenics_brainshift import load_scene, run

    out = tmp_path / "out"
    run(load_scene("brain", ["mesh.voxel=0.012", "time.mode=quasi-static", "output.pictures=false"]), out)
    slicer = _read_model_as_slicer_does(out / "surface_final.stl")
    vtk = meshio.read(out / "surface_final.vtk")
    expected = vtk.points[vtk.cells_dict["triangle"]].reshape(-1, 3) * 1e3  # m -> mm, RAS
    np.testing.assert_allclose(slicer, expected, atol=1e-3)  # float32 in the STL: a micrometre
    assert 120 < np.ptp(slicer[:, 1]) < 200  # a brain, front to back, in mm
    surface = meshio.read(out / "surface_final.stl")  # and other readers (meshio) read it too
    assert len(surface.cells_dict["triangle"]) == len(vtk.cells_dict["triangle"])
