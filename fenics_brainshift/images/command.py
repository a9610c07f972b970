"""`brainshift warp RUN_DIR --image PRE -o INTRA`: the command around warp.py."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..outputs.files import check_writable
from .volumes import is_volume, read_volume, write_like
from .warp import DeformedMesh, Warp, check_size, run_status, write_itk_transform


def warp_command(args, comm) -> list[str]:
    """`brainshift warp` (arguments: cli.py); returns the report's lines (cli prints them)."""

    output = Path(args.output)
    if not 0 < args.blend < float("inf"):
        raise InputError(f"warp: --blend must be a finite number of mm > 0 (got {args.blend:g})")
    if not is_volume(output) or output.name.lower().endswith(".nhdr"):  # (a detached header: two files)
        raise InputError(f"warp: -o '{output.name}': use a .nii.gz or .nrrd file name")
    if args.transform and not args.transform.lower().endswith((".h5", ".hdf5")):
        raise InputError(f"warp: --transform '{args.transform}': use an ITK transform file name ending in .h5")
    for path in [output] + ([Path(args.transform)] if args.transform else []):
        check_writable(path.parent, comm, "folder of " + ("-o" if path == output else "--transform"), "-o")
    volume = read_volume(args.image, "warp: --image")
    body = DeformedMesh.from_run(args.run_dir, args.mesh_frame)
    check_size(body.points, volume, args.labels)
    warp = Warp.compute(volume, body, args.blend, comm, labels=args.labels)
    if not warp.inside.any():
        raise InputError(f"warp: the run's brain does not overlap '{Path(args.image).name}' (mesh {body.points.min(0)} "
                         f"to {body.points.max(0)} mm RAS); is the image in the mesh's frame? (--mesh-frame)")
    if comm.rank == 0:  # both or neither: each to a temporary file, then both moved into place
        warped = warp.apply(labels=args.labels)
        transform = Path(args.transform) if args.transform else None
        for path in [output] + ([transform] if transform else []):  # (check_writable allowed new folders)
            path.parent.mkdir(parents=True, exist_ok=True)
        _write_both(output, lambda path: write_like(volume, warped, path), transform,
                    lambda path: write_itk_transform(warp, path, float32=args.transform_float32))
    comm.barrier()
    moved = warp.moved()
    status = run_status(Path(args.run_dir))
    note = [] if status in (None, "ok") else [f"warp: the run did not end well (summary.json: {status[:100]}): "
                                              f"this is its last good state, not the final one"]
    return note + [f"warp: {int(moved.sum())} of {moved.size} voxels moved (largest {warp.largest_mm():.2f} mm, "
            f"{int(warp.inside.sum())} inside the deformed brain); {'nearest' if args.labels else 'linear'} "
            f"sampling; wrote {output}" + (f" and {args.transform}" if args.transform else "")
            + (f"; labels {sorted(np.unique(warped).tolist())[:12]}" if args.labels and comm.rank == 0 else "")]


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
        for target, temporary, write in pending:
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
