"""A coarse grid around the brain on which the update's displacement and uncertainty travel
as images (OpenIGTLink IMAGE: 3D Slicer makes a grid transform of the one, an overlay of the
other). Axis-aligned in RAS; the mesh is laid on it once (images/rasterize.py), so each update
only interpolates its nodal values at the voxels inside the brain (0 outside)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..images.rasterize import rasterize

PADDING = 10e-3  # m around the brain's bounding box
MAX_VOXELS = 4_000_000


class Grid:
    def __init__(self, points: np.ndarray, tetrahedra: np.ndarray, spacing: float):
        if not 0.5e-3 <= spacing <= 20e-3:
            raise InputError(f"--grid: {spacing * 1e3:g} mm; the displacement's grid spacing is 0.5-20 mm")
        self.origin = points.min(axis=0) - PADDING
        self.spacing = spacing
        self.shape = tuple(int(n) for n in np.ceil((np.ptp(points, axis=0) + 2 * PADDING) / spacing).astype(int) + 1)
        if np.prod(self.shape) > MAX_VOXELS:
            raise InputError(
                f"--grid: {spacing * 1e3:g} mm makes {np.prod(self.shape):,} voxels around this brain (at most "
                f"{MAX_VOXELS:,}); take a coarser spacing"
            )
        self.voxel, tet, self.weight = rasterize((points - self.origin) / spacing, tetrahedra, self.shape)
        self.corners = tetrahedra[tet]  # (inside voxels, 4)

    def sample(self, field: np.ndarray) -> np.ndarray:
        """A nodal field (N,) or (N, 3) on the grid, (i, j, k[, 3]) with 0 outside the brain."""
        values = np.einsum("vj,vj...->v...", self.weight, field[self.corners])
        out = np.zeros((int(np.prod(self.shape)),) + field.shape[1:], dtype=np.float32)
        out[self.voxel] = values
        return out.reshape(self.shape + field.shape[1:])

    def ijk_to_ras(self, scale: float = 1e3) -> np.ndarray:
        """The 4x4 index-to-RAS matrix (in mm by default)."""
        matrix = np.eye(4)
        matrix[:3, :3] *= self.spacing * scale
        matrix[:3, 3] = self.origin * scale
        return matrix
