"""The atlas mesh's boundary as the update uses it: its vertices, its triangles (oriented out),
and every mode at its vertices in two layouts. The skull's rows and a surface without a fine one
need every mode there at every update; the boundary's vertices are scattered through the
mesh's node order, so atlas.h5 stores this block apart and contiguous (store.py), and a
prepared update reads it whole without touching the rest of the modes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Boundary:
    vertices: np.ndarray  # (B,) the mesh's boundary vertices, ascending
    triangles: np.ndarray  # (T, 3) numbered in `vertices`, each normal out of its tetrahedron
    modes: np.ndarray  # (M, B, 3) float32: by mode (a combination of a few weights reads their rows)
    by_node: np.ndarray  # (B, 3, M) float32: by vertex (a row of the skull's is a vertex's block)

    @classmethod
    def of(cls, points: np.ndarray, tetrahedra: np.ndarray, modes) -> Boundary:
        """The boundary of a mesh and its modes (M, N, 3)."""
        vertices, triangles = boundary_triangles(points, tetrahedra)
        at = np.ascontiguousarray(modes[:, vertices, :], dtype=np.float32)
        return cls(vertices, triangles, at, np.ascontiguousarray(at.transpose(1, 2, 0)))


def boundary_triangles(points: np.ndarray, tetrahedra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles over them) of the mesh's boundary (the faces of one tetrahedron),
    each triangle ordered so that its normal points out of its tetrahedron."""
    faces = tetrahedra[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    faces = faces[first[counts == 1]]
    opposite = tetrahedra[
        np.repeat(np.arange(len(tetrahedra)), 4)[first[counts == 1]],
        np.tile(np.arange(4), len(tetrahedra))[first[counts == 1]],
    ]
    a, b, c = (points[faces[:, i]] for i in range(3))
    inward = np.einsum("ni,ni->n", np.cross(b - a, c - a), points[opposite] - a) > 0
    faces[inward] = faces[inward][:, [0, 2, 1]]
    vertices, triangles = np.unique(faces, return_inverse=True)
    return vertices, triangles.reshape(-1, 3)
