"""Frictionless contact of the body's surface nodes with a rigid skull, by an augmented
Lagrangian whose multiplier at each node is a vector (the projection form of Alart-Curnier's,
without friction).

Each surface vertex i, with its share w_i of the surface area (a third of each surface
triangle it is a corner of), at y_i = x_i + u_i, carries the force

    f_i = w_i p(z_i) grad phi(z_i),   z_i = y_i - lambda_i / k,   p(z) = k max(0, -phi(z)),

phi the skull's distance field (surfaces/skull.py: negative past the skull), lambda_i the
node's multiplier (a pressure vector, Pa) and k a penalty (Pa/m) set from the stiffness and
the mesh size, not by hand (and, in a time step, from the inertia too). That force is
k (z's nearest point inside the skull - z) (the kink aside): on a flat wall, the scalar form
max(0, lambda . n - k phi(y)) n. The multiplier is a vector because a node may press two
walls at once (a concave edge of the skull): the force needed there is any vector between
the walls' normals, and with a scalar multiplier along grad phi(y) its direction was set by
where the node sat micrometres past the edge, turning at a rate of 1/phi as it moved
(benchmarks/results/contact_box_corner.md); with lambda / k the shifted point z lies
|lambda| / k past the edge, and the direction turns no faster than k / |lambda|. The kink
of max is rounded over a tenth of the tolerance, so that Newton does not cycle between a
node's two sides of it. Newton solves the equilibrium for fixed multipliers, then
lambda <- p(z) grad phi(z), until the contact conditions hold to the scene's tolerance: no
node deeper past the skull, and none pushed while off it. The force is along the skull's
normal at z's nearest point, so nodes slide freely along the skull. The tangent of -f, each
node's 3x3 block, is taken by central differences of the node's force: the pressure term
w k n n^T and the turning of n around the skull's edges and corners alike. A node off the
skull adds nothing to it: where no fraction of Newton's step reduces the residual, the step
is taken as far as the first such node's contact (step_limit; stepping/newton.py's watchdog).

Distances are the cost: phi is 1-Lipschitz, so a point whose last exact phi, less how far it
has moved since, still leaves it far from the skull cannot be pressed, and is not queried
again (its phi is then that lower bound). On N ranks each rank handles the vertices of the
surface facets of its cells, with its share of their area; the forces are summed over ranks.
"""

from __future__ import annotations

from typing import NamedTuple

import dolfinx.la
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

PENALTY_FACTOR = 10.0  # k = PENALTY_FACTOR x E / (the surface's median edge length)
SMOOTHING = 0.1  # the kink of the pressure is rounded over this fraction of the tolerance
REACH = 40.0  # a node more than REACH rounding widths off the skull (beyond lambda / k) is free
FD_STEP = 1e-7  # the central-difference step of the tangent, relative to the element size


def _add_blocks(A: PETSc.Mat, dofs: np.ndarray, blocks: np.ndarray) -> None:
    """A[dof, dof] += block for each node (block-local numbering), then A assembled."""
    for dof, block in zip(dofs, blocks):
        A.setValuesBlockedLocal([dof], [dof], block.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
    A.assemble()


class _Distances:
    """phi and grad phi at the nodes' points, exact only where they may matter: a point whose
    last exact phi, less how far it has moved since, is above ``reach`` (per node) keeps that
    lower bound (phi is 1-Lipschitz) and its last normal."""

    def __init__(self, skull, n: int):
        self.skull = skull
        self.queries = 0
        self._y = np.full((n, 3), np.nan)  # where phi was last computed exactly
        self._phi = np.zeros(n)
        self._normal = np.zeros((n, 3))

    def __call__(self, y: np.ndarray, reach) -> tuple[np.ndarray, np.ndarray]:
        bound = self._phi - np.linalg.norm(y - self._y, axis=1)
        need = ~(bound > reach)  # (NaN: never computed)
        if np.any(need):
            phi, normal = self.skull.phi(y[need])
            self._y[need], self._phi[need], self._normal[need] = y[need], phi, normal
            self.queries += int(need.sum())
        bound[need] = self._phi[need]
        return bound, self._normal


class ContactState(NamedTuple):
    """The nodes at a displacement: positions y, shifted points z = y - lambda / k, phi and
    grad phi at z, and the pressures p(z) (Pa)."""

    y: np.ndarray
    z: np.ndarray
    phi: np.ndarray
    normal: np.ndarray
    p: np.ndarray


class SkullContact:
    def __init__(self, V, facets, skull, E: float, tolerance: float, constraints=None):
        self.V, self.skull, self.tolerance = V, skull, tolerance
        self.constraints = constraints  # physics/constraints.py: septa take the normal part of its blocks
        self.comm = V.mesh.comm
        X = facets.x_vertices  # (F, 3, 3)
        edges = np.linalg.norm(X - np.roll(X, 1, axis=1), axis=2).ravel()
        h = self.comm.allreduce(float(np.median(edges)) if edges.size else 0.0, op=MPI.MAX)
        self.h = max(h, 1e-300)
        self.static_penalty = self.penalty = PENALTY_FACTOR * E / self.h
        self.vector = dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)
        self._n_owned = V.dofmap.index_map.size_local
        self._queried = 0  # exact distance queries of earlier surfaces and of the tangent
        self.nodes = np.zeros(0, dtype=np.int32)
        self.multipliers = np.zeros((0, 3))
        self.set_surface(facets)

    def set_surface(self, facets) -> None:
        """The surface in contact: its vertices and their areas (again after a resection, when
        the cut faces join it); a node kept keeps its multiplier."""
        X = facets.x_vertices  # (F, 3, 3)
        area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
        nodes, first, pair_node = np.unique(facets.vertex_dofs.ravel(), return_index=True, return_inverse=True)
        nodes = nodes.astype(np.int32)  # block dofs of V on the surface, this rank's share
        kept = np.zeros((len(nodes), 3))
        if len(self.nodes):
            where = np.searchsorted(self.nodes, nodes).clip(max=len(self.nodes) - 1)
            found = self.nodes[where] == nodes
            kept[found] = self.multipliers[where[found]]
            self._queried = self.queries
        self.nodes, self.multipliers = nodes, kept  # multipliers: pressure vectors (Pa)
        self.X = X.reshape(-1, 3)[first]  # their reference positions
        self.weights = np.bincount(pair_node, weights=np.repeat(area / 3.0, 3), minlength=len(nodes))
        self._area = None  # nodal surface areas, for the pressure output
        self._at_z = _Distances(self.skull, len(nodes))  # the shifted points', for the forces
        self._at_y = _Distances(self.skull, len(nodes))  # the nodes' own, for the measures

    @property
    def queries(self) -> int:
        """Exact distance queries over the run (points)."""
        return self._queried + self._at_z.queries + self._at_y.queries

    # -- the distance, queried only where a node may be pressed -------------------------------
    def _width(self) -> float:
        return SMOOTHING * self.tolerance

    def _pressure(self, phi: np.ndarray) -> np.ndarray:
        """k max(0, -phi), its kink rounded over the width (softplus)."""
        width = self._width()
        z = -phi / width
        return self.penalty * width * (np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z))))

    def _state(self, u) -> ContactState:
        """The nodes' positions, shifted points, phi and normals there, and pressures at u."""
        y = self.X + u.x.array.reshape(-1, 3)[self.nodes]
        z = y - self.multipliers / self.penalty
        phi, normal = self._at_z(z, REACH * self._width())
        return ContactState(y, z, phi, normal, self._pressure(phi))

    def _room(self, u) -> np.ndarray:
        """phi at the nodes themselves: exact wherever a node may be pressed or past the skull,
        a lower bound elsewhere."""
        y = self.X + u.x.array.reshape(-1, 3)[self.nodes]
        reach = np.linalg.norm(self.multipliers, axis=1) / self.penalty + REACH * self._width()
        return self._at_y(y, reach)[0]

    # -- what Newton needs ----------------------------------------------------------------------
    def assemble(self, u) -> PETSc.Vec:
        """The contact forces at u into self.vector (owned entries summed over ranks)."""
        state = self._state(u)
        with self.vector.localForm() as local:
            local.set(0.0)
            local.array.reshape(-1, 3)[self.nodes] = (self.weights * state.p)[:, None] * state.normal
        self.vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self.vector

    def tangent_blocks(self, u, scale: float = 1.0, engaged: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(block dofs (n,), blocks (n, 3, 3)): scale d(-f)/du of the pressed nodes. A node just
        touching is pressed with half the penalty (the rounded kink): a body resting on the
        skull at rest then has a regular tangent. engaged: every node within reach as if
        pressed well past the kink (the full penalty): for a matrix that must hold the nodes
        about to press, not the tangent."""
        state = self._state(u)
        pressed = self._pressed(state.phi)
        z, w = state.z[pressed], self.weights[pressed]
        if engaged:  # as if pressed well past the rounded kink: the full penalty
            depth = np.maximum(state.phi[pressed] + 10.0 * self._width(), 0.0)
            z = z - depth[:, None] * state.normal[pressed]
        h = FD_STEP * self.h
        blocks = np.empty((len(z), 3, 3))
        for j in range(3):
            step = np.zeros(3)
            step[j] = h
            blocks[:, :, j] = -scale * (self._force(z + step, w) - self._force(z - step, w)) / (2 * h)
        if self.constraints is not None:  # a node on a septum: its block projected as the matrix is
            blocks = self.constraints.blocks(self.nodes[pressed], blocks)
        return self.nodes[pressed], blocks

    def _pressed(self, phi: np.ndarray) -> np.ndarray:
        """Which nodes the tangent holds: their shifted points within REACH rounding widths of
        the skull (phi at z)."""
        return phi <= REACH * self._width()

    def pressed_dofs(self, u) -> np.ndarray:
        """The block dofs of the nodes tangent_blocks would hold at u (no finite differences)."""
        return self.nodes[self._pressed(self._state(u).phi)]

    def add_tangent(self, A: PETSc.Mat, u, scale: float = 1.0, blocks=None) -> None:
        """A += scale d(-f)/du on the pressed nodes (A assembled after); ``blocks``: those of
        tangent_blocks (or their stiffness), if already computed."""
        dofs, blocks = self.tangent_blocks(u, scale) if blocks is None else blocks
        _add_blocks(A, dofs, blocks)

    @staticmethod
    def stiffness(blocks) -> tuple[np.ndarray, np.ndarray]:
        """The symmetric, positive semi-definite part of tangent blocks (dofs, blocks): the
        contact's stiffness in a matrix that must stay SPD for a Cholesky factor (the turning
        of the normal at a concave corner can make a block indefinite, and it is not
        symmetric)."""
        dofs, blocks = blocks
        symmetric = 0.5 * (blocks + blocks.transpose(0, 2, 1))
        values, vectors = np.linalg.eigh(symmetric)
        return dofs, np.einsum("nij,nj,nkj->nik", vectors, np.maximum(values, 0.0), vectors)

    def times(self, blocks, u) -> PETSc.Vec:
        """The product of blocks (dofs, blocks) with the Function u, into self.vector (owned
        entries summed over ranks, like the forces)."""
        dofs, blocks = blocks
        with self.vector.localForm() as local:
            local.set(0.0)
            local.array.reshape(-1, 3)[dofs] = np.einsum("nij,nj->ni", blocks, u.x.array.reshape(-1, 3)[dofs])
        self.vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self.vector

    def _force(self, z: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Forces (n, 3) of nodes whose shifted points are z (exact distances)."""
        phi, normal = self.skull.phi(z)
        self._queried += len(z)
        return (weights * self._pressure(phi))[:, None] * normal

    def step_limit(self, u, du) -> float:
        """The largest fraction (at most 1) of the step du from u that brings no node from the
        force-free side of its pressure's kink (phi(z) > 0) past it, by phi's linear
        prediction along the normal at z; the same on every rank. Such a node adds nothing to
        the tangent, so Newton's whole step takes it as far past the skull as the step reaches."""
        state = self._state(u)
        rate = np.einsum("ni,ni->n", state.normal, du.x.array.reshape(-1, 3)[self.nodes])  # d phi / d step
        reaching = (state.phi > 0) & (state.phi + rate < 0)
        local = float(np.min(state.phi[reaching] / -rate[reaching], initial=1.0))
        return self.comm.allreduce(local, op=MPI.MIN)

    def update_multipliers(self, u) -> None:
        """lambda <- the pressure vector at u."""
        state = self._state(u)
        self.multipliers = state.p[:, None] * state.normal

    def for_time_step(self, c_mass: float, density: float) -> None:
        """In a time step inertia stiffens every node by c_mass M: the penalty follows it (else
        an impact needs dozens of multiplier updates): PENALTY_FACTOR (E / h + c_mass rho h)."""
        self.penalty = self.static_penalty + PENALTY_FACTOR * c_mass * density * self.h

    # -- measures ---------------------------------------------------------------------------------
    def violation(self, u) -> float:
        """How far the contact conditions are from holding (m): the largest |min(phi, p / k)|,
        phi at the node itself, which counts a node past the skull (phi < 0) and a node pushed
        while off it (p > 0 with phi > 0: a stale multiplier) alike."""
        phi, p = self._room(u), self._state(u).p
        local = float(np.abs(np.minimum(phi, p / self.penalty)).max(initial=0.0))
        return self.comm.allreduce(local, op=MPI.MAX)

    def pressing(self, u) -> bool:
        """Is any node pressed, as the tangent counts them (on every rank)?"""
        local = bool(np.any(self._pressed(self._state(u).phi)))
        return self.comm.allreduce(local, op=MPI.LOR)

    def penetration(self, u) -> float:
        """The deepest any surface node is past the skull (m, 0 if none)."""
        phi = self._room(u)
        return self.comm.allreduce(float(max(0.0, -phi.min(initial=np.inf))), op=MPI.MAX)

    def clearance(self, u) -> float:
        """The smallest room left between the surface and the skull (m; negative: penetration;
        nodes far from the skull count with a lower bound)."""
        return self.comm.allreduce(float(self._room(u).min(initial=np.inf)), op=MPI.MIN)

    def nodal_pressure(self, u) -> np.ndarray:
        """The contact pressure (Pa) at every owned block dof of V: the node's force over its
        share of the surface area (0 off the surface)."""
        if self._area is None:
            self._area = self.vector.duplicate()
            with self._area.localForm() as local:
                local.set(0.0)
                local.array.reshape(-1, 3)[self.nodes, 0] = self.weights
            self._area.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        force = np.linalg.norm(self.assemble(u).array_r.reshape(-1, 3), axis=1)
        area = self._area.array_r.reshape(-1, 3)[:, 0]
        return np.divide(force, area, out=np.zeros_like(force), where=area > 0)

    def report(self, u) -> dict:
        """Total contact force (N), pressed nodes, deepest penetration and clearance (m)."""
        self.assemble(u)
        owned = self.vector.array_r.reshape(-1, 3)[: self._n_owned]
        total = self.comm.allreduce(owned.sum(axis=0), op=MPI.SUM)
        size = np.linalg.norm(owned, axis=1)
        largest = self.comm.allreduce(float(size.max(initial=0.0)), op=MPI.MAX)
        pressed = self.comm.allreduce(int(np.count_nonzero(size > 1e-6 * largest)), op=MPI.SUM)
        return {
            "force_N": [float(v) for v in total],
            "pressed_nodes": pressed,
            "max_penetration_m": self.penetration(u),
            "clearance_m": self.clearance(u),
            "penalty_Pa_per_m": self.penalty,
            "tolerance_m": self.tolerance,
            "distance_queries": self.queries,
        }
