"""Time stepping: Newmark / generalized-alpha on a model, with the energy guard and resection.

The effective matrix and its solver are built once (and again after a resection); each step
costs one right-hand side (a diagonal mass product, and K applied to the state once, shared
with the energy guard), one solve warm-started from the previous increment (per follower
iteration), and the array update of u, v, a.
"""

from __future__ import annotations

import dolfinx.la
from dolfinx import fem

from .. import compat
from ..linalg import LinearSolver, PairProduct, solve_preconditioned_by
from ..logs import get_logger
from .energy import EnergyBalance
from .integrators import TimeIntegrator, initial_stiffness_weight
from .settle import Settle
from .solves import Solves
from .state import State

log = get_logger("stepping")


class DynamicStepper:
    """Advances a State on a Model by one time step at a time.

    integrator: a TimeIntegrator; damping: Rayleigh (a 1/s, b s); solves: the step solver
    (Solves); the guard stops a run whose energy grows (energy.py)."""

    def __init__(
        self,
        model,
        state: State,
        integrator: TimeIntegrator,
        damping: tuple[float, float],
        solves: Solves,
        follower_tolerance: float = 1e-4,
    ):
        self.model, self.state, self.integrator = model, state, integrator
        self.damping_a, self.damping_b = damping
        self.solves = solves
        V = model.V
        self.du = fem.Function(V)
        self._geometry = fem.Function(V)
        # work vectors, allocated once (they own their memory: never wrap a temporary Function)
        self._F = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self._F_old, self._rhs, self._tmp, self._wm, self._wk, self._base, self._K_u, self._K_wk = (
            self._F.duplicate() for _ in range(8)
        )
        self._K_wk_of_step = -1
        self.settle = Settle(self._F, model.constraints, model.fluid, follower_tolerance)
        newmark = integrator.alpha_m == 0.0 and integrator.alpha_f == 0.0
        self.energy = EnergyBalance(tolerance=1e-2 if newmark else 1.0)
        self.check_energy = True
        self.steps_taken = 0
        self.removals: list[dict] = []  # what each resection took, for the summary
        self.M = self.K = self.A = self._pair = None

    # -- setup --------------------------------------------------------------------------------
    def setup(self) -> None:
        """Remove what is due at t = 0, build the operators, start in equilibrium."""
        self._remove_due_cells()
        self._build_operators()
        self._initial_acceleration()
        self._energy_check()

    def _build_operators(self) -> None:
        """M, K, the effective matrix and its solver, and F_n. Once, and again after a
        resection (the matrices change; the state u, v, a carries over: _resect)."""
        m = self.model
        cm, ck = self.integrator.effective_coefficients(self.damping_a, self.damping_b)
        self.M = m.mass_matrix()  # M and K only ever multiply vectors
        self.K = m.assemble(m.stiffness_form(), with_bcs=False)
        self.A = m.assemble(m.combined(cm, ck), with_bcs=True)
        self._mass_diagonal = self.M.getDiagonal() if m.lumped else None
        self._pair = PairProduct(self.K)
        self._K_wk_of_step = -1  # K w_k is cached for the state after this many steps
        self._factor_step_matrix()
        self._current_load(self._F_old)

    def _current_load(self, out) -> None:
        """F_n, the loads on the current state, into out."""
        self.model.load_into(self.state.t, out, self.state.u)

    def _internal_force_of_state(self, out) -> None:
        """f_int(u_n) into out: K u_n for a linear material."""
        self.K.mult(compat.petsc_vec(self.state.u), out)

    def _factor_step_matrix(self) -> None:
        """The step solver's factor (or preconditioner), of the effective matrix A."""
        self.solves.reset(self.A)

    def _initial_acceleration(self) -> None:
        """(M + dt/2 b K) a0 = F(0) - C v0 - f_int(u0): the acceleration at the start, averaged
        over the first half step.

        The plain M a0 = ... is the instantaneous value. A load that is not in equilibrium
        element by element (pressure on the surface nodes, gravity inside) gives the stiffly
        damped modes (b omega^2 dt >> 1) a huge a0 that really dies out within 1/(b omega^2), far
        inside the first step. Generalized-alpha with rho_inf < 1 carries a_n into the damping
        velocity (gamma != 2 beta) and turns that a0 into a displacement independent of omega:
        the brain at rho_inf = 0.5 moved 30 mm per node in its first step. The averaged a0 is
        the instantaneous one for the modes a time step resolves (1 + dt/2 b omega^2 ~ 1) and
        ~0 for the stiff ones; it leaves rigid motion exact (K annihilates it) and on a modal
        model is as accurate as the instantaneous a0 for the low modes and 4x more accurate
        for the stiff ones with Newmark (tests/test_integrators.py)."""
        m, st = self.model, self.state
        rhs = self._rhs
        self._F_old.copy(rhs)
        v = compat.petsc_vec(st.v)
        self._internal_force_of_state(self._tmp)  # K u0, or a hyperelastic body's f_int(u0)
        rhs.axpy(-1.0, self._tmp)
        self._wm.array[:] = self.damping_a * v.array_r
        self._wk.array[:] = self.damping_b * v.array_r
        self.M.mult(self._wm, self._tmp)
        rhs.axpy(-1.0, self._tmp)
        self.K.mult(self._wk, self._tmp)
        rhs.axpy(-1.0, self._tmp)
        m.constraints.vector(rhs)
        its = self._solve_averaged_mass(rhs, compat.petsc_vec(st.a))
        log.debug("initial acceleration: %d CG iterations", its)
        st.a.x.scatter_forward()

    def _solve_averaged_mass(self, rhs, a) -> int:
        """(M + dt/2 b K) a = rhs with the supports (a = 0 there): the acceleration a force
        gives, averaged over half a step (_initial_acceleration says why)."""
        m = self.model
        weight = initial_stiffness_weight(self.integrator.dt, self.damping_b)
        if weight == 0.0:  # M a = ...: one Jacobi sweep for a lumped mass
            M_bc = m.assemble(m.mass_form(), with_bcs=True)
            mass_solver = LinearSolver(M_bc, "cg-jacobi", rtol=1e-14, atol=1e-300, max_it=10000, name="mass")
            its = mass_solver.solve(rhs, a)
            mass_solver.destroy()
        else:  # M + w K is spectrally close to K_eff = cM M + cK K: its solver preconditions CG
            M_bc = m.assemble(m.combined(1.0, weight), with_bcs=True)
            its = solve_preconditioned_by(M_bc, self.solves.solver, rhs, a, rtol=1e-12, name="acceleration")
        M_bc.destroy()
        m.constraints.project_owned(a)
        return its

    def _unbalanced_force(self, out) -> None:
        """F_n - C v_n - f_int(u_n) - M a_n into out: what the time scheme left of the equation of
        motion at t_n (zero for Newmark up to its solves; generalized-alpha balances elsewhere)."""
        st = self.state
        self._F_old.copy(out)
        self._internal_force_of_state(self._tmp)
        out.axpy(-1.0, self._tmp)
        v, a = compat.petsc_vec(st.v), compat.petsc_vec(st.a)
        self._wm.array[:] = self.damping_a * v.array_r + a.array_r  # (a M + ...) v + M a in one product
        self.M.mult(self._wm, self._tmp)
        out.axpy(-1.0, self._tmp)
        self.K.mult(v, self._tmp)
        out.axpy(-self.damping_b, self._tmp)
        self._K_wk_of_step = -1  # _wm was used as scratch

    # -- resection ------------------------------------------------------------------------------
    def _remove_due_cells(self) -> bool:
        """Apply the cuts due at the current time; True if any was."""
        tissue = self.model.tissue
        if tissue is None:
            return False
        due = tissue.due(self.state.t, 1e-9 * self.integrator.dt)
        if not due:
            return False
        for index in due:
            self.removals.append(tissue.cut(index, self.state.t))
        self.model.tissue_changed()
        return True

    def _resect(self) -> None:
        """Between steps: remove due cells, rebuild the operators on what is left, and stop
        the nodes left without tissue (their rows become identity rows with zero load).

        The state carries over: u and v as they are, and the acceleration takes the jump of
        the forces the removal makes and nothing else: with g = F - C v - f_int(u), primes after
        the removal, M' a' - g' = M a - g (what the time scheme left unbalanced at t_n stays),
        the jump a' - a averaged over half a step as the start's acceleration is
        ((M' + dt/2 b K') (a' - a) = g' - g - (M' - M) a). Without stiffness damping (b = 0) and
        with a lumped mass a node the removed cells did not touch keeps its a; with b > 0 the
        jump spreads over about the distance a wave travels in dt/2, as the start's
        acceleration does; either way a rebuild that removes nothing changes nothing, and under
        Newmark (which leaves nothing unbalanced) a piece cut free falls with g from the cut
        on. (Recomputing a from the start's formula changed it everywhere: K0 u stood in for a
        hyperelastic internal force, and the averaging filtered the whole acceleration of a
        damped body.)"""
        tissue = self.model.tissue
        if tissue is None or not tissue.due(self.state.t, 1e-9 * self.integrator.dt):
            return
        kept = self._F.duplicate()
        self._unbalanced_force(kept)
        self._remove_due_cells()
        self._destroy_operators()
        self._build_operators()
        jump = self._F.duplicate()
        self._unbalanced_force(jump)  # g' - M' a, with a still the old one
        jump.axpy(-1.0, kept)  # g' - g - (M' - M) a
        self.model.constraints.vector(jump)
        change = jump.duplicate()
        self._solve_averaged_mass(jump, change)
        compat.petsc_vec(self.state.a).axpy(1.0, change)
        for vec in (kept, jump, change):
            vec.destroy()
        empty = self.M.getDiagonal()
        orphans = empty.array_r == 0.0
        empty.destroy()
        for f in (self.state.v, self.state.a):
            f.x.array[: self.state.n_owned][orphans] = 0.0
            f.x.scatter_forward()

    # -- the step -------------------------------------------------------------------------------
    def step(self) -> int:
        """Advance one time step; returns the Krylov iterations of the last solve. With follower
        loading the fluid load at t_{n+1} is evaluated on x + u_{n+1}, iterated within the step."""
        self._resect()
        its = self._linear_step((self.steps_taken + 1) * self.integrator.dt)  # not a running sum: no drift in t
        self.steps_taken += 1
        self._energy_check()
        return its

    def _linear_step(self, t_new: float, same_problem: bool = True, solve=None, reaction=None) -> int:
        """The step to t_new of the linear model (the follower load by the fixed point);
        same_problem: the last step was one too (the acceleration keeps its history); solve:
        (rhs, x, t) -> iterations, the step solver by default; reaction: a load that depends
        on where the body is (the skull's: stepping/lagged_contact.py), in the fixed point
        too, settled again while it asks for another round."""
        st, ti = self.state, self.integrator
        w_new, w_old = ti.load_weights()
        if self._K_wk_of_step != self.steps_taken:  # w_m, w_k, K w_k not left by the last energy check
            self._rhs_vectors()
            self.K.mult(self._wk, self._K_wk)
        base = self._base  # everything but w_new F_{n+1}
        base.array[:] = w_old * self._F_old.array_r
        self.M.mult(self._wm, self._tmp)
        base.axpy(-1.0, self._tmp)
        base.axpy(-1.0, self._K_wk)
        follower = self.settle.follower

        def rhs_for_current_du():
            if follower or reaction is not None:  # the geometry of this iterate: x + u_n + du
                self._geometry.x.array[:] = st.u.x.array + self.du.x.array
            self.model.load_into(t_new, self._F, self._geometry if follower else st.u)
            if reaction is not None:
                reaction.add_force(self._F, self._geometry)
            base.copy(self._rhs)
            self._rhs.axpy(w_new, self._F)
            if reaction is not None:
                reaction.add_lagged(self._rhs, self.du)
            return self._rhs

        def settle(same: bool) -> int:
            return self.settle(
                self.du,
                rhs_for_current_du,
                solve or self.solves,
                t_new,
                scale=st.norm(st.u),
                same_problem=same,
                depends_on_x=reaction is not None,
            )

        its = settle(same_problem)
        while reaction is not None:
            self._geometry.x.array[:] = st.u.x.array + self.du.x.array
            if not reaction.another_round(self._geometry):
                break
            its = settle(True)
        n = st.n_owned
        ti.update(st.u.x.array[:n], st.v.x.array[:n], st.a.x.array[:n], self.du.x.array[:n])
        for f in (st.u, st.v, st.a):
            f.x.scatter_forward()
        du = compat.petsc_vec(self.du)
        self.energy.add_work(0.5 * (du.dot(self._F) + du.dot(self._F_old)))
        self._F.copy(self._F_old)  # F_{n+1} becomes F_n
        st.t = t_new
        return its

    def restore(self, snapshot: tuple) -> None:
        """Back to a state taken before a step that failed a guard."""
        self.state.restore(snapshot)
        self._K_wk_of_step = -1

    # -- energy -------------------------------------------------------------------------------
    def energies(self, K_u=None) -> tuple[float, float]:
        """(kinetic, strain) energy of the current state, J (K_u: K u, when known)."""
        u, v = compat.petsc_vec(self.state.u), compat.petsc_vec(self.state.v)
        if self._mass_diagonal is not None:  # no matrix product for a diagonal mass
            self._tmp.pointwiseMult(v, v)
            kinetic = 0.5 * self._tmp.dot(self._mass_diagonal)
        else:
            self.M.mult(v, self._tmp)
            kinetic = 0.5 * v.dot(self._tmp)
        if K_u is None:
            K_u = self._tmp
            self.K.mult(u, K_u)
        return kinetic, 0.5 * u.dot(K_u)

    def _rhs_vectors(self) -> None:
        """w_m and w_k of the current state (rhs = F_mid - M w_m - K w_k) into their vectors."""
        st = self.state
        n = st.n_owned
        wm, wk = self.integrator.rhs_vectors(
            st.u.x.array[:n], st.v.x.array[:n], st.a.x.array[:n], self.damping_a, self.damping_b
        )
        self._wm.array[:] = wm
        self._wk.array[:] = wk

    def _energy_check(self) -> None:
        """The energy guard on the current state. K u comes with K w_k, the next step's
        right-hand-side product, in one pass over K (linalg/products.py)."""
        if not self.check_energy:
            return
        self._rhs_vectors()
        self._pair.multiply(compat.petsc_vec(self.state.u), self._wk, self._K_u, self._K_wk)
        self._K_wk_of_step = self.steps_taken
        self.energy.check(self.state.t, *self.energies(self._K_u))

    def _destroy_operators(self) -> None:
        for mat in (self.M, self.K, self.A):
            mat.destroy()
        self._pair.destroy()

    def destroy(self) -> None:
        if self.M is not None:
            self._destroy_operators()
        self.solves.destroy()
