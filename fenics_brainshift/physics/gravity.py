"""Gravity as an assembled load vector, and helpers for assembled vectors."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector, create_vector
from petsc4py import PETSc

from .. import compat
from .forms import body_force

if TYPE_CHECKING:
    from mpi4py import MPI


def assemble_into(b: PETSc.Vec, compiled_form) -> PETSc.Vec:
    """Assemble a linear form into b (zeroed first), summing ghost contributions to owners."""
    with b.localForm() as local:
        local.set(0.0)
    assemble_vector(b, compiled_form)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return b


def total_force(b: PETSc.Vec, comm: MPI.Intracomm) -> np.ndarray:
    """Sum of an assembled nodal load over all nodes: the resultant force (N), global."""
    local = b.getArray(readonly=True).reshape(-1, 3).sum(axis=0)
    return comm.allreduce(local)


class GravityLoad:
    """rho g over the volume of V's mesh; ``density`` is a number or a UFL coefficient (with the
    tissue indicator: call refresh() after a resection); ``gravity`` a 3-vector (m/s2)."""

    def __init__(self, V, density, gravity):
        mesh = V.mesh
        v = ufl.TestFunction(V)
        self.g = fem.Constant(mesh, np.array(gravity, dtype=PETSc.ScalarType))
        rho = PETSc.ScalarType(density) if isinstance(density, (int, float)) else density
        self.form = compat.form(body_force(v, rho, self.g))
        self.vector = assemble_into(create_vector(self.form), self.form)

    def set_gravity(self, gravity) -> None:
        """Another gravity vector (a head pose), reassembled."""
        self.g.value[:] = np.asarray(gravity, dtype=float)
        self.refresh()

    def refresh(self) -> None:
        assemble_into(self.vector, self.form)
