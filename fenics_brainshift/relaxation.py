"""Accelerated fixed-point iteration, for loads that depend on the displacement.

The follower fluid load F(x + u) makes each solve a fixed-point problem u = G(u). Plain
iteration diverges when the load's sensitivity to the geometry rivals the stiffness (measured
on the supine phantom: growth factor 1.26 per iteration), which happens for soft tissue deep
under water because linear elasticity has no initial-stress stiffness to balance the
pressure-load stiffness. Aitken's dynamic relaxation (Irons & Tuck 1969; Kuttler & Wall 2008)
picks the step length from the last two residuals and settles such cases in 10-20 solves;
Anderson mixing (below, the one the simulation uses) combines the last eight and, keeping
them from one time step to the next, needs about 7 solves per brain step and 11 for the
settled state from rest (Aitken: 9.9 and 18).
The coupling is strong because the pressure's load stiffness, p/h, is comparable with G: a
geometrically nonlinear model would balance it with the prestress's initial-stress stiffness.
"""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc


class AitkenRelaxation:
    def __init__(self, template: PETSc.Vec, omega: float = 1.0):
        self.omega0 = omega
        self.residual = template.duplicate()
        self.last = template.duplicate()
        self.diff = template.duplicate()
        self.reset()

    def reset(self, keep_omega: bool = False) -> None:
        """Start a new fixed-point problem; keep_omega starts from the last factor (a time
        step's coupling is much like the previous step's)."""
        if not keep_omega:
            self.omega = self.omega0
        self.iteration = 0

    def update(self, x: PETSc.Vec, gx: PETSc.Vec) -> float:
        """x <- x + omega (G(x) - x), with omega from the last two residuals.
        Returns |G(x) - x|, for the caller to compare with its own scale."""
        r, last, diff = self.residual, self.last, self.diff
        gx.copy(r)
        r.axpy(-1.0, x)
        if self.iteration > 0:
            r.copy(diff)
            diff.axpy(-1.0, last)
            denominator = diff.dot(diff)
            if denominator > 0.0:
                self.omega = -self.omega * last.dot(diff) / denominator
        r.copy(last)
        self.iteration += 1
        x.axpy(self.omega, r)
        return r.norm()


class AndersonAcceleration:
    """Anderson mixing (type II, depth m) for the same fixed point u = G(u): the next iterate
    combines the last m+1 map values so that the linearised residual is least in the 2-norm
    (Walker & Ni 2011). The small least-squares problem is formed from global dot products,
    so it is the same on every rank. Same interface as AitkenRelaxation."""

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

    def reset(self, keep_omega: bool = False) -> None:
        """Start a new fixed-point problem. keep_omega (a time step like the last): keep the
        difference pairs, which sample the load's sensitivity to the geometry, much the same
        from step to step; otherwise forget them."""
        if not keep_omega:
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
