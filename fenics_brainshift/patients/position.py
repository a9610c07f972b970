"""The head's position on the table as gravity in the patient's frame, and the CSF level a
craniotomy drains to.

The positions name the direction of gravity in the head's own anatomical frame (the
template's: x right, y anterior, z superior): supine, face up, gravity towards posterior;
prone towards anterior; lying on the left side (left lateral decubitus) towards the left; on
the right side towards the right. ANGLES "ax,ay,az" turn the supine direction about the
anatomical x, then y, then z axis (degrees), as `brainshift fit`'s gravity.angle_* do. The
direction is carried into the patient's frame by the rotation of the registration's affine
part, so a head scanned tilted gets gravity along its own anatomy. CRANIOTOMY_UP turns the
head so the craniotomy is uppermost, as a surgeon positions it for a lateral or low lesion:
gravity from the craniotomy's centre towards the brain's centroid.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from .carry import index_to_lps

G = 9.81
POSITIONS = {"supine": (0.0, -1.0, 0.0), "prone": (0.0, 1.0, 0.0), "left": (-1.0, 0.0, 0.0), "right": (1.0, 0.0, 0.0)}
CRANIOTOMY_UP = "craniotomy-up"
DEEP_RIM_MM = 40.0  # a rim this far below the brain's top as the head lies drains most of the brain: a warning
RIM_RADIUS = 25.0  # mm: a craniotomy of 5 cm
MAX_FROM_SURFACE = 30.0  # mm: a craniotomy centre farther from the brain's surface is a frame or unit slip


def anatomical_gravity(position: str) -> np.ndarray:
    """Gravity's unit direction in the anatomical (template RAS) frame for --position."""
    text = str(position).strip().lower()
    if text in POSITIONS:
        return np.array(POSITIONS[text])
    if text == CRANIOTOMY_UP:  # chosen once the craniotomy is known (craniotomy_up_direction); supine till then
        return np.array(POSITIONS["supine"])
    try:
        angles = [float(v) for v in text.split(",")]
    except ValueError:
        angles = []
    if len(angles) != 3 or not np.all(np.isfinite(angles)):
        raise InputError(
            f"--position: '{position}' is not one of {', '.join([*POSITIONS, CRANIOTOMY_UP])} nor three angles "
            f'"ax,ay,az" in degrees (the supine direction turned about x, then y, then z)'
        )
    return Rotation.from_euler("xyz", angles, degrees=True).apply(POSITIONS["supine"])


def patient_direction(direction_template_ras: np.ndarray, affine_matrix: np.ndarray) -> np.ndarray:
    """A direction of the template's frame in the patient's (both RAS), by the rotation of
    the affine (patient LPS -> template LPS) from its polar decomposition: scaling and shear
    do not turn gravity."""
    u, _, vt = np.linalg.svd(np.asarray(affine_matrix).reshape(3, 3))
    rotation = u @ vt  # template <- patient, LPS
    d = LPS_TO_RAS @ rotation.T @ LPS_TO_RAS @ np.asarray(direction_template_ras, dtype=float)
    return d / np.linalg.norm(d)


def craniotomy_levels(
    surface_ras_mm: np.ndarray, up: np.ndarray, centre: np.ndarray | None, radius: float = RIM_RADIUS
) -> dict:
    """The CSF level (m along up) the craniotomy drains to: the lowest point of the brain's
    surface within ``radius`` mm of the craniotomy's centre (its rim's lowest point, where
    the CSF spills out), and the level before (above the brain's highest point). No centre:
    the craniotomy is at the brain's highest point (docs/patients.md)."""
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    heights = surface_ras_mm @ up
    if centre is None:
        centre = surface_ras_mm[int(np.argmax(heights))]
    centre = np.asarray(centre, dtype=float)
    distance = np.linalg.norm(surface_ras_mm - centre, axis=1)
    nearest = float(distance.min())
    if nearest > MAX_FROM_SURFACE:
        raise InputError(
            f"--craniotomy: ({', '.join(f'{v:g}' for v in centre)}) mm is {nearest:.0f} mm from the "
            f"brain's surface; give the craniotomy's centre on the head in the T1's RAS frame, mm, as "
            f"3D Slicer shows it (LPS numbers have x and y negated)"
        )
    rim = distance <= radius
    at = int(np.argmin(distance))
    rim_level, start_level = float(heights[rim].min()), float(heights.max() + 5.0)
    # the levels a surgeon reads: mm above the craniotomy rim's lowest point (the drained level);
    # centre_height: the centre's share of the brain's height as the head lies (0 bottom, 1 top)
    return {
        "centre_mm": surface_ras_mm[at].tolist(),
        "rim_level_m": rim_level * 1e-3,
        "start_level_m": start_level * 1e-3,
        "radius_mm": radius,
        "start_above_rim_mm": round(start_level - rim_level, 2),
        "brain_top_above_rim_mm": round(float(heights.max()) - rim_level, 2),
        "brain_bottom_above_rim_mm": round(float(heights.min()) - rim_level, 2),
        "centre_height": round(float((heights[at] - heights.min()) / max(np.ptp(heights), 1e-9)), 3),
    }


def mask_centroid(mask: np.ndarray, grid) -> np.ndarray:
    """The centroid (RAS mm) of a mask on the grid's voxels ([k, j, i])."""
    return index_to_lps(grid, np.argwhere(mask)[:, ::-1].mean(axis=0)[None, :])[0] @ LPS_TO_RAS


def over_tumour_centre(tumour: np.ndarray, patient, surface_ras_mm: np.ndarray, up: np.ndarray | None) -> np.ndarray:
    """The craniotomy's centre over the tumour: the brain surface's point nearest to the
    tumour's centroid among those above it as the head lies (RAS mm); with ``up`` None (the
    head is turned to bring the craniotomy up), among all."""
    centroid = mask_centroid(tumour, patient)
    candidates = surface_ras_mm
    if up is not None:
        heights = surface_ras_mm @ (up / np.linalg.norm(up))
        above = surface_ras_mm[heights >= centroid @ (up / np.linalg.norm(up))]
        candidates = above if len(above) else surface_ras_mm
    return candidates[int(np.argmin(np.linalg.norm(candidates - centroid, axis=1)))]


def is_craniotomy_up(position: str) -> bool:
    return str(position).strip().lower() == CRANIOTOMY_UP


def craniotomy_up_direction(centre_ras_mm: np.ndarray, brain, patient) -> np.ndarray:
    """Up (unit, patient RAS) with the head turned so the craniotomy is uppermost: from the
    centroid of the brain (a mask on the patient's grid, [k, j, i]) through the craniotomy's
    centre."""
    centroid = mask_centroid(brain, patient)
    up = np.asarray(centre_ras_mm, dtype=float) - centroid
    if np.linalg.norm(up) < 20.0:  # (the surface's checks come later: a centre inside would turn anywhere)
        raise InputError(
            f"--craniotomy: ({', '.join(f'{v:g}' for v in centre_ras_mm)}) mm is {np.linalg.norm(up):.0f} mm from "
            f"the brain's centroid, not on its surface; give the craniotomy's centre on the head (RAS mm)"
        )
    return up / np.linalg.norm(up)
