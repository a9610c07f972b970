"""The nodes' constraints as one projector: supports hold components, septa hold normals.

At a node on septa the admissible displacements have no component along any of its septa's
normals, nor along the axes its supports hold: u_s in range(P_s), P_s = I - Q_s Q_s^T with
Q_s an orthonormal basis of those directions (two septa meeting leave the line between them).
A system A x = b restricted to range(P) is solved as

    (P A P + (I - P)) x = P b,

block diagonal over range(P) and its complement, so x (and every Krylov iterate and every
Newton update) stays in range(P). For a septum along an axis this is exactly what a Dirichlet
condition makes of A (its row and column replaced by the identity): the same answer to
round-off. P differs from I only at septum nodes; the product is PETSc's PtAP, its sparsity
built once per matrix (on the 5 mm brain a reused product costs ~3 % of assembling K).
Supports alone keep DOLFINx's Dirichlet conditions: nothing here changes their path.
"""

from __future__ import annotations

import numpy as np
from dolfinx.fem.petsc import set_bc
from mpi4py import MPI
from petsc4py import PETSc

RANK_TOL = 1e-8  # directions this close to dependent (relative) are one constraint
_PRODUCT = "brainshift_projected"  # the name a matrix's reused PtAP is composed under


def fixed_dofs(bcs) -> np.ndarray:
    """The local (unrolled) indices of every dof the supports hold, for zeroRowsColumnsLocal."""
    if not bcs:
        return np.zeros(0, dtype=np.int32)
    return np.unique(np.concatenate([bc.dof_indices()[0] for bc in bcs])).astype(np.int32)


class Constraints:
    """Supports (DOLFINx Dirichlet conditions ``bcs``) and septa: ``septa`` is a list of
    (label, block dofs (n,) local incl. ghosts, unit normals (n, 3)), from septa.septum_nodes."""

    def __init__(self, V, bcs, septa=()):
        self.V, self.bcs = V, bcs
        self.fixed = fixed_dofs(bcs)
        self.labels = [label for label, _, _ in septa]
        self.comm = V.mesh.comm
        index_map = V.dofmap.index_map
        self._owned = index_map.size_local
        n_blocks = index_map.size_local + index_map.num_ghosts
        pairs = [(nodes, normals, k) for k, (_, nodes, normals) in enumerate(septa)]
        nodes = np.unique(np.concatenate([p[0] for p in pairs])) if pairs else np.zeros(0, dtype=np.int32)
        self.nodes = nodes.astype(np.int32)  # local block dofs on any septum (owned and ghosts)
        self._index = np.full(n_blocks, -1)
        self._index[self.nodes] = np.arange(len(self.nodes))
        # each node's constraint directions, and whose (septum k, or -1: a support)
        self.directions: list[list[tuple[int, np.ndarray]]] = [[] for _ in self.nodes]
        for node_dofs, normals, k in pairs:
            for i, n in zip(self._index[node_dofs], normals):
                self.directions[i].append((k, np.asarray(n, dtype=float)))
        held = self.fixed[np.isin(self.fixed // 3, self.nodes)]
        for dof in held:
            self.directions[self._index[dof // 3]].append((-1, np.eye(3)[dof % 3]))
        self.P = np.array([_projector([d for _, d in dirs]) for dirs in self.directions]).reshape(-1, 3, 3)
        self.has_septa = self.comm.allreduce(len(self.nodes), op=MPI.SUM) > 0
        self._matrix = self._block_matrix(self.P) if self.has_septa else None
        # I - P, added after the product: zero but at the septum nodes' diagonal blocks
        self._complement = self._block_matrix(np.eye(3) - self.P, identity=False) if self.has_septa else None

    # -- the projector as a PETSc matrix ----------------------------------------------------
    def _block_matrix(self, at_nodes: np.ndarray, identity: bool = True) -> PETSc.Mat:
        """A block-diagonal AIJ matrix (block size 3): ``at_nodes`` (per local septum node) at
        the owned septum nodes' blocks, the identity (or zero) elsewhere."""
        n = self._owned
        start = self.V.dofmap.index_map.local_range[0]
        blocks = np.broadcast_to(np.eye(3) if identity else np.zeros((3, 3)), (n, 3, 3)).copy()
        owned = self.nodes < n
        blocks[self.nodes[owned]] = at_nodes[owned]
        columns = 3 * (start + np.arange(n))[:, None, None] + np.arange(3)[None, None, :]
        indices = np.broadcast_to(columns, (n, 3, 3)).reshape(-1).astype(PETSc.IntType)
        indptr = np.arange(0, 9 * n + 1, 3, dtype=PETSc.IntType)
        size = (3 * n, 3 * self.V.dofmap.index_map.size_global)
        return PETSc.Mat().createAIJ((size, size), bsize=3, csr=(indptr, indices, blocks.reshape(-1)), comm=self.comm)

    # -- applied to matrices, vectors and contact blocks ------------------------------------
    def matrix(self, A: PETSc.Mat, supports: bool = True) -> PETSc.Mat:
        """A <- P A P + (I - P) at the septa (an AIJ matrix, assembled); then, with
        ``supports``, the supports' rows and columns replaced by the identity."""
        if self.has_septa:
            product = A.query(_PRODUCT)
            if product is None:
                product = A.PtAP(self._matrix)
                A.compose(_PRODUCT, product)
            else:
                A.PtAP(self._matrix, result=product)
            product.copy(A, PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            A.axpy(1.0, self._complement, PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        if supports:  # collective: every rank calls it, with or without rows of its own
            A.zeroRowsColumnsLocal(self.fixed, 1.0)
        return A

    def vector(self, b: PETSc.Vec) -> PETSc.Vec:
        """b <- P b (owned entries): zero where the supports hold, no normal part at the septa."""
        set_bc(b, self.bcs)
        self.project_owned(b)
        return b

    def project_owned(self, b: PETSc.Vec) -> None:
        """The septa's part of vector(): b_s <- P_s b_s at the owned septum nodes."""
        owned = self.nodes < self._owned
        if owned.any():
            values = b.array.reshape(-1, 3)
            values[self.nodes[owned]] = np.einsum("nij,nj->ni", self.P[owned], values[self.nodes[owned]])

    def restrict(self, values: np.ndarray, owned_only: bool = False) -> np.ndarray:
        """S v for a flat array of local scalar values (owned and ghosts, or the owned alone):
        zero where the supports hold, P_s v_s at the septum nodes (in place; returned)."""
        values[self.fixed[self.fixed < len(values)]] = 0.0
        nodes = self.nodes[3 * self.nodes < len(values)] if owned_only else self.nodes
        if len(nodes):
            v = values.reshape(-1, 3)
            v[nodes] = np.einsum("nij,nj->ni", self.P[self._index[nodes]], v[nodes])
        return values

    def blocks(self, dofs: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        """Nodal 3x3 blocks (a contact stiffness) at local block ``dofs``: P_s B P_s at the
        septum nodes, so that a matrix they are added to stays projected."""
        if not len(self.nodes) or not len(dofs):
            return blocks
        where = self._index[dofs]
        on = where >= 0
        if on.any():
            P = self.P[where[on]]
            blocks = blocks.copy()
            blocks[on] = np.einsum("nij,njk,nlk->nil", P, blocks[on], P)
        return blocks

    # -- what the septa carry ---------------------------------------------------------------
    def reactions(self, residual: PETSc.Vec) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per septum: (its owned block dofs, the force (n, 3) N it exerts on the tissue at
        each), from the unconstrained residual r = f_int + inertia - F: the loads and the
        septum's force together balance f_int + inertia, so that force is r along its normal.
        At a node a support also holds, the support carries what lies along its axes; the
        rest is shared among the node's septa by least squares."""
        r = residual.array.reshape(-1, 3)
        out = [([], []) for _ in self.labels]
        for node, dirs in zip(self.nodes, self.directions):
            if node >= self._owned:
                continue
            held = np.eye(3) - _projector([d for k, d in dirs if k < 0])  # onto the supports' axes
            rest = r[node] - held @ r[node]
            septa = [(k, n) for k, n in dirs if k >= 0]
            share = np.linalg.lstsq(np.array([n for _, n in septa]).T, rest, rcond=None)[0]
            for (k, n), s in zip(septa, share):
                out[k][0].append(node)
                out[k][1].append(s * n)
        return [(np.array(nodes, dtype=np.int32), np.array(forces).reshape(-1, 3)) for nodes, forces in out]

    def report(self, residual: PETSc.Vec, u) -> list[dict]:
        """Per septum: its nodes, the resultant force it exerts on the tissue (N), the sum
        of its nodes' normal forces' sizes (N: what it carries, pushed from both sides), the
        largest slide along it and the largest motion across it at its nodes (m; round-off:
        the constraint holds)."""
        values = u.x.array.reshape(-1, 3)
        c = self.comm
        out = []
        for k, (label, (nodes, forces)) in enumerate(zip(self.labels, self.reactions(residual))):
            normals = np.array([n for node in nodes for j, n in self.directions[self._index[node]] if j == k])
            moved = values[nodes]
            across = np.einsum("ni,ni->n", moved, normals) if len(nodes) else np.zeros(0)
            slide = np.linalg.norm(moved - across[:, None] * normals, axis=1) if len(nodes) else np.zeros(0)
            out.append(
                {
                    "name": label,
                    "nodes": c.allreduce(len(nodes)),
                    "force_N": c.allreduce(forces.sum(axis=0)).tolist(),
                    "normal_force_sum_N": c.allreduce(float(np.linalg.norm(forces, axis=1).sum())),
                    "largest_slide_m": c.allreduce(float(slide.max(initial=0.0)), op=MPI.MAX),
                    "largest_motion_across_m": c.allreduce(float(np.abs(across).max(initial=0.0)), op=MPI.MAX),
                }
            )
        return out

    def free_rigid_motion(self) -> str | None:
        """A rigid motion the supports and septa together leave free (a settled state then has
        no unique answer: K is singular), in words; None when they hold all six. Each held
        direction d at a point x sees the motions t + w x (x - c) through d . t + (x - c) x d . w."""
        X = self.V.tabulate_dof_coordinates()
        owned = self._owned
        fixed = self.fixed[self.fixed // 3 < owned]
        septa = [
            (node, n) for node, dirs in zip(self.nodes, self.directions) if node < owned for k, n in dirs if k >= 0
        ]
        points = np.concatenate([X[fixed // 3], X[[node for node, _ in septa]].reshape(-1, 3)])
        held = np.concatenate([np.eye(3)[fixed % 3], np.array([n for _, n in septa]).reshape(-1, 3)])
        c = self.comm
        count = c.allreduce(owned)
        centre = c.allreduce(X[:owned].sum(axis=0)) / max(count, 1)
        size = max(c.allreduce(float(np.abs(X[:owned] - centre).max(initial=0.0)), op=MPI.MAX), 1e-300)
        g = np.hstack([held, np.cross((points - centre) / size, held)])  # a row per held direction
        G = c.allreduce(g.T @ g)
        values, vectors = np.linalg.eigh(G)
        if values[-1] > 0 and values[0] > 1e-10 * values[-1]:
            return None

        def words(v):
            v = v / np.linalg.norm(v)
            v = v * np.sign(v[np.argmax(np.abs(v))])
            return ", ".join(f"{c:.2g}" for c in np.where(np.abs(v) < 1e-6, 0.0, v))

        moves, along = np.linalg.eigh(G[:3, :3])  # the translations alone
        if moves[0] <= 1e-10 * values[-1]:
            return f"move along ({words(along[:, 0])})"
        return f"turn about an axis along ({words(vectors[3:, 0])})"

    def destroy(self) -> None:
        for matrix in (self._matrix, self._complement):
            if matrix is not None:
                matrix.destroy()


def _projector(directions: list[np.ndarray]) -> np.ndarray:
    """I - Q Q^T, Q an orthonormal basis of the span of ``directions`` (3-vectors)."""
    if not directions:
        return np.eye(3)
    _, s, vt = np.linalg.svd(np.array(directions))
    Q = vt[: int(np.count_nonzero(s > RANK_TOL * s[0]))]
    return np.eye(3) - Q.T @ Q
