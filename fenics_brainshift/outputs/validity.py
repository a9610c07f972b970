"""Is the small-strain model still valid? The largest principal Green-Lagrange strain and the
largest rotation of any cell, from the deformation gradient F = I + grad u.

Linear elasticity assumes both are small; past a few per cent of strain (or tens of degrees
of rotation, where the linear strain of a rigid rotation is no longer near zero) its answer
drifts from any finite-deformation model. A linear run beyond STRAIN_LIMIT is reported, in
the log and in summary.json, naming the finite-deformation model to use instead.
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from .. import compat

STRAIN_LIMIT = 0.05  # largest principal Green-Lagrange strain a linear run is trusted with
NONLINEAR_MODEL = "neo-hookean"


class StrainMeter:
    """The deformation gradient of u at each cell's midpoint (DG0), and what it says."""

    def __init__(self, u: fem.Function):
        self.comm = u.function_space.mesh.comm
        space = compat.cell_tensor_space(u.function_space.mesh)
        self.F = fem.Function(space)
        self._expression = compat.expression(ufl.Identity(3) + ufl.grad(u), space)
        self.n_owned = space.dofmap.index_map.size_local

    def measure(self) -> tuple[float, float, int]:
        """(largest principal Green-Lagrange strain, largest rotation in degrees, cells turned
        inside out: det F <= 0), global."""
        self.F.interpolate(self._expression)
        F = self.F.x.array.reshape(-1, 3, 3)[: self.n_owned]
        strain, rotation = principal_strain_and_rotation(F)
        local = (float(strain.max(initial=0.0)), float(rotation.max(initial=0.0)))
        inverted = self.comm.allreduce(int(np.count_nonzero(np.linalg.det(F) <= 0.0)), op=MPI.SUM)
        return (*(self.comm.allreduce(v, op=MPI.MAX) for v in local), inverted)


def principal_strain_and_rotation(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For deformation gradients F (n, 3, 3): the largest eigenvalue of E = (F^T F - I) / 2 and
    the angle (degrees) of the rotation R of the polar decomposition F = R U."""
    E = 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(3))
    strain = np.linalg.eigvalsh(E)[:, -1]
    W, _, Vt = np.linalg.svd(F)
    R = W @ Vt  # the orthogonal factor (det > 0 for an element that has not inverted)
    cosine = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return strain, np.degrees(np.arccos(cosine))


def assessment(strain: float, rotation_deg: float, model: str = "linear", inverted: int = 0) -> dict:
    """The summary's `validity` entry, with a warning when a linear run left small strain or
    turned cells inside out (a displacement no body can take)."""
    out = {"model": model, "max_green_lagrange_strain": strain, "max_rotation_deg": rotation_deg,
           "strain_limit": STRAIN_LIMIT, "inverted_cells": inverted}
    if inverted:
        out["warning"] = (f"{inverted} cells are turned inside out (det F <= 0): the displacement is not "
                          f"physical; use a finite-deformation model ([material] model = \"{NONLINEAR_MODEL}\") "
                          f"or check the loads and supports")
    elif model == "linear" and strain > STRAIN_LIMIT:
        out["warning"] = (f"the largest principal strain is {strain:.1%}, past the {STRAIN_LIMIT:.0%} a linear "
                          f"(small-strain) model is valid for; its answer may be far off: use a finite-"
                          f"deformation model ([material] model = \"{NONLINEAR_MODEL}\")")
    return out
