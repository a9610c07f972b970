"""Solves with K + E B E^T, K factored once, B the 3x3 blocks of whichever nodes are pressed
now, by the Sherman-Morrison-Woodbury formula

    (K + E B E^T)^-1 r = K^-1 (r - E y),   y = (I + B G)^-1 B E^T K^-1 r,   G = E^T K^-1 E,

two triangular solves an application, however many nodes are pressed. G, the compliance of K
between the dofs of the nodes ever pressed, is kept and grows as nodes join: a node's three
columns K^-1 e are solved once (with the others that join with it, in one multi-right-hand-side
solve), their rows at the dofs known then kept, and the rest of G follows from its symmetry.
Over an atlas's hundreds of settled states the same few hundred nodes press again and again:
the contact's preconditioner is then exact for every Newton iteration without another
factorisation (stepping/exact_contact.py; contact_preconditioner.py rebuilds one each time the
pressed set has moved; docs/performance.md, "Skull contact"). G is dense: 1000 nodes ever
pressed keep 72 MB.

Works on N ranks: dofs are global scalar dofs, the same on every rank, and so is G.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

BATCH = 256  # columns per multi-right-hand-side solve (a dense block of BATCH x the dofs)


class Compliance:
    """apply_K(rhs, x): x = K^-1 rhs by the factor; factor(): the factor matrix (for many
    columns at once; None: one solve a column); template: a vector of K's layout."""

    def __init__(self, apply_K, template: PETSc.Vec, factor=None):
        self.apply_K, self.template, self.factor = apply_K, template, factor
        self.comm = template.getComm().tompi4py()
        self.lo, self.hi = template.getOwnershipRange()
        self.known = np.zeros(0, dtype=np.int64)  # global scalar dofs whose columns were solved
        self.G = np.zeros((0, 0))  # E^T K^-1 E over the known dofs, in their order
        self._position: dict[int, int] = {}
        self.columns = 0  # columns solved (over the life of the factor)
        self.dofs = np.zeros(0, dtype=np.int64)  # the pressed dofs now
        self._core = None  # LU of I + B G over them
        self._B = scipy.sparse.csr_matrix((0, 0))
        self._w, self._correction = template.duplicate(), template.duplicate()

    # -- the compliance between the dofs ever pressed ---------------------------------------------
    def learn(self, dofs: np.ndarray) -> None:
        """Solve the columns of the dofs not yet known and extend G (collective; the same dofs
        on every rank)."""
        new = np.setdiff1d(np.asarray(dofs, dtype=np.int64), self.known)
        for start in range(0, len(new), BATCH):
            self._extend(new[start : start + BATCH])

    def _extend(self, new: np.ndarray) -> None:
        Z = self._solve_columns(new)  # (local rows, len(new))
        known = np.concatenate([self.known, new])
        rows = np.zeros((len(known), len(new)))
        mine = (known >= self.lo) & (known < self.hi)
        rows[mine] = Z[known[mine] - self.lo]
        self.comm.Allreduce(MPI.IN_PLACE, rows, op=MPI.SUM)  # each dof's row from its owner
        n_old = len(self.known)
        G = np.empty((len(known), len(known)))
        G[:n_old, :n_old] = self.G
        G[:, n_old:] = rows
        G[n_old:, :n_old] = rows[:n_old].T  # K symmetric: G too
        G[n_old:, n_old:] = 0.5 * (rows[n_old:] + rows[n_old:].T)
        self.G, self.known = G, known
        self._position.update((int(d), n_old + k) for k, d in enumerate(new))
        self.columns += len(new)

    def _solve_columns(self, dofs: np.ndarray) -> np.ndarray:
        """K^-1 e_d for each global dof d: this rank's rows (n_local, len(dofs))."""
        n_local = self.hi - self.lo
        if self.factor is not None:
            try:
                return self._columns_at_once(dofs, n_local)
            except PETSc.Error:  # a factor package without MatMatSolve
                self.factor = None
        out = np.empty((n_local, len(dofs)))
        e, z = self.template.duplicate(), self.template.duplicate()
        for k, dof in enumerate(dofs):
            e.set(0.0)
            if self.lo <= dof < self.hi:
                e.setValue(int(dof), 1.0)
            e.assemble()
            self.apply_K(e, z)
            out[:, k] = z.getArray()
        e.destroy()
        z.destroy()
        return out

    def _columns_at_once(self, dofs: np.ndarray, n_local: int) -> np.ndarray:
        size = ((n_local, self.template.getSize()), (None, len(dofs)))
        E = PETSc.Mat().createDense(size, comm=self.template.getComm())
        Z = PETSc.Mat().createDense(size, comm=self.template.getComm())
        E.setUp()
        Z.setUp()
        try:
            local = E.getDenseArray()
            local[:] = 0.0
            mine = np.flatnonzero((dofs >= self.lo) & (dofs < self.hi))
            local[dofs[mine] - self.lo, mine] = 1.0
            E.assemble()
            self.factor().matSolve(E, Z)
            return Z.getDenseArray().copy()
        finally:
            E.destroy()
            Z.destroy()

    # -- the preconditioner for the nodes pressed now ----------------------------------------------
    def set(self, dofs: np.ndarray, B: np.ndarray) -> bool:
        """The pressed dofs (global scalar, the same on every rank) and B over them (any square
        matrix, dense or sparse: nodes' blocks). False, and the former change kept, if K + E B E^T is singular
        (to round-off)."""
        dofs = np.asarray(dofs, dtype=np.int64)
        self.learn(dofs)
        B = scipy.sparse.csr_matrix(B if scipy.sparse.issparse(B) else np.asarray(B, dtype=float), dtype=float)
        if not len(dofs):
            self.dofs, self._B, self._core = dofs, B, None
            return True
        where = np.array([self._position[int(d)] for d in dofs])
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)  # (singular: told below)
            core = scipy.linalg.lu_factor(np.eye(len(dofs)) + B @ self.G[np.ix_(where, where)], check_finite=False)
        pivots = np.abs(np.diag(core[0]))
        if not (np.isfinite(core[0]).all() and pivots.min() > 1e-12 * max(pivots.max(), 1.0)):
            return False  # det(K + E B E^T) = det K det(I + B G): singular with the core
        self.dofs, self._B, self._core = dofs, B, core
        return True

    def solve(self, rhs: PETSc.Vec, x: PETSc.Vec) -> None:
        """x = (K + E B E^T)^-1 rhs."""
        self.apply_K(rhs, x)
        if self._core is None:
            return
        mine = (self.dofs >= self.lo) & (self.dofs < self.hi)
        at = np.zeros(len(self.dofs))
        at[mine] = x.getArray(readonly=True)[self.dofs[mine] - self.lo]
        self.comm.Allreduce(MPI.IN_PLACE, at, op=MPI.SUM)
        y = scipy.linalg.lu_solve(self._core, self._B @ at, check_finite=False)
        w = self._w
        w.set(0.0)
        local = w.getArray()
        local[self.dofs[mine] - self.lo] = -y[mine]
        w.assemble()
        self.apply_K(w, self._correction)
        x.axpy(1.0, self._correction)  # K^-1 (r - E y)

    def destroy(self) -> None:
        self._w.destroy()
        self._correction.destroy()
