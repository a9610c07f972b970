"""The warp as an ITK displacement-field transform file 3D Slicer loads (LPS mm, output point
-> input point: what resampling needs), checked to lie on the grid ITK reads from the image."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..images.volumes import Volume
from .warp import Warp


def write_itk_transform(warp: Warp, path: str | Path, float32: bool = False) -> Path:
    """The warp as an ITK displacement-field transform file (.h5 / .hdf5), LPS mm, on the input's
    grid as SimpleITK reads it, cropped to the voxels that move (and one around them); float32:
    the values stored in single precision (half the file; 1e-7 relative, far below a voxel)."""
    import SimpleITK as sitk

    path = Path(path)
    if not path.name.lower().endswith((".h5", ".hdf5")):
        raise InputError(
            f"--transform: '{path.name}': use an ITK HDF5 transform file name (.h5), which 3D Slicer "
            f"loads as a transform"
        )
    reference = sitk.ReadImage(str(warp.volume.path))
    _check_same_grid(reference, warp.volume)
    # the field on the box of the voxels that move, a voxel of zeros around it: ITK moves no
    # point outside a displacement field's grid, and the whole 1 mm head grid was 208 MB
    moving = np.argwhere(warp.moved())
    shape = np.array(warp.v.shape[:3])
    lo = np.maximum(moving.min(axis=0) - 1, 0) if len(moving) else np.zeros(3, dtype=int)
    hi = np.minimum(moving.max(axis=0) + 2, shape) if len(moving) else np.ones(3, dtype=int)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    field = sitk.GetImageFromArray(
        np.ascontiguousarray(warp.displacement_lps_mm()[box].transpose(2, 1, 0, 3)), isVector=True
    )
    field.SetSpacing(reference.GetSpacing())
    field.SetDirection(reference.GetDirection())
    field.SetOrigin(reference.TransformIndexToPhysicalPoint([int(i) for i in lo]))
    transform = sitk.DisplacementFieldTransform(sitk.Cast(field, sitk.sitkVectorFloat64))
    tmp = path.with_name(f".{path.name}.tmp.h5")
    try:
        sitk.WriteTransform(transform, str(tmp))
        _compress_parameters(tmp, np.float32 if float32 else np.float64)
        tmp.replace(path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _compress_parameters(path: Path, dtype) -> None:
    """The field's values stored gzip-compressed (level 1), in ``dtype``: ITK (SimpleITK, 3D
    Slicer) reads them as before, HDF5 converting float32 to the transform's double; the
    resampling is unchanged to the bit for float64 (tests/test_warp.py). On the 1 mm head:
    208 MB for the whole grid uncompressed, 65 MB cropped and compressed, 33 MB in float32
    (benchmarks/results/warp.md). SimpleITK itself writes neither."""
    import h5py

    with h5py.File(path, "r+") as f:
        name = "TransformGroup/0/TransformParameters"
        values = f[name][...]
        del f[name]
        f.create_dataset(name, data=values.astype(dtype), compression="gzip", compression_opts=1, chunks=True)


def _check_same_grid(image, volume: Volume) -> None:
    """ITK's view of the file's grid (LPS) must be ours (RAS): else the transform would be
    written on another grid than the warp (a NIfTI whose qform and sform disagree, say)."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float) * (np.array(volume.data.shape) - 1)
    ours = volume.index_to_ras(corners) @ LPS_TO_RAS
    theirs = np.array([image.TransformContinuousIndexToPhysicalPoint(c.tolist()) for c in corners])
    if np.abs(ours - theirs).max() > 1e-3 * volume.spacing.min():
        raise InputError(
            f"--image: ITK and nibabel/pynrrd read different grids from '{volume.path.name}' (corners "
            f"{np.abs(ours - theirs).max():.3g} mm apart; a NIfTI with disagreeing qform and sform?); "
            f"re-save it from 3D Slicer"
        )
