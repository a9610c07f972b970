"""Newton's tangent matrix, shared by the settled states (newton.py) and the time steps
(newton_dynamic.py): how it is stored, assembled into one matrix again and again, and the
Krylov method that solves with it."""

from __future__ import annotations

from dolfinx.fem.petsc import assemble_matrix, create_matrix
from petsc4py import PETSc

# The tangent is stored in 3x3 blocks (PETSc BAIJ): on the 5 mm brain its assembly is 2.7x
# (neo-Hookean) to 3.5x (linear) faster than into scalar AIJ, a product about 2x
# (benchmarks/results/tangent_storage.md)
TANGENT_TYPE = "baij"


def tangent_settings(settings: dict) -> dict:
    """The tangent is not symmetric with a follower load: the Krylov method is GMRES,
    preconditioned by the scene's kind (a Cholesky factor, AMG, ...) built once on the linear
    stiffness K at rest; only if GMRES stalls is it rebuilt, as an LU factor of the current
    tangent (a compressive prestress can make the tangent indefinite)."""
    # right preconditioning: GMRES then measures the true residual, which the forcing term
    # must bound (a preconditioned one can be small while the true one is not)
    return {**settings, "options": {"ksp_type": "gmres", "ksp_pc_side": "right", **settings.get("options", {})}}


def tangent_type(model) -> str:
    """3x3 blocks, but scalar AIJ where septa project it (PETSc's PtAP takes no BAIJ)."""
    return "aij" if model.constraints.has_septa else TANGENT_TYPE


def reassemble(matrix: PETSc.Mat | None, compiled_form, kind: str = TANGENT_TYPE) -> PETSc.Mat:
    """The form's matrix, assembled into ``matrix`` (made on the first call, of type ``kind``:
    the sparsity pattern is built once, not every Newton iteration)."""
    if matrix is None:
        matrix = create_matrix(compiled_form, kind)
    matrix.zeroEntries()
    assemble_matrix(matrix, compiled_form)
    matrix.assemble()
    return matrix
