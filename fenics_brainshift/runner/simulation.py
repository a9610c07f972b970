"""A scene set up to run, for users who drive the loop themselves (and for run()).

sim = Simulation(load_scene("cube"))   # mesh, model, plan: every input check
sim.setup()                            # operators and the factor or preconditioner
while sim.t < 1.0:
    sim.step()                         # one time step (dynamic)
sim.solve_to_settled(10.0)             # or the settled state for the loads at t = 10 s
sim.u                                  # the displacement, a DOLFINx Function
"""

from __future__ import annotations

import numpy as np
import ufl
from dolfinx.fem.petsc import assemble_vector
from mpi4py import MPI
from petsc4py import PETSc

from .. import compat
from ..errors import InputError
from ..linalg import rigid_body_modes
from ..logs import get_logger
from ..outputs.probes import Probes, SurfaceAverages
from ..outputs.validity import StrainMeter
from ..physics import total_force
from ..physics.free_pieces import unheld_cells
from ..physics.surface import surface_facets
from ..scene import Scene
from ..stepping import DynamicStepper, Solves, State, StaticSolver
from ..stepping.contact_skip import ContactWhenReached
from ..stepping.newton import NewtonStatic
from ..stepping.newton_dynamic import NewtonDynamicStepper
from . import build
from .plan import make_plan

log = get_logger(__name__)


class Simulation:
    """Model, state, plan, and the time stepper or quasi-static solver of a scene."""

    def __init__(self, scene: Scene, comm=MPI.COMM_WORLD, model=None):
        """``model``: one built before from this scene (build_model), to share its mesh."""
        if scene.material.model == "auto":
            raise InputError(
                '[material] model = "auto" is decided by run() (a linear trial run first); '
                'a Simulation needs "linear", "neo-hookean" or "saint-venant-kirchhoff"'
            )
        self.scene = scene
        self.model = model if model is not None else build.build_model(scene, comm)
        self.plan = make_plan(scene, self.model.mesh)
        self.contact = build.skull_contact(scene, self.model)  # checked now: a bad skull stops before any output
        if self.plan.mode == "quasi-static" and self.contact is None:  # (the skull may hold it; the mass does)
            free = self.model.constraints.free_rigid_motion()
            if free is not None:
                raise InputError(
                    f"[[fixed]] / [[septum]]: the supports and septa leave the body free to {free}, so a "
                    f"settled state has no unique answer; hold it there (a [[fixed]] region or another "
                    f'septum), or use [time] mode = "dynamic"'
                )
        self.state = State(self.model.V)
        self.probes = Probes(self.model.mesh, scene.probes)
        self.surfaces = SurfaceAverages(self.state.u, scene.surfaces)
        fixed = np.concatenate([bc.dof_indices()[0] for bc in self.model.bcs]) if self.model.bcs else None
        tissue = self.model.tissue.indicator if self.model.tissue is not None else None
        self.strain_meter = StrainMeter(self.state.u, fixed, tissue)
        nullspace = rigid_body_modes(self.model.V) if scene.solver.kind == "cg-gamg" else None
        self.solves = Solves(build.solver_settings(scene), nullspace)
        if self.model.constraints.has_septa:  # every answer kept on the septa exactly
            self.solves.project = self.model.constraints.project_owned
        self.dynamic: DynamicStepper | None = None
        self.static: StaticSolver | None = None
        self.newton_rtol = 1e-9  # settled states by Newton: |R| <= this x the loads (set before setup)
        self._settled_removals: list[dict] = []  # the cuts settled states applied (time stepping keeps its own)

    # -- driving it -------------------------------------------------------------------------
    @property
    def is_dynamic(self) -> bool:
        """What the plan chose: time stepping, or settled states."""
        return self.plan.mode == "dynamic"

    def setup(self) -> None:
        """Build the operators and the solver the plan chose (may raise InputError for bad
        solver settings, before anything is written)."""
        if self.is_dynamic:
            self._dynamic()
        else:
            self._static()

    def step(self) -> int:
        """One time step; returns the Krylov iterations of its last solve."""
        return self._dynamic().step()

    def solve_to_settled(self, t: float) -> int:
        """The settled (quasi-static) state for the loads at time t, after the [[remove]]s due
        by then; returns the iterations."""
        self._resect_settled(t)
        return self._static().solve(t)

    @property
    def removals(self) -> list[dict]:
        """Each cut made so far: its region, time, cells, and the cells taken with it."""
        return self.dynamic.removals if self.dynamic is not None else self._settled_removals

    def _resect_settled(self, t: float) -> None:
        """The cuts due by t applied before a settled state, and every piece they cut free of
        the supports taken out with them: a settled state cannot hold a piece nothing holds (K
        is singular on it), where time stepping lets it fall; the operators are built again
        on what is left."""
        tissue = self.model.tissue
        due = tissue.due(t, 1e-12 * max(abs(t), 1.0)) if tissue is not None else []
        if due:
            self.cut_now(due, t)

    def cut_now(self, indices: list[int], t: float | None = None) -> None:
        """Apply these pending cuts (indices into model.tissue.cuts) before the next settled
        state, whatever their time (an atlas's resection stages), with the pieces they free."""
        tissue = self.model.tissue
        t = self.state.t if t is None else t
        V = self.model.V
        for index in indices:
            cut = tissue.cuts[index]
            record = tissue.cut(index, t)
            left = tissue.count_present()
            freed = tissue.take(unheld_cells(V, tissue.present, self.model.constraints.fixed))
            if freed == left:
                who = f"--resect: {cut.label}" if cut.label.startswith("resection stage") else f"[[remove]] {cut.label}"
                raise InputError(
                    f"{who}: no piece of what "
                    f"is left is held by the supports against every rigid motion (the cut takes them, or leaves "
                    f"them on a point or a line), so it has no settled state; cut less, or hold what is left "
                    f"([[fixed]])"
                )
            self._settled_removals.append({**record, "free_cells": freed})
            if freed:
                log.warning(
                    "  t=%.3f s: the cut (%s) left %d cells in pieces no support holds; a settled state cannot hold "
                    "them, so they are taken out with the cut (time stepping would let them fall: [time] mode = "
                    '"dynamic")',
                    t,
                    cut.label,
                    freed,
                )
        self.model.tissue_changed()
        if self.contact is not None:  # the cut faces meet the skull too
            self.contact.set_surface(surface_facets(V, tissue.present))
        if self.static is not None:  # K is another matrix now
            self.static.destroy()
            self.static = None

    def _dynamic(self) -> DynamicStepper:
        if self.dynamic is None:
            self.solves.hint = "reduce [time] dt, or check the loads against the stiffness (moduli in Pa, levels in m)"
            common = (
                self.model,
                self.state,
                build.integrator(self.scene),
                (self.scene.damping.a, self.scene.damping.b),
                self.solves,
                build.follower_tolerance(self.scene, time_step=True),
            )
            if self.model.nonlinear or self.contact is not None:  # Newton in every step
                self.dynamic = NewtonDynamicStepper(*common, contact=self.contact)
            else:
                self.dynamic = DynamicStepper(*common)
            self.dynamic.setup()
        return self.dynamic

    def _static(self) -> StaticSolver | NewtonStatic:
        if self.static is None:
            if self.model.nonlinear:  # Newton: a material that needs it
                self.static = NewtonStatic(
                    self.model, self.state, self.solves, rtol=self.newton_rtol, contact=self.contact
                )
            elif self.contact is not None:  # the fixed point while nothing reaches the skull
                self.static = ContactWhenReached(
                    StaticSolver(self.model, self.state, self.solves, build.follower_tolerance(self.scene)),
                    lambda: NewtonStatic(
                        self.model, self.state, self.solves, rtol=self.newton_rtol, contact=self.contact
                    ),
                    self.contact,
                    self.state,
                )
            else:
                self.static = StaticSolver(self.model, self.state, self.solves, build.follower_tolerance(self.scene))
            self.static.setup()
        return self.static

    def back_to_rest(self) -> None:
        """u = v = a = 0, and the next settled state is solved from there with its loads grown
        from zero (Newton's load steps), not continued from the last one."""
        for f in (self.state.u, self.state.v, self.state.a):
            f.x.array[:] = 0.0
        forget = getattr(self.static, "forget_settled", None)
        if forget is not None:
            forget()

    def restore(self, snapshot: tuple) -> None:
        """Back to a state taken with state.snapshot() (after a guard fired)."""
        (self.dynamic.restore if self.dynamic is not None else self.state.restore)(snapshot)

    def destroy(self) -> None:
        for part in (self.dynamic, self.static):
            if part is not None:
                part.destroy()

    # -- what it holds ----------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self.state.t

    @property
    def u(self):
        """The displacement (m), a DOLFINx Function."""
        return self.state.u

    @property
    def level(self) -> float | None:
        """The fluid level of the last load evaluation (None when dry)."""
        return self.model.fluid.level if self.model.fluid is not None else None

    @property
    def follower_iterations(self) -> int:
        part = self.dynamic if self.is_dynamic else self.static
        if part is None or not hasattr(part, "settle"):
            return 0  # Newton: the follower load is inside its residual, no separate iteration
        return part.settle.iterations

    def probe_values(self) -> np.ndarray:
        """(n_probes, 3) displacement at the scene's probes (m), on every rank."""
        return self.probes.values(self.state.u)

    def forces(self) -> dict:
        """Resultant gravity and fluid forces (N), the fluid level and the submerged volume,
        on the current state."""
        grav, fluid = self.model.external_load(self.state.t, self.state.u)
        hydro = self.model.fluid.hydro if fluid is not None else None
        return {
            "gravity_force_N": total_force(grav, self.model.comm),
            "fluid_force_N": hydro.force if hydro else np.zeros(3),
            "submerged_volume_m3": hydro.submerged_volume if hydro else 0.0,
            "final_level_m": self.level,
        }

    def septa_report(self) -> list[dict]:
        """What each septum carries at the current state (physics/constraints.py): its
        reaction is what the equation of motion leaves unbalanced at its nodes,
        f_int(u) + M (a + a_d v) + b_d K v - F(t, u) - the skull's forces (a settled state:
        no inertia)."""
        model, st = self.model, self.state
        v = ufl.TestFunction(model.V)
        r = assemble_vector(compat.form(model.constitutive.internal_force(st.u, v)))
        r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        loads = r.duplicate()
        model.load_into(st.t, loads, st.u)
        if self.contact is not None:
            loads.axpy(1.0, self.contact.assemble(st.u))
        r.axpy(-1.0, loads)
        r.scale(1.0 / model.load_scale)  # the loads were scaled for a stiffness fitted on the same factor
        if self.is_dynamic:
            M, K = model.mass_matrix(), model.assemble(model.stiffness_form(), with_bcs=False)
            velocity = compat.petsc_vec(st.v)
            motion = velocity.duplicate()
            motion.waxpy(self.scene.damping.a, velocity, compat.petsc_vec(st.a))
            M.multAdd(motion, r, r)
            motion.array[:] = self.scene.damping.b * velocity.array_r
            K.multAdd(motion, r, r)
            for part in (M, K, motion):
                part.destroy()
        report = model.constraints.report(r, st.u)
        for part in (r, loads):
            part.destroy()
        return report
