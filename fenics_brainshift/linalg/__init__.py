"""PETSc: linear solvers under one options prefix, the near-nullspace, matrix products."""

from .nullspace import rigid_body_modes
from .products import PairProduct, diagonal_matrix
from .solver import KINDS, LinearSolver, solve_preconditioned_by

__all__ = ["KINDS", "LinearSolver", "PairProduct", "diagonal_matrix", "rigid_body_modes", "solve_preconditioned_by"]
