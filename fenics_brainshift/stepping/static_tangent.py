"""Newton's tangent for a settled state (newton.py): assembled as a matrix, or, for a linear
body against the skull whose solves are preconditioned exactly by K's factor, as an action
(tangent_action.py). Both add the follower load's tangent (physics/load_tangent.py) and the
pressed nodes' contact blocks, and both are projected by the constraints."""

from __future__ import annotations

from petsc4py import PETSc

from ..physics.load_tangent import add_load_tangent, load_tangent_blocks
from .tangent import reassemble, tangent_type
from .tangent_action import TangentAction


class StaticTangent:
    """model, state: the Newton solve's; form: the compiled tangent form (a linear material's
    is its stiffness); contact: a SkullContact or None; follower_load: whether the follower
    load's tangent is added (False: a baseline that leaves it out)."""

    def __init__(self, model, state, form, contact, follower_load: bool):
        self.model, self.state, self.contact = model, state, contact
        self._form = form
        self.follower_load = follower_load
        self.K0: PETSc.Mat | None = None  # a linear material's stiffness, in the tangent's storage
        self._A: PETSc.Mat | None = None  # the tangent, assembled anew into the same matrix each iteration
        self._action: TangentAction | None = None
        self.contact_blocks = None  # the contact's blocks at the last tangent

    def stiffness(self) -> PETSc.Mat:
        """K of a linear material (made once; also the residual's K u product)."""
        if self.K0 is None:
            self.K0 = reassemble(None, self._form, tangent_type(self.model))
        return self.K0

    def _wet(self) -> bool:
        """Is the follower load's tangent added now (a fluid level is known)?"""
        fluid = self.model.fluid
        return self.follower_load and fluid.level == fluid.level

    def matrix(self, factor: float, with_load: bool = True) -> PETSc.Mat:
        """The tangent with supports, into the one matrix kept for it (its sparsity built once)."""
        if self.model.nonlinear:
            A = self._A = reassemble(self._A, self._form, tangent_type(self.model))
        else:  # the linear material's part never changes: copied, not assembled again
            K0 = self.stiffness()
            if self._A is None:  # (a duplicate of K0 lacks the local numbering)
                self._A = reassemble(None, self._form, tangent_type(self.model))
            A = self._A
            K0.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        if with_load and self._wet():
            fluid = self.model.fluid
            add_load_tangent(A, fluid.hydro, fluid.level, self.state.u, -factor * self.model.load_scale)
        if self.contact is not None:
            self.contact_blocks = self.contact.tangent_blocks(self.state.u)
            self.contact.add_tangent(A, None, blocks=self.contact_blocks)
        self.model.constraints.matrix(A)
        return A

    def action(self, K: PETSc.Mat, factor: float) -> PETSc.Mat:
        """A linear body's tangent against the skull as an action: K with the constraints (the
        matrix K's factor was made of) and this iteration's load and contact blocks."""
        self.stiffness()
        if self._action is None or self._action.K is not K:
            if self._action is not None:
                self._action.free()
            self._action = TangentAction(K, self.model.constraints, self.model.V)
        load = None
        if self._wet():
            fluid = self.model.fluid
            rows, cols, blocks = load_tangent_blocks(fluid.hydro, fluid.level, self.state.u)
            load = (rows, cols, (-factor * self.model.load_scale) * blocks)
        self.contact_blocks = self.contact.tangent_blocks(self.state.u)
        self._action.set(load, self.contact_blocks)
        return self._action.mat

    def destroy(self) -> None:
        for matrix in (self._A, self.K0):
            if matrix is not None:
                matrix.destroy()
        if self._action is not None:
            self._action.free()
