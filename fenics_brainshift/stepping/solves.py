"""Every linear solve of a run goes through here: counted, timed, checked for NaN/Inf."""

from __future__ import annotations

import time

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..errors import SolverError
from ..linalg import LinearSolver


class Solves:
    """A LinearSolver on one matrix (rebuilt with ``reset``), with totals over the run."""

    def __init__(self, settings: dict, near_nullspace=None):
        self.settings = settings  # LinearSolver keywords: kind, rtol, atol, max_it, options
        self.near_nullspace = near_nullspace
        self.solver: LinearSolver | None = None
        self.count = 0
        self.factors = 0  # factorisations or preconditioner setups
        self.last_factor_seconds = 0.0  # what the last one took (the slowest rank)
        self.seconds = 0.0
        self.last_seconds = 0.0  # of the last solve
        self.iterations: list[int] = []
        # x <- P x after every solve (physics/constraints.py), or None: an inexact Krylov solve
        # (Newton's forcing) with a preconditioner that does not keep range(P) leaves it
        self.project = None
        # what a non-finite answer suggests: the stepper in time sets its own (dt)
        self.hint = "check the loads against the stiffness (moduli in Pa, levels in m)"

    def reset(self, A: PETSc.Mat) -> None:
        """A new matrix: its solver is set up now (factor or preconditioner)."""
        self.destroy()
        t0 = time.perf_counter()
        self.solver = LinearSolver(A, near_nullspace=self.near_nullspace, **self.settings)
        self.last_factor_seconds = A.getComm().tompi4py().allreduce(time.perf_counter() - t0, op=MPI.MAX)
        self.factors += 1

    def operate_with(self, A: PETSc.Mat) -> None:
        """Solve with A from now on, keeping the factor or preconditioner of the matrix the
        solver was set up with (a Krylov method then makes up the difference)."""
        self.solver.ksp.setOperators(A, self.solver.ksp.getOperators()[1])

    def __call__(self, rhs: PETSc.Vec, x: PETSc.Vec, t: float) -> int:
        t0 = time.perf_counter()
        its = self.solver.solve(rhs, x)
        self.record(its, time.perf_counter() - t0, x, t)
        return its

    def record(self, its: int, seconds: float, x: PETSc.Vec, t: float) -> None:
        """Count a solve made (by this solver or by another Krylov method on its factor):
        x projected onto the constraints, checked for NaN/Inf."""
        if self.project is not None:
            self.project(x)
        self.last_seconds = seconds
        self.seconds += seconds
        self.count += 1
        self.iterations.append(its)
        if not np.isfinite(x.norm()):
            raise SolverError(f"the solution is no longer finite at t = {t:g} s (NaN or Inf): {self.hint}")

    def by_factor(self, rhs: PETSc.Vec, x: PETSc.Vec, t: float) -> int:
        """x = P^-1 rhs by the solver's factor alone, no Krylov method around it: the answer
        when the factor is of the very matrix to solve (a right-preconditioned GMRES would
        apply it twice). Counted as a solve of one iteration."""
        t0 = time.perf_counter()
        self.solver.ksp.getPC().apply(rhs, x)
        if self.project is not None:
            self.project(x)
        self.last_seconds = time.perf_counter() - t0
        self.seconds += self.last_seconds
        self.count += 1
        self.iterations.append(1)
        if not np.isfinite(x.norm()):
            raise SolverError(f"the solution is no longer finite at t = {t:g} s (NaN or Inf): {self.hint}")
        return 1

    def destroy(self) -> None:
        if self.solver is not None:
            self.solver.destroy()
            self.solver = None
