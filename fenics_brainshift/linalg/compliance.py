"""Solves with K + W C W^T, K factored once, W unit directions at the pressed nodes and C their
contact stiffness along them, by the Sherman-Morrison-Woodbury formula

    (K + W C W^T)^-1 r = K^-1 (r - W y),   y = (I + C G)^-1 C W^T K^-1 r,   G = W^T K^-1 W,

two triangular solves an application, however many nodes are pressed. A node's 3x3 block B
is taken along the directions that carry it: a node pressed on a smooth wall has one, k n n^T,
and only where its normal turns (a skull's edge, a staircase step) does it need a second or
a third. A node's directions are added as its blocks need them (the directions outside those it has
that carry more than SHARE of the block's stiffness, B's and B^T's alike), and B is taken as
D (D^T B D) D^T on them: exact with all it carries.
G, the compliance of K between the directions ever needed, is kept and grows as they join:
a direction's column K^-1 w is solved once (with the others that join with it, in one
multi-right-hand-side solve), its rows at the directions known then kept, and the rest of G
follows from its symmetry. Over an atlas's hundreds of settled states the same few hundred
nodes press again and again: the preconditioner is then (nearly) exact for every Newton
iteration without another factorisation (stepping/exact_contact.py; contact_preconditioner.py
rebuilds one each time the pressed set has moved; docs/performance.md, "Skull contact").

Cost: a column is one triangular solve of K's factor with many right-hand sides; at 3 mm
voxels (84,065 nodes) they were most of a chain of levels when every node took three
(benchmarks/results/compliance_directions.md). G is dense: 3000 directions keep 72 MB.

Works on N ranks: nodes are global block indices, the blocks the same on every rank, and so
are the directions and G.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

BATCH = 256  # columns per multi-right-hand-side solve (a dense block of BATCH x the dofs)
SHARE = 1e-3  # a node gets another direction while its block's stiffness outside them exceeds this share
WEAK = 1e-3  # a node whose block is below this share of the stiffest pressed node's is left out


class Compliance:
    """apply_K(rhs, x): x = K^-1 rhs by the factor; factor(): the factor matrix (for many
    columns at once; None: one solve a column); template: a vector of K's layout (three
    scalar dofs a node, in block order)."""

    def __init__(
        self, apply_K, template: PETSc.Vec, factor=None, share: float | None = None, weak: float | None = None
    ):
        self.apply_K, self.template, self.factor = apply_K, template, factor
        self.share = SHARE if share is None else share  # (0 and 0: every direction of every pressed node)
        self.weak = WEAK if weak is None else weak
        self.comm = template.getComm().tompi4py()
        self.lo, self.hi = template.getOwnershipRange()
        self.node = np.zeros(0, dtype=np.int64)  # each known direction's node (global block index)
        self.direction = np.zeros((0, 3))  # and its unit vector
        self.G = np.zeros((0, 0))  # W^T K^-1 W over the known directions, in their order
        self._of_node: dict[int, list[int]] = {}  # a node's directions (positions in G)
        self.columns = 0  # columns solved (over the life of the factor)
        self.chosen = np.zeros(0, dtype=np.int64)  # the directions in the preconditioner now
        self._core = None  # LU of I + C G over them
        self._C = scipy.sparse.csr_matrix((0, 0))
        self._w, self._correction = template.duplicate(), template.duplicate()

    # -- the compliance between the directions ever needed -----------------------------------------
    def learn(self, node: np.ndarray, direction: np.ndarray) -> None:
        """Solve the columns of new directions (unit vectors at nodes) and extend G
        (collective; the same on every rank)."""
        for start in range(0, len(node), BATCH):
            self._extend(node[start : start + BATCH], direction[start : start + BATCH])

    def _extend(self, node: np.ndarray, direction: np.ndarray) -> None:
        Z = self._solve_columns(node, direction)  # (local rows, len(node))
        known_node = np.concatenate([self.node, node])
        known_direction = np.concatenate([self.direction, direction])
        rows = np.zeros((len(known_node), len(node)))
        dofs = 3 * known_node[:, None] + np.arange(3)
        mine = (dofs >= self.lo) & (dofs < self.hi)  # (a node's three dofs have one owner)
        mine_node = mine.all(axis=1)
        local = Z[dofs[mine_node] - self.lo]  # (mine, 3, new)
        rows[mine_node] = np.einsum("md,mdn->mn", known_direction[mine_node], local)
        self.comm.Allreduce(MPI.IN_PLACE, rows, op=MPI.SUM)  # each direction's row from its owner
        n_old = len(self.node)
        G = np.empty((len(known_node), len(known_node)))
        G[:n_old, :n_old] = self.G
        G[:, n_old:] = rows
        G[n_old:, :n_old] = rows[:n_old].T  # K symmetric: G too
        G[n_old:, n_old:] = 0.5 * (rows[n_old:] + rows[n_old:].T)
        self.G, self.node, self.direction = G, known_node, known_direction
        for k, n in enumerate(node.tolist()):
            self._of_node.setdefault(n, []).append(n_old + k)
        self.columns += len(node)

    def _solve_columns(self, node: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """K^-1 w for each direction w (a unit vector at a node): this rank's rows (n_local, len(node))."""
        n_local = self.hi - self.lo
        if self.factor is not None:
            try:
                return self._columns_at_once(node, direction, n_local)
            except PETSc.Error:  # a factor package without MatMatSolve
                self.factor = None
        out = np.empty((n_local, len(node)))
        e, z = self.template.duplicate(), self.template.duplicate()
        for k in range(len(node)):
            e.set(0.0)
            for c in range(3):
                dof = 3 * int(node[k]) + c
                if self.lo <= dof < self.hi:
                    e.setValue(dof, direction[k, c])
            e.assemble()
            self.apply_K(e, z)
            out[:, k] = z.getArray()
        e.destroy()
        z.destroy()
        return out

    def _columns_at_once(self, node: np.ndarray, direction: np.ndarray, n_local: int) -> np.ndarray:
        size = ((n_local, self.template.getSize()), (None, len(node)))
        E = PETSc.Mat().createDense(size, comm=self.template.getComm())
        Z = PETSc.Mat().createDense(size, comm=self.template.getComm())
        E.setUp()
        Z.setUp()
        try:
            local = E.getDenseArray()
            local[:] = 0.0
            dofs = 3 * node[:, None] + np.arange(3)
            mine = np.flatnonzero(((dofs >= self.lo) & (dofs < self.hi)).all(axis=1))
            local[dofs[mine] - self.lo, mine[:, None]] = direction[mine]
            E.assemble()
            self.factor().matSolve(E, Z)
            return Z.getDenseArray().copy()
        finally:
            E.destroy()
            Z.destroy()

    # -- the directions a node's block needs --------------------------------------------------------
    def _projectors(self, nodes: np.ndarray) -> np.ndarray:
        """P (n, 3, 3): the projection onto each node's known directions."""
        P = np.zeros((len(nodes), 3, 3))
        for i, n in enumerate(nodes.tolist()):
            for k in self._of_node.get(n, ()):
                P[i] += np.outer(self.direction[k], self.direction[k])
        return P

    def _cover(self, nodes: np.ndarray, blocks: np.ndarray, strong: np.ndarray) -> None:
        """Learn the directions the strong nodes' blocks B need, in one solve: the eigenvectors
        of M = B B^T + B^T B (whose range is B's and B^T's: all of an unsymmetric block; for a
        symmetric one 2 B^2, B's own eigenvectors) outside a node's known directions whose
        stiffness (the root of M's eigenvalue over 2) exceeds SHARE of its largest (adding them
        one by one, the largest first, would end at the same ones)."""
        M = blocks @ blocks.transpose(0, 2, 1) + blocks.transpose(0, 2, 1) @ blocks
        scale = np.linalg.eigvalsh(M).max(axis=1) if len(M) else np.zeros(0)
        outside = np.eye(3) - self._projectors(nodes)
        values, vectors = np.linalg.eigh(outside @ M @ outside)  # (ascending: a node's m known ones ~0, first)
        known = np.array([len(self._of_node.get(n, ())) for n in nodes.tolist()], dtype=int)
        # (share 0: every direction with any stiffness, however little: a floor at round-off
        # left out one carrying 3e-10 of a block on two ranks, and the solve was off by 1e-6)
        new_only = np.arange(3)[None, :] >= known[:, None]  # never a fourth direction
        need = strong[:, None] & new_only & (values > self.share**2 * scale[:, None])  # (n, 3)
        which, k = np.nonzero(need)
        new = vectors[which, :, k]  # (m, 3), unit
        # rank 0's choice on every rank: round-off near the floor must not give the ranks
        # different columns to solve (a collective solve of different sizes waits for ever)
        which, new = self.comm.bcast(
            (which, new / np.linalg.norm(new, axis=1)[:, None]) if len(which) else (which, new)
        )
        if len(which):
            self.learn(nodes[which], new)

    # -- the preconditioner for the nodes pressed now ----------------------------------------------
    def set(self, nodes: np.ndarray, blocks: np.ndarray) -> bool:
        """The pressed nodes (global block indices, the same on every rank, each once) and
        their 3x3 blocks (any: need not be symmetric; a support's rows and columns zero).
        False, and the former change kept, if K plus them is singular (to round-off)."""
        nodes = np.asarray(nodes, dtype=np.int64)
        blocks = np.asarray(blocks, dtype=float).reshape(-1, 3, 3)
        size = np.abs(blocks).reshape(len(blocks), -1).max(axis=1) if len(blocks) else np.zeros(0)
        strong = size > self.weak * size.max(initial=0.0)
        self._cover(nodes, blocks, strong)
        chosen, pieces = [], []
        for i in np.flatnonzero(strong):
            where = self._of_node.get(int(nodes[i]), [])
            if where:
                D = self.direction[where]  # (m, 3)
                chosen.extend(where)
                pieces.append(D @ blocks[i] @ D.T)
        chosen = np.asarray(chosen, dtype=np.int64)
        C = scipy.sparse.block_diag(pieces, format="csr") if pieces else scipy.sparse.csr_matrix((0, 0))
        if not len(chosen):
            self.chosen, self._C, self._core = chosen, C, None
            return True
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)  # (singular: told below)
            core = scipy.linalg.lu_factor(np.eye(len(chosen)) + C @ self.G[np.ix_(chosen, chosen)], check_finite=False)
        pivots = np.abs(np.diag(core[0]))
        regular = bool(np.isfinite(core[0]).all() and pivots.min() > 1e-12 * max(pivots.max(), 1.0))
        if not self.comm.bcast(regular):  # (rank 0's verdict on every rank, as the directions)
            return False  # det(K + W C W^T) = det K det(I + C G): singular with the core
        self.chosen, self._C, self._core = chosen, C, core
        return True

    def clear(self) -> None:
        """No node in the preconditioner: K alone (the directions learned are kept)."""
        self.chosen, self._C, self._core = np.zeros(0, dtype=np.int64), scipy.sparse.csr_matrix((0, 0)), None

    def solve(self, rhs: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = (K + W C W^T)^-1 rhs."""
        self.apply_K(rhs, x)
        if self._core is None:
            return
        node, direction = self.node[self.chosen], self.direction[self.chosen]
        dofs = 3 * node[:, None] + np.arange(3)
        mine = ((dofs >= self.lo) & (dofs < self.hi)).all(axis=1)
        at = np.zeros(len(node))
        at[mine] = np.einsum("md,md->m", direction[mine], x.getArray(readonly=True)[dofs[mine] - self.lo])
        self.comm.Allreduce(MPI.IN_PLACE, at, op=MPI.SUM)
        y = scipy.linalg.lu_solve(self._core, self._C @ at, check_finite=False)
        w = self._w
        w.set(0.0)
        local = w.getArray()
        np.add.at(local, dofs[mine] - self.lo, -y[mine, None] * direction[mine])
        w.assemble()
        self.apply_K(w, self._correction)
        x.axpy(1.0, self._correction)  # K^-1 (r - W y)

    def destroy(self) -> None:
        self._w.destroy()
        self._correction.destroy()
