"""Inside or outside a closed triangulated surface, on a grid of sample points: ray parity
along one axis (the voxel mesher takes a majority of the three axes, so that a hole spoils at
most one), and the volume the surface encloses."""

from __future__ import annotations

import numpy as np


def parity_inside(points, triangles, axes, ray: int) -> np.ndarray:
    """Inside test on the sample grid by counting surface crossings of rays along axis ``ray``."""
    a, b = [k for k in range(3) if k != ray]
    P = points[triangles]  # (T, 3, 3)
    ga, gb, gr = axes[a], axes[b], axes[ray]
    da, db = ga[1] - ga[0] if len(ga) > 1 else 1.0, gb[1] - gb[0] if len(gb) > 1 else 1.0
    # candidate (triangle, column) pairs from each triangle's bounding box in the (a, b) plane
    ia0 = np.clip(np.ceil((P[:, :, a].min(1) - ga[0]) / da).astype(int), 0, len(ga))
    ia1 = np.clip(np.floor((P[:, :, a].max(1) - ga[0]) / da).astype(int), -1, len(ga) - 1)
    ib0 = np.clip(np.ceil((P[:, :, b].min(1) - gb[0]) / db).astype(int), 0, len(gb))
    ib1 = np.clip(np.floor((P[:, :, b].max(1) - gb[0]) / db).astype(int), -1, len(gb) - 1)
    na, nb = np.maximum(ia1 - ia0 + 1, 0), np.maximum(ib1 - ib0 + 1, 0)
    count = na * nb
    tri = np.repeat(np.arange(len(P)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ca = ia0[tri] + local // np.maximum(nb[tri], 1)
    cb = ib0[tri] + local % np.maximum(nb[tri], 1)
    # barycentric coordinates of the column in the triangle's projection
    x, y = ga[ca], gb[cb]
    p0, p1, p2 = P[tri, 0], P[tri, 1], P[tri, 2]
    d = (p1[:, a] - p0[:, a]) * (p2[:, b] - p0[:, b]) - (p2[:, a] - p0[:, a]) * (p1[:, b] - p0[:, b])
    good = np.abs(d) > 1e-300
    l1 = np.where(
        good,
        ((x - p0[:, a]) * (p2[:, b] - p0[:, b]) - (p2[:, a] - p0[:, a]) * (y - p0[:, b])) / np.where(good, d, 1),
        -1,
    )
    l2 = np.where(
        good,
        ((p1[:, a] - p0[:, a]) * (y - p0[:, b]) - (x - p0[:, a]) * (p1[:, b] - p0[:, b])) / np.where(good, d, 1),
        -1,
    )
    l0 = 1 - l1 - l2
    hit = good & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    z = (l0 * p0[:, ray] + l1 * p1[:, ray] + l2 * p2[:, ray])[hit]
    column = (ca * len(gb) + cb)[hit]
    # crossings below each sample, per column, by one sorted key array
    zmin, span = gr[0] - 1.0, (gr[-1] - gr[0]) + 2.0
    keys = np.sort(column * 4.0 + (z - zmin) / span)
    cols = np.arange(len(ga) * len(gb))
    starts = np.searchsorted(keys, cols * 4.0)
    sample_keys = cols[:, None] * 4.0 + ((gr - zmin) / span)[None, :]
    below = np.searchsorted(keys, sample_keys.ravel()).reshape(sample_keys.shape) - starts[:, None]
    inside = (below % 2 == 1).reshape(len(ga), len(gb), len(gr))
    order = np.argsort([a, b, ray])
    return inside.transpose(order).astype(np.int8)


def enclosed_volume(points, triangles) -> float:
    """Signed volume enclosed by the triangles (divergence theorem); for an open surface it is
    only an estimate, reported as such."""
    p = points[triangles]
    return abs(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)
