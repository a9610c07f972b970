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
from .resection import Tissue, fill_empty_diagonal
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
    tissue: Tissue | None = None  # only for scenes with [[remove]]

    @property
    def comm(self):
        return self.mesh.comm

    # -- forms ---------------------------------------------------------------------------
    def _trial_test(self):
        return ufl.TrialFunction(self.V), ufl.TestFunction(self.V)

    @property
    def lumped(self) -> bool:
        return self.scene.element.mass == "lumped"

    def _present(self, coefficient: float):
        """A material coefficient, times the tissue indicator when cells can be removed."""
        c = PETSc.ScalarType(coefficient)
        return c * self.tissue.indicator if self.tissue is not None else c

    def mass_form(self):
        u, v = self._trial_test()
        return forms.mass(u, v, self._present(self.scene.material.density), self.lumped)

    def stiffness_form(self):
        u, v = self._trial_test()
        return forms.stiffness(u, v, self._present(self.mu), self._present(self.lmbda))

    def assemble(self, ufl_form, with_bcs: bool) -> PETSc.Mat:
        """A matrix; with_bcs: rows and columns of fixed dofs replaced by the identity, and
        (after a resection) a unit diagonal on rows with no tissue left, so the matrix that
        is solved stays regular."""
        A = assemble_matrix(fem.form(ufl_form), bcs=self.bcs if with_bcs else [])
        A.assemble()
        if with_bcs and self.tissue is not None:
            fill_empty_diagonal(A)
        return A

    def mass_matrix(self) -> PETSc.Mat:
        """M without supports, for products: a lumped mass keeps only its diagonal (the
        assembled matrix carries the full stiffness pattern, full of zeros: a product with
        it cost as much as one with K, 0.65 ms on the 15k-dof brain, against 0.014 ms)."""
        if not self.lumped:
            return self.assemble(self.mass_form(), with_bcs=False)
        full = self.assemble(self.mass_form(), with_bcs=False)
        diagonal = full.getDiagonal()
        full.destroy()
        return diagonal_matrix(diagonal)

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


def diagonal_matrix(diagonal: PETSc.Vec) -> PETSc.Mat:
    """A matrix holding only the given diagonal (same parallel layout)."""
    sizes = diagonal.getSizes()
    D = PETSc.Mat().createAIJ((sizes, sizes), nnz=(1, 0), comm=diagonal.getComm())
    D.setDiagonal(diagonal)
    D.assemble()
    return D


def fixed_conditions(V, scene: Scene) -> list:
    """Homogeneous Dirichlet conditions from the [[fixed]] predicates, per axis.

    The predicate is evaluated on the mesh's own vertex coordinates (and, for P2, an edge's
    dofs are fixed when both its vertices are), not on tabulated dof coordinates: those are
    recomputed cell by cell and round differently on different partitions, so a region whose
    bound falls on a grid plane (y < -0.0985 on a 5 mm voxel mesh) would select different
    nodes for different rank counts."""
    import dolfinx.mesh

    mesh, comm = V.mesh, V.mesh.comm
    tdim = mesh.topology.dim
    dims = [0, 1] if compat.element_degree(V) == 2 else [0]
    for dim in dims:
        mesh.topology.create_connectivity(dim, tdim)
    bcs = []
    for region in scene.fixed:
        entities = {dim: dolfinx.mesh.locate_entities(mesh, dim, region.predicate) for dim in dims}
        count = comm.allreduce(int(np.sum(entities[0] < mesh.topology.index_map(0).size_local)))
        if count == 0:
            raise SceneError(f"[[fixed]] where = \"{region.where}\" selects no node of the mesh; "
                             f"check the coordinates (metres, mesh frame)")
        if len(region.components) == 3:
            dofs = np.unique(np.concatenate([fem.locate_dofs_topological(V, d, e) for d, e in entities.items()]))
            bcs.append(fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs.astype(np.int32), V))
        else:
            for i in region.components:
                dofs = np.unique(np.concatenate([fem.locate_dofs_topological(V.sub(i), d, e)
                                                 for d, e in entities.items()]))
                bcs.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs.astype(np.int32), V.sub(i)))
    return bcs


def build_model(scene: Scene, comm) -> Model:
    mesh = build_mesh(scene.mesh, comm)
    V = compat.vector_space(mesh, scene.element.degree)
    bcs = fixed_conditions(V, scene)
    mat = scene.material
    tissue = Tissue(mesh, scene) if scene.remove else None
    density = PETSc.ScalarType(mat.density) * (tissue.indicator if tissue is not None else 1.0)
    gravity = GravityLoad(V, density, scene.gravity)
    fluid = FluidLoad(V, scene.fluid, scene.gravity) if scene.fluid is not None else None
    return Model(scene, mesh, V, bcs, mat.mu, mat.lmbda, gravity, fluid, tissue)
