"""All PETSc: Krylov/direct solver setup under the ``brainshift_`` options prefix,
the rigid-body near-nullspace for AMG, and failures turned into clear errors.

Any PETSc option can be given in the scene (``[solver] options = { ksp_monitor = true }``)
or in the environment (``PETSC_OPTIONS="-brainshift_ksp_view"``). Precedence: the scene's
options, then the environment, then this module's defaults for the chosen ``kind``.
The step (or static) solver reads ``-brainshift_*``; the one-off mass solve for the initial
acceleration reads ``-brainshift_mass_*``.
"""
from __future__ import annotations

import dolfinx.la
import numpy as np
from petsc4py import PETSc

from .scene import SolverConfig

PREFIX = "brainshift_"


class SolverError(RuntimeError):
    """A linear solve failed; the message names PETSc's reason and the iteration count."""


def rigid_body_modes(V) -> PETSc.NullSpace:
    """Three translations and three rotations of the dof coordinates, orthonormalised:
    the near-nullspace that makes smoothed-aggregation AMG work for elasticity."""
    index_map = V.dofmap.index_map
    bs = V.dofmap.index_map_bs
    n_owned = index_map.size_local
    x = V.tabulate_dof_coordinates()[:n_owned]
    basis = [dolfinx.la.create_petsc_vector(index_map, bs) for _ in range(6)]
    arrays = [np.zeros((n_owned, bs)) for _ in range(6)]
    for i in range(3):
        arrays[i][:, i] = 1.0
    arrays[3][:, 0], arrays[3][:, 1] = -x[:, 1], x[:, 0]
    arrays[4][:, 0], arrays[4][:, 2] = x[:, 2], -x[:, 0]
    arrays[5][:, 1], arrays[5][:, 2] = -x[:, 2], x[:, 1]
    for vec, arr in zip(basis, arrays):
        vec.array[:] = arr.ravel()
    # modified Gram-Schmidt (collective, exact enough for a preconditioner hint)
    for i, vi in enumerate(basis):
        for vj in basis[:i]:
            vi.axpy(-vi.dot(vj), vj)
        vi.normalize()
    return PETSc.NullSpace().create(vectors=basis, comm=V.mesh.comm)


class LinearSolver:
    """A KSP for one fixed matrix, set up once and reused for every right-hand side."""

    def __init__(self, A: PETSc.Mat, config: SolverConfig, name: str, near_nullspace=None):
        self.config = config
        self.name = name
        self.ksp = PETSc.KSP().create(A.getComm())
        self.ksp.setOperators(A)
        prefix = f"{PREFIX}{name}_" if name else PREFIX  # name "" for the main solver
        self.ksp.setOptionsPrefix(prefix)
        # Options go into PETSc's global database only for this setFromOptions, then out again,
        # so one scene's choices never leak into the next solver made in the same process.
        opts = PETSc.Options()
        inserted = {}
        for key, value in _defaults(config.kind, A.getComm().getSize() == 1).items():
            if not opts.hasName(prefix + key):  # PETSC_OPTIONS from the environment wins
                inserted[prefix + key] = value
        for key, value in config.options.items():
            inserted[prefix + key.lstrip("-")] = _option_text(value)
        for key, value in inserted.items():
            opts.setValue(key, value)
        if config.kind == "cg-gamg" and near_nullspace is not None:
            A.setNearNullSpace(near_nullspace)
        self.ksp.setTolerances(rtol=config.rtol, atol=config.atol, max_it=config.max_it)
        try:
            self.ksp.setFromOptions()
            self.ksp.setUp()  # the factor and the multigrid levels read their options here
        except PETSc.Error as exc:  # a bad option, or a factor that fails (CHOLMOD: not positive definite)
            hint = ("the matrix is not positive definite: a body needs [[fixed]] supports unless [time] mode = "
                    "\"dynamic\"" if exc.ierr == 81 else "check [solver] options (PETSc's message is above)")
            raise SolverError(f"{name or 'step'} solver '{config.kind}' could not be set up (PETSc error "
                              f"{exc.ierr}): {hint}") from None
        finally:
            for key in inserted:
                opts.delValue(key)
        self.iterations: list[int] = []

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> int:
        """Solve A x = b; x holds the initial guess (the previous step's answer)."""
        self.ksp.solve(b, x)
        reason = self.ksp.getConvergedReason()
        its = self.ksp.getIterationNumber()
        if reason < 0:
            detail = _factor_detail(self.ksp)
            raise SolverError(
                f"{self.name or 'step'} solve diverged: {_reason_name(reason)}{detail} after {its} "
                f"iterations (solver '{self.config.kind}', rtol {self.config.rtol:g}); try "
                f"[solver] kind = \"cholesky\" or a smaller dt")
        self.iterations.append(its)
        return its

    def destroy(self) -> None:
        self.ksp.destroy()


def _defaults(kind: str, serial: bool) -> dict[str, str]:
    if kind == "cg-gamg":
        # Unsmoothed aggregation with a 0.01 drop threshold: more CG iterations at nu -> 0.5, but
        # sparse coarse operators; measured on the 2:2:1 block, 2 ranks (benchmarks/scaling.py):
        # 78k dofs setup 4.8 -> 0.9 s, step 3.5 -> 1.8 s; 254k dofs 24.8 -> 3.1 s, 14.7 -> 8.2 s.
        return {"ksp_type": "cg", "pc_type": "gamg", "ksp_initial_guess_nonzero": "true",
                "pc_gamg_agg_nsmooths": "0", "pc_gamg_threshold": "0.01",
                "pc_gamg_coarse_eq_limit": "1000", "mg_levels_ksp_type": "chebyshev",
                "mg_levels_pc_type": "jacobi", "mg_levels_esteig_ksp_type": "cg"}
    if kind == "cg-hypre":
        # BoomerAMG with HMIS coarsening, extended+i interpolation (at most 4 entries per row)
        # and strength 0.5, the usual 3-D choice: on the 2:2:1 block at nu = 0.48 its CG
        # iterations go 20 -> 22 from 8k to 78k dofs where GAMG's go 38 -> 54
        # (benchmarks/scaling.py --kind cg-hypre)
        if not PETSc.Sys.hasExternalPackage("hypre"):
            raise SolverError("[solver] kind = \"cg-hypre\" needs PETSc built with hypre; use \"cg-gamg\"")
        return {"ksp_type": "cg", "pc_type": "hypre", "pc_hypre_type": "boomeramg",
                "pc_hypre_boomeramg_strong_threshold": "0.5", "pc_hypre_boomeramg_coarsen_type": "HMIS",
                "pc_hypre_boomeramg_interp_type": "ext+i", "pc_hypre_boomeramg_P_max": "4",
                "ksp_initial_guess_nonzero": "true"}
    if kind == "cg-jacobi":
        return {"ksp_type": "cg", "pc_type": "jacobi", "ksp_initial_guess_nonzero": "true"}
    return {"ksp_type": "preonly", "pc_type": kind, **_factor_package(kind, serial)}


def _factor_package(kind: str, serial: bool) -> dict[str, str]:
    """Which library factors the matrix.

    One rank, Cholesky: CHOLMOD (SuiteSparse). Its supernodal factor of the 15k-dof brain has
    2.4 M entries against MUMPS's 3.1 M, and a pair of triangular solves takes 1.9 ms against
    3.7 ms (benchmarks/solvers.py) -- the solve is most of a dynamic step. Otherwise MUMPS, with
    room to spare: its workspace estimate (ICNTL(14), default +20 %) was seen to fall short
    once in parallel (INFOG(1) = -9 style failure in PCSetUp)."""
    if kind == "cholesky" and serial and PETSc.Sys.hasExternalPackage("suitesparse"):  # CHOLMOD
        return {"pc_factor_mat_solver_type": "cholmod"}
    if PETSc.Sys.hasExternalPackage("mumps"):
        return {"pc_factor_mat_solver_type": "mumps", "mat_mumps_icntl_14": "100"}
    return {}


def _factor_detail(ksp) -> str:
    """MUMPS's own error code, when a factorisation failed."""
    try:
        factor = ksp.getPC().getFactorMatrix()
        return f" (MUMPS INFOG(1) = {factor.getMumpsInfog(1)}, INFOG(2) = {factor.getMumpsInfog(2)})"
    except Exception:  # not a MUMPS factor, or no factor at all
        return ""


def _option_text(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _reason_name(reason: int) -> str:
    names = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"
