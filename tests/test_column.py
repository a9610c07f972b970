"""Statics against exact answers: the confined column under gravity (scene path) and a
manufactured non-polynomial column (forms path), with observed convergence rates."""

from __future__ import annotations

import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from dolfinx import fem

from fenics_brainshift import compat
from fenics_brainshift.linalg import LinearSolver
from fenics_brainshift.physics import forms
from fenics_brainshift.physics.gravity import assemble_into
from fenics_brainshift.runner import Simulation, build_model
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi
H = 0.1


def _errors(u, exact_z) -> tuple[float, float]:
    """Global L2 error and H1-seminorm error of u against (0, 0, exact_z(z))."""
    mesh = u.function_space.mesh
    x = ufl.SpatialCoordinate(mesh)
    exact = ufl.as_vector((0.0, 0.0, exact_z(x[2])))
    e = u - exact
    dx = ufl.dx(metadata={"quadrature_degree": 8})
    l2 = fem.assemble_scalar(fem.form(ufl.inner(e, e) * dx))
    h1 = fem.assemble_scalar(fem.form(ufl.inner(ufl.grad(e), ufl.grad(e)) * dx))
    return np.sqrt(COMM.allreduce(l2)), np.sqrt(COMM.allreduce(h1))


def _rate(hs, errors) -> float:
    return float(np.polyfit(np.log(hs), np.log(errors), 1)[0])


def _gravity_column(layers: int, degree: int):
    scene = scene_from_dict(column_dict(layers, degree, height=H))
    sim = Simulation(scene, COMM)
    sim.solve_to_settled(0.0)
    mat = scene.material
    modulus = mat.lmbda + 2 * mat.mu  # uniaxial strain (P-wave) modulus
    rho_g = mat.density * 9.81
    return sim, lambda z: -rho_g / modulus * (H * z - z * z / 2)


def test_column_under_gravity_p1_rates_and_p2_exact():
    layers = [16, 32, 64]  # past the pre-asymptotic range of the anisotropic 1 x 1 x n grid
    p1 = []
    for n in layers:
        sim, exact = _gravity_column(n, 1)
        p1.append(_errors(sim.u, exact))
    hs = [H / n for n in layers]
    l2, h1 = zip(*p1)
    assert _rate(hs, l2) == pytest.approx(2.0, abs=0.15)
    assert _rate(hs, h1) == pytest.approx(1.0, abs=0.1)
    # The exact solution is quadratic in z: P2 holds it, so the error is round-off.
    sim, exact = _gravity_column(4, 2)
    scale = abs(exact(H))
    l2_p2, h1_p2 = _errors(sim.u, exact)
    assert l2_p2 / (scale * np.sqrt(0.02 * 0.02 * H)) < 1e-9
    # and the probe at the top matches the closed form
    top = sim.probe_values()[0]
    assert top[2] == pytest.approx(exact(H), rel=1e-9)
    assert abs(top[0]) < 1e-12 and abs(top[1]) < 1e-12


def _manufactured(layers: int, degree: int) -> tuple[float, float]:
    """u_z = c sin(pi z / 2H): clamped bottom, traction-free top, body force M u_z''."""
    scene = scene_from_dict(column_dict(layers, degree, height=H, gravity=(0.0, 0.0, 0.0)))
    model = build_model(scene, COMM)
    mat, c = scene.material, 1e-3
    modulus = mat.lmbda + 2 * mat.mu
    k = np.pi / (2 * H)
    x = ufl.SpatialCoordinate(model.mesh)
    v = ufl.TestFunction(model.V)
    body = ufl.as_vector((0.0, 0.0, modulus * c * k * k * ufl.sin(k * x[2])))
    L = fem.form(forms.body_force(v, 1.0, body))
    b = assemble_into(dolfinx.fem.petsc.create_vector(L), L)
    dolfinx.fem.petsc.set_bc(b, model.bcs)
    K = model.assemble(model.stiffness_form(), with_bcs=True)
    u = fem.Function(model.V)
    LinearSolver(K, "cholesky", name="").solve(b, compat.petsc_vec(u))
    u.x.scatter_forward()
    return _errors(u, lambda z: c * ufl.sin(k * z))


@pytest.mark.parametrize("degree, l2_rate, h1_rate", [(1, 2.0, 1.0), (2, 3.0, 2.0)])
def test_manufactured_column_convergence_rates(degree, l2_rate, h1_rate):
    layers = [16, 32, 64]  # past the pre-asymptotic range of the anisotropic 1 x 1 x n grid
    l2, h1 = zip(*[_manufactured(n, degree) for n in layers])
    hs = [H / n for n in layers]
    assert _rate(hs, l2) == pytest.approx(l2_rate, abs=0.15)
    assert _rate(hs, h1) == pytest.approx(h1_rate, abs=0.15)
