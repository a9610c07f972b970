"""The rows of the update's least-squares problem: what each measurement and the skull say
about the weights c of the modes (u(c) = sum_k c_k U_k, linear in c).

- point to point: the predicted intra-operative position of a pre-operative point X is
  X + u(c)(X), u interpolated in X's tetrahedron: three rows A c = y - X, exact;
- point to surface: the signed distance of a measured point y to the moved surface, linearised
  about the current weights at y's nearest point q (barycentric beta in its triangle, outward
  normal n): d(c) = d(c0) - n . (u_q(c) - u_q(c0)), one row; the nearest points are found
  again from the new weights (iterated closest point, update.py);
- the skull: the room phi(X + u(c)) >= 0 of every boundary node, linearised where it is
  small: phi0 + grad phi . (u(c) - u(c0)) >= -SKULL_SLACK, one inequality row per node.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .locate import MeshLocator, SurfaceLocator

OUTSIDE_CELLS = 2.0  # a pre-operative point farther than this many cells outside the body is refused
SKULL_MARGIN = 1.5e-3  # m: nodes with less room than this get a skull row (the rest cannot reach it)
SKULL_SLACK = 0.1e-3  # m past the skull a row allows: the modes' own contact is settled to a
# tolerance ([skull] tolerance), and a mix of states each a hair past cannot be wholly inside
EASED = 0.1  # of SKULL_SLACK: how far inside an eased row (ease) its start is kept


class PointRows:
    """Point-pair rows: the pre-operative points located once in the atlas's mesh."""

    def __init__(self, locator: MeshLocator, pre: np.ndarray, measured: np.ndarray, labels):
        self.index, self.weight, outside = locator.weights(pre)
        far = np.flatnonzero(outside > OUTSIDE_CELLS * locator.cell_size)
        if len(far):
            names = ", ".join(labels[i] for i in far[:5])
            raise InputError(
                f"--pre: {len(far)} point(s) ({names}) lie outside the atlas's body, farther than "
                f"{OUTSIDE_CELLS:g} cells from it: a frame or unit slip (RAS or LPS, mm)? or points "
                f"not on the brain"
            )
        self.pre, self.measured = pre, measured

    def at(self, field: np.ndarray) -> np.ndarray:
        """A vertex field (N, 3) or the modes (M, N, 3) at the points: (n, 3) or (M, n, 3)."""
        return np.einsum("nj,...njd->...nd", self.weight, field[..., self.index, :])

    def rows(self, modes: np.ndarray):
        """(A (3n, M), b (3n,), groups (3n,)): A c - b is the error of the predicted positions."""
        at = self.at(modes)  # (M, n, 3)
        n = len(self.pre)
        return at.reshape(len(modes), -1).T, (self.measured - self.pre).ravel(), np.repeat(np.arange(n), 3)

    def errors(self, field: np.ndarray) -> np.ndarray:
        """(n,) distance of the predicted positions under a displacement field from the measured."""
        return np.linalg.norm(self.pre + self.at(field) - self.measured, axis=1)


class SurfaceRows:
    """Point-to-surface rows against a triangulated surface that the modes move; its modes by
    vertex (S, 3, M): a vertex's are one contiguous block."""

    def __init__(self, points: np.ndarray, triangles: np.ndarray, modes: np.ndarray):
        self.points, self.triangles, self.modes = points, np.asarray(triangles), modes
        self.locator = SurfaceLocator(points, self.triangles)

    def moved(self, c: np.ndarray) -> np.ndarray:
        return self.points + (self.modes.reshape(-1, self.modes.shape[2]) @ c).reshape(-1, 3)

    def rows(self, c: np.ndarray, measured: np.ndarray):
        """(A (n, M), b (n,), groups, signed distances (n,) at c)."""
        triangle, bary, normal, distance = self.locator.nearest(self.moved(c), measured)
        corners = self.triangles[triangle]  # (n, 3)
        at = np.einsum("nj,njdm->ndm", bary, self.modes[corners])  # u_q per unit weight (n, 3, M)
        A = np.einsum("ndm,nd->nm", at, normal)
        return A, distance + A @ c, np.arange(len(measured)), distance


class SkullRows:
    """Inequality rows keeping the boundary nodes inside the skull (a RigidSkull).

    The room phi is a signed distance, 1-Lipschitz: phi(X + u) >= phi(X + u_k) - |u - u_k|.
    Each node's room where it was last measured is kept (at first, every node's at the first
    weights asked), and a later question (which nodes have less room than a margin, how deep
    the deepest is past the skull) measures the distance only at the nodes that bound leaves in
    doubt: the update's rounds asked it of every boundary node, a third of an update with the
    skull (distances to 40k triangles); each node's own last measurement, not the first
    weights', as the fits' weights move away from those and the bound from them loosens.
    The distances at the last weights asked are kept too: a round asks the depth, the nodes
    near and their rows at the same weights."""

    def __init__(self, skull, points: np.ndarray, modes: np.ndarray, by_node: np.ndarray | None = None):
        self.skull, self.points = skull, points  # the boundary nodes and their modes (M, B, 3)
        # float64 and contiguous once, in two layouts: by weight (a combination of the few
        # weights not 0 is one product) and by node (B, 3, M) (a row of C is then a node's
        # contiguous block: gathering the nodes' columns from the first layout was most of
        # rows()); the second as stored (atlas.h5's boundary/by_node), else transposed here
        self.flat = np.ascontiguousarray(modes.reshape(len(modes), -1), dtype=float)
        if by_node is None:
            by_node = self.flat.T.reshape(len(points), 3, len(modes))
        self.by_node = np.ascontiguousarray(by_node, dtype=float)
        self._known = None  # (u (B, 3), room (B,)): each node where its room was last measured
        self._last = None  # (weights, u (B, 3), room (B,) NaN where not measured, grad (B, 3))

    def displacement(self, c: np.ndarray) -> np.ndarray:
        """u (B, 3) of the nodes at weights c, over the weights that are not 0 (all of them when
        most are not: gathering the rows first then copied most of the modes)."""
        used = c.nonzero()[0]
        if 4 * len(used) > len(c):
            return (c @ self.flat).reshape(-1, 3)
        return (c[used] @ self.flat[used]).reshape(-1, 3)

    def _at(self, c: np.ndarray) -> tuple:
        """(c, u (B, 3), room (B,) NaN where not yet measured, grad (B, 3)) at weights c."""
        if self._last is None or not np.array_equal(self._last[0], c):
            B = len(self.points)
            self._last = (np.array(c, dtype=float), self.displacement(c), np.full(B, np.nan), np.zeros((B, 3)))
        return self._last

    def _phi(self, c: np.ndarray, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(room, grad) of these nodes (default: all) at weights c, measured once per weights."""
        _, u, room, grad = self._at(c)
        nodes = np.arange(len(self.points)) if nodes is None else nodes
        missing = nodes[np.isnan(room[nodes])]
        if len(missing):
            room[missing], grad[missing] = self.skull.phi(self.points[missing] + u[missing])
            if self._known is not None and np.isfinite(room[missing]).all():
                self._known[0][missing], self._known[1][missing] = u[missing], room[missing]
        return room[nodes], grad[nodes]

    def room(self, c: np.ndarray) -> np.ndarray:
        """phi (B,) of the nodes at weights c: the room left before the skull (< 0: past it)."""
        return self._phi(c)[0]

    def _in_doubt(self, c: np.ndarray, below: float) -> tuple[np.ndarray, np.ndarray]:
        """(nodes whose room at c may be below `below`, their room at c): the rest have more."""
        if self._known is None:
            room = self.room(c)
            if not (np.isfinite(c).all() and np.isfinite(room).all()):  # (no bound from it: every node)
                return np.arange(len(room)), room
            self._known = (self._at(c)[1].copy(), room.copy())
        u_known, room_known = self._known
        du = self._at(c)[1] - u_known
        doubt = np.flatnonzero(room_known - np.linalg.norm(du, axis=1) < below)
        if not len(doubt):
            return doubt, np.zeros(0)
        return doubt, self._phi(c, doubt)[0]

    def near(self, c: np.ndarray, margin: float = SKULL_MARGIN) -> np.ndarray:
        """The nodes with less room than `margin` at c."""
        doubt, room = self._in_doubt(c, margin)
        return doubt[room < margin]

    def deepest(self, c: np.ndarray) -> float:
        """How far the deepest node is past the skull at c (m; 0 if none is)."""
        _, room = self._in_doubt(c, 0.0)
        return float(max(0.0, -room.min(initial=0.0)))

    def rows(self, c: np.ndarray, nodes: np.ndarray):
        """(C, d): C c >= d keeps these nodes inside (to SKULL_SLACK), linearised at c."""
        phi, grad = self._phi(c, nodes)
        C = np.einsum("nd,ndm->nm", grad, self.by_node[nodes])
        u = self._at(c)[1][nodes]
        return C, np.einsum("nd,nd->n", grad, u) - phi - SKULL_SLACK


def ease(C: np.ndarray, d: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skull rows C c >= d linearised at a fit, eased where the update's first start (inside
    the rows of its first round, which allow SKULL_SLACK past the skull: prepared.start_inside)
    would break them: such a row misjudges the far side. Eased rows keep that start a tenth of
    SKULL_SLACK inside, not on them (a fit may then pass the skull there by that much more): a
    start on more rows than it has free weights leaves the active-set method no step, and the
    refit fell to NNLS from scratch, the slowest solve there is. The depth at the fit is
    measured on the skull itself after the round (update.py)."""
    return C, np.minimum(d, C @ inside - EASED * SKULL_SLACK)
