"""UFL forms that do not depend on the material: mass, gravity, surface pressure.

Coefficients are passed in (Constants or numbers) so the same forms serve every scene and test.
"""

from __future__ import annotations

import ufl

# A vertex quadrature rule puts V/4 of each tetrahedron's mass on its vertices: the paper's
# lumped mass (eq. 3), exactly, without row sums.
dx_vertex = ufl.dx(metadata={"quadrature_rule": "vertex", "quadrature_degree": 1})


def mass(u, v, rho, lumped: bool):
    return rho * ufl.inner(u, v) * (dx_vertex if lumped else ufl.dx)


def body_force(v, rho, g):
    """Gravity: rho g . v over the volume (with lumped P1 mass this is m_i g, eq. 6)."""
    return rho * ufl.inner(g, v) * ufl.dx


def clipped_hydrostatic_pressure(x, rho_fluid, g_magnitude, up, level):
    """p = rho_f |g| max(level - x.up, 0): zero above the free surface."""
    return rho_fluid * g_magnitude * ufl.max_value(level - ufl.dot(x, up), 0.0)


def pressure_load(v, p, n, quadrature_degree: int):
    """Pressure acting along -n on the exterior surface, by plain quadrature (the kink at the
    water line is integrated only approximately: see hydrostatic.py for the exact rule)."""
    ds = ufl.ds(metadata={"quadrature_degree": quadrature_degree})
    return -p * ufl.inner(n, v) * ds
