"""A pre-operative T1 as a 3-D SimpleITK image (LPS mm, ITK's frame): a DICOM series folder
(GDCM through SimpleITK), a NIfTI or a NRRD, refused in one line when it cannot be a T1
volume (2-D, 4-D, several components, missing slices, a label map)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import SimpleITK as sitk

from ..errors import InputError
from ..images.volumes import check_grid, is_volume, say_non_finite

log = logging.getLogger(__name__)

MIN_SIZE = 16  # voxels along each axis: fewer is a localiser or a slab, not a head
VOXEL_MM = (0.05, 30.0)  # a head MRI's voxel sizes (0.2-1 mm 3-D, slabs up to 7 mm) with room
MAX_LABELS = 16  # a T1 has thousands of grey values; this few is a segmentation
GAP_FACTOR = 1.5  # a step between slice positions this many times the usual one: a missing slice


def read_t1(path: str | Path, what: str = "T1") -> sitk.Image:
    """The T1 at ``path`` as float32; InputError naming ``what`` and the fix otherwise."""
    path = Path(path)
    if path.is_dir():
        image = _read_dicom_series(path, what)
    elif not path.is_file():
        raise InputError(f"{what}: no file or folder '{path}'")
    elif is_volume(path) or path.name.lower().endswith(".dcm"):
        _check_header(path, what)
        try:
            image = sitk.ReadImage(str(path))
        except RuntimeError as exc:
            raise InputError(f"{what}: '{path.name}' could not be read ({_first_line(exc)})") from None
        _say_non_finite(path, what)
    else:
        raise InputError(
            f"{what}: '{path.name}' is neither a DICOM series folder nor a NIfTI (.nii, .nii.gz) or NRRD (.nrrd) volume"
        )
    return _checked(image, path, what)


def _say_non_finite(path: Path, what: str) -> None:
    """ITK reads a NIfTI's NaN and infinite voxels as 0 without a word (SimpleITK 2.5): counted
    from the file itself and said, as every other reader of images says it."""
    if not path.name.lower().endswith((".nii", ".nii.gz")):
        return
    import nibabel as nib

    try:
        image = nib.load(str(path))
        if not np.issubdtype(image.get_data_dtype(), np.floating):
            return
        values = np.asanyarray(image.dataobj)
    except Exception:  # (ITK read it; nibabel's view is only for the count)
        return
    say_non_finite(values, path.name, what)


def _check_header(path: Path, what: str) -> None:
    """The grid a file's header claims, judged before its voxels are read: a size past
    MAX_VOXELS was allocated first (and failed), a NaN in the affine stalled the registration."""
    if path.name.lower().endswith((".nii", ".nii.gz")):  # (ITK's SVD of a NaN affine prints a page first)
        _check_nifti_affine(path, what)
    reader = sitk.ImageFileReader()
    reader.SetFileName(str(path))
    try:
        reader.ReadImageInformation()
    except RuntimeError as exc:
        raise InputError(f"{what}: '{path.name}' could not be read ({_first_line(exc)})") from None
    check_grid(reader.GetSize(), np.eye(4), path.name, what)  # (its size: the geometry is ITK's, below)
    _check_geometry(reader.GetSpacing(), reader.GetOrigin(), reader.GetDirection(), path.name, what)


def _check_nifti_affine(path: Path, what: str) -> None:
    import nibabel as nib

    try:
        header = nib.load(str(path)).header
        with np.errstate(invalid="ignore"):
            matrices = [header.get_zooms()[:3]]
            if header["sform_code"] > 0:
                matrices.append(header.get_sform())
            if header["qform_code"] > 0:
                matrices.append(header.get_qform())
    except Exception:  # (a header nibabel cannot read: ITK says why below)
        return
    if not all(np.isfinite(np.asarray(m, dtype=float)).all() for m in matrices):
        raise InputError(
            f"{what}: '{path.name}' has an affine (voxel size, origin or orientation) that is not a finite "
            f"number: its header is damaged; export the scan again"
        )


def _check_geometry(spacing, origin, direction, name: str, what: str) -> None:
    geometry = np.concatenate([spacing, origin, direction]).astype(float)
    if not np.isfinite(geometry).all():
        raise InputError(
            f"{what}: '{name}' has a voxel size, origin or orientation that is not a finite number: its header "
            f"is damaged; export the scan again"
        )
    size = np.abs(np.asarray(spacing, dtype=float))  # (a negative pixdim is a flip ITK takes into the direction)
    if not (VOXEL_MM[0] <= size.min() and size.max() <= VOXEL_MM[1]):
        raise InputError(
            f"{what}: '{name}' has voxels of {' x '.join(f'{v:.3g}' for v in size)} mm; a head MRI's are "
            f"{VOXEL_MM[0]:g}-{VOXEL_MM[1]:g} mm (a header in another unit, or damaged?); export the scan again"
        )
    if abs(np.linalg.det(np.reshape(direction, (len(spacing), len(spacing))))) < 1e-3:
        raise InputError(f"{what}: '{name}' has a singular orientation in its header; export the scan again")


def _checked(image: sitk.Image, path: Path, what: str) -> sitk.Image:
    name = path.name
    _check_geometry(image.GetSpacing(), image.GetOrigin(), image.GetDirection(), name, what)
    if image.GetNumberOfComponentsPerPixel() != 1:
        raise InputError(
            f"{what}: '{name}' has {image.GetNumberOfComponentsPerPixel()} components per voxel "
            f"(colour or a vector field); a T1 has one grey value"
        )
    size = list(image.GetSize())
    if image.GetDimension() == 4 and size[3] == 1:
        image = image[:, :, :, 0]
        size = size[:3]
    if image.GetDimension() != 3:
        kind = "2-D" if image.GetDimension() == 2 else f"{image.GetDimension()}-D"
        raise InputError(
            f"{what}: '{name}' is a {kind} image of size {size}; a 3-D T1 volume is needed "
            f"(a 4-D series holds several volumes: export the T1 alone)"
        )
    if min(size) < MIN_SIZE:
        raise InputError(
            f"{what}: '{name}' is {size[0]} x {size[1]} x {size[2]} voxels; a T1 of the head has at "
            f"least {MIN_SIZE} along each axis (is it a single slice or a localiser?)"
        )
    image = sitk.Cast(image, sitk.sitkFloat32)
    values = sitk.GetArrayViewFromImage(image)
    if not np.isfinite(values).all():
        raise InputError(f"{what}: '{name}' holds NaN or infinite voxel values")
    sample = values[::4, ::4, ::4]
    if len(np.unique(sample)) <= MAX_LABELS:
        raise InputError(
            f"{what}: '{name}' has only {len(np.unique(sample))} distinct values: a segmentation, "
            f"not a T1 (give the MRI; a tumour segmentation goes to --tumour)"
        )
    return image


def _read_dicom_series(folder: Path, what: str) -> sitk.Image:
    ids = sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(folder))
    if not ids:
        raise InputError(
            f"{what}: no DICOM series in folder '{folder}' (give the folder that holds the T1's .dcm files, or a NIfTI)"
        )
    files = {uid: sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(folder), uid) for uid in ids}
    uid = max(ids, key=lambda u: len(files[u]))
    if len(ids) > 1:  # (a folder of a whole study: the largest is usually the 3-D T1, not always)
        others = ", ".join(f"'{_description(files[u][0])}' ({len(files[u])} files)" for u in ids if u != uid)
        log.warning(
            "%s: %d DICOM series in '%s'; reading the largest, '%s' (%d files), not %s: if that is not the scan "
            "to prepare, give a folder that holds it alone",
            what,
            len(ids),
            folder.name,
            _description(files[uid][0]),
            len(files[uid]),
            others,
        )
    names = list(files[uid])
    if len(names) == 1:
        raise InputError(
            f"{what}: the DICOM series in '{folder.name}' is one file: a 2-D image or a multi-frame "
            f"file; convert it to NIfTI (e.g. dcm2niix) and give that"
        )
    _check_slice_positions(names, folder, what)
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(names)
    try:
        return reader.Execute()
    except RuntimeError as exc:
        raise InputError(
            f"{what}: the DICOM series in '{folder.name}' could not be read ({_first_line(exc)})"
        ) from None


def _check_slice_positions(names: list[str], folder: Path, what: str) -> None:
    """Slices evenly spaced along one normal, one slice per position: else a slice is missing
    or the series holds several volumes."""
    positions, normals = [], []
    for name in names:
        reader = sitk.ImageFileReader()
        reader.SetFileName(name)
        try:
            reader.ReadImageInformation()
            position = [float(v) for v in reader.GetMetaData("0020|0032").split("\\")]
            cosines = [float(v) for v in reader.GetMetaData("0020|0037").split("\\")]
        except (RuntimeError, ValueError):
            raise InputError(
                f"{what}: '{Path(name).name}' in '{folder.name}' has no readable image position or "
                f"orientation (DICOM 0020,0032 and 0020,0037)"
            ) from None
        positions.append(position)
        normals.append(np.cross(cosines[:3], cosines[3:6]))
    normal = normals[0]
    if any(abs(float(np.dot(n, normal))) < 0.999 for n in normals):
        raise InputError(
            f"{what}: the slices in '{folder.name}' are not parallel (a localiser or several series "
            f"mixed in one folder); give the T1's folder alone"
        )
    heights = np.sort(np.asarray(positions) @ normal)
    steps = np.diff(heights)
    if np.any(steps < 1e-3):
        raise InputError(
            f"{what}: the DICOM series in '{folder.name}' has several slices at one position: a 4-D "
            f"series (several volumes or echoes); export the T1 volume alone"
        )
    usual = float(np.median(steps))
    gaps = np.flatnonzero(steps > GAP_FACTOR * usual)
    if len(gaps):
        at = heights[gaps[0]]
        raise InputError(
            f"{what}: the DICOM series in '{folder.name}' misses slices: {len(gaps)} gap(s) in the "
            f"slice positions, the first after {at:.1f} mm ({steps[gaps[0]]:.2f} mm against the usual "
            f"{usual:.2f} mm); copy the whole series"
        )


def _description(file: str) -> str:
    """A DICOM file's series description (0008|103E), or its series number, or "?"."""
    reader = sitk.ImageFileReader()
    reader.SetFileName(file)
    try:
        reader.ReadImageInformation()
    except RuntimeError:
        return "?"
    for tag in ("0008|103e", "0020|0011"):
        if reader.HasMetaDataKey(tag) and reader.GetMetaData(tag).strip():
            return reader.GetMetaData(tag).strip()[:60]
    return "?"


def _first_line(exc: Exception) -> str:
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[-1] if lines else type(exc).__name__


DESCRIBING_TAGS = ("0008|103e", "0018|1030", "0018|0010")  # series description, protocol name, contrast agent


def series_metadata(path: str | Path) -> dict[str, str]:
    """The tags that say what a DICOM series was taken as (DESCRIBING_TAGS), from the first file
    of the folder's largest series; {} for a NIfTI or NRRD."""
    path = Path(path)
    if not path.is_dir():
        return {}
    ids = sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(path))
    if not ids:
        return {}
    names = max((sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(path), uid) for uid in ids), key=len)
    reader = sitk.ImageFileReader()
    reader.SetFileName(names[0])
    try:
        reader.ReadImageInformation()
    except RuntimeError:
        return {}
    return {tag: reader.GetMetaData(tag).strip() for tag in DESCRIBING_TAGS if reader.HasMetaDataKey(tag)}
