"""Resection: which cells a [[remove]] takes away, and the tissue indicator the forms use.

Removal does not change the mesh. A cell-wise indicator ``tissue`` (DG0: 1 present, 0
removed) multiplies the mass, stiffness and gravity forms, and the fluid acts on the surface
of the cells that remain (surface.surface_facets). Nodes left with no tissue around
them ("orphans") get a unit diagonal and a zero right-hand side, so they stay where they
were. A piece cut free keeps a positive-definite effective matrix through its mass, which is
why the paper solves the dynamic problem: K alone would be singular.

Cells are chosen by their centroid, so a region selects the same cells on any number of
ranks (centroids are computed from the mesh geometry, ghosts included).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from .. import compat
from ..errors import InputError
from ..logs import get_logger
from ..meshing.facets import present_facet_counts

log = get_logger("stepping")  # (the time loop's log, where cuts were said before)


def cell_centroids(mesh) -> np.ndarray:
    """(num_local_cells incl. ghosts, 3) centroids of the tetrahedra."""
    geo = compat.geometry_dofmap(mesh)
    return mesh.geometry.x[geo].mean(axis=1)


@dataclass(frozen=True)
class Cut:
    """A removal: at time ``at`` (s), the cells whose centroid ``select`` ((N, 3) -> bool (N,))
    accepts; ``label`` names it in messages and in the summary."""

    at: float
    label: str
    select: Callable[[np.ndarray], np.ndarray]


class Tissue:
    """The cells still present, as a DG0 indicator, and the removals still to come."""

    def __init__(self, mesh, cuts):
        self.mesh = mesh
        self.comm = mesh.comm
        self.n_owned = mesh.topology.index_map(3).size_local
        self.indicator = fem.Function(compat.scalar_space(mesh, "DG", 0), name="tissue")
        self.indicator.x.array[:] = 1.0
        self.present = np.ones(len(self.indicator.x.array), dtype=bool)
        self.total = self._count(self.present)
        self.total_volume = self.volume()
        self.cuts = sorted(cuts, key=lambda c: c.at)
        self.pending = list(self.cuts)
        centroids = cell_centroids(mesh)
        self.masks = [np.asarray(cut.select(centroids), dtype=bool) for cut in self.cuts]
        self._check()

    def _count(self, mask: np.ndarray) -> int:
        return self.comm.allreduce(int(np.count_nonzero(mask[: self.n_owned])), op=MPI.SUM)

    def _check(self) -> None:
        """Before anything runs: each removal takes something, and not everything is taken."""
        left = self.present.copy()
        for cut, mask in zip(self.cuts, self.masks):
            taken = self._count(mask & left)
            if taken == 0:
                raise InputError(
                    f"[[remove]] {cut.label} (at {cut.at:g} s) selects no cell that is "
                    f"still present; check the region (metres, mesh frame, cell centroids)"
                )
            left &= ~mask
            if self._count(left) == 0:
                raise InputError(
                    f"[[remove]] {cut.label} (at {cut.at:g} s) would remove every "
                    f"remaining cell; nothing would be left to simulate"
                )

    def count_present(self) -> int:
        """The cells still present, globally. Collective."""
        return self._count(self.present)

    @property
    def removed_fraction(self) -> float:
        return 1.0 - self._count(self.present) / self.total

    def due(self, t: float, tol: float) -> list[int]:
        """Indices (into cuts) of the pending removals with at <= t (+tol)."""
        return [i for i, r in enumerate(self.pending) if r is not None and r.at <= t + tol]

    def apply(self, index: int) -> tuple[int, int]:
        """Remove the cells of pending removal ``index``, then any cell left with no face
        shared with a present cell (a tetrahedron hanging by an edge or a vertex: a cut
        through a voxel's five tetrahedra leaves such slivers of the region's boundary, and
        each one is a mechanism that falls freely). Returns (cells in the region, isolated
        cells removed with them), global counts. Collective."""
        mask = self.masks[index] & self.present
        removed = self._count(mask)
        self.present &= ~mask
        cells, counts = present_facet_counts(self.mesh, self.present)
        isolated = cells[np.all(counts == 1, axis=1)]
        self.take(isolated)
        self.pending[index] = None
        return removed, self.comm.allreduce(len(isolated), op=MPI.SUM)

    def cut(self, index: int, t: float) -> dict:
        """Apply pending removal ``index`` at time t (apply), say so in the log, and return its
        record: {at, t, region, cells, isolated_cells}. Collective."""
        cut = self.cuts[index]
        count, isolated = self.apply(index)
        log.info(
            "  t=%.3f s: removed %d cells (%s) and %d left hanging by an edge or vertex; %.1f %% of the body "
            "removed so far",
            t,
            count,
            cut.label,
            isolated,
            100.0 * self.removed_fraction,
        )
        return {"at": cut.at, "t": t, "region": cut.label, "cells": count, "isolated_cells": isolated}

    def take(self, cells: np.ndarray) -> int:
        """Remove these owned cells (local indices) too; returns how many, globally. Collective."""
        values = self.indicator.x.array
        values[:] = self.present.astype(PETSc.ScalarType)
        values[cells] = 0.0
        self.indicator.x.scatter_forward()  # ghosts learn what their owners removed
        self.present = values > 0.5
        return self.comm.allreduce(len(cells), op=MPI.SUM)

    def volume(self) -> float:
        """The present cells' volume (m^3), on every rank. Collective."""
        X = self.mesh.geometry.x[compat.geometry_dofmap(self.mesh)[: self.n_owned]]
        edges = X[:, 1:] - X[:, :1]
        volumes = np.abs(np.linalg.det(edges)) / 6.0
        return self.comm.allreduce(float(volumes[self.present[: self.n_owned]].sum()), op=MPI.SUM)


def fill_empty_diagonal(A: PETSc.Mat) -> int:
    """Put 1 on each exactly-zero diagonal entry (rows with no tissue around them); returns
    how many owned rows that was. Collective."""
    diag = A.getDiagonal()
    empty = diag.array_r == 0.0
    diag.array[empty] = 1.0
    A.setDiagonal(diag, addv=PETSc.InsertMode.INSERT_VALUES)
    diag.destroy()
    return int(np.count_nonzero(empty))
