"""The finite-element model of a scene: mesh, space, supports, matrices and loads.

Built once; the time loop and the quasi-static path both use it. Nothing here steps in time.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_matrix
from petsc4py import PETSc

from . import compat, forms
from .loads import FluidLoad, GravityLoad
from .meshing import build_mesh
from .scene import Scene, SceneError


@dataclass
class Model:
    scene: Scene
    mesh: object
    V: object
    bcs: list
    mu: float
    lmbda: float
    gravity: GravityLoad
    fluid: FluidLoad | None

    @property
    def comm(self):
        return self.mesh.comm

    # -- forms ---------------------------------------------------------------------------
    def _trial_test(self):
        return ufl.TrialFunction(self.V), ufl.TestFunction(self.V)

    @property
    def lumped(self) -> bool:
        return self.scene.element.mass == "lumped"

    def mass_form(self):
        u, v = self._trial_test()
        return forms.mass(u, v, PETSc.ScalarType(self.scene.material.density), self.lumped)

    def stiffness_form(self):
        u, v = self._trial_test()
        return forms.stiffness(u, v, PETSc.ScalarType(self.mu), PETSc.ScalarType(self.lmbda))

    def assemble(self, ufl_form, with_bcs: bool) -> PETSc.Mat:
        """A matrix; with_bcs: rows and columns of fixed dofs replaced by the identity."""
        A = assemble_matrix(fem.form(ufl_form), bcs=self.bcs if with_bcs else [])
        A.assemble()
        return A

    def combined(self, c_mass: float, c_stiff: float):
        """c_mass M + c_stiff K as one form (the effective matrix of a time scheme)."""
        return c_mass * self.mass_form() + c_stiff * self.stiffness_form()

    # -- sizes ---------------------------------------------------------------------------
    def sizes(self) -> dict:
        topo = self.mesh.topology
        im = self.V.dofmap.index_map
        return {
            "nodes": int(topo.index_map(0).size_global),
            "cells": int(topo.index_map(topo.dim).size_global),
            "dofs": int(im.size_global * self.V.dofmap.index_map_bs),
        }

    def external_load(self, t: float, u=None) -> tuple[PETSc.Vec, PETSc.Vec | None]:
        """(F_gravity, F_fluid at time t on the geometry x + u) as assembled vectors; the
        fluid part is None without a [fluid]."""
        fluid = self.fluid.assemble(t, u) if self.fluid is not None else None
        return self.gravity.vector, fluid


def fixed_conditions(V, scene: Scene) -> list:
    """Homogeneous Dirichlet conditions from the [[fixed]] predicates, per axis."""
    comm = V.mesh.comm
    bcs = []
    for region in scene.fixed:
        marker = region.predicate
        if region.axes == "xyz" or len(region.components) == 3:
            dofs = fem.locate_dofs_geometrical(V, marker)
            count = comm.allreduce(_owned_blocks(V, dofs))
            zero = np.zeros(3, dtype=PETSc.ScalarType)
            new = [fem.dirichletbc(zero, dofs, V)]
        else:
            new, count = [], 0
            for i in region.components:
                Vi, _ = V.sub(i).collapse()
                dofs = fem.locate_dofs_geometrical((V.sub(i), Vi), marker)
                count += comm.allreduce(int(np.sum(dofs[1] < Vi.dofmap.index_map.size_local)))
                new.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs[0], V.sub(i)))
        if count == 0:
            raise SceneError(f"[[fixed]] where = \"{region.where}\" selects no node of the mesh; "
                             f"check the coordinates (metres, mesh frame)")
        bcs.extend(new)
    return bcs


def _owned_blocks(V, block_dofs: np.ndarray) -> int:
    return int(np.sum(block_dofs < V.dofmap.index_map.size_local))


def build_model(scene: Scene, comm) -> Model:
    mesh = build_mesh(scene.mesh, comm)
    V = compat.vector_space(mesh, scene.element.degree)
    bcs = fixed_conditions(V, scene)
    mat = scene.material
    gravity = GravityLoad(V, mat.density, scene.gravity)
    fluid = FluidLoad(V, scene.fluid, scene.gravity) if scene.fluid is not None else None
    return Model(scene, mesh, V, bcs, mat.mu, mat.lmbda, gravity, fluid)
