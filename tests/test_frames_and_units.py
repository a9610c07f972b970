"""Unit and frame slips on the way in: each used to pass with exit 0 and a wrong
answer; now the frame a file declares is honoured and a unit slip is one line naming it,
before anything is written. References are hand-built: the points written, with x and y
negated by hand for LPS."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fenics_brainshift.data import MESHES
from fenics_brainshift.errors import InputError
from fenics_brainshift.images.targets import read_target
from fenics_brainshift.runner import run
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.surfaces.files import read_surface, write_slicer_stl

from conftest import COMM

BOX = {
    "name": "box",
    "mesh": {"shape": "box", "size": [0.05, 0.05, 0.025], "cells": [4, 4, 2]},
    "material": {"E": 3000.0, "nu": 0.45},
    "fixed": [{"where": "z < 1e-9"}],
    "time": {"mode": "quasi-static"},
}
# a tetrahedron's corners (mm), not symmetric in x or y: a mirror shows
CORNERS = np.array([[10.0, 20.0, 30.0], [40.0, 25.0, 35.0], [15.0, 60.0, 32.0], [18.0, 28.0, 70.0]])
FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
LPS = np.array([-1.0, -1.0, 1.0])


def _vtk(path, points, header: str) -> str:
    """A legacy ASCII VTK polydata with ``header`` as its title line (where Slicer writes SPACE=)."""
    lines = ["# vtk DataFile Version 3.0", header, "ASCII", "DATASET POLYDATA", f"POINTS {len(points)} double"]
    lines += [" ".join(f"{c:.17g}" for c in p) for p in points]
    lines += [f"POLYGONS {len(FACES)} {4 * len(FACES)}"] + [f"3 {a} {b} {c}" for a, b, c in FACES]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.mark.parametrize(
    "header, frame, expected",
    [
        ("3D Slicer output. SPACE=LPS", None, LPS),  # Slicer 4.11+: models saved in LPS
        ("3D Slicer output. SPACE=RAS", None, 1.0),
        ("vtk output", None, 1.0),  # untagged: RAS, this project's frame
        ("vtk output", "LPS", LPS),  # untagged, --frame LPS
        ("3D Slicer output. SPACE=LPS", "LPS", LPS),
    ],
)
def test_a_surface_target_is_read_in_the_frame_its_header_declares(tmp_path, header, frame, expected):
    target = read_target(_vtk(tmp_path / "scan.vtk", CORNERS, header), None, frame)
    got = target.measured[np.lexsort(target.measured.T)]
    want = CORNERS * expected * 1e-3
    np.testing.assert_allclose(got, want[np.lexsort(want.T)], atol=1e-12)


def test_a_slicer_stl_tagged_lps_reads_as_ras_and_ours_round_trips(tmp_path):
    """The binary STL header (80 bytes) carries the tag; the STL this project writes (RAS, mm)
    reads back where it was written."""
    ours = write_slicer_stl(tmp_path / "ours.stl", CORNERS, FACES)
    points, _ = read_surface(ours, 1e-3)
    np.testing.assert_allclose(np.unique(points, axis=0), np.unique(CORNERS * 1e-3, axis=0), atol=1e-9)
    slicer = tmp_path / "slicer.stl"
    slicer.write_bytes(b"3D Slicer output. SPACE=LPS".ljust(80, b" ") + ours.read_bytes()[80:])
    points, _ = read_surface(slicer, 1e-3)
    np.testing.assert_allclose(np.unique(points, axis=0), np.unique(CORNERS * LPS * 1e-3, axis=0), atol=1e-9)


@pytest.mark.parametrize(
    "header, frame, words",
    [
        ("SPACE=LPS", "RAS", "--frame RAS but 'scan.vtk' declares SPACE=LPS"),
        ("SPACE=LPS and SPACE=RAS", None, "declares both SPACE=RAS and SPACE=LPS"),
    ],
)
def test_contradicting_frames_are_refused(tmp_path, header, frame, words):
    with pytest.raises(InputError, match=words):
        read_target(_vtk(tmp_path / "scan.vtk", CORNERS, header), None, frame)


def test_a_csv_target_in_lps_is_turned_to_ras(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("x,y,z,x_pre,y_pre,z_pre\n1,2,3,4,5,6\n")
    target = read_target(path, None, "LPS")
    np.testing.assert_allclose(target.measured, [[-1e-3, -2e-3, 3e-3]])
    np.testing.assert_allclose(target.pre, [[-4e-3, -5e-3, 6e-3]])


def test_markups_in_metres_are_refused(tmp_path):
    """A brain's landmarks written in metres all lie within 0.2 "mm" of the origin: they
    collapsed into one point inside the brain, exit 0."""
    path = tmp_path / "m.mrk.json"
    points = [{"label": f"F-{i}", "position": list(p * 1e-3)} for i, p in enumerate(CORNERS)]
    path.write_text(json.dumps({"markups": [{"coordinateSystem": "LPS", "controlPoints": points}]}))
    data = dict(BOX, probes={"markups": str(path)})
    with pytest.raises(InputError, match=r"\[probes\] markups: 'm.mrk.json': .*positions in metres\?"):
        scene_from_dict(data)


@pytest.mark.mpi
@pytest.mark.parametrize(
    "scale, words",
    [
        (1e-3, r"\[mesh\] surface: it is 7.5e\+04 mm across .* the mesh 75 mm \(1e\+03x\): is it in another unit"),
        (1e3, r"\[mesh\] surface: it is 0.075 mm across .* \(0.001x\)"),
        ("slivers", r"\[mesh\] surface: its triangles cover .* degenerate triangles, or not the body's closed"),
        (1.0, None),
        ("patch", None),
    ],
)  # a piece of the top face, a fifth of the box across: the craniotomy's cortex alone
def test_a_fine_surface_in_another_unit_than_the_mesh_is_refused(shared_tmp, scale, words):
    """The box's own surface written in mm under [mesh] unit = "m" came out 1000x too large,
    exit 0; in km (as metres under "mm") it lay at the mesh's corner, 1000x too small, and
    was written so, exit 0; so was a surface of degenerate triangles. In metres it follows
    the mesh, and so does a patch of it (the limits catch a unit's 1000x, not a part)."""
    x, y, z = BOX["mesh"]["size"]
    corners = np.array([[i * x, j * y, k * z] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    if scale == "slivers":  # one sliver across the box, the rest without area
        corners = np.vstack([corners, corners[7] + [1e-4, 0.0, 0.0]])
        triangles = np.array([[0, 7, 8]] + [[1, 1, 2]] * 11)
    elif scale == "patch":
        top = corners[[1, 3, 7, 5]]  # z = z max
        corners = top.mean(axis=0) + 0.2 * (top - top.mean(axis=0))
        triangles = np.array([[0, 1, 2], [0, 2, 3]])
    else:
        corners = corners / scale
    refused = words is not None
    surface = shared_tmp / "box.stl"
    if COMM.rank == 0:
        write_slicer_stl(surface, corners, triangles)  # (its header says RAS: no mirror)
    COMM.barrier()
    data = dict(BOX, mesh=dict(BOX["mesh"], surface=str(surface)))
    out = shared_tmp / "out"
    if refused:
        with pytest.raises(InputError, match=words):
            run(scene_from_dict(data), out, COMM)
        assert not out.exists()  # refused before anything is written
    else:
        assert run(scene_from_dict(data), out, COMM).summary["status"] == "ok"
        assert (out / "surface_final.stl").is_file() or any(out.glob("surface_*.stl"))


@pytest.mark.mpi
def test_brainshift_mesh_with_the_wrong_scale_names_it(shared_tmp, capsys):
    """`brainshift mesh --scale 1` on the mm brain mask wrote a 284 m, 2e12 ml mesh, exit 0."""
    from fenics_brainshift.cli import main

    output = shared_tmp / "brain.xdmf"
    argv = ["mesh", str(MESHES / "mni152_brain_mask_2mm.nii.gz"), "--voxel", "10", "--scale", "1", "-o", str(output)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    if COMM.rank == 0:
        assert "the body is 284 m across" in err and "is it in mm? give --scale 0.001" in err
    assert not output.exists()


@pytest.mark.mpi
def test_an_image_in_mm_declared_metres_names_the_unit_not_the_voxel():
    """The bundled brain's mm image under [mesh] unit = "m": a 284 m object whose grid of 5 mm
    voxels would need 1.35 PB; the refusal asked whether the voxel size was in the right unit."""
    from fenics_brainshift import Simulation, load_scene

    with pytest.raises(InputError, match=r"the body is 284 m across .*: is it in mm\? \(a scene's \[mesh\] unit"):
        Simulation(load_scene("brain", ["mesh.unit=m", "time.mode=quasi-static"]), COMM)


@pytest.mark.mpi
@pytest.mark.parametrize(
    "override, words",
    [
        (
            "material.G=2.37",
            r"E = 7.074 Pa \(G = 2.37 Pa\): the body's weight alone would strain it about 259 .* is it in kPa\?",
        ),
        (
            "fluid.level=[[0, 85], [10, 30], [16, 30]]",
            r"\[fluid\] level = 85 at t = 0 s is 84.9 m above the body's top .* is it in mm\?",
        ),
        ("fluid.level=-30", r"\[fluid\] level = -30 at t = 0 s is 29.9 m below its bottom"),
    ],
)
def test_moduli_in_kpa_and_levels_in_mm_are_refused_before_the_solve(override, words):
    """Both ended in NaN and "reduce [time] dt" in a quasi-static run (no dt there)."""
    from fenics_brainshift import Simulation, load_scene

    with pytest.raises(InputError, match=words):
        Simulation(load_scene("brain", ["mesh.voxel=0.01", "time.mode=quasi-static", override]), COMM)


@pytest.mark.mpi
def test_a_settled_state_that_diverges_does_not_blame_the_time_step():
    """A linear brain too soft for its follower load (G = 237 Pa, weight strain 2.6: not a unit
    slip) has no settled state: the message names the loads and moduli, not dt."""
    from fenics_brainshift import Simulation, load_scene
    from fenics_brainshift.errors import SolverError

    sim = Simulation(load_scene("brain", ["mesh.voxel=0.01", "time.mode=quasi-static", "material.G=237"]), COMM)
    sim.setup()
    with pytest.raises(SolverError, match=r"no longer finite .*check the loads against the stiffness") as caught:
        sim.solve_to_settled(16.0)
    assert "dt" not in str(caught.value)
    sim.destroy()
