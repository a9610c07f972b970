"""The tumour's segmentation on the patient's grid (a DICOM-SEG placed by its frames, a NIfTI
or a (.seg).nrrd, refused on another grid), and how much of it lies in the brain found."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import SimpleITK as sitk

from ..errors import InputError
from ..images.dicom_seg import is_dicom_seg_path, read_dicom_seg
from ..images.volumes import label_mask, read_volume, segment_names
from .carry import ras_affine

log = logging.getLogger(__name__)


def read_tumour(path: str, patient: sitk.Image, segments: str | None) -> np.ndarray:
    """The tumour segmentation's voxels ([k, j, i]) on the T1's grid: a DICOM-SEG (placed by its
    frames' positions), a NIfTI or a (.seg).nrrd; the segments named by ``segments`` (names or
    label values, comma-separated), needed when the file holds more than one; refused on
    another grid."""
    chosen = [s.strip() for s in segments.split(",") if s.strip()] if segments is not None else None
    if chosen == []:
        raise InputError(
            f"--tumour-segment: '{segments}' names no segment; give names or label values, comma-separated"
        )
    if is_dicom_seg_path(path):
        by_name = read_dicom_seg(path, patient, "--tumour")
        names = list(by_name)
        _check_segments(path, names, chosen)
        unknown = [s for s in chosen or [] if s not in by_name]
        if unknown:
            raise InputError(
                f"--tumour-segment: no segment '{unknown[0]}' in '{Path(path).name}'; its segments: "
                + ", ".join(f"'{n}'" for n in names)
            )
        mask = np.logical_or.reduce([by_name[n] for n in (chosen or names)])
    else:
        volume = read_volume(path, "--tumour", layered=True)
        size = tuple(patient.GetSize())
        if volume.data.shape != size or not np.allclose(volume.affine, ras_affine(patient), atol=1e-3):
            raise InputError(
                f"--tumour: '{Path(path).name}' is on another grid than the T1 ({volume.data.shape} "
                f"against {size}, or another origin, spacing or orientation); export it from 3D "
                f"Slicer with the T1 as reference geometry"
            )
        present = segment_names(volume) or [str(v) for v in np.unique(volume.data) if v > 0]
        _check_segments(path, present, chosen)
        mask = np.transpose(label_mask(volume, chosen, "--tumour-segment"), (2, 1, 0))
    if not mask.any():
        raise InputError(
            f"--tumour: '{Path(path).name}' has no labelled voxel" + (f" in {', '.join(chosen)}" if chosen else "")
        )
    return np.ascontiguousarray(mask)


def _check_segments(path: str, present: list[str], chosen: list[str] | None) -> None:
    """A file with several segments (a tumour's core and oedema, or brain and tumour) is not
    taken whole: the user says which are the tumour."""
    if chosen is None and len(present) > 1:
        raise InputError(
            f"--tumour: '{Path(path).name}' holds {len(present)} segments ("
            + ", ".join(f"'{n}'" for n in present)
            + "); say which are the tumour with --tumour-segment NAME[,NAME]"
        )


def tumour_report(tumour: np.ndarray, brain: np.ndarray, patient: sitk.Image) -> dict:
    inside = float((tumour & brain).sum()) / float(tumour.sum())
    if inside == 0.0:
        raise InputError(
            "--tumour: none of the tumour lies in the brain found (a segmentation of another scan or "
            "structure, or on a flipped grid?); check it over the T1 in 3D Slicer and give the "
            "segmentation drawn on this scan"
        )
    if inside < 0.5:
        log.warning(
            "--tumour: only %.0f %% of the tumour lies in the brain found (an extra-axial lesion, or a "
            "segmentation of another image?); it is meshed with the brain",
            100 * inside,
        )
    return {
        "ml": round(float(tumour.sum()) * float(np.prod(patient.GetSpacing())) * 1e-3, 3),
        "inside_brain": round(inside, 4),
    }
