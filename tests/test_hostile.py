"""Hostile and careless input, refused at its root: files written as strict JSON, conditions of
bounded size and depth, atlases of bounded size estimated before any work. Each case broke,
stalled or wrote a file no strict reader could parse before its fix."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest

from fenics_brainshift import json_text
from fenics_brainshift.errors import InputError

from conftest import COMM


def _strict(text: str):
    """json.loads that refuses NaN and Infinity, as JSON itself does (and every other reader)."""

    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_are_written_as_null_and_said_where():
    data = {"residual_mm": np.array([0.5, np.nan, 1.0]), "rms": float("inf"), "n": np.int64(3), "ok": True}
    back = _strict(json_text.dumps(data))
    assert back["residual_mm"] == [0.5, None, 1.0] and back["rms"] is None and back["n"] == 3
    assert back["non_finite"] == {"residual_mm[1]": "nan", "rms": "inf"}
    assert "non_finite" not in _strict(json_text.dumps({"a": [1.0, 2.0]}))


def test_every_json_file_writer_is_strict(tmp_path):
    """The writers of summary/update/fit JSON, markups and atlas.json all go through json_text."""
    from mpi4py import MPI

    from fenics_brainshift.images.frames import write_markups
    from fenics_brainshift.outputs.files import write_json

    write_json(tmp_path / "s.json", {"max": float("nan")}, MPI.COMM_SELF)
    assert _strict((tmp_path / "s.json").read_text())["non_finite"] == {"max": "nan"}
    write_markups(tmp_path / "m.mrk.json", ["a"], np.array([[1.0, 2.0, 3.0]]))
    _strict((tmp_path / "m.mrk.json").read_text())


@pytest.mark.parametrize(
    "text, words",
    [
        ("(" * 5000 + "x < 1" + ")" * 5000, "characters long"),
        ("not " * 5000 + "x < 1", "characters long"),
        (" or ".join(["x < 1"] * 100_000), "characters long"),
        ("-" * 1000 + "x < 1", "nested"),
        ("+".join(["x"] * 300) + " < 1", "nested"),
    ],
)
def test_a_condition_too_long_or_too_deep_is_one_line_not_a_recursion_error(text, words):
    from fenics_brainshift.scene.predicates import parse_predicate

    with pytest.raises(InputError, match=words):
        parse_predicate(text)


def test_conditions_a_scene_writes_still_parse():
    from fenics_brainshift.scene.predicates import parse_predicate

    where = parse_predicate("x < 0.01 or (y > 0.05 and not z < 0.02) or sqrt(x**2 + y**2) < max(0.01, abs(z))")
    assert where(np.array([[0.0, 1.0], [0.0, 0.0], [0.5, 0.5]])).tolist() == [True, False]


@pytest.mark.mpi
@pytest.mark.parametrize(
    "vary, words",
    [
        (["fluid.level=0.01:0.05:1000000000"], "1,000,000,000 values, at most 200"),
        (["fluid.level=0.01:0.05:1000", "gravity.angle_x=-10:10:1000"], "1,000 values"),
        (["fluid.level=0.01:0.05:100", "gravity.angle_x=-10:10:100"], "10,000 drain/pose scenarios"),
    ],
)
def test_an_atlas_too_large_is_refused_at_once_with_its_estimate(shared_tmp, capsys, vary, words):
    """10^9 levels ran out of memory (a traceback); 10^4 modes ran for hours until killed. On
    every rank (an atlas is built under mpirun): each refuses, rank 0 says it."""
    from fenics_brainshift.cli import main

    start = time.perf_counter()
    code = main(["atlas", "brain", "-o", str(shared_tmp / "a"), *[a for v in vary for a in ("--vary", v)]])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert words in err if COMM.rank == 0 else err == ""
    assert time.perf_counter() - start < 5.0
    COMM.barrier()
    assert not (shared_tmp / "a").exists()


def test_a_folder_of_two_dicom_series_says_which_it_read(tmp_path, caplog):
    """A study folder holding two series was prepared from the larger without a word."""
    import logging
    import shutil

    import SimpleITK as sitk

    from fenics_brainshift.patients.series import read_t1
    from fenics_brainshift.patients.synthetic import write_dicom_series

    rng = np.random.default_rng(0)
    for name, slices in (("big", 40), ("small", 24)):
        image = sitk.GetImageFromArray(rng.uniform(0.0, 1000.0, (slices, 40, 40)).astype(np.float32))
        image.SetSpacing((1.0, 1.0, 1.5))
        write_dicom_series(image, tmp_path / name)
        for file in (tmp_path / name).iterdir():
            (tmp_path / "study").mkdir(exist_ok=True)
            shutil.copy(file, tmp_path / "study" / f"{name}_{file.name}")
    logger = logging.getLogger("fenics_brainshift")  # (the CLI's logging keeps it from the root)
    logger.addHandler(caplog.handler)
    try:
        with caplog.at_level(logging.WARNING, logger="fenics_brainshift"):
            read = read_t1(tmp_path / "study")
    finally:
        logger.removeHandler(caplog.handler)
    assert read.GetSize()[2] == 40
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("2 DICOM series" in m and "(40 files)" in m and "(24 files)" in m for m in said), said


def _obj(path, points):
    """A surface of one fan of triangles over the points, as Wavefront OBJ text."""
    lines = [f"v {x} {y} {z}" for x, y, z in points]
    lines += [f"f 1 {i} {i + 1}" for i in range(2, len(points))]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "scale, broken, words",
    [
        (1.0, True, "vertices that are not finite"),
        (1e-3, False, "positions in metres? give millimetres"),
    ],
)
def test_a_scanned_surface_with_a_nan_vertex_or_in_metres_is_refused(tmp_path, scale, broken, words):
    """Both were taken as measured cortex: a NaN vertex (its residual NaN in update.json) and a
    laser scan in metres (every point at the head's centre, millimetres from the origin)."""
    from fenics_brainshift.images.targets import read_target

    rng = np.random.default_rng(1)
    points = (np.array([0.0, 20.0, 60.0]) + rng.uniform(-30.0, 30.0, (12, 3))) * scale
    if broken:
        points[4, 1] = np.nan
    with pytest.raises(InputError, match=re.escape(words)):
        read_target(_obj(tmp_path / "scan.obj", points))
    assert len(read_target(_obj(tmp_path / "good.obj", points[5:] / scale)).measured) == 7


def test_two_atlas_builds_into_one_folder_are_one_at_a_time(tmp_path, capsys):
    """Two builds into one folder both exited 0, their files interleaved; the second is now refused
    while the first holds the folder (the lock's flock, as another process holds it)."""
    import fcntl

    from fenics_brainshift.cli import main

    out = tmp_path / "a"
    out.mkdir()
    with open(out / ".brainshift.lock", "a+") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        code = main(["atlas", "brain", "-o", str(out), "--set", "mesh.voxel=0.01", "--vary", "fluid.level=0.02,0.03"])
    err = capsys.readouterr().err
    assert code == 2 and "another brainshift process" in err and "-o" in err, err
    assert not (out / "atlas.h5").exists()


def _nifti(path, shape, srow_x=(1.0, 0.0, 0.0, 0.0), data: bool = True, pixdim_x: float = 1.0):
    """A NIfTI-1 file written field by field (nibabel refuses to make a NaN affine itself)."""
    import nibabel as nib

    header = nib.Nifti1Header()
    header.set_data_shape(shape)
    header.set_data_dtype(np.float32)
    header["sform_code"], header["qform_code"] = 1, 0
    header["srow_x"], header["srow_y"], header["srow_z"] = srow_x, (0, 1, 0, 0), (0, 0, 1, 0)
    header["pixdim"][1:4] = (pixdim_x, 1.0, 1.0)
    header["vox_offset"] = 352
    voxels = np.random.default_rng(0).uniform(0, 100, shape).astype(np.float32) if data else np.zeros(10)
    path.write_bytes(header.binaryblock + b"\0" * 4 + voxels.tobytes(order="F"))
    return path


@pytest.mark.parametrize(
    "case, words",
    [
        ("nan affine", "has an affine (voxel size, origin or orientation) that is not a finite number"),
        ("huge grid", "claims 4000 x 4000 x 4000 voxels (256 GB as float)"),
    ],
)
def test_a_scan_whose_header_is_damaged_is_refused_before_its_voxels_are_read(tmp_path, capsys, case, words):
    """A NaN in the affine ran the registration past 300 s; a header claiming 4000^3 voxels was
    allocated before it was judged ("Failed to allocate memory for image")."""
    from fenics_brainshift.cli import main

    if case == "nan affine":
        scan = _nifti(tmp_path / "t1.nii", (40, 40, 40), srow_x=(np.nan, 0.0, 0.0, 0.0))
    else:
        scan = _nifti(tmp_path / "t1.nii", (4000, 4000, 4000), data=False)
    start = time.perf_counter()
    code = main(["prepare", str(scan), "-o", str(tmp_path / "P")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err
    assert time.perf_counter() - start < 10.0 and not (tmp_path / "P").exists()


@pytest.mark.parametrize(
    "case, words",
    [
        ("nan affine", "has an affine (voxel size, origin or orientation) that is not a finite number"),
        ("singular affine", "has a singular affine"),
        ("huge grid", "claims 4000 x 4000 x 4000 voxels (256 GB as float)"),
        ("huge nrrd", "claims 3000 x 3000 x 3000 voxels"),
    ],
)
def test_every_image_reader_judges_the_header_before_the_voxels(tmp_path, case, words):
    """`warp --image`, `update --image` and `mesh` read images through read_volume: a singular
    affine was a LinAlgError traceback, a header claiming 1500^3 voxels had 3.4 GB allocated
    before it was refused, 3000^3 an empty MemoryError; prepare alone judged the header."""
    import tracemalloc

    from fenics_brainshift.images.volumes import read_volume

    if case == "nan affine":
        scan = _nifti(tmp_path / "t1.nii", (40, 40, 40), srow_x=(np.nan, 0.0, 0.0, 0.0))
    elif case == "singular affine":
        scan = _nifti(tmp_path / "t1.nii", (40, 40, 40), srow_x=(0.0, 1.0, 0.0, 0.0))  # x along y
    elif case == "huge grid":
        scan = _nifti(tmp_path / "t1.nii", (4000, 4000, 4000), data=False)
    else:
        scan = tmp_path / "t1.nrrd"
        scan.write_bytes(
            b"NRRD0004\ntype: float\ndimension: 3\nspace: left-posterior-superior\nsizes: 3000 3000 3000\n"
            b"space directions: (1,0,0) (0,1,0) (0,0,1)\nencoding: raw\nendian: little\n"
            b"space origin: (0,0,0)\n\n" + b"\0" * 1000
        )
    tracemalloc.start()
    with pytest.raises(InputError, match=re.escape(words)):
        read_volume(scan, "warp: --image")
    assert tracemalloc.get_traced_memory()[1] < 50e6  # (nothing the size of the claimed grid)
    tracemalloc.stop()


def _box(lo, hi, offset: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A box's 8 corners and its 12 triangles, normals outward."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return corners, np.array(triangles) + offset


def test_a_skull_of_two_shells_or_turned_triangles_is_refused_naming_that(tmp_path):
    """A skull file holding an inner and an outer shell was accepted (its distance field then
    wrong inside); one with a triangle turned the wrong way was refused as a unit or frame slip."""
    from mpi4py import MPI

    from fenics_brainshift import Simulation, scene_from_dict
    from fenics_brainshift.surfaces.triangles import closed_surface_problem, shell_problem

    outer, outer_t = _box([-0.01] * 3, [0.03] * 3)
    inner, inner_t = _box([-0.005] * 3, [0.025] * 3, offset=8)
    one = (outer, outer_t)
    two = (np.vstack([outer, inner]), np.vstack([outer_t, inner_t]))
    turned = outer_t.copy()
    turned[3] = turned[3, ::-1]
    assert closed_surface_problem(one[1]) is None and shell_problem(one[1]) is None
    assert closed_surface_problem(two[1]) is None and "2 separate closed surfaces" in shell_problem(two[1])
    assert closed_surface_problem(turned) is None and "not consistently oriented" in shell_problem(turned)
    for name, (points, triangles), words in (
        ("two.obj", two, "2 separate closed surfaces"),
        ("turned.obj", (outer, turned), "not consistently oriented"),
    ):
        lines = [f"v {x} {y} {z}" for x, y, z in points]  # (m, as the box scene)
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        data = {
            "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [2, 2, 2]},
            "material": {"E": 1e4, "nu": 0.3},
            "fixed": [{"where": "z < 1e-9"}],
            "time": {"mode": "quasi-static"},
            "skull": {"file": str(tmp_path / name)},
        }
        with pytest.raises(InputError, match=re.escape(f"[skull] file '{name}': ") + ".*" + words):
            Simulation(scene_from_dict(data), MPI.COMM_SELF)


def test_a_volume_with_nan_voxels_is_read_with_them_as_zero_and_says_so(tmp_path, caplog):
    """A NaN voxel of a warped image spread to 9 voxels of the output without a word; prepare
    read a T1's as 0 and never said so."""
    import logging

    import nibabel as nib

    from fenics_brainshift.images.volumes import read_volume

    data = np.random.default_rng(0).uniform(0, 100, (20, 20, 20)).astype(np.float32)
    data[3, 4, 5], data[6, 7, 8] = np.nan, np.inf
    nib.save(nib.Nifti1Image(data, np.eye(4)), tmp_path / "t1.nii.gz")
    logger = logging.getLogger("fenics_brainshift")
    logger.addHandler(caplog.handler)
    try:
        with caplog.at_level(logging.WARNING, logger="fenics_brainshift"):
            volume = read_volume(tmp_path / "t1.nii.gz")
    finally:
        logger.removeHandler(caplog.handler)
    assert np.isfinite(volume.data).all() and volume.data[3, 4, 5] == 0 and volume.data[6, 7, 8] == 0
    assert volume.data[0, 0, 0] == data[0, 0, 0]
    assert any("holds 2 voxels that are not finite" in r.getMessage() for r in caplog.records)
    # prepare's reader: ITK reads them as 0 without a word; said the same way
    from fenics_brainshift.patients.series import read_t1

    caplog.clear()
    data = np.random.default_rng(0).uniform(0, 100, (40, 40, 40)).astype(np.float32)
    data[3, 4, 5], data[6, 7, 8] = np.nan, -np.inf
    nib.save(nib.Nifti1Image(data, np.diag([2.0, 2.0, 2.0, 1.0])), tmp_path / "scan.nii.gz")
    logger.addHandler(caplog.handler)
    try:
        with caplog.at_level(logging.WARNING, logger="fenics_brainshift"):
            read_t1(tmp_path / "scan.nii.gz")
    finally:
        logger.removeHandler(caplog.handler)
    assert any("'scan.nii.gz' holds 2 voxels that are not finite" in r.getMessage() for r in caplog.records)


def test_a_scan_header_flipped_by_a_negative_voxel_size_is_read_and_absurd_voxel_sizes_are_not(tmp_path):
    """A negative pixdim is a flip (ITK takes it into the direction): it was refused as not finite.
    Voxels of 1e-6 mm or 1e6 mm passed the header and ended in ITK tracebacks."""
    from fenics_brainshift.patients.series import read_t1

    flipped = _nifti(tmp_path / "flipped.nii", (40, 40, 40), srow_x=(-1.0, 0.0, 0.0, 0.0), pixdim_x=-1.0)
    assert read_t1(flipped).GetSize() == (40, 40, 40)
    for size, name in ((1e-6, "tiny.nii"), (1e6, "huge_voxels.nii")):
        scan = _nifti(tmp_path / name, (40, 40, 40), srow_x=(size, 0.0, 0.0, 0.0), pixdim_x=size)
        with pytest.raises(InputError, match="a head MRI's are 0.05-30 mm"):
            read_t1(scan)


def test_a_condition_with_a_nul_character_is_one_line():
    from fenics_brainshift.scene.predicates import parse_predicate

    with pytest.raises(InputError, match="NUL character"):
        parse_predicate("z < 1e-6\x00")


@pytest.fixture(scope="module")
def small_atlas(tmp_path_factory):
    """A 4-mode atlas of the 1 cm brain in a folder every rank sees (rank 0's), built by the CLI
    on every rank of the pass."""
    from fenics_brainshift.cli import main

    folder = Path(COMM.bcast(str(tmp_path_factory.mktemp("small_atlas")), root=0)) / "atlas"
    vary = ["--vary", "fluid.level=0.01,0.03", "--vary", "gravity.angle_x=0,8"]
    assert main(["atlas", "brain", "-o", str(folder), "--set", "mesh.voxel=0.01", *vary]) == 0
    return folder


def _points(folder: Path, atlas_folder: Path, nan: bool = False) -> list[str]:
    """--pre and --target markups of 12 top vertices of the atlas's brain moved 2 mm down; a
    NaN in one with ``nan``."""
    from fenics_brainshift.atlas import store
    from fenics_brainshift.images import write_markups

    points = 1e3 * store.read(atlas_folder).points
    top = points[np.argsort(points[:, 2])[-12:]]
    moved = top - [0.0, 0.0, 2.0]
    if nan:
        moved[3, 1] = np.nan
    if COMM.rank == 0:
        write_markups(folder / "pre.mrk.json", [f"P{i}" for i in range(12)], top)
        write_markups(folder / "intra.mrk.json", [f"P{i}" for i in range(12)], moved)
    COMM.barrier()
    return ["--pre", str(folder / "pre.mrk.json"), "--target", str(folder / "intra.mrk.json")]


@pytest.mark.mpi
@pytest.mark.parametrize(
    "case, words",
    [
        ("damaged atlas", "damaged"),
        ("noise 1e-300", "--noise"),
        ("noise 1e300", "--noise"),
        ("nan point", "control point 4 has no position of 3 numbers"),
        ("over a run", "holds a run's results"),
        ("where too deep", "nested"),
        ("warp over its image", "is the --image it reads"),
    ],
)
def test_every_rank_refuses_in_one_line_and_writes_nothing(small_atlas, shared_tmp, capsys, case, words):
    """Each check made on every rank (or on rank 0 and sent to the others) under mpirun -n 2:
    both ranks exit 2, rank 0 says the one line, none hangs, nothing is written."""
    import shutil

    import h5py

    from fenics_brainshift.cli import main

    out = shared_tmp / "out"
    atlas = small_atlas
    points = _points(shared_tmp, small_atlas, nan=case == "nan point")
    argv = ["update", str(atlas), *points, "--out", str(out)]
    if case == "damaged atlas":
        atlas = shared_tmp / "damaged"
        if COMM.rank == 0:
            shutil.copytree(small_atlas, atlas)
            with h5py.File(atlas / "atlas.h5", "r+") as f:
                data = f["modes/vertex"][...]
                data.flat[data.size // 2] = np.nan
                f["modes/vertex"][...] = data
        COMM.barrier()
        argv[1] = str(atlas)
    elif case.startswith("noise"):
        argv += ["--noise", case.split()[1]]
    elif case == "over a run":
        assert main(["run", "cube", "--out", str(out), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.end=0.2"]) == 0
        capsys.readouterr()
    elif case == "where too deep":
        argv = ["run", "cube", "--out", str(out), "--set", "fixed.0.where=" + "-" * 1000 + "z < 0.001"]
    elif case == "warp over its image":
        import nibabel as nib

        assert main(["run", "cube", "--out", str(out), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.end=0.2"]) == 0
        capsys.readouterr()
        if COMM.rank == 0:
            nib.save(nib.Nifti1Image(np.ones((60, 60, 60), np.float32), np.eye(4)), str(shared_tmp / "pre.nii.gz"))
        COMM.barrier()
        image = str(shared_tmp / "pre.nii.gz")
        argv = ["warp", str(out), "--image", image, "-o", image]
    before = sorted(p.name for p in out.iterdir()) if out.exists() else None
    code = main(argv)
    err = capsys.readouterr().err
    codes = COMM.allgather(code)
    assert codes == [2] * COMM.size, (codes, err)
    assert "Traceback" not in err
    if COMM.rank == 0:
        lines = err.strip().splitlines()
        assert words in lines[-1], err
    else:
        assert err == ""
    COMM.barrier()
    assert (sorted(p.name for p in out.iterdir()) if out.exists() else None) == before


@pytest.mark.mpi
def test_every_rank_fits_points_the_noise_cannot_explain_and_says_so_once(small_atlas, shared_tmp, capsys):
    """Points of another operation (a random shift of 5 mm, the noise said to be 1 mm): the update
    runs on both ranks, and rank 0 says, once, that the noise cannot explain it, with the
    chi-square."""
    from fenics_brainshift.atlas import store
    from fenics_brainshift.cli import main
    from fenics_brainshift.images import write_markups

    points = 1e3 * store.read(small_atlas).points
    top = points[np.argsort(points[:, 2])[-12:]]
    moved = top + np.random.default_rng(3).normal(0.0, 5.0, top.shape)
    if COMM.rank == 0:
        write_markups(shared_tmp / "pre.mrk.json", [f"P{i}" for i in range(12)], top)
        write_markups(shared_tmp / "intra.mrk.json", [f"P{i}" for i in range(12)], moved)
    COMM.barrier()
    out = shared_tmp / "out"
    argv = ["update", str(small_atlas), "--pre", str(shared_tmp / "pre.mrk.json"), "--target",
            str(shared_tmp / "intra.mrk.json"), "--noise", "1", "--keep-all", "--out", str(out)]  # fmt: skip
    assert COMM.allgather(main(argv)) == [0] * COMM.size
    said = capsys.readouterr()
    if COMM.rank == 0:
        assert said.out.count("chi-square") == 1 and "does not explain" in said.out, said.out
    else:
        assert "chi-square" not in said.out + said.err
    COMM.barrier()
    assert "chi-square" in _strict((out / "update.json").read_text())["warning"]


def test_mesh_and_compare_never_write_over_a_runs_files_or_their_input(tmp_path, capsys, serial_only):
    """`mesh -o RUN/displacement.xdmf` and `compare -o RUN/summary.json` replaced a run's files
    (warp then called the run damaged); now refused in one line, the run untouched, unless
    --overwrite."""
    import hashlib

    import nibabel as nib

    from fenics_brainshift.cli import main

    run = tmp_path / "run"
    assert main(["run", "cube", "--out", str(run), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.end=0.2"]) == 0
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.iterdir() if p.is_file()}
    mask = np.zeros((12, 12, 12), np.uint8)
    mask[3:9, 3:9, 3:9] = 1
    nib.save(nib.Nifti1Image(mask, np.eye(4)), str(tmp_path / "mask.nii.gz"))
    capsys.readouterr()
    mesh = ["mesh", str(tmp_path / "mask.nii.gz"), "--voxel", "2", "-o"]
    assert main(mesh + [str(run / "displacement.xdmf")]) == 2
    err = capsys.readouterr().err
    assert "-o '" in err and "is a run's displacement.xdmf: writing there would lose it" in err
    sphere = tmp_path / "s.stl"
    _stl_sphere(sphere)
    compare = ["compare", str(sphere), str(sphere), str(sphere), "-o"]
    assert main(compare + [str(run / "summary.json")]) == 2
    assert "is a run's summary.json: writing there would lose it" in capsys.readouterr().err
    assert main(compare + [str(sphere)]) == 2
    assert "is the PRE surface it reads" in capsys.readouterr().err
    (run / "deformed.png").write_bytes(b"the run's picture")  # (compare writes its PNG beside its JSON)
    before["deformed.png"] = hashlib.sha256(b"the run's picture").hexdigest()
    assert main(compare + [str(run / "deformed.json")]) == 2
    assert "is a run's deformed.png: writing there would lose it" in capsys.readouterr().err
    after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.iterdir() if p.is_file()}
    assert after == before
    assert main(mesh + [str(run / "displacement.xdmf"), "--overwrite"]) == 0


def _stl_sphere(path) -> None:
    """A closed triangulated sphere of radius 30 mm (an STL in mm)."""
    import meshio
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(0)
    points = rng.normal(size=(300, 3))
    points = 30.0 * points / np.linalg.norm(points, axis=1, keepdims=True)
    meshio.write(str(path), meshio.Mesh(points, [("triangle", ConvexHull(points).simplices)]))
