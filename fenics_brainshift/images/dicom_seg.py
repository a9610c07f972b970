"""DICOM-SEG: a segmentation as a PACS, 3D Slicer (QuantitativeReporting) or a planning system
stores it, read by highdicom and placed on the voxels of the image it was drawn on.

A DICOM-SEG is one multi-frame file: each frame is one plane of one segment (BINARY or
FRACTIONAL), or of all segments at once (LABELMAP), at its own ImagePositionPatient. Frames
that hold nothing are usually left out, so the file is not a volume of its own. Each frame is
placed on the reference grid by its own position, orientation and pixel spacing. Spacing
Between Slices is not used: writers copy it from the source series, and a series that states
it wrongly would shift every plane. A frame that does not fall on the reference's voxels is
refused ("another grid"); it is never resampled.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

GRID_TOLERANCE = 1e-2  # voxels: how far a frame's pixel may sit from the reference's voxel centre


def is_dicom_seg_path(path: str | Path) -> bool:
    """A .dcm file, or a folder (a DICOM export) given where a segmentation is expected."""
    path = Path(path)
    return path.is_dir() or path.suffix.lower() in (".dcm", ".dicom")


def read_dicom_seg(path: str | Path, reference, what: str) -> dict[str, np.ndarray]:
    """Each segment of the DICOM-SEG at ``path`` (a file, or a folder that holds one) as voxels
    (bool, [k, j, i]) of ``reference`` (a SimpleITK image, LPS as DICOM), by segment label.
    InputError names ``what`` for a file that is not a DICOM-SEG or is on another grid."""
    seg = _read(_seg_file(Path(path), what), what)
    name = Path(path).name
    size = np.array(reference.GetSize())  # i, j, k
    to_index = np.linalg.inv(_index_to_lps(reference))
    labelmap = str(seg.SegmentationType) == "LABELMAP"
    fractional = str(seg.SegmentationType) == "FRACTIONAL"
    try:
        frames = np.asarray(seg.pixel_array)
    except Exception as exc:  # truncated or undecodable pixel data
        raise InputError(f"{what}: '{name}': its pixel data could not be read ({exc}); is the file complete?") from None
    if frames.ndim == 2:  # a single frame
        frames = frames[None]
    if "PerFrameFunctionalGroupsSequence" not in seg or len(seg.PerFrameFunctionalGroupsSequence) != len(frames):
        raise InputError(
            f"{what}: '{name}' does not say where each of its {len(frames)} frames lies (no per-frame "
            f"functional groups); it is not a DICOM-SEG this reader can place"
        )
    half = 0.5 * float(getattr(seg, "MaximumFractionalValue", 1)) if fractional else 0.5

    numbers = [int(n) for n in seg.get_segment_numbers()]
    labels = _labels(seg, numbers)
    masks = {number: np.zeros(tuple(size[::-1]), dtype=bool) for number in numbers}
    planes = set()  # the T1 planes the frames lie on
    for f, group in enumerate(seg.PerFrameFunctionalGroupsSequence):
        frame_to_index = to_index @ _frame_to_lps(seg, group, what, name)
        i, j, k = _frame_voxels(frame_to_index, frames.shape[1:], what, name)
        if np.ptp(k) == 0:
            planes.add(int(k[0, 0]))
        frame = frames[f]
        for number in numbers if labelmap else [_segment_of(seg, group, numbers, what, name)]:
            on = frame == number if labelmap else frame >= half
            r, c = np.nonzero(on)
            if r.size == 0:
                continue
            ii, jj, kk = i[r, c], j[r, c], k[r, c]
            if (
                (ii < 0).any()
                or (jj < 0).any()
                or (kk < 0).any()
                or (ii >= size[0]).any()
                or (jj >= size[1]).any()
                or (kk >= size[2]).any()
            ):
                raise InputError(
                    f"{what}: '{name}' labels voxels outside the T1 (segment '{labels[number]}'); "
                    f"it was drawn on another image; export it with the T1 as its reference"
                )
            masks[number][kk, jj, ii] = True
    _check_planes(planes, what, name)
    return {labels[number]: mask for number, mask in masks.items()}


def _check_planes(planes: set, what: str, name: str) -> None:
    """Frames on every second (third...) plane of the T1 only: drawn on a series of thicker
    slices, whose voxels span planes between them; laid on the T1's it would be striped."""
    k = np.array(sorted(planes))
    if len(k) > 1 and np.gcd.reduce(np.diff(k)) > 1:
        raise InputError(
            f"{what}: '{name}' has frames on every {np.gcd.reduce(np.diff(k))}th plane of the T1 only: "
            f"it was drawn on a series of thicker slices; export it on the T1's grid (3D Slicer: "
            f"resample the segmentation with the T1 as reference)"
        )


def _seg_file(path: Path, what: str) -> Path:
    if path.is_file():
        return path
    if not path.is_dir():
        raise InputError(f"{what}: no file '{path}'")
    files = [p for p in sorted(path.iterdir()) if p.is_file() and _modality(p) == "SEG"]
    if len(files) != 1:
        raise InputError(
            f"{what}: the folder '{path.name}' holds {len(files)} DICOM-SEG files; give the one segmentation file"
        )
    return files[0]


def _modality(path: Path) -> str | None:
    import pydicom

    try:
        return str(pydicom.dcmread(path, stop_before_pixels=True, specific_tags=["Modality"]).get("Modality", ""))
    except Exception:  # not DICOM: not a candidate
        return None


def _read(path: Path, what: str):
    import highdicom as hd

    modality = _modality(path)
    if modality is None:
        raise InputError(f"{what}: '{path.name}' is not a DICOM file; give a DICOM-SEG, a NIfTI or a .seg.nrrd")
    if modality != "SEG":
        raise InputError(
            f"{what}: '{path.name}' is a DICOM {modality or 'file'} image, not a segmentation "
            f"(DICOM-SEG); give the segmentation file"
        )
    try:
        return hd.seg.segread(path)
    except Exception as exc:  # a damaged or non-conformant file: highdicom's own words
        raise InputError(f"{what}: '{path.name}' could not be read as a DICOM-SEG ({exc})") from None


def _labels(seg, numbers: list[int]) -> dict[int, str]:
    """Segment number -> its label; a label two segments share gets its number appended."""
    labels = {n: str(seg.get_segment_description(n).segment_label) for n in numbers}
    shared = {label for label in labels.values() if list(labels.values()).count(label) > 1}
    return {n: f"{label} #{n}" if label in shared else label for n, label in labels.items()}


def _index_to_lps(image) -> np.ndarray:
    """4x4: a SimpleITK image's index (i, j, k, 1) to LPS mm."""
    affine = np.eye(4)
    affine[:3, :3] = np.reshape(image.GetDirection(), (3, 3)) * np.array(image.GetSpacing())
    affine[:3, 3] = image.GetOrigin()
    return affine


def _functional(seg, group, sequence: str, what: str, name: str):
    """One functional group's item: the frame's own, or the one all frames share."""
    for source in (group, *seg.get("SharedFunctionalGroupsSequence", [])):
        if sequence in source:
            return source[sequence].value[0]
    raise InputError(f"{what}: '{name}' has no {sequence} for a frame; it does not say where its planes lie")


def _frame_to_lps(seg, group, what: str, name: str) -> np.ndarray:
    """4x4: a frame's (column, row, 0, 1) to LPS mm, from its position, orientation, spacing."""
    position = np.array(_functional(seg, group, "PlanePositionSequence", what, name).ImagePositionPatient, float)
    cosines = np.array(_functional(seg, group, "PlaneOrientationSequence", what, name).ImageOrientationPatient, float)
    row_mm, column_mm = (float(v) for v in _functional(seg, group, "PixelMeasuresSequence", what, name).PixelSpacing)
    affine = np.eye(4)
    affine[:3, 0] = cosines[:3] * column_mm  # along a row: the column index grows
    affine[:3, 1] = cosines[3:] * row_mm  # down a column: the row index grows
    affine[:3, 2] = np.cross(cosines[:3], cosines[3:])
    affine[:3, 3] = position
    return affine


def _frame_voxels(frame_to_index: np.ndarray, shape, what: str, name: str):
    """The reference's (i, j, k) of each pixel [row, column] of a frame; refused unless every
    pixel, to the frame's far corner, sits on a voxel centre and neighbouring pixels on
    neighbouring voxels (a step off by 0.01 voxel drifts a voxel over 100 pixels)."""
    steps = frame_to_index[:3, :2]
    offset = frame_to_index[:3, 3]
    off_step = np.abs(steps - np.round(steps))  # (3, 2): per pixel along columns, along rows
    drift = off_step[:, 0] * (shape[1] - 1) + off_step[:, 1] * (shape[0] - 1) + np.abs(offset - np.round(offset))
    if drift.max() > GRID_TOLERANCE or not np.allclose(np.abs(np.round(steps)).sum(axis=0), 1.0):
        raise InputError(
            f"{what}: '{name}' is on another grid than the T1 (its planes do not fall on the T1's "
            f"voxels: another orientation, spacing or origin); export it with the T1 as its reference"
        )
    rows, columns = np.indices(shape)
    ijk = (
        np.round(offset)[:, None, None]
        + np.round(steps[:, 0])[:, None, None] * columns
        + np.round(steps[:, 1])[:, None, None] * rows
    )
    return ijk.astype(np.int64)


def _segment_of(seg, group, numbers: list[int], what: str, name: str) -> int:
    """The segment a frame belongs to (its own, or, with one segment, the shared group's)."""
    item = _functional(seg, group, "SegmentIdentificationSequence", what, name)
    number = int(item.ReferencedSegmentNumber)
    if number not in numbers:
        raise InputError(
            f"{what}: '{name}' has a frame of segment {number}, which it does not describe "
            f"(its segments: {', '.join(map(str, numbers))}); the file is damaged"
        )
    return number
