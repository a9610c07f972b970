"""External loads as assembled vectors: gravity (constant) and the fluid pressure (per level).

The fluid load here integrates the clipped pressure with a fixed quadrature degree. The kink
of max(level - height, 0) at the water line makes that inexact on cut facets; the total force
converges with refinement but does not satisfy Archimedes to round-off.
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector, create_vector
from petsc4py import PETSc

from . import forms
from .scene import Fluid, Gravity


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
    def __init__(self, V, density: float, gravity: Gravity):
        mesh = V.mesh
        v = ufl.TestFunction(V)
        g = fem.Constant(mesh, np.array(gravity.vector, dtype=PETSc.ScalarType))
        self.form = fem.form(forms.body_force(v, PETSc.ScalarType(density), g))
        self.vector = assemble_into(create_vector(self.form), self.form)


class QuadratureFluidLoad:
    """-p n on the exterior surface, p = rho_f |g| max(level - x.up, 0), by quadrature."""

    def __init__(self, V, fluid: Fluid, gravity: Gravity):
        mesh = V.mesh
        v = ufl.TestFunction(V)
        self.level = fem.Constant(mesh, PETSc.ScalarType(0.0))
        up = fem.Constant(mesh, np.array(gravity.up, dtype=PETSc.ScalarType))
        x = ufl.SpatialCoordinate(mesh)
        p = forms.clipped_hydrostatic_pressure(x, fluid.density, gravity.magnitude, up, self.level)
        self.form = fem.form(forms.pressure_load(v, p, ufl.FacetNormal(mesh), fluid.quadrature_degree))
        self.vector = create_vector(self.form)
        self._assembled_level: float | None = None

    def assemble(self, level: float) -> PETSc.Vec:
        """The nodal load at this level; not reassembled while the level is unchanged."""
        if level != self._assembled_level:
            self.level.value = level
            assemble_into(self.vector, self.form)
            self._assembled_level = level
        return self.vector
