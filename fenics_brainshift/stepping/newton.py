"""Settled states of a hyperelastic body: Newton's method with a line search, the consistent
tangent (static_tangent.py: material by UFL, follower fluid load, contact), and load stepping
where a full step does not converge.

The residual is R(u) = f_int(u) - F_ext(u): the internal force of the stored energy, total
Lagrangian on the reference mesh, and gravity plus the fluid load on the current surface
(follower) or the reference one. A step from the last settled state to the loads of time t
is tried whole; if Newton fails (too many iterations, a line search that finds no descent,
an element that inverts: NaN), the step is halved — the loads follow the schedule to the
intermediate time, or, from rest, are scaled by a factor — down to MIN_FRACTION of it.
"""

from __future__ import annotations

import dolfinx.la
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from petsc4py import PETSc

from .. import compat
from ..errors import SolverError
from ..linalg import solve_preconditioned_by
from ..logs import get_logger
from . import contact_verdict
from .contact_preconditioner import ContactPreconditioner
from .exact_contact import FACTOR_KINDS, ExactContactSolve
from .newton_iteration import newton_iterate, round_off_floor
from .solves import Solves
from .state import State
from .static_tangent import StaticTangent
from .tangent import tangent_settings

log = get_logger("newton")
MIN_FRACTION = 1.0 / 1024.0


MAX_KRYLOV = 100  # GMRES iterations before the preconditioner is rebuilt on the current tangent
STALE_KRYLOV = 30  # more than this in a solve: the next one rebuilds it first
STALL_WITH_CONTACT = 1e3  # no descent within 1e-6 of the load counts as converged with contact
MAX_CONTACT_ROUNDS = 30  # augmented-Lagrangian multiplier updates per settled state
# with the skull, the first solve's residual target this many times the settled state's: a multiplier
# update often follows (the contact not yet within its tolerance), and the iterations from there to the
# tight target were lost; where none follows, the state is then solved on to the tight target. An
# atlas's settled states (5 mm brain, 3 mm gap): 5.5 Newton iterations a state against 6.3, the modes
# 0.019 mm apart (benchmarks/results/skull_atlas.md); 1000 saved no more
FIRST_LOOSER = 100.0
WATCHDOG = 10  # with contact: iterations a step taken without descent has to bring |R| below where it was


class NewtonStatic:
    """Settled states of a Model with a hyperelastic material, or of any Model in contact with
    the skull (then also the contact forces' residual and tangent, physics/contact.py)."""

    def __init__(
        self,
        model,
        state: State,
        solves: Solves,
        rtol: float = 1e-9,
        max_iterations: int = 25,
        load_tangent: bool = True,
        contact=None,
    ):
        self.model, self.state, self.solves = model, state, solves
        solves.settings = tangent_settings(solves.settings)
        self.rtol, self.max_iterations = rtol, max_iterations
        V = model.V
        v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
        material = model.hyperelastic if model.nonlinear else model.material  # linear: Newton for the follower load
        self._internal = compat.form(material.internal_force(state.u, v))
        follower_load = load_tangent and model.fluid is not None and model.fluid.follower
        self.tangent = StaticTangent(
            model, state, compat.form(material.tangent(state.u, du, v)), contact, follower_load
        )
        self._R = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self._F, self._du = self._R.duplicate(), fem.Function(V)
        self._K = None  # K with supports: the preconditioner at rest
        self._P = None  # an LU copy of a tangent, when GMRES failed with the factor it had
        self._stale = False  # GMRES needed many iterations with it: rebuild before the next solve
        self._fixed = model.constraints.fixed
        self.contact = contact  # a SkullContact (physics/contact.py) or None
        self._contact_pc = ContactPreconditioner(solves, contact, lambda: self._K, self._fixed) if contact else None
        self._exact: ExactContactSolve | None = None  # K's factor and the pressed nodes exactly (linear body)
        self.contact_rounds = 0  # multiplier updates over the run (as the time steppers count them)
        self.iterations = 0  # Newton iterations of the last solve
        self.history: list[float] = []  # residual norms of the last Newton solve
        self.cuts = 0  # load steps halved, over the run
        self._t_settled: float | None = None
        self._floor = 0.0  # |R| round-off leaves (newton_iteration.round_off_floor), with K
        self._settled = contact_verdict.SettledMeasure(contact.tolerance, model.comm) if contact else None
        self._loads = (0.0, 1.0)  # (t, factor) of the Newton solve under way

    def setup(self) -> None:
        """The preconditioner at rest (a factor of K, or AMG), reused by every Newton step."""
        if self._K is None:
            self._preconditioner_at_rest()

    # -- one Newton solve -----------------------------------------------------------------------
    def _residual(self, t: float, factor: float) -> float:
        """R = f_int(u) - factor F_ext(t, u) into self._R (zero at fixed dofs); returns |R|."""
        u = self.state.u
        try:
            self.model.load_into(t, self._F, u)
        except SolverError:  # no fluid level for this shape (a container iterate gone wild)
            return np.inf
        if self.tangent.K0 is not None:  # a linear material: K u, one product (assembling the form took 3x as long)
            self.tangent.K0.mult(compat.petsc_vec(u), self._R)
        else:
            with self._R.localForm() as local:
                local.set(0.0)
            assemble_vector(self._R, self._internal)
            self._R.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self._R.axpy(-factor, self._F)
        if self.contact is not None:  # the skull's reaction: not scaled with the loads
            self._R.axpy(-1.0, self.contact.assemble(u))
        self.model.constraints.vector(self._R)
        self._load_norm = factor * self._F.norm() + self.model.growth_scale(t)
        norm = self._R.norm()
        return norm if np.isfinite(norm) else np.inf

    def _preconditioner_at_rest(self) -> None:
        """The factor (or AMG) of K with supports, built once; with contact, of K and the
        stiffness of the nodes touching the skull at rest (they may carry the body: K alone
        can be singular)."""
        self._K = self.model.assemble(self.model.stiffness_form(), with_bcs=True)
        self._floor = round_off_floor(self._K, self.model.cell_size())
        if self.contact is not None and not (self._exact_possible() and not self.contact.pressing(self.state.u)):
            self._contact_pc.rebuild(self.contact.tangent_blocks(self.state.u))
        else:
            self.solves.reset(self._K)
            self._start_exact()
        self.solves.solver.ksp.setTolerances(max_it=MAX_KRYLOV)

    def _exact_possible(self) -> bool:
        """Can Newton's solves be preconditioned exactly for K and the contact (exact_contact.py)?
        A linear body (K is its stiffness), factored (not AMG), in contact with the skull."""
        return self.contact is not None and not self.model.nonlinear and self.solves.settings["kind"] in FACTOR_KINDS

    def _start_exact(self) -> None:
        """The solver's factor is K's own: from now on every solve is preconditioned exactly."""
        if self._exact_possible():
            if self._exact is not None:
                self._exact.destroy()
            self._exact = ExactContactSolve(self.solves, self.contact, self._fixed, MAX_KRYLOV)

    def adopt_preconditioner(self, K: PETSc.Mat) -> None:
        """Take over K with supports, already factored (or AMG'd) by this solver's Solves for a
        contact-free solve: the preconditioner at rest without building it again (the 5 mm
        brain's Cholesky factor takes 1.2 s). Only the Krylov method changes."""
        self._K = K
        self._floor = round_off_floor(K, self.model.cell_size())
        ksp = self.solves.solver.ksp
        options = self.solves.settings["options"]
        ksp.setType(options["ksp_type"])
        ksp.setPCSide(PETSc.PC.Side.RIGHT if options["ksp_pc_side"] == "right" else PETSc.PC.Side.LEFT)
        ksp.setTolerances(max_it=MAX_KRYLOV)
        self._start_exact()

    def _preconditioner_now(self, A: PETSc.Mat) -> None:
        """An LU factor of the current full tangent A (GMRES slowed down with the one it had)."""
        log.debug("  Newton: LU factor of the current tangent")
        settings, self.solves.settings = self.solves.settings, {**self.solves.settings, "kind": "lu"}
        old, self._P = self._P, A.convert("aij", PETSc.Mat())  # a scalar copy (out=None converts A in place)
        try:
            self.solves.reset(self._P)
        finally:
            self.solves.settings = settings  # a contact rebuild factors by the scene's kind again
        if old is not None:
            old.destroy()
        self.solves.solver.ksp.setTolerances(max_it=MAX_KRYLOV)
        self._stale = False

    def _refreshed_preconditioner(self, A: PETSc.Mat) -> None:
        """GMRES slowed down: a linear body in contact gets a new factor (by the scene's kind:
        Cholesky, or AMG) of K and the contact stiffness of the nodes pressed now, since the
        nodes pressed after the last factor are what slowed it; it stays symmetric, cheaper
        than an LU of the whole tangent (docs/performance.md). Otherwise an LU factor of the
        current tangent (a hyperelastic body's tangent is not K's)."""
        if self.contact is not None and not self.model.nonlinear:
            log.debug("  Newton: a factor of K and the contact stiffness now")
            self._contact_pc.rebuild(self.contact.tangent_blocks(self.state.u))
            self._stale = False
        else:
            self._preconditioner_now(A)

    def _solve_step(self, factor: float, t: float, forcing: float) -> None:
        """du = -K_T^-1 R to the relative tolerance ``forcing``, by GMRES on the full tangent."""
        if self._K is None:
            self._preconditioner_at_rest()
        if self._exact is not None and self._exact.factored is not self.solves.solver:
            self._start_exact()  # K was factored anew
        if self._exact is not None:  # the tangent as an action: flexible GMRES only multiplies by it
            du = compat.petsc_vec(self._du)
            action = self.tangent.action(self._K, factor)
            self._exact.prepare(self.tangent.contact_blocks)
            self._exact(action, self._R, du, forcing, t, lambda: self.tangent.matrix(factor))
            du.scale(-1.0)
            return
        A = self.tangent.matrix(factor)
        if self._stale:
            self._refreshed_preconditioner(A)
        du = compat.petsc_vec(self._du)
        for attempt in range(2):
            if attempt == 1:  # GMRES did not converge: a factor of this very tangent
                self._preconditioner_now(A)
            self.solves.operate_with(A)
            self.solves.solver.ksp.setTolerances(rtol=forcing)
            du.set(0.0)
            try:
                # (a factor with the pressed nodes only once GMRES slows down: from rest the
                # pressed set grows every iteration; docs/performance.md)
                self._stale = self.solves(self._R, du, t) > STALE_KRYLOV
                du.scale(-1.0)
                return
            except SolverError:
                if attempt == 1:
                    raise

    def _newton(self, t: float, factor: float) -> bool:
        """Newton from the current state to the loads (t, factor); False if it failed (the
        state is then wherever it stopped: the caller restores it)."""
        self._loads = (t, factor)
        converged, self.history = newton_iterate(
            self.state.u,
            self._du,
            lambda: self._residual(t, factor),
            lambda forcing: self._solve_step(factor, t, forcing),
            lambda: max(self._load_norm, self._floor / self.rtol),
            self.rtol,
            self.solves.settings["rtol"],
            self.max_iterations,
            *self._globalisation(),
        )
        self.iterations = len(self.history) - 1
        return converged

    def _globalisation(self) -> tuple:
        """(stall, watchdog, step_limit, immaterial) of newton_iterate: with contact, round-off
        at the kink counts as converged, and so does, where Newton would fail, a state whose step
        is tiny (contact_verdict); a step without descent may be taken up to the first node's
        contact; without contact, none of these."""
        if self.contact is None:
            return 1.0, 0, None, None
        return (
            STALL_WITH_CONTACT,
            WATCHDOG,
            lambda: self.contact.step_limit(self.state.u, self._du),
            self._immaterial,
        )

    def _immaterial(self) -> bool:
        """Is Newton's step from here (into du; newton_iterate keeps its own) tiny (contact_verdict)?"""
        try:
            self._solve_step(self._loads[1], self._loads[0], self.solves.settings["rtol"])
        except SolverError:
            return False
        return self._settled(compat.petsc_vec(self._du))

    @property
    def settled_measure(self) -> contact_verdict.SettledMeasure | None:
        """What let Newton solves that would have failed settle (their step tiny), with contact."""
        return self._settled

    # -- a settled state, with load stepping ------------------------------------------------------
    def forget_settled(self) -> None:
        """The next settled state grows its loads from zero (the state must be at rest): for
        loads that changed otherwise than in time (a calibration's parameters)."""
        self._t_settled = None

    def solve_from_here(self, t: float) -> bool:
        """Newton from the current state to the loads at time t, no load steps and no multiplier
        updates; False if it fails (the state restored). For a caller that steps the loads
        itself (a calibration's parameter continuation: fit/forward.py)."""
        saved = self.state.u.x.array.copy()
        if self._newton(t, 1.0):
            self._t_settled, self.state.t = t, t
            return True
        self.state.u.x.array[:] = saved
        return False

    def solve(self, t: float) -> int:
        """The settled state for the loads at time t, from the last one (or from rest: the loads
        then grow from zero). With skull contact, the multipliers are updated after each
        solve until the deepest node is within the tolerance; the first solve stops at
        FIRST_LOOSER times the target, and is taken on to the target if no update follows.
        Returns the Newton iterations of the last load step."""
        tight = self.rtol
        if self.contact is not None:  # first to a looser residual: a multiplier update may follow
            self.rtol = tight * FIRST_LOOSER
        try:
            iterations = self._solve_loads(t)
        finally:
            self.rtol = tight
        rounds, tightened = 0, self.contact is None
        while self.contact is not None:
            if self.contact.violation(self.state.u) <= self.contact.tolerance:
                if tightened:
                    break
                iterations, tightened = self._solve_loads(t), True
                continue
            if rounds == MAX_CONTACT_ROUNDS:
                raise SolverError(
                    f"skull contact at t = {t:g} s: the contact conditions are still off by "
                    f"{self.contact.violation(self.state.u) * 1e3:.3g} mm after "
                    f"{MAX_CONTACT_ROUNDS} multiplier updates; raise [skull] tolerance or check "
                    f"that the loads can be carried by the skull"
                )
            before = self.contact.multipliers.copy()
            self.contact.update_multipliers(self.state.u)
            rounds += 1
            self.contact_rounds += 1
            iterations, tightened = self._solve_loads(t, before), True
        return iterations

    def _linear_start(self, t: float) -> bool:
        """A hyperelastic body that shrinks or swells, from rest: Newton from the linear answer
        K0 u = F(t) + the linearised growth load, True if it converged. (From rest the growth's
        prestress, of the order of mu for a nearly incompressible brain shrinking by 2 %, is in
        the tangent though the shrinking releases it; the whole brain took 12 damped Newton
        iterations and two LU factors, 6.6x the time without swelling, and 6 from the linear
        answer: benchmarks/results/swelling.md.) The factor of K at rest preconditions CG."""
        u = self.state.u
        rhs = self._F.duplicate()
        try:
            self.model.load_into(t, rhs, u)
            rhs.axpy(1.0, self.model.growth_load(t))
            self.model.constraints.vector(rhs)
            solve_preconditioned_by(
                self._K, self.solves.solver, rhs, compat.petsc_vec(u), rtol=1e-10, name="linear start"
            )
            self.model.constraints.project_owned(compat.petsc_vec(u))
            u.x.scatter_forward()
            return self._newton(t, 1.0)
        except SolverError:
            return False
        finally:
            rhs.destroy()

    def _solve_loads(self, t: float, multipliers_before: np.ndarray | None = None) -> int:
        """Newton with load stepping to the loads at time t (see solve). From a settled state
        at t itself, after a multiplier update (``multipliers_before``: the ones it settled
        with), the loads are the same: what is stepped is the multipliers' change (a cut of
        the loads would solve the very same problem again)."""
        start, done, step = self._t_settled, 0.0, 1.0
        stepping_multipliers = multipliers_before is not None and start == t
        if stepping_multipliers:
            after = self.contact.multipliers.copy()
        if start is None and self.model.growth is not None and self.model.nonlinear and self.contact is None:
            at_rest = self.state.u.x.array.copy()
            if self._linear_start(t):
                self._t_settled = self.state.t = t
                return self.iterations
            self.state.u.x.array[:] = at_rest  # then the loads grow from zero, as without growth
        while done < 1.0:
            fraction = min(1.0, done + step)
            t_k, factor = (t, fraction) if start is None else (start + fraction * (t - start), 1.0)
            if stepping_multipliers:
                self.contact.multipliers = multipliers_before + fraction * (after - multipliers_before)
            saved = self.state.u.x.array.copy()
            if self._newton(t_k, factor):
                done = fraction
                step = min(2.0 * step, 1.0 - done) if done < 1.0 else step
                continue
            deepest = None  # (where the last try stopped)
            if 0.5 * step < MIN_FRACTION:
                deepest = contact_verdict.deepest(self.contact, self.state.u, self.model.comm)
            self.state.u.x.array[:] = saved
            step *= 0.5
            self.cuts += 1
            if step < MIN_FRACTION:
                what = "the multipliers' update" if stepping_multipliers else "the load step"
                raise SolverError(
                    f"Newton did not converge at t = {t:g} s even with {what} cut to "
                    f"{MIN_FRACTION:g} of it (residual {self.history[-1]:.2e}); the body may have "
                    f"no equilibrium under these loads (a support missing?), or the material "
                    f"lost stability (Saint Venant-Kirchhoff does under strong compression)"
                    + contact_verdict.contact_note(self.contact, deepest)
                )
            log.info(
                "  t=%g s: Newton did not converge; %s cut to %g",
                t,
                "the multipliers' update" if stepping_multipliers else "load step",
                step,
            )
        self._t_settled = t
        self.state.t = t
        return self.iterations

    def destroy(self) -> None:
        for matrix in (self._P, self._K):
            if matrix is not None:
                matrix.destroy()
        self.tangent.destroy()
        if self._contact_pc is not None:
            self._contact_pc.destroy()
        if self._exact is not None:
            self._exact.destroy()
        self.solves.destroy()
