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
    body passes them times the tissue indicator). growth: 1, or the growth stretch g of a
    shrinking or swelling body (physics/growth.py), whose eigenstrain (g - 1) I is a load
    (growth_load) and is taken off the strain in the stress that is written (von_mises)."""

    mu: object
    lmbda: object
    growth: object = 1.0

    @staticmethod
    def strain(u):
        return ufl.sym(ufl.grad(u))

    def stress(self, u):
        eps = self.strain(u)
        return 2.0 * self.mu * eps + self.lmbda * ufl.tr(eps) * ufl.Identity(len(u))

    def elastic_stress(self, u):
        """C : (eps(u) - (g - 1) I): the stress with the free growth taken off."""
        return self.stress(u) - (3.0 * self.lmbda + 2.0 * self.mu) * (self.growth - 1.0) * ufl.Identity(len(u))

    def von_mises(self, u):
        s = self.elastic_stress(u)
        dev = s - ufl.tr(s) / 3.0 * ufl.Identity(len(u))
        return ufl.sqrt(1.5 * ufl.inner(dev, dev))

    def growth_load(self, v):
        """The eigenstrain's load, int C : (g - 1) I : eps(v) dx (K u = F + this)."""
        return (3.0 * self.lmbda + 2.0 * self.mu) * (self.growth - 1.0) * ufl.div(v) * ufl.dx

    def stiffness(self, u, v):
        """The bilinear form of K."""
        return ufl.inner(self.stress(u), self.strain(v)) * ufl.dx

    def internal_force(self, u, v):
        """K u as a residual form (u a Function): the same interface as Hyperelastic."""
        return self.stiffness(u, v)

    def tangent(self, u, du, v):
        return self.stiffness(du, v)


@dataclass(frozen=True)
class Hyperelastic:
    """A finite-deformation material given by its strain-energy density psi(F) per reference
    volume (total Lagrangian). mu, lmbda: the small-strain Lame parameters (numbers or UFL
    coefficients), so that the linearisation at F = I is LinearElastic(mu, lmbda)."""

    mu: object
    lmbda: object
    kind: str = "neo-hookean"
    quadrature_degree: int | None = None  # None: UFL's estimate (high: ln J, det F)
    # 1, or a resection's tissue indicator: a removed cell (0) is evaluated at F = I, not at its
    # leftover deformation, whose ln J is NaN once it has turned inside out (and 0 * NaN is NaN)
    present: object = 1.0
    # 1, or the growth stretch g (physics/growth.py): F = F_e g I, and det(g I) psi(F_e) is stored
    growth: object = 1.0

    @classmethod
    def for_degree(cls, mu, lmbda, kind: str, degree: int, present=1.0, growth=1.0) -> Hyperelastic:
        """The quadrature a Lagrange degree needs: P1's deformation gradient is constant on a
        (straight) tetrahedron, so one point integrates the energy exactly; P2's is linear,
        and four-degree quadrature is the usual choice for the nonlinear energy."""
        return cls(mu, lmbda, kind, 1 if degree == 1 else 4, present, growth)

    def deformation_gradient(self, u):
        return ufl.variable(ufl.Identity(len(u)) + self.present * ufl.grad(u))

    def energy_density(self, F):
        """The stored energy per reference volume, g^3 psi(F / g) (g = 1 without growth).
        psi: compressible neo-Hookean mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2; Saint
        Venant-Kirchhoff lmbda/2 (tr E)^2 + mu E:E with E = (F^T F - I) / 2."""
        if isinstance(self.growth, (int, float)) and self.growth == 1.0:
            return self._psi(F)
        return self.growth**3 * self._psi(F / self.growth)

    def _psi(self, F):
        if self.kind == "neo-hookean":
            J = ufl.det(F)
            return self.mu / 2 * (ufl.tr(F.T * F) - 3) - self.mu * ufl.ln(J) + self.lmbda / 2 * ufl.ln(J) ** 2
        E = 0.5 * (F.T * F - ufl.Identity(3))
        return self.lmbda / 2 * ufl.tr(E) ** 2 + self.mu * ufl.inner(E, E)

    def first_piola(self, u):
        F = self.deformation_gradient(u)
        return ufl.diff(self.energy_density(F), F)

    def cauchy(self, u):
        F = self.deformation_gradient(u)
        return self.first_piola(u) * F.T / ufl.det(F)

    def internal_force(self, u, v):
        """The residual's internal part: the derivative of the stored energy along v."""
        dx = ufl.dx(metadata={"quadrature_degree": self.quadrature_degree}) if self.quadrature_degree else ufl.dx
        return ufl.inner(self.first_piola(u), ufl.grad(v)) * dx

    def tangent(self, u, du, v):
        """The consistent tangent: the derivative of internal_force along du."""
        return ufl.derivative(self.internal_force(u, v), u, du)

    def von_mises(self, u):
        s = self.cauchy(u)
        dev = s - ufl.tr(s) / 3.0 * ufl.Identity(len(u))
        return ufl.sqrt(1.5 * ufl.inner(dev, dev))


MODELS = ("linear", "neo-hookean", "saint-venant-kirchhoff")
