"""The fluid load by plain UFL quadrature: the reference the exact rule is measured against
(the kink of max(level - height, 0) at the water line makes it inexact on cut facets)."""

from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import create_vector
from petsc4py import PETSc

from .. import compat
from .forms import clipped_hydrostatic_pressure, pressure_load
from .gravity import assemble_into


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
        p = clipped_hydrostatic_pressure(x, rho_fluid, float(np.linalg.norm(g)), up, self.level)
        self.form = compat.form(pressure_load(v, p, ufl.FacetNormal(mesh), quadrature_degree))
        self.vector = create_vector(self.form)
        self._assembled_level: float | None = None

    def assemble(self, level: float) -> PETSc.Vec:
        """The nodal load at this level; not reassembled while the level is unchanged."""
        if level != self._assembled_level:
            self.level.value = level
            assemble_into(self.vector, self.form)
            self._assembled_level = level
        return self.vector
