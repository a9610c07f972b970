"""The tangent of a linear body against the skull as an action, for the exact contact solves.

Newton's tangent for a linear body with follower loading and skull contact is

    A = S (K + s L + C) S + (what the constraints put where S is zero),

K the stiffness (constant), L the fluid load's tangent on the wet facets and C the pressed
nodes' blocks (both change every iteration), S the constraints' projector (supports and
septa: physics/constraints.py). Flexible GMRES only multiplies by A (exact_contact.py: its
preconditioner is K's factor with C), so A need not be a matrix: K with the constraints is
projected once (K_c), and each product is K_c x plus the facets' and nodes' small dense blocks
applied to S x, summed over ranks like an assembly, instead of K copied, the blocks added
and the septa's PtAP made again every iteration (one pose's levels of a prepared patient's
atlas in 0.74 of the time: benchmarks/results/tangent_action_t2w.md). K_c is the matrix K's
factor was made of: no copy of K is kept for it.
"""

from __future__ import annotations

import dolfinx.la
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc


class TangentAction:
    """A PETSc (python) matrix whose product is the tangent: K_c (K with the constraints, the
    caller's matrix: not copied, not destroyed here) plus, on S x, the blocks given to ``set``.
    ``constraints``: the model's Constraints; V its function space."""

    def __init__(self, K_constrained: PETSc.Mat, constraints, V):
        self.K, self.constraints = K_constrained, constraints
        index_map = V.dofmap.index_map
        self._owned = V.dofmap.index_map_bs * index_map.size_local
        self._x = dolfinx.la.create_petsc_vector(index_map, V.dofmap.index_map_bs)  # ghosted work vectors
        self._y = self._x.duplicate()
        self._load = None  # (scalar rows (F, 3n), scalar columns (F, 9), blocks (F, 3n, 9))
        self._nodes = None  # (scalar dofs (n, 3), blocks (n, 3, 3))
        self._blocks = False  # any rank has blocks
        self.mat = PETSc.Mat().createPython(K_constrained.getSizes(), self, comm=K_constrained.getComm())
        self.mat.setUp()

    def set(self, load=None, nodes=None) -> None:
        """The blocks of this iteration: ``load`` (row block dofs (F, n), column block dofs
        (F, 3), blocks (F, 3 n, 9)) as physics/load_tangent.py gives them, already scaled;
        ``nodes`` (block dofs (n,), blocks (n, 3, 3)), the contact's (projected at septa).
        All in this rank's local numbering (ghosts included); a rank adds its own share.
        Collective."""
        self._load = None
        if load is not None and len(load[0]):
            rows, cols, blocks = load
            self._load = (_scalar(rows), _scalar(cols), np.ascontiguousarray(blocks))
        self._nodes = None
        if nodes is not None and len(nodes[0]):
            dofs, blocks = nodes
            self._nodes = (_scalar(np.asarray(dofs)[:, None]), np.ascontiguousarray(blocks))
        # collective: a rank without blocks of its own still takes part in the ghost updates
        self._blocks = (
            self.K.getComm().tompi4py().allreduce(self._load is not None or self._nodes is not None, op=MPI.LOR)
        )

    def mult(self, _mat, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.K.mult(x, y)
        if not self._blocks:
            return
        with self._x.localForm() as local:
            local.array[: self._owned] = x.array_r
        self._x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        with self._x.localForm() as local:
            v = self.constraints.restrict(local.array.copy())
        w = np.zeros_like(v)
        if self._load is not None:
            rows, cols, blocks = self._load
            w += np.bincount(rows.ravel(), np.einsum("fij,fj->fi", blocks, v[cols]).ravel(), minlength=len(w))
        if self._nodes is not None:
            dofs, blocks = self._nodes
            at = v[dofs].reshape(-1, 3)
            w += np.bincount(dofs.ravel(), np.einsum("nij,nj->ni", blocks, at).ravel(), minlength=len(w))
        with self._y.localForm() as local:
            local.array[:] = w
        self._y.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        owned = self.constraints.restrict(self._y.array_r.copy(), owned_only=True)
        y.array[:] += owned

    def free(self) -> None:
        """Its matrix and vectors, K kept (not ``destroy``: PETSc calls a python matrix's
        context by that name when the matrix goes)."""
        self.mat.destroy()
        self._x.destroy()
        self._y.destroy()


def _scalar(block_dofs: np.ndarray) -> np.ndarray:
    """Block dofs (..., m) to their scalar dofs (..., 3 m), component fastest."""
    block_dofs = np.asarray(block_dofs, dtype=np.int64)
    return (3 * block_dofs[..., None] + np.arange(3)).reshape(*block_dofs.shape[:-1], -1)
