"""Material models as UFL forms. Linear elasticity (small strain) today; a hyperelastic model
goes beside it with the same methods (stress, stiffness, von_mises)."""
from __future__ import annotations

from dataclasses import dataclass

import ufl


def lame_parameters(E: float, nu: float) -> tuple[float, float]:
    """(mu, lambda) of Young's modulus E and Poisson's ratio nu."""
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


@dataclass(frozen=True)
class LinearElastic:
    """Isotropic linear elasticity; mu and lmbda are numbers or UFL coefficients (a resected
    body passes them times the tissue indicator)."""

    mu: object
    lmbda: object

    @staticmethod
    def strain(u):
        return ufl.sym(ufl.grad(u))

    def stress(self, u):
        eps = self.strain(u)
        return 2.0 * self.mu * eps + self.lmbda * ufl.tr(eps) * ufl.Identity(len(u))

    def von_mises(self, u):
        s = self.stress(u)
        dev = s - ufl.tr(s) / 3.0 * ufl.Identity(len(u))
        return ufl.sqrt(1.5 * ufl.inner(dev, dev))

    def stiffness(self, u, v):
        """The bilinear form of K."""
        return ufl.inner(self.stress(u), self.strain(v)) * ufl.dx
