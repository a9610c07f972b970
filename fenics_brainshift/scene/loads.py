"""The loads: gravity, and the fluid (CSF or oil) with its level or volume schedule."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..errors import InputError
from .checks import choice, integer, non_negative, number, positive, vector3
from .schedule import Schedule


@dataclass(slots=True)
class Gravity:
    """[gravity]: the acceleration vector in the mesh's frame (m/s^2; default -9.81 along z)."""

    vector: tuple[float, float, float] = (0.0, 0.0, -9.81)

    def __post_init__(self):
        self.vector = vector3("[gravity] vector", self.vector)

    @property
    def magnitude(self) -> float:
        return math.sqrt(sum(c * c for c in self.vector))

    @property
    def up(self) -> tuple[float, float, float]:
        g = self.magnitude
        return tuple(-c / g for c in self.vector)  # type: ignore[return-value]


FLUID_RULES = ("consistent", "paper", "quadrature")
# where the follower load's fixed point stops, as a fraction of |u|. A settled state: on the
# 8 mm brain demo 1e-4 keeps the frontal pole within 0.1 um of 1e-6's answer in half the solves.
# A time step: its fixed point's error is then under a hundredth of the time step's own (dt
# against dt / 4 on the 10 mm brain's drain), in about half the solves of 1e-4
# (tests/test_follower_step.py; benchmarks/results/hyperelastic.md)
SETTLED_FOLLOWER_TOL = 1e-4
STEP_FOLLOWER_TOL = 1e-2


@dataclass(slots=True)
class Fluid:
    """CSF (or oil) with a free surface at a height along up = -gravity/|gravity|.

    Give the surface either as ``level`` (m, a number or [[t, h], ...]) or, for a container,
    as ``volume`` (m3, a number or [[t, V], ...]) with the container's ``container_area``
    (m2, its footprint) and ``floor`` (the floor's height along up, m): the level then follows
    from volume = area (level - floor) - submerged volume of the body, recomputed as the body
    deforms. ``rule``: "consistent" (exact integral of p N_i over the wet part), "paper"
    (the paper's depth-weighted nodal shares, P1), "quadrature" (plain UFL quadrature of
    degree ``quadrature_degree``, a reference). ``follower``: evaluate the load on the current
    geometry x + u (the paper does), iterated to convergence within each time step and each
    quasi-static solve (one step late would be unstable: docs/physics.md, Follower geometry)."""

    density: float = 1000.0
    level: Schedule | Any = None
    volume: Schedule | Any = None
    container_area: float | None = None
    floor: float = 0.0
    rule: str = "consistent"
    follower: bool | None = None  # None: true, except for the reference rule "quadrature"
    quadrature_degree: int = 4
    reuse_tol: float = 1e-8
    # the follower iteration stops when an update changes u by less than this fraction of |u|;
    # None: SETTLED_FOLLOWER_TOL for a settled state, STEP_FOLLOWER_TOL for a time step
    follower_tol: float | None = None

    def __post_init__(self):
        self.density = positive("[fluid] density", self.density)
        if (self.level is None) == (self.volume is None):
            raise InputError("[fluid] give exactly one of level (m) or volume (m3, with container_area)")
        if self.level is not None and not isinstance(self.level, Schedule):
            self.level = Schedule(self.level, "[fluid] level")
        if self.volume is not None:
            if not isinstance(self.volume, Schedule):
                self.volume = Schedule(self.volume, "[fluid] volume")
            for i, (_, v) in enumerate(self.volume.points):
                if v < 0:
                    raise InputError(f"[fluid] volume[{i}] must be >= 0 m3 (got {v:g})")
            if self.container_area is None:
                raise InputError("[fluid] volume needs container_area (m2), the container's footprint")
            self.container_area = positive("[fluid] container_area", self.container_area)
        self.floor = number("[fluid] floor", self.floor)
        choice("[fluid] rule", self.rule, FLUID_RULES)
        if self.follower is None:
            self.follower = self.rule != "quadrature"  # the UFL reference integrates on the reference geometry
        if not isinstance(self.follower, bool):
            raise InputError(f"[fluid] follower must be true or false (got {self.follower!r})")
        if self.rule == "quadrature" and self.follower:
            raise InputError(
                '[fluid] rule = "quadrature" integrates on the undeformed surface only: set '
                'follower = false, or use rule = "consistent" for follower loading'
            )
        self.quadrature_degree = integer("[fluid] quadrature_degree", self.quadrature_degree, 1)
        self.reuse_tol = non_negative("[fluid] reuse_tol", self.reuse_tol)
        if self.follower_tol is not None:
            self.follower_tol = positive("[fluid] follower_tol", self.follower_tol)
            if self.follower_tol >= 1.0:
                raise InputError(
                    f"[fluid] follower_tol is a fraction of the displacement and must be below 1 "
                    f"(got {self.follower_tol!r}); the default is {SETTLED_FOLLOWER_TOL:g} for a settled "
                    f"state, {STEP_FOLLOWER_TOL:g} for a time step"
                )

    def follower_tolerance(self, time_step: bool) -> float:
        """Where the follower load's fixed point stops (a fraction of |u|): follower_tol if
        given, else the default of a time step or of a settled state."""
        if self.follower_tol is not None:
            return self.follower_tol
        return STEP_FOLLOWER_TOL if time_step else SETTLED_FOLLOWER_TOL

    @property
    def schedule(self) -> Schedule:
        return self.level if self.level is not None else self.volume
