"""The paper's "embedding" mesher: imperfect segmentations to conforming tetrahedra.

Embed the object in its bounding box, cut the box into voxels of a chosen size, keep the voxels
the object fills, drop floating pieces, and split every kept voxel into five tetrahedra that
conform with their neighbours (hexgrid.voxel_mesh). It never needs a watertight surface.

Which voxels are kept: a voxel is kept when the object fills at least ``fill`` of it (default
0.5, which keeps the volume right on average); ``fill = 0`` keeps every voxel the object touches,
the paper's rule ("elements that did not include a part of the 3D model were removed"), which
grows the volume by about half a voxel all round. The fill fraction is measured
- for a label volume (NIfTI): the share of the voxel's volume covered by object voxels of the
  image (their centres binned into the coarse voxels);
- for a surface (STL, OBJ, PLY, VTK, ...): the share of ``samples**3`` points inside the
  surface, each decided by ray parity along x, y and z and a majority of the three, so a
  hole in the surface spoils at most one direction.
Then only the largest face-connected part is kept (or the ``parts`` largest), and blocks of
2 x 2 x 2 voxels that touch only along an edge or at a corner are filled (see close_pinches).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from .. import formats
from ..errors import InputError
from ..surfaces.files import read_surface
from ..surfaces.inside import enclosed_volume, parity_inside
from .budget import GRID_BYTES_PER_VOXEL, SAMPLE_BYTES, require
from .extent import size_problem
from .hexgrid import voxel_mesh


class VoxelizeError(InputError):
    """Input that cannot be voxelised; the message says why and what to change."""


def check_grid(shape, voxel: float, bytes_per_voxel: float, size: float, scale: float) -> None:
    """Refuse a voxel grid that would not fit in memory, naming the likely slip: the object's
    unit where its size (``size`` m across) is no soft-tissue body's (a mm image under [mesh]
    unit = "m" is 284 m across: the refusal blamed the voxel size), else the voxel's."""
    problem = size_problem(size, scale)
    if problem is not None and problem[1] is not None:  # the object's unit, not the voxel's
        what, unit = problem
        hint = (
            f'{what}: is it in {unit}? (a scene\'s [mesh] unit = "{unit}"; `brainshift mesh --scale` the '
            f"factor from it to m)"
        )
    else:
        hint = (
            "is the voxel size in the right unit? (a scene's [mesh] voxel is in metres; `brainshift mesh "
            "--voxel` is in the input's unit, mm for medical images)"
        )
    cells = float(np.prod(np.asarray(shape, dtype=float)))
    across = f"{size:.3g} m" if size >= 1.0 else f"{size * 1e3:.3g} mm"  # (as the hint says it)
    require(
        cells * bytes_per_voxel,
        f"a grid of {cells:.3g} voxels of {voxel * 1e3:g} mm over an object {across} across",
        hint,
    )


@dataclass
class VoxelModel:
    points: np.ndarray  # (N, 3) m
    tets: np.ndarray  # (M, 4)
    voxels: np.ndarray  # (V, 3) integer index of each kept voxel
    tet_voxel: np.ndarray  # (M,) which kept voxel each tetrahedron comes from
    voxel_size: float  # m
    origin: np.ndarray  # (3,) m, corner of voxel (0, 0, 0)
    input_volume_m3: float
    dropped_parts: int

    @property
    def volume_m3(self) -> float:
        return len(self.voxels) * self.voxel_size**3

    def report(self) -> str:
        change = 100.0 * (self.volume_m3 / self.input_volume_m3 - 1.0) if self.input_volume_m3 else float("nan")
        return (
            f"{len(self.points)} nodes, {len(self.tets)} tetrahedra from {len(self.voxels)} voxels of "
            f"{self.voxel_size * 1e3:g} mm; volume {self.volume_m3 * 1e6:.1f} ml against the input's "
            f"{self.input_volume_m3 * 1e6:.1f} ml ({change:+.1f} %); {self.dropped_parts} floating part(s) dropped"
        )


def voxelize(
    path: str | Path,
    voxel: float,
    scale: float = 1e-3,
    fill: float = 0.5,
    parts: int = 1,
    labels: list[int] | None = None,
    samples: int = 3,
) -> VoxelModel:
    """Voxel model of a label volume or surface file. ``voxel`` in m; ``scale`` turns the
    file's coordinates into m (1e-3 for mm, the usual unit of medical images)."""
    path = Path(path)
    if not path.is_file():
        raise VoxelizeError(f"'{path}' not found")
    if not voxel > 0:
        raise VoxelizeError(f"voxel size must be > 0 (got {voxel})")
    if not 0.0 <= fill <= 1.0:
        raise VoxelizeError(f"fill must be in [0, 1] (got {fill})")
    if formats.is_label_volume(path):
        fraction, origin, input_volume = label_occupancy(path, voxel, scale, labels)
    elif formats.is_surface(path):
        fraction, origin, input_volume = surface_occupancy(read_surface(path, scale), voxel, samples, scale)
    else:
        raise VoxelizeError(
            f"'{path.name}': use a label volume ({', '.join(formats.LABEL_SUFFIXES)}) or a "
            f"surface ({', '.join(formats.SURFACE_SUFFIXES)})"
        )
    keep = fraction >= fill if fill > 0 else fraction > 0
    keep, dropped = largest_parts(keep, parts)
    keep = close_pinches(keep)
    if not keep.any():
        raise VoxelizeError(
            f"'{path.name}': no voxel of {voxel * 1e3:g} mm is filled to {fill:g}; use a smaller voxel or a lower fill"
        )
    points, tets = voxel_mesh(keep, (voxel,) * 3, origin)
    voxels = np.argwhere(keep)
    return VoxelModel(points, tets, voxels, np.repeat(np.arange(len(voxels)), 5), voxel, origin, input_volume, dropped)


def largest_parts(mask: np.ndarray, parts: int = 1) -> tuple[np.ndarray, int]:
    """Keep the ``parts`` largest face-connected parts; returns (mask, number dropped)."""
    labelled, count = ndimage.label(mask)
    if count <= parts:
        return mask, 0
    sizes = np.bincount(labelled.ravel())[1:]
    keep_labels = 1 + np.argsort(sizes)[::-1][:parts]
    return np.isin(labelled, keep_labels), count - parts


def _pinched_codes() -> np.ndarray:
    """For each of the 256 occupancy patterns of a 2 x 2 x 2 block of voxels: do the occupied
    ones fall apart into several face-connected groups (voxels touching at an edge or a corner
    only)?"""
    bad = np.zeros(256, dtype=bool)
    for code in range(256):
        cube = np.array([(code >> k) & 1 for k in range(8)], dtype=bool).reshape(2, 2, 2)
        bad[code] = ndimage.label(cube)[1] > 1
    return bad


_PINCHED = _pinched_codes()


def close_pinches(mask: np.ndarray, max_rounds: int = 50) -> np.ndarray:
    """Fill every 2 x 2 x 2 block whose voxels touch only along an edge or at a corner.

    Such pinches are segmentation artefacts, and a mesh vertex or edge shared by cells that no
    face connects is split apart when the mesh is distributed over MPI ranks (DOLFINx shares
    entities between ranks through facets), so the answer would depend on the rank count.
    Two voxels that touch differ by at most one index per axis, so every pinch lies in a block
    inside the grid and filling it never leaves the grid."""
    mask = mask.copy()
    if min(mask.shape) < 2:
        return mask
    n0, n1, n2 = mask.shape
    for _ in range(max_rounds):
        code = sum(
            mask[i : n0 - 1 + i, j : n1 - 1 + j, k : n2 - 1 + k].astype(np.int32) << (i + 2 * j + 4 * k)
            for i in (0, 1)
            for j in (0, 1)
            for k in (0, 1)
        )
        bad = np.argwhere(_PINCHED[code])
        if len(bad) == 0:
            break
        for i in (0, 1):
            for j in (0, 1):
                for k in (0, 1):
                    mask[bad[:, 0] + i, bad[:, 1] + j, bad[:, 2] + k] = True
    return mask


# ----------------------------------------------------------------- label volumes
def label_occupancy(path: Path, voxel: float, scale: float, labels=None):
    """Fill fraction of coarse voxels by the object's image voxels (any affine); labels:
    values or segment names (a Slicer .seg.nrrd), default every label > 0."""
    from ..errors import InputError
    from ..images.volumes import label_mask, read_volume, segment_names

    try:
        volume = read_volume(path, "label volume", layered=True)
        names = segment_names(volume)
        if not labels and len(names) > 1:  # a brain, a tumour and a skull meshed as one body
            raise InputError(
                f"'{path.name}' holds {len(names)} segments ({', '.join(names)}): choose the body's, "
                f'e.g. [mesh] labels = ["{names[0]}"] (brainshift mesh --labels {names[0]})'
            )
        inside = label_mask(volume, labels or None, "labels")
    except InputError as exc:
        raise VoxelizeError(str(exc)) from None
    ijk = np.argwhere(inside)
    if len(ijk) == 0:
        raise VoxelizeError(f"'{path.name}' has no voxel with label {labels or '> 0'}")
    A = volume.affine
    centres = (ijk @ A[:3, :3].T + A[:3, 3]) * scale
    fine_volume = abs(np.linalg.det(A[:3, :3])) * scale**3
    half = 0.5 * np.abs(A[:3, :3]).sum(axis=1) * scale  # half an image voxel's extent
    origin = centres.min(axis=0) - half
    shape = np.floor((centres.max(axis=0) + half - origin) / voxel).astype(np.int64) + 1
    check_grid(shape, voxel, GRID_BYTES_PER_VOXEL, float(np.linalg.norm(np.ptp(centres, axis=0) + 2 * half)), scale)
    counts = np.zeros(shape)
    steps = A[:3, :3].T * scale  # row k: one image voxel along the image's axis k (m)
    # an image voxel longer than half a coarse voxel along an axis (a 2-D series' 6.5 mm slices
    # at 5 mm) is counted at that many points along it: its centre alone would leave whole
    # layers of coarse voxels empty between slices
    splits = np.maximum(np.ceil(2.0 * np.linalg.norm(steps, axis=1) / voxel), 1).astype(int)
    for offset in _sub_points(splits) @ steps:
        index = np.clip(np.floor((centres + offset - origin) / voxel).astype(np.int64), 0, shape - 1)
        np.add.at(counts, tuple(index.T), 1.0 / splits.prod())
    return np.minimum(counts * fine_volume / voxel**3, 1.0), origin, len(ijk) * fine_volume


def _sub_points(splits: np.ndarray) -> np.ndarray:
    """Offsets (in image voxels) of the centres of an image voxel split splits[k] times along axis k."""
    axes = [(np.arange(n) + 0.5) / n - 0.5 for n in splits]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


# ----------------------------------------------------------------- surfaces
def surface_occupancy(surface, voxel: float, samples: int, scale: float = 1.0):
    points, triangles = surface
    lo, hi = points.min(axis=0), points.max(axis=0)
    origin = lo - 0.5 * voxel
    shape = np.floor((hi - origin) / voxel).astype(int) + 1
    check_grid(shape, voxel, GRID_BYTES_PER_VOXEL + SAMPLE_BYTES * samples**3, float(np.linalg.norm(hi - lo)), scale)
    # sample points: samples^3 per voxel, at sub-cell centres
    sub = (np.arange(samples) + 0.5) / samples
    axes = [origin[a] + voxel * (np.arange(shape[a])[:, None] + sub[None, :]).ravel() for a in range(3)]
    inside_votes = np.zeros([len(ax) for ax in axes], dtype=np.int8)
    for ray in range(3):
        inside_votes += parity_inside(points, triangles, axes, ray)
    inside = inside_votes >= 2
    n = samples
    fraction = inside.reshape(shape[0], n, shape[1], n, shape[2], n).mean(axis=(1, 3, 5))
    input_volume = enclosed_volume(points, triangles)
    return fraction, origin, input_volume
