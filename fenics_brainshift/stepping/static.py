"""The quasi-static path: K u = F(t), the settled state for a load that changes slowly."""

from __future__ import annotations

import dolfinx.la

from .settle import Settle
from .solves import Solves
from .state import State


class StaticSolver:
    """Settled states of a Model: K (with supports) factored or preconditioned once, then one
    solve per load (iterated with follower loading), each from the previous answer."""

    def __init__(self, model, state: State, solves: Solves, follower_tolerance: float = 1e-4):
        self.model, self.state, self.solves = model, state, solves
        V = model.V
        self._rhs = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self.settle = Settle(self._rhs, model.constraints, model.fluid, follower_tolerance)
        self.K = None

    def setup(self) -> None:
        self.K = self.model.assemble(self.model.stiffness_form(), with_bcs=True)
        self.solves.reset(self.K)

    def solve(self, t: float) -> int:
        """u for the loads at time t; returns the Krylov iterations of the last solve."""
        its = self.settle(
            self.state.u,
            lambda: self.model.load_into(t, self._rhs, self.state.u),
            self.solves,
            t,
            scale=0.0,
            same_problem=False,
        )
        self.state.t = t
        return its

    def destroy(self) -> None:
        if self.K is not None:
            self.K.destroy()
        self.solves.destroy()
