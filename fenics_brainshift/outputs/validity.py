"""Is the small-strain model still valid? The principal Green-Lagrange strains and the
rotation of every cell, from the deformation gradient F = I + grad u at its midpoint.

Linear elasticity assumes both are small; past a few per cent of strain - of either sign: a
brain resting on the skull is compressed, not stretched - or tens of degrees of rotation its
answer drifts from any finite-deformation model. One cell past the limit next to a pinned
corner is a local concentration the model lives with; a tenth of the body past it is a model
that is wrong in bulk. So the check reports the largest strain and where it is (next to a
support, at the skull contact, on the surface or inside), and the fraction of the body's
volume past STRAIN_LIMIT, and a linear run is warned (and model = "auto" switches) when that
fraction exceeds VOLUME_LIMIT.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import dolfinx.mesh
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from .. import compat

STRAIN_LIMIT = 0.05  # largest principal Green-Lagrange strain (either sign) a linear run is trusted with
VOLUME_LIMIT = 0.01  # the fraction of the body's volume that may be past it before the model is in doubt
NONLINEAR_MODEL = "neo-hookean"
PLACES = ("next to a support", "at the skull contact", "on the surface", "inside")


@dataclass
class StrainReport:
    """What StrainMeter.measure found (global values)."""

    strain: float = 0.0  # the principal Green-Lagrange strain of largest magnitude (< 0: compression)
    rotation_deg: float = 0.0
    inverted: int = 0  # cells with det F <= 0
    volume_past_limit: float = 0.0  # fraction of the body's volume with |strain| > STRAIN_LIMIT
    where: list = field(default_factory=lambda: [0.0, 0.0, 0.0])  # m: the midpoint of that cell
    near: str = "inside"  # one of PLACES

    def worse(self, other: StrainReport) -> StrainReport:
        """Per quantity, the worse of two reports (the run's history over output times)."""
        big = self if abs(self.strain) >= abs(other.strain) else other
        return StrainReport(
            big.strain,
            max(self.rotation_deg, other.rotation_deg),
            max(self.inverted, other.inverted),
            max(self.volume_past_limit, other.volume_past_limit),
            big.where,
            big.near,
        )


class StrainMeter:
    """The deformation gradient of u at each cell's midpoint (DG0), and what it says.

    fixed_dofs: the (unrolled, local) dofs the supports hold; a cell with a node held in all
    three directions is "next to a support". tissue: a resection's DG0 indicator (removed
    cells are not measured)."""

    def __init__(self, u: fem.Function, fixed_dofs: np.ndarray | None = None, tissue: fem.Function | None = None):
        V = u.function_space
        mesh = V.mesh
        self.comm = mesh.comm
        space = compat.cell_tensor_space(mesh)
        self.F = fem.Function(space)
        self._expression = compat.expression(ufl.Identity(3) + ufl.grad(u), space)
        self.n_owned = mesh.topology.index_map(mesh.topology.dim).size_local
        self.tissue = tissue
        corners = mesh.geometry.x[compat.geometry_dofmap(mesh)[: self.n_owned]]
        self.midpoints = corners.mean(axis=1)
        edges = corners[:, 1:] - corners[:, :1]
        self.volumes = np.abs(np.linalg.det(edges)) / 6.0  # affine tetrahedra
        cell_blocks = compat.dofmap_array(V)[: self.n_owned]
        n_blocks = len(u.x.array) // 3
        held = np.zeros(n_blocks, dtype=int)
        if fixed_dofs is not None and len(fixed_dofs):
            np.add.at(held, np.unique(np.asarray(fixed_dofs)) // 3, 1)
        self.near_support = np.any(held[cell_blocks] == 3, axis=1)
        tdim = mesh.topology.dim
        mesh.topology.create_connectivity(tdim - 1, tdim)
        outside = np.zeros(n_blocks, dtype=bool)
        outside[fem.locate_dofs_topological(V, tdim - 1, dolfinx.mesh.exterior_facet_indices(mesh.topology))] = True
        self.on_surface = np.any(outside[cell_blocks], axis=1)
        self._cell_blocks = cell_blocks
        self._n_blocks = n_blocks

    def measure(self, pressed_blocks: np.ndarray | None = None) -> StrainReport:
        """The report of the current u (global); pressed_blocks: the local block dofs of the
        nodes pressed on the skull, if any."""
        self.F.interpolate(self._expression)
        F = self.F.x.array.reshape(-1, 3, 3)[: self.n_owned]
        present = np.ones(self.n_owned, dtype=bool)
        if self.tissue is not None:
            present = self.tissue.x.array[: self.n_owned] > 0.5
        strain, rotation = principal_strain_and_rotation(F)
        strain = np.where(present, strain, 0.0)
        rotation = np.where(present, rotation, 0.0)
        past = present & (np.abs(strain) > STRAIN_LIMIT)
        sums = self.comm.allreduce(np.array([self.volumes[past].sum(), self.volumes[present].sum()]), op=MPI.SUM)
        inverted = self.comm.allreduce(int(np.count_nonzero(present & (np.linalg.det(F) <= 0.0))), op=MPI.SUM)
        rotation_max = self.comm.allreduce(float(rotation.max(initial=0.0)), op=MPI.MAX)
        # the largest |strain| and where: each rank's candidate, the largest wins
        local = (0.0, 0.0, [0.0, 0.0, 0.0], PLACES[-1])
        if self.n_owned:
            c = int(np.argmax(np.abs(strain)))
            local = (
                abs(float(strain[c])),
                float(strain[c]),
                self.midpoints[c].tolist(),
                self._place(c, pressed_blocks),
            )
        _, signed, where, near = max(self.comm.allgather(local), key=lambda item: item[0])
        fraction = float(sums[0] / sums[1]) if sums[1] > 0 else 0.0
        return StrainReport(signed, rotation_max, inverted, fraction, where, near)

    def _place(self, cell: int, pressed_blocks) -> str:
        if self.near_support[cell]:
            return PLACES[0]
        if pressed_blocks is not None and np.isin(self._cell_blocks[cell], pressed_blocks).any():
            return PLACES[1]
        return PLACES[2] if self.on_surface[cell] else PLACES[3]


def principal_strain_and_rotation(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For deformation gradients F (n, 3, 3): the eigenvalue of E = (F^T F - I) / 2 of largest
    magnitude (signed: negative in compression) and the angle (degrees) of the rotation R of
    the polar decomposition F = R U."""
    E = 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(3))
    eigenvalues = np.linalg.eigvalsh(E)  # ascending: the extremes are the first and the last
    low, high = eigenvalues[:, 0], eigenvalues[:, -1]
    strain = np.where(np.abs(low) > np.abs(high), low, high)
    W, _, Vt = np.linalg.svd(F)
    R = W @ Vt  # the orthogonal factor (det > 0 for an element that has not inverted)
    cosine = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return strain, np.degrees(np.arccos(cosine))


def in_doubt(report: StrainReport) -> bool:
    """Is a linear model's answer in doubt: cells inside out, or too much volume past the limit?"""
    return bool(report.inverted) or report.volume_past_limit > VOLUME_LIMIT


def assessment(report: StrainReport, model: str = "linear") -> dict:
    """The summary's `validity` entry: the largest strain, where it is, the volume past the
    limit; a warning when a linear run is past the limit in bulk or turned cells inside out
    (a displacement no body can take), a note when only a local concentration is."""
    kind = "compression" if report.strain < 0 else "tension"
    out = {
        "model": model,
        "max_green_lagrange_strain": report.strain,
        "max_strain_kind": kind,
        "max_strain_at_m": report.where,
        "max_strain_near": report.near,
        "volume_past_limit": report.volume_past_limit,
        "strain_limit": STRAIN_LIMIT,
        "volume_limit": VOLUME_LIMIT,
        "max_rotation_deg": report.rotation_deg,
        "inverted_cells": report.inverted,
    }
    at = ", ".join(f"{c * 1e3:.1f}" for c in report.where)
    largest = (
        f"the largest principal strain is {abs(report.strain):.1%} ({kind}, {report.near}, at "
        f"({at}) mm); {report.volume_past_limit:.1%} of the volume is past {STRAIN_LIMIT:.0%}"
    )
    if report.inverted:
        out["warning"] = (
            f"{report.inverted} cells are turned inside out (det F <= 0): the displacement is not "
            f'physical; use a finite-deformation model ([material] model = "{NONLINEAR_MODEL}") '
            f"or check the loads and supports"
        )
    elif model == "linear" and in_doubt(report):
        out["warning"] = (
            f"{largest}, more than the {VOLUME_LIMIT:.0%} a linear (small-strain) model can be "
            f"trusted with: its answer may be far off; use a finite-deformation model "
            f'([material] model = "{NONLINEAR_MODEL}")'
        )
    elif model == "linear" and abs(report.strain) > STRAIN_LIMIT:
        out["note"] = f"{largest}: a local concentration, within the {VOLUME_LIMIT:.0%} of the volume allowed"
    return out
