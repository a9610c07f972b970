"""External loads as assembled vectors: gravity (constant) and the fluid load of a scene
(FluidLoad: the level from a schedule or a container volume, the exact facet assembly of
hydrostatics.py). QuadratureFluidLoad is the plain UFL form, kept as the reference the exact
rule is measured against: the kink of max(level - height, 0) at the water line makes it
inexact on cut facets.
"""
from __future__ import annotations

import numpy as np
import ufl
from mpi4py import MPI
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector, create_vector
from petsc4py import PETSc

from . import forms
from .scene import Fluid, Gravity, SceneError


def assemble_into(b: PETSc.Vec, compiled_form) -> PETSc.Vec:
    """Assemble a linear form into b (zeroed first), summing ghost contributions to owners."""
    with b.localForm() as local:
        local.set(0.0)
    assemble_vector(b, compiled_form)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return b


def total_force(b: PETSc.Vec, comm) -> np.ndarray:
    """Sum of an assembled nodal load over all nodes: the resultant force (N), global."""
    local = b.getArray(readonly=True).reshape(-1, 3).sum(axis=0)
    return comm.allreduce(local)


class GravityLoad:
    """rho g over the volume; ``density`` may carry the tissue indicator (then call refresh()
    after a resection)."""

    def __init__(self, V, density, gravity: Gravity):
        mesh = V.mesh
        v = ufl.TestFunction(V)
        g = fem.Constant(mesh, np.array(gravity.vector, dtype=PETSc.ScalarType))
        rho = PETSc.ScalarType(density) if isinstance(density, (int, float)) else density
        self.form = fem.form(forms.body_force(v, rho, g))
        self.vector = assemble_into(create_vector(self.form), self.form)

    def refresh(self) -> None:
        assemble_into(self.vector, self.form)


class QuadratureFluidLoad:
    """-p n on the exterior surface, p = rho_f |g| max(level - x.up, 0), by quadrature of the
    given degree on the reference geometry (the reference the exact rule is measured against)."""

    def __init__(self, V, rho_fluid: float, gravity, quadrature_degree: int):
        mesh = V.mesh
        v = ufl.TestFunction(V)
        g = np.asarray(gravity, dtype=float)
        self.level = fem.Constant(mesh, PETSc.ScalarType(0.0))
        up = fem.Constant(mesh, np.array(-g / np.linalg.norm(g), dtype=PETSc.ScalarType))
        x = ufl.SpatialCoordinate(mesh)
        p = forms.clipped_hydrostatic_pressure(x, rho_fluid, float(np.linalg.norm(g)), up, self.level)
        self.form = fem.form(forms.pressure_load(v, p, ufl.FacetNormal(mesh), quadrature_degree))
        self.vector = create_vector(self.form)
        self._assembled_level: float | None = None

    def assemble(self, level: float) -> PETSc.Vec:
        """The nodal load at this level; not reassembled while the level is unchanged."""
        if level != self._assembled_level:
            self.level.value = level
            assemble_into(self.vector, self.form)
            self._assembled_level = level
        return self.vector


class FluidLoad:
    """The fluid's nodal load at time t: the level comes from the schedule, or from the fluid
    volume in a container (then it depends on how much of the body is under water)."""

    def __init__(self, V, fluid: Fluid, gravity: Gravity):
        from .hydrostatics import HydrostaticLoad

        self.fluid = fluid
        self.hydro = HydrostaticLoad(V, fluid.density, gravity.vector, fluid.rule, fluid.quadrature_degree)
        self.level = float("nan")
        self._assembled_key = None
        self._surface_dofs = None
        self._assembled_surface = None
        self.assemblies = 0
        self.reuses = 0
        self.reused_last = False
        self._last_level = float("nan")
        self._last_slope = fluid.container_area or 1.0
        if fluid.volume is not None:
            body = self.hydro.volume_below(self.hydro.highest())
            if self.hydro.volume_below(fluid.floor) > 1e-9 * body:
                raise SceneError(f"[fluid] floor = {fluid.floor:g} m cuts through the body; "
                                 f"it must be at or below the body's lowest point")

    def set_present(self, present) -> None:
        """After a resection: act on the surface of the cells still present."""
        self.hydro.set_present(present)
        self._assembled_key = None
        self._surface_dofs = None
        self._assembled_surface = None

    def level_at(self, t: float, u=None) -> float:
        fluid = self.fluid
        if fluid.level is not None:
            return fluid.level(t)
        return self.container_level(fluid.volume(t), u)

    def container_level(self, volume: float, u=None) -> float:
        """Solve f(h) = area (h - floor) - V_below(h) - volume = 0 for the level h.

        f is increasing (f' = area - wet cross-section, in (0, area]), so secant steps from
        the last level settle in two or three surface integrals; Brent's method on a
        guaranteed bracket takes over if they do not."""
        from scipy.optimize import brentq

        area, floor = self.fluid.container_area, self.fluid.floor
        if volume == 0.0:
            return floor

        def f(h):
            return area * (h - floor) - self.hydro.volume_below(h, u) - volume

        h0 = self._last_level if np.isfinite(self._last_level) else floor + volume / area
        f0, slope = f(h0), self._last_slope
        for _ in range(12):
            if f0 == 0.0:
                return self._remember(h0, slope)
            h1 = h0 - f0 / slope
            f1 = f(h1)
            if abs(h1 - h0) <= 1e-13:
                return self._remember(h1, slope)
            slope = min(max((f1 - f0) / (h1 - h0), 1e-6 * area), area)
            h0, f0 = h1, f1
        body = self.hydro.volume_below(self.hydro.highest(u), u)
        top = floor + 1.001 * (volume + body) / area  # f(top) >= 0.001 (volume + body) > 0
        h = brentq(f, floor, top, xtol=1e-14, rtol=1e-15, maxiter=200)
        return self._remember(h, slope)

    def _remember(self, level: float, slope: float) -> float:
        self._last_level, self._last_slope = level, slope
        return level

    def assemble(self, t: float, u=None) -> PETSc.Vec:
        """The load at time t on the geometry x + u (u ignored unless follower loading is on).
        Reassembled only when the level changes or, with follower loading, when the surface
        has moved by more than reuse_tol of its largest displacement since the last assembly
        (below that the load differs by less than the follower iteration's own tolerance)."""
        u = u if self.fluid.follower else None
        level = self.level_at(t, u)
        self.reused_last = not (level != self._assembled_key or (u is not None and self._surface_moved(u)))
        if not self.reused_last:
            self.hydro.assemble(level, u)
            self.assemblies += 1
            if u is not None:
                self._assembled_surface = self._surface_values(u).copy()
        else:
            self.reuses += 1
        self._assembled_key = level
        self.level = level
        return self.hydro.vector

    def _surface_values(self, u) -> np.ndarray:
        if self._surface_dofs is None:
            f = self.hydro.facets
            dofs = [f.vertex_dofs.ravel()] + ([f.edge_dofs.ravel()] if f.edge_dofs is not None else [])
            self._surface_dofs = np.unique(np.concatenate(dofs))
        return u.x.array.reshape(-1, 3)[self._surface_dofs]

    def _surface_moved(self, u) -> bool:
        """Has the surface moved by more than reuse_tol x its largest displacement (global)?"""
        if self._assembled_surface is None or self.fluid.reuse_tol == 0.0:
            return True
        now = self._surface_values(u)
        comm = self.hydro.comm
        moved = comm.allreduce(float(np.abs(now - self._assembled_surface).max(initial=0.0)), op=MPI.MAX)
        size = comm.allreduce(float(np.abs(now).max(initial=0.0)), op=MPI.MAX)
        return moved > self.fluid.reuse_tol * size
