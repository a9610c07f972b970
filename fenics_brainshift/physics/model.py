"""The finite-element model: mesh, space, supports, material, matrices and loads.

Built once from plain values (runner/build.py makes them from a scene); the time loop and the
quasi-static path both use it. Nothing here steps in time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import ufl
from dolfinx.fem.petsc import assemble_matrix, create_vector
from petsc4py import PETSc

from .. import compat
from ..linalg import diagonal_matrix
from . import forms
from .constraints import Constraints
from .fluid import FluidLoad, FluidSettings
from .gravity import GravityLoad, assemble_into
from .growth import Growth
from .material import MODELS, Hyperelastic, LinearElastic, lame_parameters
from .resection import Tissue, cell_centroids, fill_empty_diagonal
from .septa import septum_nodes
from .supports import fixed_conditions


@dataclass
class Model:
    """The discrete model of a scene: the mesh, the space V, the supports, the Lame parameters and
    density, and the loads (gravity, fluid, growth, contact) the steppers assemble."""

    mesh: object
    V: object
    bcs: list
    mu: float
    lmbda: float
    density: float
    lumped: bool
    gravity: GravityLoad
    fluid: FluidLoad | None = None
    tissue: Tissue | None = None  # only when cells can be removed
    material_model: str = "linear"  # or "neo-hookean", "saint-venant-kirchhoff"
    # every external load times this: with nu fixed the internal force is proportional to G,
    # so the body at G solves as the body at G0 with the loads times G0 / G, on the same
    # factor (the calibration's stiffness, fit/forward.py); 1 otherwise
    load_scale: float = 1.0
    growth: Growth | None = None  # only when the tissue shrinks or swells
    _growth_form: object = field(default=None, repr=False)  # its linear load, compiled on first use
    _growth_vector: object = field(default=None, repr=False)
    _growth_scale: tuple = field(default=(None, 0.0), repr=False)  # (t, |load|): Newton asks it often
    constraints: Constraints | None = None  # supports and septa as one projector (constraints.py)

    def __post_init__(self):
        if self.constraints is None:
            self.constraints = Constraints(self.V, self.bcs)

    @classmethod
    def create(
        cls,
        mesh,
        degree: int,
        E: float,
        nu: float,
        density: float,
        gravity,
        supports=(),
        fluid: FluidSettings | None = None,
        cuts=(),
        lumped: bool | None = None,
        material_model: str = "linear",
        swelling=(),
        septa=(),
    ) -> Model:
        """A model on ``mesh``: Lagrange ``degree`` 1 or 2, a material (E Pa, nu; "linear",
        "neo-hookean" or "saint-venant-kirchhoff"), density (kg/m3), gravity (m/s2, 3-vector),
        supports (supports.Support), an optional fluid, cuts (resection.Cut); lumped mass by
        default for P1 (consistent for P2); swelling: (select: cell centroids (N, 3) -> bool,
        t -> volume change) pairs, the regions that shrink or swell; septa (septa.Septum): rigid
        membranes the tissue slides along."""
        if material_model not in MODELS:
            raise ValueError(f"material_model must be one of {', '.join(MODELS)} (got {material_model!r})")
        V = compat.vector_space(mesh, degree)
        bcs = fixed_conditions(V, supports)
        constraints = Constraints(V, bcs, [(s.name, *septum_nodes(V, s)) for s in septa])
        mu, lmbda = lame_parameters(E, nu)
        tissue = Tissue(mesh, cuts) if cuts else None
        rho = PETSc.ScalarType(density) * (tissue.indicator if tissue is not None else 1.0)
        fluid_load = FluidLoad(V, fluid) if fluid is not None else None
        growth = None
        if swelling:
            centroids = cell_centroids(mesh)
            growth = Growth(mesh, [(np.asarray(select(centroids), dtype=bool), change) for select, change in swelling])
        return cls(
            mesh,
            V,
            bcs,
            mu,
            lmbda,
            density,
            degree == 1 if lumped is None else lumped,
            GravityLoad(V, rho, gravity),
            fluid_load,
            tissue,
            material_model,
            growth=growth,
            constraints=constraints,
        )

    @property
    def comm(self):
        return self.mesh.comm

    # -- forms ---------------------------------------------------------------------------
    def _trial_test(self):
        return ufl.TrialFunction(self.V), ufl.TestFunction(self.V)

    def _present(self, coefficient: float):
        """A material coefficient, times the tissue indicator when cells can be removed."""
        c = PETSc.ScalarType(coefficient)
        return c * self.tissue.indicator if self.tissue is not None else c

    @property
    def nonlinear(self) -> bool:
        return self.material_model != "linear"

    @property
    def _stretch(self):
        return self.growth.stretch if self.growth is not None else 1.0

    @property
    def material(self) -> LinearElastic:
        """The linear material (for a hyperelastic model: its linearisation at u = 0)."""
        return LinearElastic(self._present(self.mu), self._present(self.lmbda), self._stretch)

    @property
    def hyperelastic(self) -> Hyperelastic:
        present = self.tissue.indicator if self.tissue is not None else 1.0
        return Hyperelastic.for_degree(
            self._present(self.mu),
            self._present(self.lmbda),
            self.material_model,
            compat.element_degree(self.V),
            present,
            self._stretch,
        )

    @property
    def constitutive(self) -> LinearElastic | Hyperelastic:
        """The material as the run solves it (its stress, von Mises, internal force)."""
        return self.hyperelastic if self.nonlinear else self.material

    def mass_form(self):
        u, v = self._trial_test()
        return forms.mass(u, v, self._present(self.density), self.lumped)

    def stiffness_form(self):
        u, v = self._trial_test()
        return self.material.stiffness(u, v)

    def combined(self, c_mass: float, c_stiff: float):
        """c_mass M + c_stiff K as one form (the effective matrix of a time scheme)."""
        return c_mass * self.mass_form() + c_stiff * self.stiffness_form()

    def assemble(self, ufl_form, with_bcs: bool) -> PETSc.Mat:
        """A matrix; with_bcs: rows and columns of fixed dofs replaced by the identity, (after
        a resection) a unit diagonal on rows with no tissue left, so the matrix that is solved
        stays regular, and the septa's normal parts taken out (constraints.py)."""
        A = assemble_matrix(compat.form(ufl_form), bcs=self.bcs if with_bcs else [])
        A.assemble()
        if with_bcs and self.tissue is not None:
            fill_empty_diagonal(A)
        if with_bcs:
            self.constraints.matrix(A, supports=False)
        return A

    def mass_matrix(self) -> PETSc.Mat:
        """M without supports, for products; a lumped mass keeps only its diagonal."""
        full = self.assemble(self.mass_form(), with_bcs=False)
        if not self.lumped:
            return full
        diagonal = full.getDiagonal()
        full.destroy()
        return diagonal_matrix(diagonal)

    # -- sizes and loads -------------------------------------------------------------------
    def sizes(self) -> dict:
        topo = self.mesh.topology
        im = self.V.dofmap.index_map
        return {
            "nodes": int(topo.index_map(0).size_global),
            "cells": int(topo.index_map(topo.dim).size_global),
            "dofs": int(im.size_global * self.V.dofmap.index_map_bs),
        }

    def cell_size(self) -> float:
        """A typical cell's size (m): the cube root of the mean cell volume, on every rank."""
        n_owned = self.mesh.topology.index_map(3).size_local
        x = self.mesh.geometry.x[compat.geometry_dofmap(self.mesh)[:n_owned, :4]]
        volume = np.abs(np.linalg.det(x[:, 1:] - x[:, :1])).sum() / 6.0
        total = self.comm.allreduce(float(volume))
        return (total / max(self.sizes()["cells"], 1)) ** (1.0 / 3.0)

    def external_load(self, t: float, u=None) -> tuple[PETSc.Vec, PETSc.Vec | None]:
        """(F_gravity, F_fluid at time t on the geometry x + u) as assembled vectors; the
        fluid part is None when dry."""
        fluid = self.fluid.assemble(t, u) if self.fluid is not None else None
        return self.gravity.vector, fluid

    def load_into(self, t: float, out: PETSc.Vec, u=None) -> PETSc.Vec:
        """F(t) = F_gravity + F_fluid into out (owned entries); with follower loading the fluid
        load is evaluated on x + u (a Function on V). With growth, its stretch is set to time t
        (a hyperelastic body's internal force then shrinks or swells) and a linear body gets the
        eigenstrain's load too, which load_scale leaves alone (it is proportional to the moduli,
        as the internal force is)."""
        grav, fluid = self.external_load(t, u)
        out.array[:] = grav.array_r if fluid is None else grav.array_r + fluid.array_r
        if self.load_scale != 1.0:
            out.scale(self.load_scale)
        if self.growth is not None:
            growth_load = self.growth_load(t)  # sets the stretch to t
            if not self.nonlinear:  # a hyperelastic body's internal force holds the growth
                out.axpy(1.0, growth_load)
        return out

    def tissue_changed(self) -> None:
        """After a resection: the loads that carry the tissue indicator, assembled again, and the
        fluid on the surface of the cells still present."""
        self.gravity.refresh()
        if self.fluid is not None:
            self.fluid.set_present(self.tissue.present)
        if self._growth_vector is not None:
            assemble_into(self._growth_vector, self._growth_form)
            self._growth_scale = (None, 0.0)

    def growth_scale(self, t: float) -> float:
        """What a hyperelastic body's growth weighs beside the loads at time t, for Newton's
        convergence test: |the linearised eigenstrain load| (its residual at rest). 0 for a
        linear body (load_into holds its growth) and without growth."""
        if self.growth is None or not self.nonlinear:
            return 0.0
        if self._growth_scale[0] != t:  # the convergence test asks at every line-search trial
            self._growth_scale = (t, self.growth_load(t).norm())
        return self._growth_scale[1]

    def growth_load(self, t: float) -> PETSc.Vec:
        """The linear(ised) eigenstrain load at time t, with the stretch set to t (a linear
        body's load; a hyperelastic body's Newton starts from its answer); assembled
        again only when the stretch changed."""
        changed = self.growth.set_time(t)
        if self._growth_form is None:
            self._growth_form = compat.form(self.material.growth_load(ufl.TestFunction(self.V)))
            self._growth_vector = assemble_into(create_vector(self._growth_form), self._growth_form)
        elif changed:
            assemble_into(self._growth_vector, self._growth_form)
        return self._growth_vector
