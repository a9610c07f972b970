"""The preconditioner of Newton's solves with skull contact: the contact-free matrix plus the
contact's stiffness on the nodes pressed when it was built, factored by the scene's kind.

With the factor of the contact-free matrix alone (K at rest, or a time step's effective
matrix), every pressed node is a direction GMRES has to find by itself: with a hundred
pressed nodes a solve takes 6-15 iterations instead of 2-3, each a triangular solve. The
pressed set changes slowly (over Newton iterations, over time steps), so a factor that
includes it stays good for many solves. When to build a new one is a rent-or-buy choice: the
Krylov iterations the solves spend beyond what a fresh factor would need (GOOD_KRYLOV) are
added up, and once they exceed what a factorisation costs (FACTOR_COST_KRYLOV iterations),
the factor is rebuilt (provided the pressed set has changed since; else a new factor would
not help). That never spends more than twice the better of the two policies in hindsight.
The price is counted in iterations, not measured in seconds: a decision taken on timings
differs from run to run, and so would the answer (within the solver's tolerance).

Only the symmetric, positive part of the contact blocks goes in (physics/contact.py,
stiffness): the factor stays a Cholesky one, as fast to apply as the contact-free
factor, and GMRES makes up the rest (that part, and the follower load's tangent).

The time steps' fixed point (lagged_contact.py) needs the matrix it solves with to hold the
nodes pressed now, exactly; there adjust() keeps the factor and puts the nodes come or gone
since, or whose block has changed, into a low-rank update (linalg/low_rank.py: three
triangular solves per node, done together), until more than MAX_UPDATED have: then a new
factor.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

from ..linalg.low_rank import LowRankUpdate
from ..logs import get_logger

log = get_logger("contact")
GOOD_KRYLOV = 3  # GMRES iterations of a solve with a fresh factor (forcing 1e-2 .. 1e-6)
FACTOR_COST_KRYLOV = 50  # a factorisation's price in iterations (each a triangular solve and a product)
MAX_UPDATED = 100  # nodes come, gone or changed since the factor beyond which adjust() factors anew
DRIFT = 0.3  # a factored node whose block has changed by more than this (relative) is updated too
# (both chosen on the 5 mm drain and the resection demo with the skull: docs/performance.md)


class ContactPreconditioner:
    """base(): the contact-free matrix with supports (kept by its owner, never changed here);
    fixed: the local dofs the supports hold."""

    def __init__(self, solves, contact, base: Callable[[], PETSc.Mat], fixed: np.ndarray):
        self.solves, self.contact, self.base, self.fixed = solves, contact, base, fixed
        self._matrix: PETSc.Mat | None = None  # the base plus contact blocks, factored now
        self._pressed: np.ndarray | None = None  # the block dofs pressed at the last build
        self._factors = -1  # solves.factors when the excess was last reset
        self._excess = 0  # Krylov iterations beyond GOOD_KRYLOV a solve since the last factor
        self._built_at = -1  # solves.factors after the last rebuild
        self.stiffness = None  # (dofs, blocks): the contact stiffness in the factor and its update
        self._factored = None  # (dofs, blocks): the part of it in the factor
        self._update: LowRankUpdate | None = None  # the nodes come or gone since
        self.rebuilds = 0
        self.updates = 0
        self.refreshed = 0  # factored nodes whose block was updated for having changed (on this rank)
        self._fixed_global: set[int] | None = None  # global scalar dofs the supports hold

    def after_solve(self, iterations: int, blocks) -> bool:
        """Called after each solve with its GMRES iterations and the tangent's contact blocks
        (dofs, blocks): rebuilds the factor when the iterations lost to slow solves have paid
        for one and the pressed set changed. Returns True if it did."""
        excess = max(0, iterations - GOOD_KRYLOV)
        if not (self.pays(excess) and self.changed(blocks[0])):
            return False
        self.rebuild(blocks)
        return True

    def pays(self, excess_iterations: int) -> bool:
        """Add iterations lost to slow solves since the last factor; have they paid for a new
        one? (The same on every rank: GMRES iterates collectively.)"""
        if self._factors != self.solves.factors:  # a factor made since (here or by the owner)
            self._factors, self._excess = self.solves.factors, 0
        self._excess += excess_iterations
        return self._excess > FACTOR_COST_KRYLOV

    def changed(self, dofs: np.ndarray) -> bool:
        """Are these pressed nodes (block dofs) other than those in the factor (on any rank)?"""
        before = self._pressed if self._pressed is not None else np.zeros(0, dtype=dofs.dtype)
        return self.contact.comm.allreduce(len(np.setxor1d(before, dofs)), op=MPI.SUM) > 0

    def rebuild(self, blocks) -> None:
        """Factor base + the contact stiffness of ``blocks`` (collective)."""
        base = self.base()
        if self._matrix is None:
            self._matrix = base.duplicate(copy=True)
            self._matrix.setLGMap(*base.getLGMap())  # (a duplicate lacks the local numbering)
        else:
            base.copy(self._matrix, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self.stiffness = self._factored = self.contact.stiffness(blocks)
        self.contact.add_tangent(self._matrix, None, blocks=self.stiffness)
        if self._update is not None:
            self._update.destroy()
            self._update = None
        self._matrix.zeroRowsColumnsLocal(self.fixed, 1.0)
        solver = self.solves.solver
        operator = solver.ksp.getOperators()[0] if solver is not None else self._matrix
        max_it = solver.ksp.getTolerances()[3] if solver is not None else None
        self.solves.reset(self._matrix)  # a new KSP with the same settings (GMRES on the tangent)
        self.solves.operate_with(operator)
        if max_it is not None:
            self.solves.solver.ksp.setTolerances(max_it=max_it)
        self._pressed = np.sort(blocks[0])
        self._built_at = self.solves.factors
        self.rebuilds += 1
        log.debug(
            "  contact: preconditioner rebuilt with %d pressed nodes (%.2f s)",
            len(blocks[0]),
            self.solves.last_factor_seconds,
        )

    def adjust(self, blocks) -> None:
        """Make the preconditioner base + the contact stiffness of ``blocks`` (the tangent's at
        the pressed nodes now): nodes come or gone since, and nodes in the factor whose block
        has changed by more than DRIFT of it (a node factored when barely within reach, or
        whose normal has turned as it slid), join a low-rank update (linalg/low_rank.py, three
        triangular solves per node); the other nodes in the factor keep the blocks they were
        factored with. More than MAX_UPDATED nodes in the update: a new factor (collective).
        A stale block costs the fixed point many iterations: the penalty is stiffer than the
        tissue (docs/performance.md)."""
        if self._factored is None or self.solves.factors != self._built_at:
            return self.rebuild(blocks)
        new = self.contact.stiffness(blocks)
        old_dofs, old_blocks = self._factored
        added = ~np.isin(new[0], old_dofs)
        removed = ~np.isin(old_dofs, new[0])
        kept = ~removed
        order = np.argsort(new[0])
        now = new[1][order[np.searchsorted(new[0][order], old_dofs[kept])]]  # the kept nodes' blocks today
        was = old_blocks[kept]
        drifted = np.linalg.norm(now - was, axis=(1, 2)) > DRIFT * np.linalg.norm(was, axis=(1, 2))
        dofs = np.concatenate([new[0][added], old_dofs[removed], old_dofs[kept][drifted]])
        deltas = np.concatenate([new[1][added], -old_blocks[removed], (now - was)[drifted]])
        if self._fixed_global is None:
            self._fixed_global = fixed_global(self.contact.V, self.fixed)
        gathered = gathered_blocks(self.contact.V, dofs, deltas, self._fixed_global, MAX_UPDATED)
        if gathered is None:
            return self.rebuild(blocks)
        scalar, B = gathered
        if self._update is None:
            pc = self.solves.solver.ksp.getPC()
            factor = (lambda: pc.getFactorMatrix()) if self.solves.settings["kind"] in ("cholesky", "lu") else None
            self._update = LowRankUpdate(lambda rhs, x: pc.apply(rhs, x), self.contact.vector, factor)
        self._update.set(scalar, B.toarray())
        self.stiffness = (
            np.concatenate([old_dofs[kept], new[0][added]]),
            np.concatenate([np.where(drifted[:, None, None], now, was), new[1][added]]),
        )
        self._pressed = np.sort(new[0])
        self.updates += 1
        self.refreshed += int(drifted.sum())

    def solve(self, rhs: PETSc.Vec, x: PETSc.Vec, t: float) -> int:
        """x = P^-1 rhs with P the factored matrix and its low-rank update (a Solves-like call:
        counted, checked)."""
        its = self.solves.by_factor(rhs, x, t)
        if self._update is not None:
            self._update.correct(x)
            if self.solves.project is not None:
                self.solves.project(x)
        return its

    def factor_is_base(self) -> bool:
        """Is the solver's factor that of the base alone (no node pressed in it, on any rank)?"""
        local = self._pressed is None or len(self._pressed) == 0 or self.solves.factors != self._built_at
        return self.contact.comm.allreduce(local, op=MPI.LAND)

    def forget(self) -> None:
        """The base changed (a resection): the next rebuild starts from it afresh."""
        if self._matrix is not None:
            self._matrix.destroy()
        if self._update is not None:
            self._update.destroy()
        self._matrix, self._pressed, self.stiffness, self._factored, self._update = None, None, None, None, None

    def destroy(self) -> None:
        self.forget()


def fixed_global(V, fixed: np.ndarray) -> set[int]:
    """The global scalar dofs the supports hold (the same set on every rank), from this rank's
    local (unrolled) ones."""
    index_map = V.dofmap.index_map
    fixed = np.asarray(fixed)
    held = (
        3 * index_map.local_to_global(np.asarray(fixed // 3, dtype=np.int32)) + fixed % 3
        if len(fixed)
        else np.zeros(0, dtype=np.int64)
    )
    return set(np.concatenate(V.mesh.comm.allgather(held)).tolist())


def gathered_node_blocks(V, dofs: np.ndarray, blocks: np.ndarray, fixed: set[int]):
    """Nodes' 3x3 blocks (this rank's block dofs (n,), blocks (n, 3, 3)) the same on every rank:
    (global block indices (m,), blocks (m, 3, 3)), a node's ranks' shares summed, the rows and
    columns of the supports' dofs zero (they stay identity)."""
    comm = V.mesh.comm
    index_map = V.dofmap.index_map
    nodes = np.concatenate(comm.allgather(index_map.local_to_global(np.asarray(dofs, dtype=np.int32))))
    blocks = np.concatenate(comm.allgather(np.asarray(blocks).reshape(-1, 3, 3)))
    unique, where = np.unique(nodes, return_inverse=True)
    summed = np.zeros((len(unique), 3, 3))
    np.add.at(summed, where, blocks)
    if fixed:
        free = ~np.isin(3 * unique[:, None] + np.arange(3), np.fromiter(fixed, dtype=np.int64))
        summed *= free[:, :, None] * free[:, None, :]
    return unique.astype(np.int64), summed


def gathered_blocks(V, dofs: np.ndarray, blocks: np.ndarray, fixed: set[int], limit: int | None = None):
    """Nodes' 3x3 blocks (this rank's block dofs (n,), blocks (n, 3, 3)) as one sparse (CSR)
    matrix over global scalar dofs, the same on every rank: (scalar dofs (m,), B (m, m)), a
    node's ranks' shares summed, the supports' dofs left out (they stay identity). None if more
    than ``limit`` nodes. (Sparse: the dense m x m, made and converted every Newton iteration,
    was a twentieth of an atlas mode's time.)"""
    unique, summed = gathered_node_blocks(V, dofs, blocks, set())
    if limit is not None and len(unique) > limit:
        return None
    first = 3 * np.arange(len(unique))[:, None, None]
    rows, columns = first + np.arange(3)[None, :, None], first + np.arange(3)[None, None, :]
    size = 3 * len(unique)
    B = scipy.sparse.csr_matrix(
        (summed.ravel(), (np.broadcast_to(rows, summed.shape).ravel(), np.broadcast_to(columns, summed.shape).ravel())),
        shape=(size, size),
    )
    scalar = (3 * unique[:, None] + np.arange(3)).ravel()
    keep = np.flatnonzero([d not in fixed for d in scalar.tolist()])
    return scalar[keep], B[keep][:, keep]
