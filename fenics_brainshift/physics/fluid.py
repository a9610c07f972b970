"""The fluid's nodal load at time t: the level from a schedule, or from a fluid volume in a
container (then it depends on how much of the body is under water), assembled exactly
(hydrostatic.py) and reassembled only when something changed."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..errors import InputError, SolverError
from .hydrostatic import HydrostaticLoad


@dataclass(frozen=True)
class FluidSettings:
    """Plain values for a FluidLoad. Give ``level`` (t -> height along up, m) or ``volume``
    (t -> m3, with ``container_area`` m2 and ``floor`` m); ``rule``: "consistent", "paper" or
    "quadrature"; ``follower``: evaluate on x + u; ``reuse_tol``: see FluidLoad.assemble."""

    density: float
    gravity: tuple[float, float, float]
    rule: str = "consistent"
    follower: bool = True
    reuse_tol: float = 1e-8
    quadrature_degree: int = 4
    level: Callable[[float], float] | None = None
    volume: Callable[[float], float] | None = None
    container_area: float | None = None
    floor: float = 0.0


class FluidLoad:
    """The fluid's nodal load at time t on a vector space V (FluidSettings says how)."""

    def __init__(self, V, settings: FluidSettings):
        self.settings = settings
        self.hydro = HydrostaticLoad(V, settings.density, settings.gravity, settings.rule, settings.quadrature_degree)
        self.level = float("nan")
        self._assembled_key = None
        self._surface_dofs = None
        self._assembled_surface = None
        self.assemblies = 0
        self.reuses = 0
        self.reused_last = False
        self._last_level = float("nan")
        self._last_slope = settings.container_area or 1.0
        if settings.volume is not None:
            self._check_container()

    @property
    def follower(self) -> bool:
        return self.settings.follower

    def _check_container(self) -> None:
        """The floor is at or below the body, and the body fits in the container: its
        horizontal cross-section (from the volume below heights 1/64 of its height apart) is
        smaller than the footprint, else the level equation has no unique root."""
        s, hydro = self.settings, self.hydro
        top = hydro.highest()
        body = hydro.volume_below(top)
        if hydro.volume_below(s.floor) > 1e-9 * body:
            raise InputError(
                f"[fluid] floor = {s.floor:g} m cuts through the body; it must be at or below the body's lowest point"
            )
        bottom = -hydro.highest(up=-1.0)
        heights = np.linspace(bottom, top, 65)
        volumes = np.array([hydro.volume_below(h) for h in heights])
        section = float(np.max(np.diff(volumes) / np.diff(heights)))
        if s.container_area <= section:
            raise InputError(
                f"[fluid] container_area = {s.container_area:g} m2 is not larger than the body's "
                f"horizontal cross-section ({section:.3g} m2): the body does not fit in the container; "
                f"give the container's floor area in m2"
            )

    def set_present(self, present) -> None:
        """After a resection: act on the surface of the cells still present."""
        self.hydro.set_present(present)
        self._assembled_key = None
        self._surface_dofs = None
        self._assembled_surface = None

    def set_gravity(self, gravity) -> None:
        """Another gravity vector (a head pose): the level is a height along the new up."""
        self.settings = replace(self.settings, gravity=tuple(float(c) for c in gravity))
        self.hydro.set_gravity(gravity)
        self._assembled_key = None

    def set_level(self, level: float) -> None:
        """A constant level (m along up) from now on, whatever the schedule said."""
        if self.settings.level is None:
            raise ValueError("a fluid given by its volume has no level to set")
        self.settings = replace(self.settings, level=lambda t, h=float(level): h)
        self._assembled_key = None

    def level_at(self, t: float, u=None) -> float:
        s = self.settings
        if s.level is not None:
            return s.level(t)
        return self.container_level(s.volume(t), u)

    def container_level(self, volume: float, u=None) -> float:
        """Solve f(h) = area (h - floor) - V_below(h) - volume = 0 for the level h.

        f is increasing (f' = area - wet cross-section, in (0, area]), so secant steps from
        the last level settle in two or three surface integrals; Brent's method on a
        guaranteed bracket takes over if they do not."""
        from scipy.optimize import brentq

        area, floor = self.settings.container_area, self.settings.floor
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
        try:
            h = brentq(f, floor, top, xtol=1e-14, rtol=1e-15, maxiter=200)
        except (ValueError, RuntimeError) as exc:  # no sign change, or no convergence
            raise SolverError(
                f"the fluid level for a volume of {volume:g} m3 could not be found ({exc}); "
                f"check [fluid] container_area and floor"
            ) from None
        return self._remember(h, slope)

    def _remember(self, level: float, slope: float) -> float:
        self._last_level, self._last_slope = level, slope
        return level

    def assemble(self, t: float, u=None) -> PETSc.Vec:
        """The load at time t on the geometry x + u (u ignored unless follower loading is on).
        Reassembled only when the level changes or, with follower loading, when the surface
        has moved by more than reuse_tol of its largest displacement since the last assembly
        (below that the load differs by less than the follower iteration's own tolerance)."""
        u = u if self.settings.follower else None
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
        if self._assembled_surface is None or self.settings.reuse_tol == 0.0:
            return True
        now = self._surface_values(u)
        comm = self.hydro.comm
        moved = comm.allreduce(float(np.abs(now - self._assembled_surface).max(initial=0.0)), op=MPI.MAX)
        size = comm.allreduce(float(np.abs(now).max(initial=0.0)), op=MPI.MAX)
        return moved > self.settings.reuse_tol * size
