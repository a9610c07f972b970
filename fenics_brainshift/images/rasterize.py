"""Which voxel centres lie in which tetrahedron: a tetrahedral mesh laid on an image grid.

Works in voxel-index coordinates, where the centres are the integer points, so an oblique or
anisotropic grid needs nothing special (barycentric coordinates do not change under the
index <-> world affine). Each tetrahedron enumerates the integer points of its bounding box
and keeps those with all four barycentric coordinates >= -TOLERANCE; vectorised over chunks
of tetrahedra so memory stays bounded. A centre on a shared face is kept once.
"""

from __future__ import annotations

import numpy as np

TOLERANCE = 1e-9  # barycentric slack: centres on a face or an edge belong to it
CANDIDATES_PER_CHUNK = 4_000_000  # bounding-box points examined at a time (~0.5 GB of work arrays)


def rasterize(
    points: np.ndarray, tets: np.ndarray, shape: tuple[int, int, int], part: int = 0, parts: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(flat voxel indices, tetrahedron of each, barycentric coordinates (n, 4)) of every voxel
    centre of a grid of ``shape`` inside the mesh (points in index coordinates). part / parts:
    only every parts-th chunk of tetrahedra from the part-th (ranks share the work)."""
    corners = points[tets]  # (m, 4, 3)
    edges = corners[:, 1:, :] - corners[:, :1, :]  # (m, 3, 3): rows v_i - v_0
    det = np.linalg.det(edges)
    usable = np.abs(det) > 1e-12 * np.abs(edges).max(axis=(1, 2)).clip(1e-300) ** 3
    lo = np.ceil(corners.min(axis=1) - TOLERANCE).astype(np.int64).clip(0, np.array(shape) - 1)
    hi = np.floor(corners.max(axis=1) + TOLERANCE).astype(np.int64)
    hi = np.minimum(hi, np.array(shape) - 1)
    extent = (hi - lo + 1).clip(0)
    counts = np.where(usable, extent.prod(axis=1), 0)
    chunks = _chunks(counts)
    found_voxel, found_tet, found_lambda = [], [], []
    for c, (start, stop) in enumerate(chunks):
        if c % parts != part:
            continue
        ids = np.arange(start, stop)
        n = counts[ids]
        if n.sum() == 0:
            continue
        tet = np.repeat(ids, n)
        offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        dj_dk = extent[tet, 1] * extent[tet, 2]
        ijk = lo[tet] + np.stack(
            [offset // dj_dk, (offset // extent[tet, 2]) % extent[tet, 1], offset % extent[tet, 2]], axis=1
        )
        inverse = np.linalg.inv(edges[ids].transpose(0, 2, 1))  # columns v_i - v_0
        local = np.searchsorted(ids, tet)
        lam = np.einsum("nij,nj->ni", inverse[local], ijk - corners[tet, 0])
        lam = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        inside = (lam >= -TOLERANCE).all(axis=1)
        flat = np.ravel_multi_index(tuple(ijk[inside].T), shape)
        found_voxel.append(flat)
        found_tet.append(tet[inside])
        found_lambda.append(lam[inside])
    if not found_voxel:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4))
    voxel = np.concatenate(found_voxel)
    voxel, first = np.unique(voxel, return_index=True)
    return voxel, np.concatenate(found_tet)[first], np.concatenate(found_lambda)[first]


def _chunks(counts: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive ranges of tetrahedra with about CANDIDATES_PER_CHUNK points each."""
    total = np.cumsum(counts)
    bounds = np.searchsorted(
        total,
        np.arange(CANDIDATES_PER_CHUNK, total[-1] + CANDIDATES_PER_CHUNK, CANDIDATES_PER_CHUNK)
        if len(total) and total[-1]
        else [],
    )
    edges = sorted({0, len(counts), *[min(int(b) + 1, len(counts)) for b in bounds]})
    return list(zip(edges[:-1], edges[1:]))
