"""Carrying the template's labels onto the patient's grid through a registration, and the
geometry of the patient's grid in the project's frame (RAS mm)."""

from __future__ import annotations

import numpy as np
import SimpleITK as sitk

from ..images.frames import LPS_TO_RAS
from .registration import Registration


def labels_on_patient(
    template_labels: dict[int, np.ndarray], template: sitk.Image, patient: sitk.Image, registration: Registration
) -> np.ndarray:
    """A label array on the patient's grid (its array order, [k, j, i]) from boolean masks on
    the template's grid, painted in the order given (a later label over an earlier one), in
    one resampling through the registration by ITK's label-linear interpolation: each voxel
    takes the label of the largest linearly interpolated share (the map is costly to evaluate
    at every voxel of a 1 mm T1: one pass, not one per label; and through its sampled
    displacement field, Registration.sampled)."""
    painted = np.zeros(template_labels[next(iter(template_labels))].shape, dtype=np.uint8)
    for value, mask in template_labels.items():
        painted[mask] = value
    image = sitk.GetImageFromArray(painted)
    image.CopyInformation(template)
    moved = sitk.Resample(image, patient, registration.sampled(), sitk.sitkLabelLinear, 0, sitk.sitkUInt8)
    return sitk.GetArrayFromImage(moved)


def voxel_centres_ras_m(image: sitk.Image, mask: np.ndarray) -> np.ndarray:
    """The centres (RAS, m) of the voxels where ``mask`` ([k, j, i]) holds, shape (n, 3)."""
    kji = np.argwhere(mask)
    return index_to_lps(image, kji[:, ::-1]) @ LPS_TO_RAS * 1e-3


def index_to_lps(image: sitk.Image, ijk: np.ndarray) -> np.ndarray:
    """Continuous (i, j, k) indices to LPS mm, vectorised (SimpleITK's rule)."""
    direction = np.array(image.GetDirection()).reshape(3, 3)
    return np.asarray(ijk, dtype=float) * np.array(image.GetSpacing()) @ direction.T + np.array(image.GetOrigin())


def lps_to_index(image: sitk.Image, lps: np.ndarray) -> np.ndarray:
    direction = np.array(image.GetDirection()).reshape(3, 3)
    return (np.asarray(lps, dtype=float) - np.array(image.GetOrigin())) @ direction / np.array(image.GetSpacing())


def ras_affine(image: sitk.Image) -> np.ndarray:
    """The 4x4 (i, j, k, 1) -> RAS mm of a SimpleITK image (NIfTI's affine)."""
    direction = np.array(image.GetDirection()).reshape(3, 3)
    affine = np.eye(4)
    affine[:3, :3] = LPS_TO_RAS @ direction * np.array(image.GetSpacing())
    affine[:3, 3] = LPS_TO_RAS @ np.array(image.GetOrigin())
    return affine
