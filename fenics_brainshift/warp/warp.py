"""The predicted intra-operative image: the pre-operative one, moved by the computed shift.

For every voxel centre y of the output grid (the input's grid) we need the pre-operative
point x with x + u(x) = y, then sample the input there. For the P1 displacement this inverse
is exact without iterating: u is affine on every tetrahedron, so x + u(x) maps each
tetrahedron onto its deformed image, and x(y) is the interpolation of the reference vertex
positions over the *deformed* mesh. So the deformed mesh is laid on the grid (rasterize.py),
and inside it x = sum_i lambda_i(y) X_i, exact to round-off. Outside the deformed brain the
inverse displacement v = x - y of the nearest voxel inside is carried over and blended to
zero over ``blend_mm`` (Euclidean distance transform; the CSF space and the skull beyond do
not move). Removed tissue (a resection) is not part of the mesh: its cavity is outside. The
voxels outside the deformed tissue whose source point lies in the removed cells before the
shift are the cavity: the warped image gives them a value of the user's (the image's
background by default: what is removed is not there to be moved), a label map a label.

The same v, in LPS millimetres on the input's grid, is an ITK displacement-field transform
(output point -> input point, what resampling needs): 3D Slicer applies it to any volume,
segmentation or model; SimpleITK's Resample with it reproduces this warp.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..images.rasterize import rasterize
from ..images.volumes import Volume
from ..logs import get_logger
from .deformed import DeformedMesh

log = get_logger("warp")

SAMPLES_PER_CHUNK = 2_000_000  # voxels interpolated at a time


@dataclass
class Warp:
    """The inverse displacement on an image's grid: x(y) = y + v(y), v in voxel-index units."""

    volume: Volume
    v: np.ndarray  # (ni, nj, nk, 3), index units
    inside: np.ndarray  # (ni, nj, nk) bool: y in the deformed tissue (v exact there)
    seconds: float = 0.0
    before: np.ndarray | None = None  # (ni, nj, nk) bool: y in the tissue before the shift
    cavity: np.ndarray | None = None  # (ni, nj, nk) bool: y in what a resection left empty

    @classmethod
    def compute(
        cls, volume: Volume, body: DeformedMesh, blend_mm: float = 10.0, comm=None, labels: bool = False
    ) -> Warp:
        """Lay the deformed mesh on the volume's grid; comm: ranks share the tetrahedra.
        labels: the volume is a label map (the mesh before the shift is laid on it too)."""
        if not 0 < blend_mm < float("inf"):
            raise InputError(f"--blend must be a finite number of mm > 0 (got {blend_mm:g})")
        t0 = time.perf_counter()
        shape = volume.data.shape
        X = volume.ras_to_index(body.points)  # reference positions, index coordinates
        Y = volume.ras_to_index(body.points + body.displacement)  # deformed
        _check_overlap(X, shape, volume)
        _check_foreground(X[body.tets].mean(axis=1), volume, labels)
        part, parts = (comm.rank, comm.size) if comm is not None else (0, 1)
        voxel, tet, lam = rasterize(Y, body.tets, shape, part, parts)
        x = np.einsum("ni,nij->nj", lam, X[body.tets[tet]])  # the pre-operative point of each
        before_voxels = rasterize(X, body.tets, shape, part, parts)[0] if labels else None  # the tissue before
        if comm is not None and comm.size > 1:
            voxel = np.concatenate(comm.allgather(voxel))
            x = np.concatenate(comm.allgather(x))
            before_voxels = np.concatenate(comm.allgather(before_voxels)) if labels else None
        before = None
        if labels:
            before = np.zeros(shape, dtype=bool)
            before.reshape(-1)[before_voxels] = True
        v = np.zeros(shape + (3,))
        inside = np.zeros(shape, dtype=bool)
        if len(voxel):
            y = np.stack(np.unravel_index(voxel, shape), axis=1)
            v.reshape(-1, 3)[voxel] = x - y
            inside.reshape(-1)[voxel] = True
            _blend_outside(v, inside, volume.spacing, blend_mm)
        cavity = None
        if body.removed is not None and len(body.removed):
            cavity = _cavity(X, body.removed, v, inside, part, parts, comm)
        return cls(volume, v, inside, time.perf_counter() - t0, before, cavity)

    def moved(self) -> np.ndarray:
        """Voxels whose source point is not themselves."""
        return np.any(self.v != 0.0, axis=-1)

    def largest_mm(self) -> float:
        return float(np.linalg.norm(self.v @ self.volume.affine[:3, :3].T, axis=-1).max(initial=0.0))

    def apply(
        self, data: np.ndarray | None = None, labels: bool = False, cavity_value: float | None = None
    ) -> np.ndarray:
        """The warped volume: linear interpolation (intensities) or nearest voxel (labels) of the
        input at x = y + v(y); voxels that do not move keep their value exactly. Labels change
        only where the tissue is after the shift or was before it (what it left is filled from
        beyond it, by the blend): the skull, the scalp, a ventricle's label outside the mesh stay
        where they are (the blend dragged 58 % of a skull label's voxels along). A resection's
        cavity takes ``cavity_value`` (None: as it was sampled)."""
        data = self.volume.data if data is None else data
        out = np.array(data, copy=True, order="C")  # reshape(-1) below must be a view
        moving = self.moved()
        if labels:
            if self.before is None:
                raise ValueError("Warp.apply(labels=True) needs Warp.compute(..., labels=True)")
            moving &= self.inside | self.before
        moved = np.flatnonzero(moving)
        shape = data.shape
        source = np.asarray(data, dtype=np.float64) if not labels else data
        for start in range(0, len(moved), SAMPLES_PER_CHUNK):
            flat = moved[start : start + SAMPLES_PER_CHUNK]
            y = np.stack(np.unravel_index(flat, shape), axis=0).astype(float)
            x = y + self.v.reshape(-1, 3)[flat].T
            if labels:
                index = np.floor(x + 0.5).astype(np.int64)  # ITK's nearest neighbour: ties go up
                for a in range(3):
                    np.clip(index[a], 0, shape[a] - 1, out=index[a])
                out.reshape(-1)[flat] = data[tuple(index)]
            else:
                values = ndimage.map_coordinates(source, x, order=1, mode="nearest")
                out.reshape(-1)[flat] = _cast(values, data.dtype)
        if self.cavity is not None and cavity_value is not None:
            out[self.cavity] = _cast(np.array([cavity_value], dtype=np.float64), data.dtype)[0]
        return out

    def displacement_lps_mm(self) -> np.ndarray:
        """v as millimetres in LPS, (ni, nj, nk, 3): the field of the ITK transform."""
        return self.v @ (LPS_TO_RAS @ self.volume.affine[:3, :3]).T


# a run whose mesh has fewer of its nodes than this inside the image's grid is not of this image
OVERLAP = 0.5


def _check_overlap(X: np.ndarray, shape, volume: Volume) -> None:
    """The body must lie on the image: a run of another object (the cube onto a brain T1), a
    mesh in another frame or unit, warped nothing or a corner, with exit 0."""
    within = np.all((X >= -0.5) & (X <= np.array(shape) - 0.5), axis=1)
    if within.mean() < OVERLAP:
        extent = np.ptp(volume.index_to_ras(np.array([[0, 0, 0], np.array(shape) - 1.0])), axis=0)
        raise InputError(
            f"warp: {within.mean():.0%} of the run's mesh lies on '{volume.path.name}' ({OVERLAP:.0%} "
            f"at least): is it the run of this image's object, in its frame (--mesh-frame) and unit? "
            f"(the image spans {extent[0]:.0f} x {extent[1]:.0f} x {extent[2]:.0f} mm)"
        )


FOREGROUND = 0.05  # of the image's range above its darkest (1st percentile): above is the object


def _on_object(volume: Volume, labels: bool = False):
    """(which values are the image's object, what that means in words): above the image's
    darkest by FOREGROUND of its range (an MR's background is 0, a CT's air -1000 HU: measured
    from the 1st percentile, not from 0), or, in a label map, any label but 0 (FreeSurfer's and
    Slicer's background)."""
    if labels:
        return (lambda values: values != 0), "its voxels labelled, not 0"
    low, high = np.percentile(np.asarray(volume.data, dtype=np.float64).ravel()[::7], [1, 99])
    threshold = low + FOREGROUND * (high - low)
    return (lambda values: values > threshold), f"its voxels above its darkest by {FOREGROUND:.0%} of its range"


def _check_foreground(centroids: np.ndarray, volume: Volume, labels: bool = False) -> None:
    """The body must lie on the image's object, not only on its grid: the cube laid on a
    brain T1's empty corner warped air, exit 0. Half the mesh's cells (their centroids' voxels)
    at least must be on the object (_on_object)."""
    data = volume.data
    index = np.clip(np.rint(centroids).astype(np.int64), 0, np.array(data.shape) - 1)
    on, what = _on_object(volume, labels)
    bright = float(on(np.asarray(data[tuple(index.T)], dtype=np.float64)).mean())
    if bright < OVERLAP:
        raise InputError(
            f"warp: {bright:.0%} of the run's mesh lies on the object in '{volume.path.name}' ({what}; "
            f"{OVERLAP:.0%} at least), the rest on its background: is it the run of this image's "
            f"object, in its frame (--mesh-frame) and unit?"
        )


SIZE = 0.4  # the mesh's diagonal at least this fraction of the image object's


def check_size(points: np.ndarray, volume: Volume, labels: bool = False) -> None:
    """The run's body must be the image's object, not a small thing inside it: the cube laid
    on a brain T1 lies on the head's foreground and passed the checks of Warp.compute (153,801
    voxels moved, exit 0). The mesh's diagonal must be SIZE of the object's at least (each a
    robust bounding box: the object's voxels' 1st to 99th percentiles along each axis): on the
    ICBM152 T1 (the head, 242 mm) the bundled brain's 8 mm mesh is 1.17 of it, the gelatin cube
    0.31 (tests/test_warp.py: a 75 mm cube in a 330 mm head). For `brainshift warp`; Warp itself
    warps any mesh on any grid."""
    data = np.asarray(volume.data)
    step = max(1, int(round((data.size / 2e6) ** (1 / 3))))  # (a few million voxels suffice)
    on, _ = _on_object(volume, labels)
    index = np.argwhere(on(data[::step, ::step, ::step].astype(np.float64))) * step
    if len(index) == 0:
        return
    lo, hi = np.percentile(volume.index_to_ras(index.astype(float)), [1, 99], axis=0)
    object_mm = float(np.linalg.norm(hi - lo))
    mesh_mm = float(np.linalg.norm(np.ptp(points, axis=0)))
    if mesh_mm < SIZE * object_mm:
        raise InputError(
            f"warp: the run's mesh is {mesh_mm:.0f} mm across (its bounding box's diagonal), the object "
            f"in '{volume.path.name}' {object_mm:.0f} mm: is it the run of this image's object, in its "
            f"unit? (of a part of it: crop the image to that part first)"
        )


def _cavity(X: np.ndarray, removed: np.ndarray, v: np.ndarray, inside: np.ndarray, part, parts, comm) -> np.ndarray:
    """The voxels outside the deformed tissue whose source point (y + v, nearest voxel) lies in
    the removed cells before the shift (X: the reference positions, index units)."""
    shape = inside.shape
    voxels = rasterize(X, removed, shape, part, parts)[0]
    if comm is not None and comm.size > 1:
        voxels = np.concatenate(comm.allgather(voxels))
    was_removed = np.zeros(shape, dtype=bool)
    was_removed.reshape(-1)[voxels] = True
    outside = np.flatnonzero(~inside)
    y = np.stack(np.unravel_index(outside, shape), axis=0).astype(float)
    source = np.floor(y + v.reshape(-1, 3)[outside].T + 0.5).astype(np.int64)
    for a in range(3):
        np.clip(source[a], 0, shape[a] - 1, out=source[a])
    cavity = np.zeros(shape, dtype=bool)
    cavity.reshape(-1)[outside] = was_removed[tuple(source)]
    return cavity


def _blend_outside(v: np.ndarray, inside: np.ndarray, spacing: np.ndarray, blend_mm: float) -> None:
    """Outside the deformed tissue: v of the nearest voxel inside, times max(0, 1 - d / blend),
    in the box around the tissue that the blend reaches (the rest stays 0)."""
    margin = np.ceil(blend_mm / spacing).astype(int) + 1
    where = np.argwhere(inside)
    lo = np.maximum(where.min(axis=0) - margin, 0)
    hi = np.minimum(where.max(axis=0) + margin + 1, inside.shape)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    distance, nearest = ndimage.distance_transform_edt(~inside[box], sampling=spacing, return_indices=True)
    weight = np.clip(1.0 - distance / blend_mm, 0.0, 1.0)
    sub = v[box]
    carried = sub[tuple(nearest)] * weight[..., None]
    outside = ~inside[box]
    sub[outside] = carried[outside]


def _cast(values: np.ndarray, dtype) -> np.ndarray:
    """Interpolated values back in the input's type (integers rounded and clipped to its range)."""
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return np.clip(np.rint(values), info.min, info.max).astype(dtype)
    return values.astype(dtype)
