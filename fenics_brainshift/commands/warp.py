"""`brainshift warp RUN_DIR --image PRE -o INTRA`: the command around the warp package."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..images.volumes import is_volume, read_volume, write_like
from ..outputs.files import check_output_file, check_writable
from ..outputs.run_folder import run_status
from ..warp import DeformedMesh, Warp, check_size, write_itk_transform
from ..warp.deformed import killed_run_time
from .help_format import Defaults, add_overwrite


def add(sub) -> None:
    warp = sub.add_parser(
        "warp",
        help="the predicted intra-operative image: warp a pre-operative volume by a run",
        description="Every voxel y of the output (the input's grid, affine and header) takes the "
        "input's value at the pre-operative point x with x + u(x) = y, u the run's "
        "last displacement (exact inversion of the P1 field); outside the brain the "
        "shift blends to zero over --blend mm. Optionally the same map as an ITK "
        "displacement-field transform for 3D Slicer (docs/slicer.md).",
        formatter_class=Defaults,
    )
    warp.add_argument("run_dir", metavar="RUN_DIR", help="a run's output folder (its displacement.xdmf)")
    warp.add_argument(
        "--image",
        required=True,
        help="pre-operative volume (.nii, .nii.gz, .nrrd, a .seg.nrrd without "
        "overlapping segments), "
        "in the frame of the run's mesh (mm)",
    )
    warp.add_argument("-o", "--output", required=True, help="warped volume (.nii.gz or .nrrd)")
    warp.add_argument(
        "--labels",
        action="store_true",
        help="a label volume: nearest voxel, labels stay labels (default: linear interpolation of intensities)",
    )
    warp.add_argument("--transform", help="also write the map as an ITK transform file (.h5) 3D Slicer loads")
    warp.add_argument(
        "--transform-float32",
        action="store_true",
        help="store the transform's values in single precision: half the file, 1e-7 relative",
    )
    warp.add_argument("--blend", type=float, default=10.0, help="mm over which the shift fades outside the brain")
    warp.add_argument(
        "--cavity-value",
        type=float,
        default=None,
        help="after a resection, the value of the cavity's voxels (default: the image's background, its 1st "
        "percentile; with --labels a new label, one above the largest)",
    )
    add_overwrite(warp, "-o and --transform")
    warp.add_argument(
        "--mesh-frame",
        choices=["RAS", "LPS"],
        default="RAS",
        help="the frame of the run's mesh coordinates (RAS: meshes from NIfTI, this project's)",
    )


def main(args, comm) -> list[str]:
    """`brainshift warp`: warp the image (and write the transform); returns the report's lines."""

    output = Path(args.output)
    if not 0 < args.blend < float("inf"):
        raise InputError(f"warp: --blend must be a finite number of mm > 0 (got {args.blend:g})")
    if not is_volume(output) or output.name.lower().endswith(".nhdr"):  # (a detached header: two files)
        raise InputError(f"warp: -o '{output.name}': use a .nii.gz or .nrrd file name")
    if args.transform and not args.transform.lower().endswith((".h5", ".hdf5")):
        raise InputError(f"warp: --transform '{args.transform}': use an ITK transform file name ending in .h5")
    for path in [output] + ([Path(args.transform)] if args.transform else []):
        flag = "-o" if path == output else "--transform"
        check_writable(path.parent, comm, "folder of " + flag, flag)
        check_output_file(path, flag, "warp", [(args.image, "--image")], args.overwrite)
    volume = read_volume(args.image, "warp: --image")
    body, status, killed_at = _run_state(Path(args.run_dir), args.mesh_frame, comm)
    check_size(body.points, volume, args.labels)
    warp = Warp.compute(volume, body, args.blend, comm, labels=args.labels)
    if not warp.inside.any():
        raise InputError(
            f"warp: the run's brain does not overlap '{Path(args.image).name}' (mesh {body.points.min(0)} "
            f"to {body.points.max(0)} mm RAS); is the image in the mesh's frame? (--mesh-frame)"
        )
    cavity_value = None
    if warp.cavity is not None and warp.cavity.any():
        cavity_value = args.cavity_value if args.cavity_value is not None else _background(volume, args.labels)
        _check_representable(cavity_value, volume, args.cavity_value is not None)
    if comm.rank == 0:  # both or neither: each to a temporary file, then both moved into place
        warped = warp.apply(labels=args.labels, cavity_value=cavity_value)
        transform = Path(args.transform) if args.transform else None
        for path in [output] + ([transform] if transform else []):  # (check_writable allowed new folders)
            path.parent.mkdir(parents=True, exist_ok=True)
        _write_both(
            output,
            lambda path: write_like(volume, warped, path),
            transform,
            lambda path: write_itk_transform(warp, path, float32=args.transform_float32),
        )
    comm.barrier()
    moved = warp.moved()
    note = []
    if killed_at is not None:
        note = [f"warp: the run was killed: this is its last complete state, t = {killed_at:g} s, not the final one"]
    elif status not in (None, "ok"):
        note = [
            f"warp: the run did not end well (summary.json: {status[:100]}): "
            f"this is its last good state, not the final one"
        ]
    return (
        note
        + [
            f"warp: {int(moved.sum())} of {moved.size} voxels moved (largest {warp.largest_mm():.2f} mm, "
            f"{int(warp.inside.sum())} inside the deformed brain); {'nearest' if args.labels else 'linear'} "
            f"sampling; wrote {output}"
            + (f" and {args.transform}" if args.transform else "")
            + (f"; labels {sorted(np.unique(warped).tolist())[:12]}" if args.labels and comm.rank == 0 else "")
        ]
        + (
            [
                f"  the resection's cavity: {int(warp.cavity.sum())} voxels "
                f"({warp.cavity.sum() * abs(np.linalg.det(volume.affine[:3, :3])) / 1e3:.1f} ml) set to "
                f"{cavity_value:g}" + ("" if args.cavity_value is not None else " (--cavity-value to choose)")
            ]
            if cavity_value is not None
            else [f"  --cavity-value {args.cavity_value:g} unused: the state warped has no cavity"]
            if args.cavity_value is not None
            else []
        )
    )


def _check_representable(value: float, volume, given: bool) -> None:
    """The cavity's value must be one the image's type holds (a uint8 label map's 300 became 255)."""
    dtype = np.asarray(volume.data).dtype
    if not np.issubdtype(dtype, np.integer):
        return
    info = np.iinfo(dtype)
    if value != int(value) or not info.min <= value <= info.max:
        what = f"--cavity-value {value:g}" if given else f"the cavity's default label {value:g}"
        raise InputError(
            f"warp: {what} is not a value '{volume.path.name}' can hold ({dtype}: whole numbers {info.min} to "
            f"{info.max}); give --cavity-value within them"
        )


def _background(volume, labels: bool) -> float:
    """A cavity's default value: a label one above the largest, else the image's darkest (its
    1st percentile: an MR's background, a CT's air)."""
    data = np.asarray(volume.data)
    if labels:
        return float(data.max()) + 1.0
    return float(np.percentile(data.ravel()[::7].astype(np.float64), 1))


def _run_state(run_dir: Path, mesh_frame: str, comm):
    """(the deformed mesh, the run's status, the time of a killed run's last state or None),
    read and judged on rank 0 and sent to every rank: whether a run is alive is asked once
    (its folder can change between two ranks' looks)."""
    found, problem = None, None
    if comm.rank == 0:
        try:
            found = (DeformedMesh.from_run(run_dir, mesh_frame), run_status(run_dir), killed_run_time(run_dir))
        except InputError as exc:
            problem = str(exc)
    problem = comm.bcast(problem, root=0)
    if problem:
        raise InputError(problem)
    return comm.bcast(found, root=0)


def _write_both(image: Path, write_image, transform: Path | None, write_transform) -> None:
    """The image and (if asked) the transform, both or neither: each written to a temporary
    name beside its target (the same ending, which says the format), then moved into place,
    a file already there set aside first; where a move fails, the new files are taken back out,
    the earlier ones put back, and the error names the target, not the temporary file."""
    pending = [(image, image.with_name(f".tmp-{image.name}"), write_image)]
    if transform is not None:
        pending.append((transform, transform.with_name(f".tmp-{transform.name}"), write_transform))
    placed, aside = [], []
    target = None
    try:
        for target, temporary, write in pending:  # noqa: B007 (a failed write names its target)
            write(temporary)
        for target, temporary, _ in pending:
            if target.is_file():
                os.replace(target, target.with_name(f".old-{target.name}"))
                aside.append(target)
            os.replace(temporary, target)
            placed.append(target)
    except OSError as exc:
        _undo(placed, aside)
        raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from None
    except BaseException:
        _undo(placed, aside)
        raise
    finally:
        for _, temporary, _ in pending:
            temporary.unlink(missing_ok=True)
    for target in aside:
        target.with_name(f".old-{target.name}").unlink(missing_ok=True)


def _undo(placed: list[Path], aside: list[Path]) -> None:
    """The new files out, the earlier ones (set aside) back."""
    for target in placed:
        target.unlink(missing_ok=True)
    for target in aside:
        os.replace(target.with_name(f".old-{target.name}"), target)
