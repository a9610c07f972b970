"""Matrix products a time step needs: one matrix times two vectors in a single pass, and a
matrix that is only a diagonal.

A dynamic step needs K u (the energy guard's strain energy) and K w (the next right-hand
side) of the same state. Two MatMult calls read K twice; MatMatMult with a dense two-column
block reads it once, which pays when K no longer sits in cache after the triangular solves
(measured in benchmarks/step_parts.py).
"""

from __future__ import annotations

from petsc4py import PETSc


class PairProduct:
    """y1, y2 = A x1, A x2 for a fixed matrix A, with the block and its product kept."""

    def __init__(self, A: PETSc.Mat):
        self.A = A
        rows = A.getSizes()[1]  # the layout of the vectors A multiplies
        self.X = PETSc.Mat().createDense((rows, (PETSc.DECIDE, 2)), comm=A.getComm())
        self.X.setUp()
        self.X.assemble()
        self.Y = A.matMult(self.X)

    def multiply(self, x1: PETSc.Vec, x2: PETSc.Vec, y1: PETSc.Vec, y2: PETSc.Vec) -> None:
        block = self.X.getDenseArray()
        block[:, 0] = x1.getArray(readonly=True)
        block[:, 1] = x2.getArray(readonly=True)
        self.A.matMult(self.X, self.Y)
        result = self.Y.getDenseArray(readonly=True)
        y1.array[:] = result[:, 0]
        y2.array[:] = result[:, 1]

    def destroy(self) -> None:
        self.X.destroy()
        self.Y.destroy()


def diagonal_matrix(diagonal: PETSc.Vec) -> PETSc.Mat:
    """A matrix holding only the given diagonal (same parallel layout): a lumped mass as a
    diagonal costs a fraction of a product with the assembled matrix, which carries the full
    stiffness pattern full of zeros."""
    sizes = diagonal.getSizes()
    D = PETSc.Mat().createAIJ((sizes, sizes), nnz=(1, 0), comm=diagonal.getComm())
    D.setDiagonal(diagonal)
    D.assemble()
    return D
