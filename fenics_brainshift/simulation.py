"""Running a scene: the dynamic time loop or the quasi-static path, and what they report.

Data flow: scene -> model (mesh, forms, loads) -> integrator + solver -> outputs. The
effective matrix and its solver are built once; each step costs one right-hand side (a
diagonal mass product, and K applied to the state once, shared with the energy guard), one
solve warm-started from the previous increment (per follower iteration), and the array
update of u, v, a.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx.la
import numpy as np
from dolfinx import fem
from dolfinx.fem.petsc import set_bc
from mpi4py import MPI
from petsc4py import PETSc

from . import compat
from .embedding import SurfaceEmbedding, load_fine_surface
from .guards import EnergyBalance
from .integrators import TimeIntegrator
from .io import FieldWriter, write_csv, write_json
from .logs import get_logger
from .model import Model, build_model
from .probes import Probes, SurfaceAverages
from .products import PairProduct
from .planner import make_plan, stiffness_band
from .progress import progress
from .relaxation import AndersonAcceleration
from .scene import Scene, SolverConfig
from .solver import LinearSolver, SolverError, rigid_body_modes

log = get_logger("simulation")


def integrator_for(scene: Scene) -> TimeIntegrator:
    t = scene.time
    if t.scheme == "newmark":
        return TimeIntegrator.newmark(t.dt)
    return TimeIntegrator.generalized_alpha(t.dt, t.rho_inf)


@dataclass
class History:
    """Per-output-step probe record (t, level, probe values) and timings."""

    times: list[float] = field(default_factory=list)
    levels: list[float] = field(default_factory=list)
    probes: list[np.ndarray] = field(default_factory=list)
    surfaces: list[np.ndarray] = field(default_factory=list)
    step_seconds: list[float] = field(default_factory=list)
    solve_seconds: float = 0.0
    solves: int = 0


class Simulation:
    """State (u, v, a) on a model, advanced by a time integrator or solved statically."""

    def __init__(self, model: Model):
        self.model = model
        self.scene = model.scene
        V = model.V
        self.u = fem.Function(V, name="displacement")
        self.v = fem.Function(V, name="velocity")
        self.a = fem.Function(V, name="acceleration")
        self.du = fem.Function(V)
        self.n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self.probes = Probes(model.mesh, self.scene.probes)
        self.surfaces = SurfaceAverages(self.u, self.scene.surfaces)
        self.follower_iterations = 0
        self.history = History()
        self.t = 0.0
        self.steps_taken = 0
        self._nullspace = rigid_body_modes(V) if self.scene.solver.kind == "cg-gamg" else None
        # work vectors, allocated once (they own their memory: never wrap a temporary Function)
        self._F = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self._rhs = self._F.duplicate()
        self._tmp = self._F.duplicate()
        self._wm = self._F.duplicate()
        self._wk = self._F.duplicate()
        self._base = self._F.duplicate()
        self._trial = self._F.duplicate()
        self._K_u = self._F.duplicate()
        self._K_wk = self._F.duplicate()
        self._K_wk_of_step = -1
        self._geometry = fem.Function(V)
        self.follower = model.fluid is not None and self.scene.fluid.follower
        self.follower_tol = 1e-6  # relative to |u|: nanometres on millimetres
        self.max_follower_iterations = 100
        # Anderson mixing of depth 8: 9-12 solves per step or state on the brain, against 14-21
        # with Aitken's relaxation (relaxation.py keeps both)
        self.relaxation = AndersonAcceleration(self._F)
        self.tissue = model.tissue
        self.energy = EnergyBalance()
        self.check_energy = True
        self.removals: list[dict] = []  # what each resection took, for the summary
        self.last_good = None

    # -- loads -----------------------------------------------------------------------------
    @property
    def level(self) -> float | None:
        """The fluid level of the last load evaluation (None when dry)."""
        return self.model.fluid.level if self.model.fluid is not None else None

    def load(self, t: float, out: PETSc.Vec, geometry=None) -> PETSc.Vec:
        """F(t) = F_gravity + F_fluid into out (owned entries); with follower loading the
        fluid load is evaluated on x + geometry (a displacement Function)."""
        grav, fluid = self.model.external_load(t, geometry)
        out.array[:] = grav.array_r if fluid is None else grav.array_r + fluid.array_r
        return out

    def forces(self) -> dict:
        """Resultant gravity and fluid forces (N), the fluid level and the submerged volume,
        evaluated on the current state."""
        from .loads import total_force

        grav, fluid = self.model.external_load(self.t, self.u)
        hydro = self.model.fluid.hydro if fluid is not None else None
        return {"gravity_force_N": total_force(grav, self.model.comm),
                "fluid_force_N": hydro.force if hydro else np.zeros(3),
                "submerged_volume_m3": hydro.submerged_volume if hydro else 0.0,
                "final_level_m": self.level}

    # -- dynamic -----------------------------------------------------------------------------
    def setup_dynamic(self) -> None:
        self.integrator = integrator_for(self.scene)
        newmark = self.integrator.alpha_m == 0.0 and self.integrator.alpha_f == 0.0
        self.energy = EnergyBalance(tolerance=1e-2 if newmark else 1.0)
        self._remove_due_cells()
        self._build_dynamic_operators()
        self._energy_check()

    def _build_dynamic_operators(self) -> None:
        """M, K, the effective matrix and its solver, F_n and a consistent a_n. Once, and
        again after a resection (the matrices change; the state u, v carries over)."""
        m, sc = self.model, self.scene
        cm, ck = self.integrator.effective_coefficients(sc.damping.a, sc.damping.b)
        self.M = m.mass_matrix()  # M and K only ever multiply vectors
        self.K = m.assemble(m.stiffness_form(), with_bcs=False)
        self.A = m.assemble(m.combined(cm, ck), with_bcs=True)
        self._mass_diagonal = self.M.getDiagonal() if m.lumped else None  # lumped M is diagonal
        self._pair = PairProduct(self.K)
        self._K_wk_of_step = -1  # K w_k is cached for the state after this many steps
        self.solver = LinearSolver(self.A, sc.solver, "", self._nullspace)
        self._F_old = self.load(self.t, self._F.duplicate(), self.u)
        self._initial_acceleration()

    # -- resection ---------------------------------------------------------------------------
    def _remove_due_cells(self) -> bool:
        """Apply the [[remove]]s due at the current time; True if any was."""
        if self.tissue is None:
            return False
        due = self.tissue.due(self.t, 1e-9 * self.integrator.dt)
        if not due:
            return False
        for index in due:
            removal = self.scene.remove[index]
            count, isolated = self.tissue.apply(index)
            self.removals.append({"at": removal.at, "t": self.t, "region": removal.describe(), "cells": count,
                                  "isolated_cells": isolated})
            log.info("  t=%.3f s: removed %d cells (%s) and %d left hanging by an edge or vertex; %.1f %% of "
                     "the body removed so far", self.t, count, removal.describe(), isolated,
                     100.0 * self.tissue.removed_fraction)
        self.model.gravity.refresh()
        if self.model.fluid is not None:
            self.model.fluid.set_present(self.tissue.present)
        return True

    def _resect(self) -> None:
        """Between steps: remove due cells, rebuild the operators on what is left, and stop
        the nodes left without tissue (their rows become identity rows with zero load)."""
        if not self._remove_due_cells():
            return
        for mat in (self.M, self.K, self.A):
            mat.destroy()
        self._pair.destroy()
        self.solver.destroy()
        self._build_dynamic_operators()
        empty = self.M.getDiagonal()
        orphans = np.flatnonzero(empty.array_r == 0.0)
        empty.destroy()
        for f in (self.v, self.a):
            f.x.array[orphans] = 0.0
            f.x.scatter_forward()

    def _initial_acceleration(self) -> None:
        """M a0 = F(0) - C v0 - K u0, so the scheme starts in equilibrium (and generalized-alpha
        with rho_inf = 1 follows Newmark's trajectory exactly)."""
        sc, m = self.scene, self.model
        rhs = self._rhs
        self._F_old.copy(rhs)
        u, v = compat.petsc_vec(self.u), compat.petsc_vec(self.v)
        self.K.mult(u, self._tmp)
        rhs.axpy(-1.0, self._tmp)
        self._wm.array[:] = sc.damping.a * v.array_r
        self._wk.array[:] = sc.damping.b * v.array_r
        self.M.mult(self._wm, self._tmp)
        rhs.axpy(-1.0, self._tmp)
        self.K.mult(self._wk, self._tmp)
        rhs.axpy(-1.0, self._tmp)
        set_bc(rhs, m.bcs)
        M_bc = m.assemble(m.mass_form(), with_bcs=True)
        mass_cfg = SolverConfig(kind="cg-jacobi", rtol=1e-14, atol=1e-300, max_it=10000)
        mass_solver = LinearSolver(M_bc, mass_cfg, "mass")
        a = compat.petsc_vec(self.a)
        mass_solver.solve(rhs, a)
        self.a.x.scatter_forward()
        mass_solver.destroy()
        M_bc.destroy()

    def step(self) -> int:
        """Advance one time step; returns the Krylov iteration count. With follower loading
        the fluid load at t_{n+1} is evaluated on x + u_{n+1}, iterated within the step
        (Anderson-accelerated); without it, one solve."""
        self._resect()
        # the state to go back to if a guard stops the run during this step
        self.last_good = (self.t, self.u.x.array.copy(), self.v.x.array.copy(), self.a.x.array.copy())
        ti = self.integrator
        n = self.n_owned
        t_new = (self.steps_taken + 1) * ti.dt  # not a running sum: no drift in t
        w_new, w_old = ti.load_weights()
        u, v, a = self.u.x.array[:n], self.v.x.array[:n], self.a.x.array[:n]
        if self._K_wk_of_step != self.steps_taken:  # w_m, w_k, K w_k not left by the last energy check
            self._rhs_vectors()
            self.K.mult(self._wk, self._K_wk)
        base = self._base  # everything but w_new F_{n+1}
        base.array[:] = w_old * self._F_old.array_r
        self.M.mult(self._wm, self._tmp)
        base.axpy(-1.0, self._tmp)
        base.axpy(-1.0, self._K_wk)

        def rhs_for_current_du() -> PETSc.Vec:
            if self.follower:  # the geometry of this iterate: x + u_n + du
                self._geometry.x.array[:] = self.u.x.array + self.du.x.array
            F_new = self.load(t_new, self._F, self._geometry if self.follower else self.u)
            base.copy(self._rhs)
            self._rhs.axpy(w_new, F_new)
            return self._rhs

        # changes are measured against |u|, not |du|; a step's coupling is like the last one's
        its = self._settle(self.du, rhs_for_current_du, scale=self._norm(self.u), keep_omega=True)
        ti.update(u, v, a, self.du.x.array[:n])
        for f in (self.u, self.v, self.a):
            f.x.scatter_forward()
        du = compat.petsc_vec(self.du)
        self.energy.add_work(0.5 * (du.dot(self._F) + du.dot(self._F_old)))
        self._F.copy(self._F_old)  # F_{n+1} becomes F_n
        self.t = t_new
        self.steps_taken += 1
        self._energy_check()
        return its

    def energies(self, K_u: PETSc.Vec | None = None) -> tuple[float, float]:
        """(kinetic, strain) energy of the current state, J (K_u: K u, when known)."""
        u, v = compat.petsc_vec(self.u), compat.petsc_vec(self.v)
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
        n, sc = self.n_owned, self.scene
        wm, wk = self.integrator.rhs_vectors(self.u.x.array[:n], self.v.x.array[:n], self.a.x.array[:n],
                                             sc.damping.a, sc.damping.b)
        self._wm.array[:] = wm
        self._wk.array[:] = wk

    def _energy_check(self) -> None:
        """The energy guard on the current state. K u comes with K w_k, the next step's
        right-hand-side product, in one pass over K (products.py); w_m and w_k are kept for
        that step too."""
        if not self.check_energy:
            return
        self._rhs_vectors()
        self._pair.multiply(compat.petsc_vec(self.u), self._wk, self._K_u, self._K_wk)
        self._K_wk_of_step = self.steps_taken
        self.energy.check(self.t, *self.energies(self._K_u))

    def restore_last_good(self) -> None:
        """Back to the state before the step that failed a guard."""
        if self.last_good is None:
            return
        self.t, u, v, a = self.last_good
        self._K_wk_of_step = -1
        for f, values in zip((self.u, self.v, self.a), (u, v, a)):
            f.x.array[:] = values

    # -- quasi-static ------------------------------------------------------------------------
    def setup_static(self) -> None:
        m = self.model
        self.K_bc = m.assemble(m.stiffness_form(), with_bcs=True)
        self.solver = LinearSolver(self.K_bc, self.scene.solver, "", self._nullspace)

    def solve_static(self, t: float) -> int:
        """K u = F(t) with the supports; u keeps the previous answer as initial guess. With
        follower loading F depends on u: iterated to the tolerance with Anderson acceleration.
        Returns the Krylov iterations of the last solve."""
        its = self._settle(self.u, lambda: self.load(t, self._rhs, self.u), scale=0.0, keep_omega=False)
        self.t = t
        return its

    def _settle(self, x, rhs_for_current_x, scale: float, keep_omega: bool) -> int:
        """Solve A x = rhs(x) for the Function x, where the rhs depends on x only through the
        follower load: one solve without follower loading, else accelerated fixed-point
        iteration until the update is below follower_tol of max(scale, |x|), or until the
        fluid load was reused because the surface has not moved (then the map's value is the
        last solve's answer, exactly). Returns the Krylov iterations of the last solve."""
        x_vec, trial = compat.petsc_vec(x), self._trial
        self.relaxation.reset(keep_omega=keep_omega)
        its = 0
        for k in range(1, self.max_follower_iterations + 1):
            rhs = rhs_for_current_x()
            if self.follower and k > 1 and self.model.fluid.reused_last:
                trial.copy(x_vec)  # same load as the last solve: its answer is the fixed point
                x.x.scatter_forward()
                break
            set_bc(rhs, self.model.bcs)
            x_vec.copy(trial)  # warm start from the current iterate
            its = self._solve(rhs, trial)
            if not self.follower:
                trial.copy(x_vec)
                x.x.scatter_forward()
                break
            change = self.relaxation.update(x_vec, trial) / max(scale, trial.norm(), 1e-300)
            x.x.scatter_forward()
            if change <= self.follower_tol:
                break
        else:
            self._not_settled(change)
        self.follower_iterations = k
        return its

    def _norm(self, f: fem.Function) -> float:
        """The global 2-norm of a Function's owned values. Not PETSc's Vec.norm(): PETSc caches
        norms until a PETSc operation changes the vector, and u, v, a are updated through their
        numpy arrays, so norm() kept returning the value of t = 0 (zero), and the follower
        tolerance was taken relative to the step's increment instead of |u|."""
        owned = f.x.array[: self.n_owned]
        return float(np.sqrt(self.model.comm.allreduce(float(owned @ owned), op=MPI.SUM)))

    def _solve(self, rhs: PETSc.Vec, x: PETSc.Vec) -> int:
        t0 = time.perf_counter()
        its = self.solver.solve(rhs, x)
        self.history.solve_seconds += time.perf_counter() - t0
        self.history.solves += 1
        if not np.isfinite(x.norm()):
            raise SolverError(f"the solution is no longer finite at t = {self.t:g} s (NaN or Inf); "
                              f"reduce [time] dt or check the loads")
        return its

    def _not_settled(self, change: float) -> None:
        raise SolverError(f"follower-load iteration did not settle in {self.max_follower_iterations} "
                          f"iterations at t = {self.t:g} s (relative change {change:.1e}); use "
                          f"[fluid] follower = false")

    # -- reporting ---------------------------------------------------------------------------
    def record(self) -> None:
        h = self.history
        h.times.append(self.t)
        level = self.level
        h.levels.append(np.nan if level is None else level)
        h.probes.append(self.probes.values(self.u))
        h.surfaces.append(self.surfaces.values())

    def max_displacement(self) -> float:
        local = self.u.x.array[: self.n_owned].reshape(-1, 3)
        local_max = float(np.max(np.linalg.norm(local, axis=1))) if local.size else 0.0
        return self.model.comm.allreduce(local_max, op=MPI.MAX)


def static_times(scene: Scene) -> list[float]:
    """Quasi-static solves happen at each breakpoint of the fluid schedule (t = 0 when dry)."""
    return scene.fluid.schedule.times if scene.fluid is not None else [0.0]


def run(scene: Scene, out_dir: str | Path, comm=MPI.COMM_WORLD) -> dict:
    """Build, run and write DIR/summary.json, DIR/displacement.xdmf, DIR/probes.csv.

    Every input check happens while building the model, before the folder is created, so
    bad input leaves no output behind."""
    t_start = time.perf_counter()
    out = Path(out_dir)
    check_writable(out, comm)
    model = build_model(scene, comm)
    plan = make_plan(scene, model.mesh)
    sim = Simulation(model)
    surface = load_fine_surface(scene.mesh)
    embedding = SurfaceEmbedding(model.mesh, *surface) if surface is not None else None
    dynamic = plan.mode == "dynamic"
    sim.setup_dynamic() if dynamic else sim.setup_static()
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    writer = FieldWriter(out, model.mesh, model.V, scene.output.fields, model.mu, model.lmbda, embedding,
                         model.tissue.indicator if model.tissue is not None else None)
    setup_s = time.perf_counter() - t_start
    sizes = model.sizes()
    for line in plan.log_lines():
        log.info(line)
    log.info("%s: %d nodes, %d cells, %d dofs, P%d, %s, solver %s, %d rank(s); setup %.2f s",
             scene.name, sizes["nodes"], sizes["cells"], sizes["dofs"], scene.element.degree,
             f"{scene.time.scheme} dt={scene.time.dt:g} s" if dynamic else "quasi-static",
             scene.solver.kind, comm.size, setup_s)

    h = sim.history
    stopped = None
    if dynamic:
        steps = scene.time.steps
        interval = scene.output.interval
        next_write = 0.0
        sim.record()
        writer.write(sim.t, sim.u, sim.v)
        next_write += interval
        bar = progress(range(1, steps + 1), scene.name, total=steps)
        try:
            for n in bar:
                t0 = time.perf_counter()
                its = sim.step()
                h.step_seconds.append(time.perf_counter() - t0)
                bar.set_postfix_str(f"t={sim.t:.2f} s level={_fmt(sim.level)} {h.step_seconds[-1] * 1e3:.0f} ms/step",
                                    refresh=False)
                sim.record()
                if sim.t >= next_write - 1e-9 * scene.time.dt or n == steps:
                    writer.write(sim.t, sim.u, sim.v)
                    next_write += max(interval, scene.time.dt) if interval > 0 else 0.0
                if n % max(1, steps // 10) == 0 or n == steps:
                    log.info("  step %d/%d  t=%.3f s  level=%s  its=%d  |u|max=%.3e m", n, steps,
                             sim.t, _fmt(sim.level), its, sim.max_displacement())
            bar.close()
        except SolverError as exc:  # a guard fired: keep the last good state, then say why
            stopped = exc
            bar.close()
            sim.restore_last_good()
            if h.times[-1] != sim.t:
                sim.record()
            if writer.last_time != sim.t:
                writer.write(sim.t, sim.u, sim.v)
    else:
        times = static_times(scene)
        try:
            for t in times:
                t0 = time.perf_counter()
                good = sim.u.x.array.copy()
                its = sim.solve_static(t)
                h.step_seconds.append(time.perf_counter() - t0)
                sim.record()
                writer.write(sim.t, sim.u, sim.v)
                log.info("  t=%g s  level=%s  its=%d  follower iterations=%d  |u|max=%.3e m", t,
                         _fmt(sim.level), its, sim.follower_iterations, sim.max_displacement())
        except SolverError as exc:
            stopped = exc
            sim.u.x.array[:] = good
            if not h.times:
                sim.record()
                writer.write(sim.t, sim.u, sim.v)
    writer.close()

    probe_header = (["t", "level"] + [f"{n}_{c}" for n in sim.probes.names for c in "xyz"]
                    + [f"{n}_mean_{c}" for n in sim.surfaces.names for c in "xyz"])
    rows = [[t, lv, *p.ravel(), *s.ravel()] for t, lv, p, s in zip(h.times, h.levels, h.probes, h.surfaces)]
    write_csv(out / "probes.csv", probe_header, rows, comm)
    its = sim.solver.iterations
    summary = {
        "scene": scene.name,
        "status": "ok" if stopped is None else f"stopped: {stopped}",
        "dolfinx_version": compat.DOLFINX_VERSION,
        "ranks": comm.size,
        **sizes,
        "degree": scene.element.degree,
        "mode": plan.mode,
        "plan": plan.as_dict(),
        "scheme": scene.time.scheme if dynamic else "static",
        "solver": scene.solver.kind,
        "steps": len(h.step_seconds),
        "setup_s": setup_s,
        "step_s_median": statistics.median(h.step_seconds) if h.step_seconds else 0.0,
        "solve_s_total": h.solve_seconds,
        "linear_solves": h.solves,
        "iterations_mean": float(np.mean(its)) if its else 0.0,
        "iterations_max": int(max(its)) if its else 0,
        "final_time": sim.t,
        "gravity_vector": list(scene.gravity.vector),
        "max_displacement_m": sim.max_displacement(),
        "probes": sim.probes.as_dict(h.probes[-1]),
        **(_energy_summary(sim) if dynamic else {}),
        **({"stiffness_band": stiffness_band(scene, plan, sim.max_displacement(), sim.probes.as_dict(h.probes[-1]))}
           if scene.material.relative_sd is not None else {}),
        **({"fluid_assemblies": model.fluid.assemblies, "fluid_reuses": model.fluid.reuses} if model.fluid else {}),
        **({"removals": sim.removals, "removed_fraction": sim.tissue.removed_fraction} if sim.tissue else {}),
        "surfaces": sim.surfaces.as_dict(h.surfaces[-1]),
        **sim.forces(),
    }
    write_json(out / "summary.json", summary, comm)
    sim.solver.destroy()
    if scene.output.pictures and stopped is None and comm.rank == 0:
        from .viz import render_in_subprocess

        for path in render_in_subprocess(out):
            log.info("  wrote %s", path)
    comm.barrier()
    if stopped is not None:
        raise SolverError(f"{stopped} (stopped; the last good state, t = {sim.t:g} s, is in {out})")
    return summary


def _energy_summary(sim: Simulation) -> dict:
    e = sim.energy
    t, kinetic, strain, work = e.history[-1] if e.history else (sim.t, 0.0, 0.0, 0.0)
    return {"energy_J": {"kinetic": kinetic, "strain": strain, "external_work": work,
                         "balance": kinetic + strain - work}}


def check_writable(out: Path, comm) -> None:
    """The output folder must be creatable and writable; checked before any work or output."""
    import os

    problem = None
    if comm.rank == 0:
        existing = out
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        if out.exists() and not out.is_dir():
            problem = f"output folder '{out}' is an existing file; choose another --out"
        elif not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
            problem = f"output folder '{out}' cannot be written ('{existing}' is not writable); choose another --out"
    problem = comm.bcast(problem, root=0)
    if problem:
        from .scene import SceneError

        raise SceneError(problem)


def _fmt(level) -> str:
    return "dry" if level is None else f"{level:.4f} m"
