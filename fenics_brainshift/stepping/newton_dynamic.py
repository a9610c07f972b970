"""Time steps of a hyperelastic body: Newmark / generalized-alpha with Newton in every step.

With C = a M + b K0 (Rayleigh, K0 the stiffness at rest) the step's residual in the
increment du is

    R(du) = cM M du + cb K0 du + M w_m + K0 (w_k - u_n) + (1 - af) f_int(u_n + du) + af f_int(u_n)
            - (1 - af) F(t_{n+1}, u_n + du) - af F_n,

cM, cb and w_m, w_k from integrators.py (for a linear material it reduces to the linear step),
and its tangent cM M + cb K0 + (1 - af) (K_T - dF/du). Newton (newton.py: line search, forcing)
solves it with GMRES preconditioned by the factor of the linear effective matrix, made once.
The energy guard uses the stored energy of the material in place of u.K u / 2; for a nonlinear
material Newmark's balance is no longer exact, it holds to O(dt^2) (tests/test_hyperelastic.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from mpi4py import MPI
from petsc4py import PETSc

from .. import compat
from ..errors import SolverError
from ..logs import get_logger
from ..physics.load_tangent import add_load_tangent
from ..physics.surface import surface_facets
from .contact_preconditioner import ContactPreconditioner
from .dynamic import DynamicStepper
from .lagged_contact import LaggedContact
from .newton import MAX_CONTACT_ROUNDS, STALL_WITH_CONTACT
from .newton_iteration import newton_iterate, round_off_floor
from .tangent import reassemble, tangent_settings, tangent_type

log = get_logger("newton")
MAX_CUTS = 5  # a failed step is cut in halves, down to dt / 32
# a linear body's step with contact by the fixed point, tried twice, else Newton: on the 5 mm
# brain a Newton step with contact costs as much as ~100 of its iterations
FIXED_POINT_ITERATIONS = 80
# ... to this change relative to |u| while nodes press: the penalty turns a displacement error
# into a force error k dx; 1e-4 (the follower load's default) left the floor's reaction 0.5 % off
# (tests/test_contact.py, a piece cut free, on 2 ranks); at 1e-5 the 5 mm drain ends within 0.1 %
# of the skull's force and 0.2 um of the shift at 1e-6, with 40 % fewer solves
FIXED_POINT_TOLERANCE = 1e-5


class NewtonDynamicStepper(DynamicStepper):
    """DynamicStepper for a hyperelastic Model, or any Model in contact with the skull: the
    same operators (M, K0, the linear effective matrix as preconditioner), a Newton iteration
    per step. The contact forces (physics/contact.py) join the external loads, at the step's
    end like them; their multipliers are updated, and the step solved again, until the
    deepest node is within the tolerance."""

    rtol = 1e-9  # |R| relative to the step's loads
    max_iterations = 25

    def __init__(self, model, state, integrator, damping, solves, follower_tolerance: float = 1e-4, contact=None):
        self.contact = contact  # a SkullContact or None (set first: setup uses it)
        self._contact_pc = None  # the factor with the pressed nodes (contact_preconditioner.py)
        self._blocks = None  # the contact's tangent blocks at the current iterate
        super().__init__(model, state, integrator, damping, solves, follower_tolerance)
        solves.settings = tangent_settings(solves.settings)
        V = model.V
        self._x = fem.Function(V)  # u_n + du, the configuration of the current iterate
        v, w = ufl.TestFunction(V), ufl.TrialFunction(V)
        material = model.constitutive
        self._internal = compat.form(material.internal_force(self._x, v))
        # the step's tangent as one form: the blocks are assembled once, with no matrix sums
        self._coefficient = {part: fem.Constant(model.mesh, PETSc.ScalarType(0.0)) for part in ("f", "M", "K0")}
        tangent = (
            self._coefficient["f"] * material.tangent(self._x, w, v) + self._coefficient["K0"] * model.stiffness_form()
        )
        if not model.lumped:  # a lumped mass is added as its diagonal
            tangent += self._coefficient["M"] * model.mass_form()
        self._tangent = compat.form(tangent)
        if model.nonlinear:
            energy = material.energy_density(material.deformation_gradient(state.u))
            dx = ufl.dx(metadata={"quadrature_degree": material.quadrature_degree})
        else:
            energy, dx = 0.5 * ufl.inner(material.stress(state.u), material.strain(state.u)), ufl.dx
        self._stored = compat.form(energy * dx)
        self._f_int_old, self._f, self._R = (self._F.duplicate() for _ in range(3))
        self._J = None
        # a linear material's part of the tangent, cM M + cK K0, is the same every iteration of
        # every step of one dt: copied (3 ms on the 5 mm brain) instead of assembled (51 ms)
        self._J_fixed, self._J_fixed_key = None, None
        self._update = fem.Function(V)  # a Newton update of du
        self._fixed = model.constraints.fixed
        if contact is not None:
            self._contact_pc = ContactPreconditioner(solves, contact, lambda: self.A, self._fixed)
        self.newton_history: list[float] = []
        self._floor = None  # |R| round-off leaves (newton_iteration.round_off_floor)
        self.cuts = 0  # time steps cut in halves, over the run
        self.contact_rounds = 0  # multiplier updates over the run
        self.fixed_point_steps = 0  # steps a linear body with the skull took by the fixed point
        self._fixed_point_run = False  # the last step was one of them
        # Newmark's balance holds to O(dt^2) here, not exactly: the guard (for a step that blows
        # up, whose energy grows without bound) allows 10 % of the energy scale
        self.energy.tolerance = max(self.energy.tolerance, 0.1)

    def _internal_force(self, out: PETSc.Vec) -> PETSc.Vec:
        with out.localForm() as local:
            local.set(0.0)
        assemble_vector(out, self._internal)
        out.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return out

    def _remove_due_cells(self) -> bool:
        removed = super()._remove_due_cells()
        if removed and self.contact is not None:  # the cut faces meet the skull too
            self.contact.set_surface(surface_facets(self.model.V, self.model.tissue.present))
        return removed

    def _factor_step_matrix(self) -> None:
        """With contact, the factor holds the nodes pressed now (the brain may rest on the skull)."""
        if self.contact is None:
            return super()._factor_step_matrix()
        cM, _ = self.integrator.effective_coefficients(self.damping_a, self.damping_b)
        self.contact.for_time_step(cM, self.model.density)
        self._contact_pc.forget()  # (after a resection its base, A, is new)
        self._contact_pc.rebuild(self.contact.tangent_blocks(self.state.u, self.integrator.load_weights()[0]))

    def _current_load(self, out) -> None:
        super()._current_load(out)
        if self.contact is not None:  # the skull's reaction is a load like the others
            cM, _ = self.integrator.effective_coefficients(self.damping_a, self.damping_b)
            self.contact.for_time_step(cM, self.model.density)
            out.axpy(1.0, self.contact.assemble(self.state.u))

    def _internal_force_of_state(self, out) -> None:
        """f_int(u_n) of the material (K0 u_n only for a linear one)."""
        self._x.x.array[:] = self.state.u.x.array
        self._internal_force(out)

    def _forget_fixed_tangent(self) -> None:
        if self._J_fixed is not None:
            self._J_fixed.destroy()
        self._J_fixed, self._J_fixed_key = None, None

    def _build_operators(self) -> None:
        super()._build_operators()
        self._forget_fixed_tangent()  # after a resection the tissue, and so K0 and M, changed
        self._x.x.array[:] = self.state.u.x.array
        self._internal_force(self._f_int_old)
        self.solves.solver.ksp.setTolerances(max_it=200)

    def step(self) -> int:
        """One time step; if Newton fails in it, the step is cut in halves (down to
        1/2**MAX_CUTS of dt), each solved the same way. Returns the Newton iterations (of the
        last sub-step)."""
        self._resect()
        t_new = (self.steps_taken + 1) * self.integrator.dt  # not a running sum: no drift in t
        iterations = self._fixed_point_step(t_new)
        if iterations is None:
            iterations = self._advance(t_new, 0)
        self.steps_taken += 1
        self._energy_check()
        return iterations

    def _fixed_point_step(self, t_new: float) -> int | None:
        """A linear body takes the contact-free stepper's step, with the skull's reaction as one
        more load of its fixed point (lagged_contact.py): triangular solves with the factor of
        A and the pressed nodes' stiffness, no tangent, no Krylov method. The lagged penalty
        is a good guess only for nodes in that matrix, so the nodes pressed at the start, and
        those pressed where a try gave up after FIXED_POINT_ITERATIONS, are put in it first
        (a low-rank update of the factor: contact_preconditioner.py). After two tries Newton
        takes the step (None). Returns the solver's iterations, or None."""
        contact, pc = self.contact, self._contact_pc
        if contact is None or self.model.nonlinear:
            return None
        st, settle = self.state, self.settle
        w_new = self.integrator.load_weights()[0]
        self._x.x.array[:] = st.u.x.array + self.du.x.array  # where the last step's increment leads
        if pc.changed(contact.pressed_dofs(self._x)):
            pc.adjust(contact.tangent_blocks(self._x, w_new, engaged=True))
            self._fixed_point_run = False
        saved = (st.snapshot(), self.du.x.array.copy(), self._F_old.copy(), self.energy.work)
        limits = settle.max_iterations, settle.tolerance
        settle.max_iterations = FIXED_POINT_ITERATIONS
        if contact.pressing(st.u):  # else the contact-free step's tolerance: its very answer while nothing presses
            settle.tolerance = min(settle.tolerance, FIXED_POINT_TOLERANCE)
        try:
            for attempt in range(2):
                reaction = LaggedContact(contact, pc, w_new)
                try:
                    its = self._linear_step(
                        t_new, same_problem=self._fixed_point_run, solve=pc.solve, reaction=reaction
                    )
                except SolverError:  # did not settle: with the nodes pressed where it stopped?
                    self._x.x.array[:] = st.u.x.array + self.du.x.array
                    pressed = contact.pressed_dofs(self._x)
                    self._undo(saved)
                    self._fixed_point_run = False
                    if attempt == 1 or not pc.changed(pressed):
                        break
                    pc.adjust(contact.tangent_blocks(self._x, w_new, engaged=True))
                    continue
                self.contact_rounds += reaction.rounds
                self.fixed_point_steps += 1
                self._fixed_point_run = True
                self.K.mult(compat.petsc_vec(st.u), self._f_int_old)  # Newton may take the next step: f_int(u_n)
                return its
        finally:
            settle.max_iterations, settle.tolerance = limits
        log.debug("  t=%g s: the fixed point with contact did not settle; Newton takes the step", t_new)
        return None

    def _undo(self, saved) -> None:
        """Back to the start of the step (a fixed point that failed)."""
        snapshot, du, F_old, work = saved
        self.state.restore(snapshot)
        self.du.x.array[:] = du
        F_old.copy(self._F_old)
        self.energy.work = work
        self._K_wk_of_step = -1

    def _advance(self, t_new: float, depth: int) -> int:
        """From the current state to t_new, halving the interval where Newton fails."""
        st, full = self.state, self.integrator
        saved = (st.snapshot(), self.du.x.array.copy(), self._F_old.copy(), self._f_int_old.copy(), self.energy.work)
        dt = t_new - st.t
        self.integrator = replace(full, dt=dt)
        try:
            return self._newton_step(t_new)
        except SolverError:
            if depth == MAX_CUTS:
                raise
        finally:
            self.integrator = full
        (snapshot, du, F_old, f_int_old, work) = saved  # back to the start, two halves
        st.restore(snapshot)
        self.du.x.array[:] = 0.5 * du
        F_old.copy(self._F_old)
        f_int_old.copy(self._f_int_old)
        self.energy.work = work
        self.cuts += 1
        log.info("  t=%g s: Newton did not converge in the step of %g s; cut in halves", t_new, dt)
        self._advance(t_new - 0.5 * dt, depth + 1)
        return self._advance(t_new, depth + 1)

    def _newton_step(self, t_new: float) -> int:
        """Newton for the increment du of one step of self.integrator to t_new."""
        st, ti = self.state, self.integrator
        w_new, w_old = ti.load_weights()
        am_f = w_new  # 1 - alpha_f
        cM, cK = ti.effective_coefficients(self.damping_a, self.damping_b)
        cb = cK - am_f  # the K0 part of the damping's effective coefficient
        if self.contact is not None:
            self.contact.for_time_step(cM, self.model.density)
        self._rhs_vectors()
        base = self._base  # M w_m + K0 (w_k - u_n) + af f_int(u_n) - af F_n
        self.M.mult(self._wm, base)
        self._tmp.array[:] = self._wk.array_r - compat.petsc_vec(st.u).array_r
        self.K.mult(self._tmp, self._R)
        base.axpy(1.0, self._R)
        base.axpy(w_old, self._f_int_old)
        base.axpy(-w_old, self._F_old)
        du, fluid = compat.petsc_vec(self.du), self.model.fluid
        follower = fluid is not None and fluid.follower

        def residual() -> float:
            self._x.x.array[:] = st.u.x.array + self.du.x.array
            try:
                self.model.load_into(t_new, self._F, self._x if follower else st.u)
            except SolverError:  # no fluid level for this shape
                return np.inf
            if self.contact is not None:
                self._F.axpy(1.0, self.contact.assemble(self._x))
            self._internal_force(self._f)
            R = self._R
            base.copy(R)
            self.M.mult(du, self._tmp)
            R.axpy(cM, self._tmp)
            self.K.mult(du, self._tmp)
            R.axpy(cb, self._tmp)
            R.axpy(am_f, self._f)
            R.axpy(-am_f, self._F)
            self.model.constraints.vector(R)
            norm = R.norm()
            return norm if np.isfinite(norm) else np.inf

        def solve(forcing: float) -> None:
            J = self._tangent_matrix(cM, cb, am_f, follower)
            update = compat.petsc_vec(self._update)
            update.set(0.0)
            self.solves.operate_with(J)
            self.solves.solver.ksp.setTolerances(rtol=forcing)
            iterations = self.solves(self._R, update, t_new)
            update.scale(-1.0)
            if self._contact_pc is not None:  # slow: a factor with the pressed nodes, if they changed
                self._contact_pc.after_solve(iterations, self._blocks)

        if self._floor is None:  # (K's entries set it: a resection changes it by little)
            self._floor = round_off_floor(self.K, self.model.cell_size())

        def newton() -> bool:
            converged, self.newton_history = newton_iterate(
                self.du,
                self._update,
                residual,
                solve,
                lambda: max(self._F.norm() + self.model.growth_scale(t_new), self._floor / self.rtol),
                self.rtol,
                self.solves.settings["rtol"],
                self.max_iterations,
                STALL_WITH_CONTACT if self.contact is not None else 1.0,
            )
            return converged

        converged, rounds = newton(), 0
        while converged and self.contact is not None and self.contact.violation(self._x) > self.contact.tolerance:
            if rounds == MAX_CONTACT_ROUNDS:
                raise SolverError(
                    f"skull contact at t = {t_new:g} s: the contact conditions are still off by "
                    f"{self.contact.violation(self._x) * 1e3:.3g} mm after "
                    f"{MAX_CONTACT_ROUNDS} multiplier updates"
                )
            self.contact.update_multipliers(self._x)
            rounds += 1
            log.debug(
                "  contact: conditions off by %.3g mm; multipliers updated (%d)",
                self.contact.violation(self._x) * 1e3,
                rounds,
            )
            converged = newton()
        self.contact_rounds += rounds
        if not converged:
            raise SolverError(
                f"Newton did not converge in the time step to t = {t_new:g} s even with the step "
                f"cut to 1/{2**MAX_CUTS} of dt (residual {self.newton_history[-1]:.2e}); reduce "
                f"[time] dt, or check the supports"
            )
        n = st.n_owned
        ti.update(st.u.x.array[:n], st.v.x.array[:n], st.a.x.array[:n], self.du.x.array[:n])
        for f in (st.u, st.v, st.a):
            f.x.scatter_forward()
        self.energy.add_work(0.5 * (du.dot(self._F) + du.dot(self._F_old)))
        self._F.copy(self._F_old)
        self._f.copy(self._f_int_old)
        st.t = t_new
        return len(self.newton_history) - 1

    def _tangent_matrix(self, cM: float, cb: float, am_f: float, follower: bool) -> PETSc.Mat:
        """(1 - af) (K_T - dF/du) + cM M + cb K0 with supports, into the one matrix kept for it."""
        key = (cM, cb, am_f)
        if self._J_fixed is not None and self._J_fixed_key == key:
            J = self._J
            self._J_fixed.copy(J, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        else:
            for part, value in (("f", am_f), ("M", cM), ("K0", cb)):
                self._coefficient[part].value = value
            J = self._J = reassemble(self._J, self._tangent, tangent_type(self.model))
            if self._mass_diagonal is not None:
                self._tmp.array[:] = cM * self._mass_diagonal.array_r
                J.setDiagonal(self._tmp, addv=PETSc.InsertMode.ADD_VALUES)
                J.assemble()
            if not self.model.nonlinear:
                self._forget_fixed_tangent()
                self._J_fixed, self._J_fixed_key = J.copy(), key
        fluid = self.model.fluid
        if follower and fluid.level == fluid.level:
            add_load_tangent(J, fluid.hydro, fluid.level, self._x, -am_f * self.model.load_scale)
        if self.contact is not None:
            self._blocks = self.contact.tangent_blocks(self._x, am_f)
            self.contact.add_tangent(J, self._x, blocks=self._blocks)
        self.model.constraints.matrix(J)
        return J

    def energies(self, K_u=None) -> tuple[float, float]:
        """(kinetic, stored) energy of the current state (J)."""
        kinetic, _ = super().energies(K_u)
        stored = fem.assemble_scalar(self._stored)
        return kinetic, self.model.comm.allreduce(stored, op=MPI.SUM)

    def destroy(self) -> None:
        if self._contact_pc is not None:
            self._contact_pc.destroy()
        self._forget_fixed_tangent()
        if self._J is not None:
            self._J.destroy()
        super().destroy()
