"""Anderson acceleration of a fixed-point iteration u = G(u), for loads that depend on the
displacement.

Plain iteration of the follower fluid load diverges when the load's sensitivity to the
geometry rivals the stiffness, which happens for soft tissue deep under water: the pressure's
load stiffness, p/h, is comparable with G, and linear elasticity has no initial-stress
stiffness to balance it. Anderson mixing combines the last m map values and, keeping them from
one time step to the next, settles such steps in a few solves (docs/performance.md).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc


class AndersonAcceleration:
    """Anderson mixing (type II, depth m) for the same fixed point u = G(u): the next iterate
    combines the last m+1 map values so that the linearised residual is least in the 2-norm
    (Walker & Ni 2011). The small least-squares problem is formed from global dot products,
    so it is the same on every rank."""

    def __init__(self, template: PETSc.Vec, depth: int = 8, regularisation: float = 1e-12):
        import collections

        self.depth = depth
        self.regularisation = regularisation
        self.residual = template.duplicate()
        self.last_residual = template.duplicate()
        self.last_map = template.duplicate()
        self.dF = collections.deque(maxlen=depth)  # residual differences
        self.dG = collections.deque(maxlen=depth)  # map-value differences
        # dF_i . dF_j, kept up to date: m new dot products per iteration instead of the m^2
        # (each a reduction in parallel) of rebuilding it
        self.gram = np.zeros((0, 0))
        self._spare: list[PETSc.Vec] = []
        self.template = template
        self.iteration = 0

    def reset(self, keep_history: bool = False) -> None:
        """Start a new fixed-point problem. keep_history (a time step like the last): keep the
        difference pairs, which sample the load's sensitivity to the geometry, much the same
        from step to step; otherwise forget them."""
        if not keep_history:
            while self.dF:
                self._spare += [self.dF.pop(), self.dG.pop()]
            self.gram = np.zeros((0, 0))
        self.iteration = 0

    def _vector(self) -> PETSc.Vec:
        return self._spare.pop() if self._spare else self.template.duplicate()

    def update(self, x: PETSc.Vec, gx: PETSc.Vec) -> float:
        """x <- the Anderson combination of the map values; returns |G(x) - x|."""
        r = self.residual
        gx.copy(r)
        r.axpy(-1.0, x)
        norm = r.norm()
        if self.iteration > 0:
            if len(self.dF) == self.depth:  # recycle the oldest pair
                self._spare += [self.dF.popleft(), self.dG.popleft()]
                self.gram = self.gram[1:, 1:]
            df, dg = self._vector(), self._vector()
            r.copy(df)
            df.axpy(-1.0, self.last_residual)
            gx.copy(dg)
            dg.axpy(-1.0, self.last_map)
            self.dF.append(df)
            self.dG.append(dg)
            row = np.array([df.dot(v) for v in self.dF])
            m = len(self.dF)
            gram = np.empty((m, m))
            gram[:-1, :-1] = self.gram
            gram[-1, :] = gram[:, -1] = row
            self.gram = gram
        r.copy(self.last_residual)
        gx.copy(self.last_map)
        gx.copy(x)  # plain iteration, then the correction below
        if self.dF:
            m = len(self.dF)
            rhs = np.array([v.dot(r) for v in self.dF])
            normal = self.gram + self.regularisation * np.trace(self.gram) * np.eye(m)
            gamma = np.linalg.solve(normal, rhs)
            x.maxpy(-gamma, list(self.dG))
        self.iteration += 1
        return norm
