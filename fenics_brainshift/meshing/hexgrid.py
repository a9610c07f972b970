"""Hexahedra split into five tetrahedra that conform across neighbours.

A hexahedron at grid index (i, j, k) is cut into one central tetrahedron and four corner
tetrahedra. The cut pattern alternates with the parity of i + j + k, so the face diagonals of
neighbouring hexahedra coincide and the tetrahedral mesh is conforming. The same split serves
the paper's structured cube grids and, later, voxel meshes.
"""

from __future__ import annotations

import numpy as np

# Local corner numbering: corner c has offsets (c & 1, (c >> 1) & 1, (c >> 2) & 1).
_OFFSETS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])
_EVEN = [c for c in range(8) if _OFFSETS[c].sum() % 2 == 0]  # 0, 3, 5, 6
_ODD = [c for c in range(8) if _OFFSETS[c].sum() % 2 == 1]  # 1, 2, 4, 7


def _split_pattern(central: list[int], corners: list[int]) -> np.ndarray:
    tets = [central]
    for c in corners:
        neighbours = [n for n in central if np.abs(_OFFSETS[n] - _OFFSETS[c]).sum() == 1]
        tets.append([c, *neighbours])
    return np.array(tets)


SPLIT_EVEN = _split_pattern(_EVEN, _ODD)  # (5, 4) local corner indices
SPLIT_ODD = _split_pattern(_ODD, _EVEN)


def hexes_to_tets(corners: np.ndarray, parity: np.ndarray) -> np.ndarray:
    """corners: (n, 8) node ids in local corner order; parity: (n,) of (i + j + k) % 2.
    Returns (5 n, 4) tetrahedra."""
    corners = np.asarray(corners)
    parity = np.asarray(parity).astype(bool)
    tets = np.empty((corners.shape[0], 5, 4), dtype=np.int64)
    tets[~parity] = corners[~parity][:, SPLIT_EVEN]
    tets[parity] = corners[parity][:, SPLIT_ODD]
    return tets.reshape(-1, 4)


def orient_positive(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Swap two vertices of every tetrahedron with negative signed volume (VTK convention)."""
    p = points[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    tets = tets.copy()
    flip = vol < 0
    tets[flip, 1], tets[flip, 2] = tets[flip, 2].copy(), tets[flip, 1].copy()
    return tets


def structured_box(size, cells, origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and tetrahedra (5 nx ny nz, 4) of a box of hexahedra split in five."""
    nx, ny, nz = cells
    axes = [np.linspace(o, o + s, n + 1) for o, s, n in zip(origin, size, cells)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    corners = np.column_stack([node(I + o[0], J + o[1], K + o[2]) for o in _OFFSETS])
    tets = hexes_to_tets(corners, (I + J + K) % 2)
    return points, orient_positive(points, tets)


def voxel_mesh(mask: np.ndarray, spacing, origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Points and conforming tetrahedra (five per voxel) of the voxels where ``mask`` is True.

    The split pattern follows the parity of the voxel's global index, so the tetrahedra of
    neighbouring voxels share their faces exactly. Only corners of kept voxels become points."""
    mask = np.asarray(mask, dtype=bool)
    nx, ny, nz = mask.shape
    I, J, K = np.nonzero(mask)

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    corners = np.column_stack([node(I + o[0], J + o[1], K + o[2]) for o in _OFFSETS])
    used, compact = np.unique(corners, return_inverse=True)
    corners = compact.reshape(corners.shape)
    ci, rest = np.divmod(used, (ny + 1) * (nz + 1))
    cj, ck = np.divmod(rest, nz + 1)
    points = np.asarray(origin, dtype=float) + np.column_stack([ci, cj, ck]) * np.asarray(spacing, dtype=float)
    tets = hexes_to_tets(corners, (I + J + K) % 2)
    return points, orient_positive(points, tets)
