"""UFL forms of linear elastodynamics, one small function each.

M (lumped or consistent), K, C = a M + b K, gravity and pressure loads. Coefficients are
passed in (Constants or numbers) so the same forms serve every scene and test.
"""
from __future__ import annotations

import ufl

# A vertex quadrature rule puts V/4 of each tetrahedron's mass on its vertices: the paper's
# lumped mass (eq. 3), exactly, without row sums.
dx_vertex = ufl.dx(metadata={"quadrature_rule": "vertex", "quadrature_degree": 1})


def strain(u):
    return ufl.sym(ufl.grad(u))


def stress(u, mu, lmbda):
    eps = strain(u)
    return 2.0 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(len(u))


def von_mises(u, mu, lmbda):
    s = stress(u, mu, lmbda)
    dev = s - ufl.tr(s) / 3.0 * ufl.Identity(len(u))
    return ufl.sqrt(1.5 * ufl.inner(dev, dev))


def stiffness(u, v, mu, lmbda):
    return ufl.inner(stress(u, mu, lmbda), strain(v)) * ufl.dx


def mass(u, v, rho, lumped: bool):
    return rho * ufl.inner(u, v) * (dx_vertex if lumped else ufl.dx)


def damping(u, v, rho, mu, lmbda, a, b, lumped: bool):
    """Rayleigh damping C = a M + b K."""
    return a * mass(u, v, rho, lumped) + b * stiffness(u, v, mu, lmbda)


def body_force(v, rho, g):
    """Gravity: rho g . v over the volume (with lumped P1 mass this is m_i g, eq. 6)."""
    return rho * ufl.inner(g, v) * ufl.dx


def clipped_hydrostatic_pressure(x, rho_fluid, g_magnitude, up, level):
    """p = rho_f |g| max(level - x.up, 0): zero above the free surface."""
    return rho_fluid * g_magnitude * ufl.max_value(level - ufl.dot(x, up), 0.0)


def pressure_load(v, p, n, quadrature_degree: int):
    """Pressure acting along -n on the exterior surface, by plain quadrature (the kink at the
    water line is integrated only approximately: see hydrostatics for the exact rule)."""
    ds = ufl.ds(metadata={"quadrature_degree": quadrature_degree})
    return -p * ufl.inner(n, v) * ds
