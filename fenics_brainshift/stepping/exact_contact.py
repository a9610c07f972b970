"""Newton's solves for a linear body against the skull, preconditioned exactly for K and the
contact blocks of the nodes pressed now, with K's one factor.

The preconditioner of contact_preconditioner.py is a factor of K plus the contact stiffness of
the nodes pressed when it was built: as the pressed set moves, GMRES needs more iterations
until a new factor is made (1.2 s each on the 5 mm brain; an atlas's settled states took
about 150 GMRES iterations and half a factorisation each). Here every Newton iteration gets
the inverse of K + C, C the pressed nodes' tangent blocks as they are (unsymmetric where a
node's normal turns; their symmetric, positive part where K + C is singular), by the Woodbury
formula on K's factor (linalg/compliance.py): two triangular solves an application, and the
compliance between the directions the pressed nodes' blocks need (one on a flat face of the
skull, up to three where the normal turns; a direction carrying less than a thousandth of the
block's stiffness left out), solved once for each over the factor's life (an atlas's modes press the same few hundred
nodes again and again). Flexible GMRES is left the follower load's tangent and what was left
out. Used where K's own factor is at hand: a
linear material, a factor (not AMG), and no node touching the skull at rest (K alone may be
singular there).
"""

from __future__ import annotations

import time

import numpy as np
from petsc4py import PETSc

from ..errors import SolverError
from ..linalg.compliance import Compliance
from ..linalg.solver import has_package
from .contact_preconditioner import fixed_global, gathered_node_blocks

FACTOR_KINDS = ("cholesky", "lu")


class ExactContactSolve:
    """solves: the Solves whose solver holds K's factor (kept, never reset here); contact: the
    SkullContact; fixed: the local dofs the supports hold."""

    def __init__(self, solves, contact, fixed: np.ndarray, max_it: int):
        self.solves, self.contact = solves, contact
        self.factored = solves.solver  # the LinearSolver whose factor this uses
        pc_K = solves.solver.ksp.getPC()
        self.compliance = Compliance(lambda rhs, x: pc_K.apply(rhs, x), contact.vector, lambda: pc_K.getFactorMatrix())
        self._fixed = fixed_global(contact.V, fixed)
        self.ksp = PETSc.KSP().create(contact.comm)
        # flexible GMRES keeps the preconditioned vectors: the answer is their combination, not
        # one more application of the preconditioner (two triangular solves) as GMRES's right
        # preconditioning needs; the same iterates (benchmarks/results/skull_atlas.md)
        self.ksp.setType("fgmres")
        self.ksp.setPCSide(PETSc.PC.Side.RIGHT)  # (measures the true residual)
        pc = self.ksp.getPC()
        pc.setType("python")
        pc.setPythonContext(_Apply(self.compliance))
        self.ksp.setTolerances(atol=1e-300, max_it=max_it)
        self.pressed = 0  # nodes in the preconditioner now
        self.lu_solves = 0  # solves GMRES could not make, by an LU of the tangent

    def prepare(self, blocks) -> None:
        """The preconditioner for the tangent's contact blocks (dofs, blocks) (collective): K
        and the blocks as they are (the Woodbury formula needs no symmetry), so that GMRES is
        left the follower load's tangent alone; where K plus them is singular (a node's normal
        turning at a concave corner can make its block indefinite), K and their symmetric,
        positive part (as the former factor held)."""
        nodes, B = gathered_node_blocks(self.contact.V, *blocks, self._fixed)
        if not self.compliance.set(nodes, B):  # (the positive part only then: eigh of every block)
            nodes, B = gathered_node_blocks(self.contact.V, *self.contact.stiffness(blocks), self._fixed)
            if not self.compliance.set(nodes, B):  # (K SPD plus PSD blocks: only by round-off) K alone,
                self.compliance.clear()  # not the former nodes' preconditioner; GMRES has the rest to do
        self.pressed = len(nodes)

    def __call__(self, A: PETSc.Mat, rhs: PETSc.Vec, x: PETSc.Vec, rtol: float, t: float, assembled=None) -> int:
        """x = A^-1 rhs to the relative tolerance rtol by flexible GMRES (x starts from zero),
        or, where it does not converge, by an LU of A; counted in the Solves like any solve.
        A may be an action (tangent_action.py): ``assembled()`` then gives it as a matrix for
        the LU."""
        start = time.perf_counter()
        self.ksp.setOperators(A)
        self.ksp.setTolerances(rtol=rtol)
        x.set(0.0)
        self.ksp.solve(rhs, x)
        reason, its = self.ksp.getConvergedReason(), self.ksp.getIterationNumber()
        if reason < 0:  # (a concave corner can make the tangent far from K + C): its own LU, once
            its += self._by_lu(A if assembled is None else assembled(), rhs, x)
        self.solves.record(its, time.perf_counter() - start, x, t)
        return its

    def _by_lu(self, A: PETSc.Mat, rhs: PETSc.Vec, x: PETSc.Vec) -> int:
        """x = A^-1 rhs by an LU factor of A made for this solve alone (K's factor is kept)."""
        self.lu_solves += 1
        scalar = A.convert("aij", PETSc.Mat())  # (out=None would convert A in place)
        ksp = PETSc.KSP().create(self.contact.comm)
        try:
            ksp.setOperators(scalar)
            ksp.setType("preonly")
            pc = ksp.getPC()
            pc.setType("lu")
            if has_package("mumps"):  # (as the former path's LU: linalg/solver.py)
                pc.setFactorSolverType("mumps")
            ksp.solve(rhs, x)
            if ksp.getConvergedReason() < 0 or not np.isfinite(x.norm()):
                raise SolverError(
                    "Newton's solve with skull contact failed: GMRES did not converge, and an LU "
                    "factor of the tangent gave no answer"
                )
            return 1
        finally:
            ksp.destroy()
            scalar.destroy()

    def destroy(self) -> None:
        self.ksp.destroy()
        self.compliance.destroy()


class _Apply:
    """The python PC's context: y = (K + C)^-1 x."""

    def __init__(self, compliance: Compliance):
        self.compliance = compliance

    def apply(self, _pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.compliance.solve(x, y)
