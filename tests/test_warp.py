"""The warp of an image by a run's displacement, and its ITK transform.

Independent references: SimpleITK's resampling with the written transform; scipy's
map_coordinates with the closed-form inverse of an affine map; DOLFINx's point evaluation of
the run's displacement."""

from __future__ import annotations

import subprocess
import sys

import nibabel as nib
import numpy as np
import pytest
import SimpleITK
from mpi4py import MPI
from scipy import ndimage

from fenics_brainshift.images import read_volume
from fenics_brainshift.warp import DeformedMesh, Warp, check_size, write_itk_transform

from conftest import mpirun, subprocess_env


def _oblique_affine(spacing=(1.0, 1.2, 0.9), angle=0.3, origin=(-20.0, 15.0, -8.0)) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(0.2), -np.sin(0.2)], [0.0, np.sin(0.2), np.cos(0.2)]]
    )
    affine = np.eye(4)
    affine[:3, :3] = rotation * np.array(spacing)
    affine[:3, 3] = origin
    return affine


def _smooth_image(shape, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(size=shape), 2.0) * 1000.0 + 500.0


# -- the warp -------------------------------------------------------------------------------------


def _box_mesh(lo, hi, n):
    """A structured tetrahedral mesh of a box (six tetrahedra per cube)."""
    axes = [np.linspace(a, b, n + 1) for a, b in zip(lo, hi)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange((n + 1) ** 3).reshape((n + 1,) * 3)
    tets = []
    for i in range(n):
        for j in range(n):
            for k in range(n):
                v = [index[i + a, j + b, k + c] for a in (0, 1) for b in (0, 1) for c in (0, 1)]
                for path in ((1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)):  # around the 0-7 diagonal
                    a, b = path
                    tets.append([v[0], v[a], v[a | b], v[7]])
    return points, np.array(tets)


def test_an_affine_displacement_warps_as_the_affine_resampling_does(tmp_path):
    """u(x) = B x + c is exact in P1: inside the deformed box the warp equals linear sampling
    at the closed-form inverse x = (I + B)^-1 (y - c) (scipy), and SimpleITK's resampling
    with the written transform reproduces the warp everywhere away from the image border."""
    affine = _oblique_affine(spacing=(1.0, 1.0, 1.0), origin=(-30.0, -30.0, -30.0))
    data = _smooth_image((60, 60, 60)).astype(np.float32)
    nib.save(nib.Nifti1Image(data, affine), str(tmp_path / "pre.nii.gz"))
    volume = read_volume(tmp_path / "pre.nii.gz")
    B = np.array([[0.02, 0.05, 0.0], [-0.03, 0.01, 0.04], [0.01, -0.02, -0.06]])
    c = np.array([1.3, -2.1, 0.7])
    centre = volume.index_to_ras(np.array([30.0, 30.0, 30.0]))
    points, tets = _box_mesh(centre - 15.0, centre + 15.0, 6)
    body = DeformedMesh(points, tets, points @ B.T + c)
    warp = Warp.compute(volume, body, blend_mm=8.0)
    warped = warp.apply()

    y_index = np.argwhere(warp.inside)
    assert len(y_index) > 20000
    x_ras = (volume.index_to_ras(y_index.astype(float)) - c) @ np.linalg.inv(np.eye(3) + B).T
    expected = ndimage.map_coordinates(data.astype(np.float64), volume.ras_to_index(x_ras).T, order=1, mode="nearest")
    np.testing.assert_allclose(warped[tuple(y_index.T)], expected, rtol=1e-5, atol=1e-3)

    write_itk_transform(warp, tmp_path / "warp.h5")
    image = SimpleITK.ReadImage(str(tmp_path / "pre.nii.gz"), SimpleITK.sitkFloat64)
    transform = SimpleITK.ReadTransform(str(tmp_path / "warp.h5"))
    resampled = SimpleITK.GetArrayFromImage(SimpleITK.Resample(image, image, transform, SimpleITK.sitkLinear, 0.0))
    core = (slice(3, -3),) * 3  # ITK and scipy treat the last half voxel differently
    np.testing.assert_allclose(resampled.transpose(2, 1, 0)[core], warped[core], rtol=1e-5, atol=1e-3)
    # outside the brain the shift fades: zero beyond the blend distance
    assert not warp.moved()[0, 0, 0] and warp.largest_mm() > 1.0


def test_labels_stay_labels_and_the_run_inverse_is_exact(tmp_path, cube_run):
    """On a real run (the cube, settled): x + u(x) = y to 1e-6 of a voxel at random voxels in
    the deformed body, u evaluated by DOLFINx at x; a warped label volume holds only its labels."""
    from fenics_brainshift.outputs.points import PointEvaluator

    result, out = cube_run
    body = DeformedMesh.from_run(out)
    lo, hi = body.points.min(axis=0), body.points.max(axis=0)
    affine = np.diag([0.7, 0.7, 0.7, 1.0])
    affine[:3, 3] = lo - 6.0
    shape = tuple(int(s) for s in np.ceil((hi - lo + 12.0) / 0.7))
    labels = np.zeros(shape, dtype=np.int16)
    labels[: shape[0] // 2] = 3
    labels[shape[0] // 2 :, : shape[1] // 3] = 7
    nib.save(nib.Nifti1Image(labels, affine), str(tmp_path / "labels.nii.gz"))
    volume = read_volume(tmp_path / "labels.nii.gz")
    warp = Warp.compute(volume, body, labels=True)
    warped = warp.apply(labels=True)
    assert warped.dtype == np.int16 and set(np.unique(warped)) <= {0, 3, 7}
    assert (warped != labels).sum() > 100  # the body moved by millimetres

    rng = np.random.default_rng(1)
    inside = np.argwhere(warp.inside)
    y = inside[rng.choice(len(inside), 200, replace=False)].astype(float)
    x = y + warp.v[tuple(y.astype(int).T)]
    x_m = volume.index_to_ras(x) * 1e-3
    u = PointEvaluator(result.mesh, x_m).values(result.displacement) * 1e3  # mm
    residual = volume.ras_to_index(volume.index_to_ras(x) + u) - y  # in voxels
    assert np.abs(residual).max() < 1e-6


@pytest.fixture(scope="module")
def cube_run(tmp_path_factory):
    from fenics_brainshift import load_scene, run

    out = tmp_path_factory.mktemp("cube")
    scene = load_scene("cube", ["time.mode=quasi-static", "mesh.cells=[10,10,5]", "output.pictures=false"])
    return run(scene, out), out


def test_warp_command_serial_and_two_ranks_agree_and_bad_input_is_one_line(tmp_path, cube_run):
    _, out = cube_run
    body = DeformedMesh.from_run(out)
    affine = np.diag([1.0, 1.0, 1.0, 1.0])
    affine[:3, 3] = body.points.min(axis=0) - 5.0
    image = _smooth_image(tuple(int(s) for s in np.ptp(body.points, axis=0) + 10)).astype(np.float32)
    nib.save(nib.Nifti1Image(image, affine), str(tmp_path / "pre.nii.gz"))
    results = {}
    for ranks in (1, 2):
        target = tmp_path / f"warped{ranks}.nrrd"
        command = [
            sys.executable,
            "-m",
            "fenics_brainshift.cli",
            "warp",
            str(out),
            "--image",
            str(tmp_path / "pre.nii.gz"),
            "-o",
            str(target),
            "--transform",
            str(tmp_path / f"t{ranks}.h5"),
        ]
        if ranks > 1:
            command = mpirun() + ["-n", "2"] + command
        done = subprocess.run(command, capture_output=True, text=True, env=subprocess_env(), timeout=300)
        assert done.returncode == 0, done.stderr
        assert "voxels moved" in done.stdout
        results[ranks] = read_volume(target)
    np.testing.assert_allclose(results[1].affine, affine, atol=1e-6)
    assert np.array_equal(results[1].data, results[2].data)

    bad = [
        (["--image", str(tmp_path / "none.nii.gz"), "-o", str(tmp_path / "x.nii.gz")], "--image: no file"),
        (["--image", str(tmp_path / "pre.nii.gz"), "-o", str(tmp_path / "x.png")], "-o 'x.png'"),
        (["--image", str(tmp_path / "pre.nii.gz"), "-o", str(tmp_path / "x.nii.gz"), "--blend", "0"], "--blend"),
        (
            [
                "--image",
                str(tmp_path / "pre.nii.gz"),
                "-o",
                str(tmp_path / "x.nii.gz"),
                "--transform",
                str(tmp_path / "t.txt"),
            ],
            "--transform",
        ),
    ]
    for args, words in bad:
        done = subprocess.run(
            [sys.executable, "-m", "fenics_brainshift.cli", "warp", str(out)] + args,
            capture_output=True,
            text=True,
            env=subprocess_env(),
            timeout=120,
        )
        assert done.returncode == 2 and words in done.stderr and "Traceback" not in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.nii.gz").exists()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "fenics_brainshift.cli",
            "warp",
            str(tmp_path),
            "--image",
            str(tmp_path / "pre.nii.gz"),
            "-o",
            str(tmp_path / "x.nii.gz"),
        ],
        capture_output=True,
        text=True,
        env=subprocess_env(),
        timeout=120,
    )
    assert done.returncode == 2 and "no displacement.xdmf" in done.stderr


def _shifted_box(volume, shift_mm, size=16.0, n=4):
    """A box of tetrahedra at the grid's centre, moved rigidly by shift_mm (exact in P1)."""
    centre = volume.index_to_ras((np.array(volume.data.shape) - 1) / 2.0)
    points, tets = _box_mesh(centre - size / 2, centre + size / 2, n)
    return DeformedMesh(points, tets, np.tile(shift_mm, (len(points), 1)))


def test_labels_outside_the_body_stay_where_they_are(tmp_path):
    """A brain (label 1) in CSF (3) inside a skull (2), the brain moved 3 mm down: the blend
    dragged the skull along; now no skull voxel changes, the brain's voxels are where it went,
    and what it left is CSF."""
    affine = np.eye(4)
    affine[:3, 3] = -30.0
    labels = np.full((61, 61, 61), 2, dtype=np.int16)
    labels[10:51, 10:51, 10:51] = 3  # CSF, 20 mm around the centre
    labels[22:39, 22:39, 22:39] = 1  # the brain: 16 mm at the centre (voxels 22..38)
    nib.save(nib.Nifti1Image(labels, affine), str(tmp_path / "labels.nii.gz"))
    volume = read_volume(tmp_path / "labels.nii.gz")
    warp = Warp.compute(volume, _shifted_box(volume, [0.0, 0.0, -3.0]), blend_mm=15.0, labels=True)
    warped = warp.apply(labels=True)
    skull = labels == 2
    assert warp.moved()[skull].sum() > 1000  # the blend reaches the skull: it used to move with it
    assert np.array_equal(warped[skull], labels[skull])
    brain = np.zeros_like(labels, dtype=bool)
    brain[22:39, 22:39, 19:36] = True  # 3 mm lower
    assert np.array_equal(warped == 1, brain)
    assert np.all(warped[22:39, 22:39, 36:39] == 3)  # the space it left: CSF


@pytest.mark.parametrize("float32", [False, True])
def test_the_transform_is_cropped_to_what_moves_and_resamples_as_the_warp(tmp_path, float32):
    """A 16 mm body in a 60 mm grid: the field covers the voxels that move and one around them
    (ITK moves nothing outside a field), its values are stored compressed, and SimpleITK's
    resampling with it equals the warp on the whole grid."""
    affine = np.eye(4)
    affine[:3, 3] = -30.0
    data = _smooth_image((61, 61, 61)).astype(np.float32)
    nib.save(nib.Nifti1Image(data, affine), str(tmp_path / "pre.nii.gz"))
    volume = read_volume(tmp_path / "pre.nii.gz")
    warp = Warp.compute(volume, _shifted_box(volume, [1.5, -2.0, -3.0]), blend_mm=6.0)
    write_itk_transform(warp, tmp_path / "warp.h5", float32=float32)
    import h5py

    with h5py.File(tmp_path / "warp.h5") as f:
        assert f["TransformGroup/0/TransformParameters"].dtype == (np.float32 if float32 else np.float64)
    transform = SimpleITK.DisplacementFieldTransform(SimpleITK.ReadTransform(str(tmp_path / "warp.h5")))
    field = transform.GetDisplacementField()
    assert np.prod(field.GetSize()) < 0.2 * data.size
    assert (tmp_path / "warp.h5").stat().st_size < 0.2 * 8 * 3 * np.prod(field.GetSize())  # compressed
    image = SimpleITK.ReadImage(str(tmp_path / "pre.nii.gz"), SimpleITK.sitkFloat64)
    resampled = SimpleITK.GetArrayFromImage(SimpleITK.Resample(image, image, transform, SimpleITK.sitkLinear, 0.0))
    np.testing.assert_allclose(resampled.transpose(2, 1, 0), warp.apply(), rtol=1e-5, atol=1e-3)


def test_a_run_that_is_not_of_this_image_or_did_not_finish_is_refused(tmp_path, cube_run):
    """The cube warped onto an image 200 mm away did nothing, exit 0; a killed run's folder
    ("running") or a truncated displacement.h5 gave a traceback or the wrong fix."""
    import shutil

    from fenics_brainshift.errors import InputError
    from fenics_brainshift.outputs.files import RunLock

    _, out = cube_run
    affine = np.eye(4)
    affine[:3, 3] = 200.0
    nib.save(nib.Nifti1Image(np.zeros((20, 20, 20), np.float32), affine), str(tmp_path / "far.nii.gz"))
    with pytest.raises(InputError, match=r"0% of the run's mesh lies on 'far.nii.gz'"):
        Warp.compute(read_volume(tmp_path / "far.nii.gz"), DeformedMesh.from_run(out))
    body = DeformedMesh.from_run(out)  # on the grid, but on its empty part: the object is elsewhere
    affine = np.eye(4)
    affine[:3, 3] = body.points.min(axis=0) - 20.0
    air = np.zeros(tuple(int(s) for s in np.ptp(body.points, axis=0) + 40), np.float32)
    air[:10] = 100.0  # a bright slab 10 mm beside the cube
    nib.save(nib.Nifti1Image(air, affine), str(tmp_path / "air.nii.gz"))
    with pytest.raises(InputError, match=r"0% of the run's mesh lies on the object in 'air.nii.gz'"):
        Warp.compute(read_volume(tmp_path / "air.nii.gz"), body)
    # the check must not refuse the object itself: a CT (air -1000 HU, brain 30, a bone slab
    # brighter; the old |value| > 5 % of the 99th percentile called the air the object and the
    # brain background) and a FreeSurfer label map (label 2 beside a parcel 2035)
    inside = np.zeros(air.shape, bool)
    lo = np.floor(body.points.min(axis=0) - affine[:3, 3]).astype(int)
    hi = np.ceil(body.points.max(axis=0) - affine[:3, 3]).astype(int)
    inside[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = True
    ct = np.where(inside, 30.0, -1000.0).astype(np.float32)
    ct[:3] = 1500.0
    nib.save(nib.Nifti1Image(ct, affine), str(tmp_path / "ct.nii.gz"))
    Warp.compute(read_volume(tmp_path / "ct.nii.gz"), body)
    aseg = np.where(inside, 2, 0).astype(np.int16)
    aseg[:5] = 2035
    nib.save(nib.Nifti1Image(aseg, affine), str(tmp_path / "aseg.nii.gz"))
    Warp.compute(read_volume(tmp_path / "aseg.nii.gz"), body, labels=True)
    with pytest.raises(
        InputError,
        match=r"0% of the run's mesh lies on the object in 'labels.nii.gz' \(its voxels "
        r"labelled",
    ):
        nib.save(nib.Nifti1Image(np.where(inside, 0, 3).astype(np.int16), affine), str(tmp_path / "labels.nii.gz"))
        Warp.compute(read_volume(tmp_path / "labels.nii.gz"), body, labels=True)
    # the cube inside a head's foreground (an ellipsoid 180 x 220 x 200 mm about it): on the
    # object, but not the object (the cube on the ICBM152 T1 moved 153,801 voxels, exit 0)
    head_affine = np.eye(4)
    head_affine[:3, 3] = body.points.mean(axis=0) - 120.0
    ijk = np.indices((240, 240, 240)).reshape(3, -1).T - 120.0
    head = ((ijk / [90.0, 110.0, 100.0]) ** 2).sum(axis=1) < 1.0
    nib.save(
        nib.Nifti1Image((200.0 * head).reshape(240, 240, 240).astype(np.float32), head_affine),
        str(tmp_path / "head.nii.gz"),
    )
    head = read_volume(tmp_path / "head.nii.gz")
    Warp.compute(head, body)  # (Warp warps any mesh on any grid)
    with pytest.raises(InputError, match=r"the run's mesh is 75 mm across .*, the object in 'head.nii.gz' 3\d\d mm"):
        check_size(body.points, head)  # brainshift warp's check
    check_size(body.points, read_volume(tmp_path / "ct.nii.gz"))  # the cube's own image
    # a folder that says "running": still running (its lock held), or killed (no holder): then
    # its last complete state, last_state.npz, is the state; without one it is refused
    killed = tmp_path / "killed"
    shutil.copytree(out, killed)
    (killed / "summary.json").write_text('{"status": "running"}')
    lock = RunLock(killed, MPI.COMM_SELF)
    with pytest.raises(InputError, match=r"is still running \(pid \d+\); wait for it to end"):
        DeformedMesh.from_run(killed)
    lock.release()
    saved = DeformedMesh.from_run(killed)
    _same_state(saved, body)
    (killed / "last_state.npz").unlink()
    with pytest.raises(InputError, match=r"was killed before it saved a complete state"):
        DeformedMesh.from_run(killed)
    # a damaged displacement.h5: the same state from last_state.npz; with neither, refused
    damaged = tmp_path / "damaged"
    shutil.copytree(out, damaged)
    h5 = damaged / "displacement.h5"
    h5.write_bytes(h5.read_bytes()[: h5.stat().st_size // 3])
    _same_state(DeformedMesh.from_run(damaged), body)
    saved = damaged / "last_state.npz"
    saved.write_bytes(saved.read_bytes()[: saved.stat().st_size // 2])
    with pytest.raises(InputError, match=r"cannot be read .*damaged or incomplete"):
        DeformedMesh.from_run(damaged)


def _same_state(a, b) -> None:
    """Two DeformedMesh of one state, their vertices in any order: the same points, the same
    displacement at each, the same tetrahedra as sets of points."""
    order_a, order_b = (np.lexsort(np.round(m.points, 6).T[::-1]) for m in (a, b))
    np.testing.assert_allclose(a.points[order_a], b.points[order_b], atol=1e-9)
    np.testing.assert_allclose(a.displacement[order_a], b.displacement[order_b], atol=1e-12)
    rank_a, rank_b = (np.argsort(order) for order in (order_a, order_b))
    cells_a, cells_b = (np.sort(rank[m.tets], axis=1) for rank, m in ((rank_a, a), (rank_b, b)))
    assert {tuple(c) for c in cells_a} == {tuple(c) for c in cells_b}


def _image_around(body, path) -> np.ndarray:
    """A smooth 1 mm image 5 mm beyond the body's bounding box on every side, written to path;
    its affine."""
    affine = np.eye(4)
    affine[:3, 3] = body.points.min(axis=0) - 5.0
    image = _smooth_image(tuple(int(s) for s in np.ptp(body.points, axis=0) + 10)).astype(np.float32)
    nib.save(nib.Nifti1Image(image, affine), str(path))
    return affine


def test_warp_writes_the_image_and_its_transform_both_or_neither(tmp_path, cube_run, capsys, monkeypatch, serial_only):
    """The transform's final move failing left the image without its transform, and the
    message spoke of a run's summary.json. Now neither is left, nor a temporary file, an
    earlier warp's image is put back, and the one line names the path. A folder where the
    transform should go is refused before the work. A detached NRRD header (.nhdr: its data
    file named for the temporary file) is refused."""
    import os

    from fenics_brainshift.cli import main
    from fenics_brainshift.commands import warp as warp_command

    _, out = cube_run
    _image_around(DeformedMesh.from_run(out), tmp_path / "pre.nii.gz")
    (tmp_path / "w").mkdir()
    args = [
        "warp",
        str(out),
        "--image",
        str(tmp_path / "pre.nii.gz"),
        "-o",
        str(tmp_path / "w" / "intra.nii.gz"),
        "--transform",
        str(tmp_path / "w" / "t.h5"),
    ]
    (tmp_path / "w" / "intra.nii.gz").write_bytes(b"an earlier warp")
    original = os.replace

    def refuse_the_transform(src, dst):  # (the transform's move fails: a full disk, a permission)
        if str(dst).endswith("t.h5"):
            raise OSError(28, "No space left on device", str(dst))
        original(src, dst)

    monkeypatch.setattr(warp_command.os, "replace", refuse_the_transform)
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'{tmp_path / 'w' / 't.h5'}'" in err[0] and "summary.json" not in err[0], err
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == ["intra.nii.gz"]  # (no temporary file)
    assert (tmp_path / "w" / "intra.nii.gz").read_bytes() == b"an earlier warp"  # put back, not lost
    monkeypatch.setattr(warp_command.os, "replace", original)
    (tmp_path / "w" / "t.h5").mkdir()  # a folder where the transform goes: refused before the work
    assert main(args) == 2 and "--transform '" in capsys.readouterr().err
    assert (tmp_path / "w" / "intra.nii.gz").read_bytes() == b"an earlier warp"
    (tmp_path / "w" / "t.h5").rmdir()
    assert main(args) == 0
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == ["intra.nii.gz", "t.h5"]
    assert main(args[:4] + ["-o", str(tmp_path / "w" / "intra.nhdr")]) == 2  # a detached header: two files
    assert "use a .nii.gz or .nrrd file name" in capsys.readouterr().err


def test_warp_of_a_run_that_stopped_says_which_state_it_warps(tmp_path, cube_run, capsys, monkeypatch, serial_only):
    """A run interrupted (Ctrl-C) or stopped by a guard (exit 3) kept its last good state: warp
    uses it and says so; a full disk while writing the image is one line, exit 1, and leaves
    neither file."""
    import errno
    import json
    import shutil

    from fenics_brainshift.cli import main
    from fenics_brainshift.commands import warp as command

    _, out = cube_run
    _image_around(DeformedMesh.from_run(out), tmp_path / "pre.nii.gz")
    for status in ("interrupted", "stopped: energy from nowhere at t = 3 s"):
        run = tmp_path / "run"
        shutil.rmtree(run, ignore_errors=True)
        shutil.copytree(out, run)
        summary = json.loads((run / "summary.json").read_text())
        (run / "summary.json").write_text(json.dumps({**summary, "status": status}))
        assert main(["warp", str(run), "--image", str(tmp_path / "pre.nii.gz"), "-o", str(tmp_path / "w.nii.gz")]) == 0
        said = capsys.readouterr().out
        assert f"the run did not end well (summary.json: {status}): this is its last good state" in said

    def full(volume, data, path):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(command, "write_like", full)
    target = tmp_path / "full" / "w.nii.gz"
    assert (
        main(
            [
                "warp",
                str(out),
                "--image",
                str(tmp_path / "pre.nii.gz"),
                "-o",
                str(target),
                "--transform",
                str(tmp_path / "full" / "t.h5"),
            ]
        )
        == 1
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "summary.json" not in err[0], err
    assert list((tmp_path / "full").iterdir()) == []


def test_warp_never_writes_over_the_image_it_warps_or_a_runs_files_unless_asked(tmp_path, cube_run, capsys):
    """-o naming the pre-operative image replaced it; --transform naming the run's
    displacement.h5 destroyed the run. Both refused in one line, nothing written;
    --overwrite asks for it."""
    import hashlib
    import shutil

    from fenics_brainshift.cli import main

    _, out = cube_run
    run = tmp_path / "run"
    shutil.copytree(out, run)
    body = DeformedMesh.from_run(run)
    _image_around(body, tmp_path / "pre.nii.gz")

    def digest(path):
        return hashlib.sha256(path.read_bytes()).hexdigest()

    image, series = digest(tmp_path / "pre.nii.gz"), digest(run / "displacement.h5")
    warp = ["warp", str(run), "--image", str(tmp_path / "pre.nii.gz")]
    assert main(warp + ["-o", str(tmp_path / "pre.nii.gz")]) == 2
    err = capsys.readouterr().err
    assert "-o '" in err and "is the --image it reads" in err and "(or --overwrite)" in err, err
    assert main(warp + ["-o", str(tmp_path / "intra.nii.gz"), "--transform", str(run / "displacement.h5")]) == 2
    err = capsys.readouterr().err
    assert "--transform '" in err and "is a run's displacement.h5: writing there would lose it" in err, err
    assert not (tmp_path / "intra.nii.gz").exists()
    assert digest(tmp_path / "pre.nii.gz") == image and digest(run / "displacement.h5") == series
    (tmp_path / "folder.h5").mkdir()
    assert main(warp + ["-o", str(tmp_path / "intra.nii.gz"), "--transform", str(tmp_path / "folder.h5")]) == 2
    assert "--transform '" in (err := capsys.readouterr().err) and "folder.h5' is a folder; give a file name" in err
    assert not (tmp_path / "intra.nii.gz").exists()
    assert main(warp + ["-o", str(tmp_path / "intra.nii.gz")]) == 0  # (anywhere else: as before)
    assert main(warp + ["-o", str(tmp_path / "intra.nii.gz")]) == 0  # over its own earlier output
    assert main(warp + ["-o", str(tmp_path / "pre.nii.gz"), "--overwrite"]) == 0
    assert digest(tmp_path / "pre.nii.gz") != image
