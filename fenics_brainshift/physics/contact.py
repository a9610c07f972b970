"""Frictionless contact of the body's surface nodes with a rigid skull, by an augmented
Lagrangian (node-wise, Alart-Curnier's form without friction).

Each surface vertex i, with its share w_i of the surface area, carries the contact pressure

    p_i = max(0, lambda_i - k phi(x_i + u_i)),     force  f_i = w_i p_i grad phi,


phi the skull's distance field (physics/skull.py: negative past the skull), lambda_i its
multiplier and k a penalty (Pa/m) set from the stiffness and the mesh size, not by hand:
Newton solves the equilibrium for fixed multipliers, then lambda <- p, until the deepest
node is within the scene's tolerance. The pressure pushes along grad phi only, so nodes
slide freely along the skull. The tangent of -f is w k n n^T on every pressed node plus the
turning of n where the closest point is an edge or corner of the skull (both taken by
central differences of the node's force). Pairs are (surface facet, vertex): a node's pressure is the same in all its
facets, each adding a third of its area; the owning rank of each facet's cell adds it.
"""
from __future__ import annotations

import dolfinx.la
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

PENALTY_FACTOR = 10.0  # k = PENALTY_FACTOR x E / (the surface's median edge length)
SMOOTHING = 0.1  # the kink of the pressure is rounded over this fraction of the tolerance
FD_STEP = 1e-7  # the central-difference step of the tangent, relative to the element size


class SkullContact:
    def __init__(self, V, facets, skull, E: float, tolerance: float):
        self.V, self.skull, self.tolerance = V, skull, tolerance
        self.comm = V.mesh.comm
        self.dofs = facets.vertex_dofs.astype(np.int32)  # (F, 3) block dofs of the facets' vertices
        self.X = facets.x_vertices  # (F, 3, 3)
        X = self.X
        area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
        self.weights = np.repeat(area[:, None] / 3.0, 3, axis=1)  # (F, 3) m2 per pair
        edges = np.linalg.norm(X - np.roll(X, 1, axis=1), axis=2).ravel()
        h = self.comm.allreduce(float(np.median(edges)) if edges.size else 0.0, op=MPI.MAX)
        self.h = max(h, 1e-300)
        self.static_penalty = self.penalty = PENALTY_FACTOR * E / self.h
        self.multipliers = np.zeros(self.dofs.shape)  # Pa, per pair
        self.vector = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self._n_owned = V.dofmap.index_map.size_local
        self._area = None  # nodal surface areas, for the pressure output

    def nodal_pressure(self, u) -> np.ndarray:
        """The contact pressure (Pa) at every owned block dof of V: the node's force over its
        share of the surface area (0 off the surface)."""
        if self._area is None:
            self._area = self.vector.duplicate()
            with self._area.localForm() as local:
                local.set(0.0)
                np.add.at(local.array.reshape(-1, 3)[:, 0], self.dofs.ravel(), self.weights.ravel())
            self._area.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        force = np.linalg.norm(self.assemble(u).array_r.reshape(-1, 3), axis=1)
        area = self._area.array_r.reshape(-1, 3)[:, 0]
        return np.divide(force, area, out=np.zeros_like(force), where=area > 0)

    def for_time_step(self, c_mass: float, density: float) -> None:
        """In a time step inertia stiffens every node by c_mass M: the penalty follows it (else
        an impact needs dozens of multiplier updates): PENALTY_FACTOR (E / h + c_mass rho h)."""
        self.penalty = self.static_penalty + PENALTY_FACTOR * c_mass * density * self.h

    def _pressures(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(phi (F, 3), unit normals (F, 3, 3), pressures (F, 3)) at the displacement u."""
        y = self.X + u.x.array.reshape(-1, 3)[self.dofs]
        phi, normal = self.skull.phi(y.reshape(-1, 3))
        phi, normal = phi.reshape(self.dofs.shape), normal.reshape(self.X.shape)
        return phi, normal, self._pressure(self.multipliers, phi)

    def _pressure(self, multipliers: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """max(0, lambda - k phi), its kink rounded over SMOOTHING x tolerance: Newton then
        does not cycle between a node's two sides of the kink (the rounding's force on a node
        further off the skull than a few tolerances is below round-off)."""
        width = SMOOTHING * self.tolerance
        z = (multipliers / self.penalty - phi) / width
        return self.penalty * width * (np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z))))

    def assemble(self, u) -> PETSc.Vec:
        """The contact forces at u into self.vector (owned entries summed over ranks)."""
        _, normal, p = self._pressures(u)
        with self.vector.localForm() as local:
            local.set(0.0)
            values = local.array.reshape(-1, 3)
            np.add.at(values, self.dofs.ravel(), ((self.weights * p)[..., None] * normal).reshape(-1, 3))
        self.vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self.vector

    def _forces(self, y: np.ndarray, multipliers: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Contact forces (n, 3) of pairs at positions y (n, 3)."""
        phi, normal = self.skull.phi(y)
        return (weights * self._pressure(multipliers, phi))[:, None] * normal

    def add_tangent(self, A: PETSc.Mat, u, scale: float = 1.0) -> None:
        """A += scale d(-f)/du on the pressed nodes (A assembled after). Each node's force depends on
        its own position only, so its 3x3 block is taken by central differences: the pressure
        term w k n n^T and the turning of n around the skull's edges and corners alike."""
        phi, _, _ = self._pressures(u)
        # a node just touching is pressed with half the penalty (the rounded kink): a body
        # resting on the skull at rest then has a regular tangent
        pressed = self.multipliers / self.penalty - phi >= -40.0 * SMOOTHING * self.tolerance
        if np.any(pressed):
            y = (self.X + u.x.array.reshape(-1, 3)[self.dofs])[pressed]
            lam, w = self.multipliers[pressed], self.weights[pressed]
            h = FD_STEP * np.sqrt(3.0 * w.max())  # of the element size
            blocks = np.empty((len(y), 3, 3))
            for j in range(3):
                step = np.zeros(3)
                step[j] = h
                blocks[:, :, j] = -scale * (self._forces(y + step, lam, w) - self._forces(y - step, lam, w)) / (2 * h)
            for dof, block in zip(self.dofs[pressed], blocks):
                A.setValuesBlockedLocal([dof], [dof], block.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
        A.assemble()

    def update_multipliers(self, u) -> None:
        self.multipliers = self._pressures(u)[2]

    def penetration(self, u) -> float:
        """The deepest any surface node is past the skull (m, 0 if none)."""
        phi = self._pressures(u)[0]
        return self.comm.allreduce(float(max(0.0, -phi.min(initial=np.inf))), op=MPI.MAX)

    def violation(self, u) -> float:
        """How far the contact conditions are from holding (m): the largest |min(phi, p / k)|
        over the nodes, which counts a node past the skull (phi < 0) and a node pushed while
        off it (p > 0 with phi > 0, a stale multiplier) alike. The multipliers are updated
        until this is within the tolerance."""
        phi, _, p = self._pressures(u)
        local = float(np.abs(np.minimum(phi, p / self.penalty)).max(initial=0.0))
        return self.comm.allreduce(local, op=MPI.MAX)

    def clearance(self, u) -> float:
        """The smallest room left between the surface and the skull (m; negative: penetration)."""
        return self.comm.allreduce(float(self._pressures(u)[0].min(initial=np.inf)), op=MPI.MIN)

    def report(self, u) -> dict:
        """Total contact force (N), pressed nodes, deepest penetration and clearance (m)."""
        self.assemble(u)
        owned = self.vector.array_r.reshape(-1, 3)[: self._n_owned]
        total = self.comm.allreduce(owned.sum(axis=0), op=MPI.SUM)
        size = np.linalg.norm(owned, axis=1)
        largest = self.comm.allreduce(float(size.max(initial=0.0)), op=MPI.MAX)
        pressed = self.comm.allreduce(int(np.count_nonzero(size > 1e-6 * largest)), op=MPI.SUM)
        return {"force_N": [float(v) for v in total], "pressed_nodes": pressed,
                "max_penetration_m": self.penetration(u), "clearance_m": self.clearance(u),
                "penalty_Pa_per_m": self.penalty, "tolerance_m": self.tolerance}
