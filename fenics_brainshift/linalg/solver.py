"""Linear solvers: a PETSc KSP per matrix, under the ``brainshift_`` options prefix.

Any PETSc option can be given in the scene (``[solver] options = { ksp_monitor = true }``)
or in the environment (``PETSC_OPTIONS="-brainshift_ksp_view"``). Precedence: the scene's
options, then the environment, then this module's defaults for the chosen ``kind``.
The step (or static) solver reads ``-brainshift_*``; the one-off mass solve for the initial
acceleration reads ``-brainshift_mass_*``. Bad settings (an option PETSc cannot parse or
does not use, a kind this PETSc lacks) are InputError; a solve or factor that fails is
SolverError.
"""

from __future__ import annotations

from petsc4py import PETSc

from ..errors import InputError, SolverError
from .options import option_text, options_in_database, unused

PREFIX = "brainshift_"
KINDS = ("cg-gamg", "cg-hypre", "cg-jacobi", "cholesky", "lu")


class LinearSolver:
    """A KSP for one fixed matrix, set up once and reused for every right-hand side.

    kind: "cg-gamg" (CG + aggregation AMG; give ``near_nullspace``, see nullspace.py),
    "cg-hypre" (CG + BoomerAMG), "cg-jacobi", "cholesky" or "lu" (factor kept); rtol, atol,
    max_it: Krylov tolerances; options: PETSc options (names without the prefix); name: ""
    for the main solver, else a sub-prefix such as "mass"."""

    def __init__(
        self,
        A: PETSc.Mat,
        kind: str = "cg-gamg",
        rtol: float = 1e-10,
        atol: float = 1e-30,
        max_it: int = 5000,
        options: dict | None = None,
        name: str = "",
        near_nullspace=None,
    ):
        if kind not in KINDS:
            raise InputError(f"[solver] kind must be one of {', '.join(KINDS)} (got {kind!r})")
        self.kind, self.rtol, self.name = kind, rtol, name
        self.ksp = PETSc.KSP().create(A.getComm())
        self.ksp.setOperators(A)
        prefix = f"{PREFIX}{name}_" if name else PREFIX
        self.ksp.setOptionsPrefix(prefix)
        database = PETSc.Options()
        inserted = {
            prefix + key: value
            for key, value in _defaults(kind, A.getComm().getSize() == 1).items()
            if not database.hasName(prefix + key)
        }  # PETSC_OPTIONS from the environment wins
        given = {prefix + key.lstrip("-"): option_text(value) for key, value in (options or {}).items()}
        inserted.update(given)
        if kind == "cg-gamg" and near_nullspace is not None:
            A.setNearNullSpace(near_nullspace)
        self.ksp.setTolerances(rtol=rtol, atol=atol, max_it=max_it)
        with options_in_database(inserted):
            try:
                self.ksp.setFromOptions()
            except PETSc.Error as exc:  # a value PETSc cannot parse
                raise InputError(
                    f"[solver] options: PETSc could not read them (error {exc.ierr}, its message is "
                    f"above); check the values of {', '.join(sorted(options or {})) or 'PETSC_OPTIONS'}"
                ) from None
            try:
                self.ksp.setUp()  # the factor and the multigrid levels read their options here
            except PETSc.Error as exc:  # a factor that fails (CHOLMOD: not positive definite)
                if exc.ierr == 92:  # PETSC_ERR_MISSING_FACTOR: a package this PETSc was not built with
                    raise InputError(
                        f"[solver] options: PETSc has no factor package for them (error 92, its message "
                        f'is above); leave pc_factor_mat_solver_type to kind = "{kind}"'
                    ) from None
                hint = (
                    "the matrix is not positive definite: a body needs [[fixed]] supports unless [time] mode = "
                    '"dynamic"'
                    if exc.ierr == 81
                    else "check [solver] options (PETSc's message is above)"
                )
                raise SolverError(
                    f"{name or 'step'} solver '{kind}' could not be set up (PETSc error {exc.ierr}): {hint}"
                ) from None
            left = unused(given)
        if left:
            names = ", ".join(k[len(prefix) :] for k in left)
            raise InputError(
                f'[solver] options: PETSc used none of {names} with kind = "{kind}" (misspelt, or an '
                f"option of another solver kind); see `-{prefix}help` for the names it knows"
            )
        self.iterations: list[int] = []

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> int:
        """Solve A x = b; x holds the initial guess (the previous step's answer). Returns the
        iteration count; a diverged solve is a SolverError with PETSc's reason."""
        self.ksp.solve(b, x)
        reason = self.ksp.getConvergedReason()
        its = self.ksp.getIterationNumber()
        if reason < 0:
            detail = _factor_detail(self.ksp)
            raise SolverError(
                f"{self.name or 'step'} solve diverged: {_reason_name(reason)}{detail} after {its} "
                f"iterations (solver '{self.kind}', rtol {self.rtol:g}); try "
                f'[solver] kind = "cholesky" or a smaller dt'
            )
        self.iterations.append(its)
        return its

    def destroy(self) -> None:
        self.ksp.destroy()


class _PreconditionerOf:
    """A python PC that applies another solver's preconditioner (its factor, or its AMG cycle)."""

    def __init__(self, pc: PETSc.PC):
        self.pc = pc

    def apply(self, _pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.pc.apply(x, y)


def solve_preconditioned_by(
    A: PETSc.Mat,
    donor: LinearSolver,
    b: PETSc.Vec,
    x: PETSc.Vec,
    rtol: float = 1e-12,
    max_it: int = 1000,
    name: str = "",
) -> int:
    """CG on A x = b, preconditioned by ``donor``'s preconditioner (no new factor or AMG setup).
    Pays when A is spectrally close to the donor's matrix, e.g. M + w K against c M + K."""
    ksp = PETSc.KSP().create(A.getComm())
    try:
        ksp.setOperators(A)
        ksp.setType("cg")
        pc = ksp.getPC()
        pc.setType("python")
        pc.setPythonContext(_PreconditionerOf(donor.ksp.getPC()))
        ksp.setTolerances(rtol=rtol, atol=1e-300, max_it=max_it)
        ksp.solve(b, x)
        reason, its = ksp.getConvergedReason(), ksp.getIterationNumber()
        if reason < 0:
            raise SolverError(
                f"{name} solve diverged: {_reason_name(reason)} after {its} iterations "
                f"(CG preconditioned by the step solver '{donor.kind}')"
            )
        return its
    finally:
        ksp.destroy()


def has_package(name: str) -> bool:
    """Was this PETSc built with the external package (hypre, mumps, cholmod, ...)?"""
    return bool(PETSc.Sys.hasExternalPackage(name))


def _defaults(kind: str, serial: bool) -> dict[str, str]:
    if kind == "cg-gamg":
        # Unsmoothed aggregation with a 0.01 drop threshold: more CG iterations at nu -> 0.5, but
        # sparse coarse operators, so faster setups and steps (docs/performance.md, Scaling)
        return {
            "ksp_type": "cg",
            "pc_type": "gamg",
            "ksp_initial_guess_nonzero": "true",
            "pc_gamg_agg_nsmooths": "0",
            "pc_gamg_threshold": "0.01",
            "pc_gamg_coarse_eq_limit": "1000",
            "mg_levels_ksp_type": "chebyshev",
            "mg_levels_pc_type": "jacobi",
            "mg_levels_esteig_ksp_type": "cg",
        }
    if kind == "cg-hypre":
        # BoomerAMG with HMIS coarsening, extended+i interpolation (at most 4 entries per row)
        # and strength 0.5, the usual 3-D choice: CG iterations nearly flat with the mesh size
        # (docs/performance.md, Scaling)
        if not has_package("hypre"):
            raise InputError(
                '[solver] kind = "cg-hypre" needs PETSc built with hypre, which this one is not; use "cg-gamg"'
            )
        return {
            "ksp_type": "cg",
            "pc_type": "hypre",
            "pc_hypre_type": "boomeramg",
            "pc_hypre_boomeramg_strong_threshold": "0.5",
            "pc_hypre_boomeramg_coarsen_type": "HMIS",
            "pc_hypre_boomeramg_interp_type": "ext+i",
            "pc_hypre_boomeramg_P_max": "4",
            "ksp_initial_guess_nonzero": "true",
        }
    if kind == "cg-jacobi":
        return {"ksp_type": "cg", "pc_type": "jacobi", "ksp_initial_guess_nonzero": "true"}
    return {"ksp_type": "preonly", "pc_type": kind, **_factor_package(kind, serial)}


def _factor_package(kind: str, serial: bool) -> dict[str, str]:
    """Which library factors the matrix.

    One rank, Cholesky: CHOLMOD (SuiteSparse), whose solves are about half MUMPS's on the
    brain (benchmarks/results/step_parts.md). Otherwise MUMPS, with workspace to spare
    (ICNTL(14) = 100 %: the default +20 % was seen to fall short in parallel)."""
    # PETSc 3.18 (Debian 12) lists SuiteSparse as "suitesparse", 3.22 (Debian 13) by its parts:
    # asking for "suitesparse" alone sent Debian 13 to MUMPS, 1.6x slower per brain step
    if kind == "cholesky" and serial and (has_package("cholmod") or has_package("suitesparse")):
        return {"pc_factor_mat_solver_type": "cholmod"}
    if has_package("mumps"):
        return {"pc_factor_mat_solver_type": "mumps", "mat_mumps_icntl_14": "100"}
    return {}


def _factor_detail(ksp) -> str:
    """MUMPS's own error code, when a factorisation failed."""
    try:
        factor = ksp.getPC().getFactorMatrix()
        return f" (MUMPS INFOG(1) = {factor.getMumpsInfog(1)}, INFOG(2) = {factor.getMumpsInfog(2)})"
    except Exception:  # not a MUMPS factor, or no factor at all
        return ""


def _reason_name(reason: int) -> str:
    names = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"
