"""Shrinkage and swelling: the tissue's free volume change, cell by cell.

A free volume change theta of the tissue (a drug that draws water out of the brain: theta < 0;
oedema: theta > 0) changes its stress-free state, not the forces on it: an isotropic growth
F_g = g I with g = (1 + theta)^(1/3). The finite-deformation models split F = F_e F_g and store
det(F_g) psi(F_e) per reference volume (physics/material.py); the linear model takes the
eigenstrain eps_g = (g - 1) I, sigma = C : (eps - eps_g), whose part C : eps_g is a load,
F_g . v = int (3 lambda + 2 mu) (g - 1) div v dx. A free body then changes its volume by
exactly theta without stress (u = (g - 1) X is exact in P1 and makes eps = eps_g); a confined
one pushes its surroundings. Regions that overlap compose: (1 + theta_1)(1 + theta_2).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from dolfinx import fem

from .. import compat


class Growth:
    """The growth stretch g of every local cell (DG0 `growth`, ghosts included) at a time.

    regions: (mask over the local cells, t -> the region's volume change) pairs."""

    def __init__(self, mesh, regions: list[tuple[np.ndarray, Callable[[float], float]]]):
        self.stretch = fem.Function(compat.scalar_space(mesh, "DG", 0), name="growth")
        self.stretch.x.array[:] = 1.0
        self.regions = regions

    def set_time(self, t: float) -> bool:
        """g of every cell at time t; True when it changed."""
        volume = np.ones(len(self.stretch.x.array))
        for mask, change in self.regions:
            volume[mask] *= 1.0 + change(t)
        g = np.cbrt(volume)
        if np.array_equal(g, self.stretch.x.array):
            return False
        self.stretch.x.array[:] = g
        return True
