"""The FEM time loop against time-integration theory, on the lowest mode of the column.

The discrete eigenvector phi (K phi = w^2 M phi) is found by inverse iteration with PETSc, so
the test runs the same under mpirun. Started from u = phi at rest with no load, the FEM
response stays in that mode, and its top displacement must follow the single-degree-of-
freedom theory at the discrete frequency w exactly.
"""
from __future__ import annotations

import numpy as np
import pytest
from dolfinx.fem.petsc import set_bc

from conftest import COMM, column_dict, decay_per_step
from fenics_brainshift.integrators import newmark_discrete_frequency
from fenics_brainshift.model import build_model
from fenics_brainshift.scene import SolverConfig, scene_from_dict
from fenics_brainshift.simulation import Simulation
from fenics_brainshift.solver import LinearSolver

pytestmark = pytest.mark.mpi
H = 0.1


def _lowest_mode(model):
    """(omega, phi) by inverse iteration; the next mode is 3x higher, so it converges fast."""
    M = model.assemble(model.mass_form(), with_bcs=False)
    K = model.assemble(model.stiffness_form(), with_bcs=False)
    K_bc = model.assemble(model.stiffness_form(), with_bcs=True)
    solver = LinearSolver(K_bc, SolverConfig(kind="cholesky"), "modes")
    x, b = K.createVecRight(), K.createVecRight()
    x.set(1.0)
    set_bc(x, model.bcs)
    for _ in range(40):
        M.mult(x, b)
        set_bc(b, model.bcs)
        solver.solve(b, x)
        x.scale(1.0 / x.norm())
    Kx, Mx = K.createVecRight(), K.createVecRight()
    K.mult(x, Kx)
    M.mult(x, Mx)
    return np.sqrt(x.dot(Kx) / x.dot(Mx)), x


def _free_vibration(scheme: dict, damping: dict, omega_dt: float, steps: int, degree: int = 1):
    data = column_dict(16, degree, height=H, gravity=(0.0, 0.0, 0.0),
                       time={"mode": "dynamic", "dt": 1.0, "end": 1.0, **scheme},
                       damping=damping)
    scene = scene_from_dict(data)
    model = build_model(scene, COMM)
    omega, phi = _lowest_mode(model)
    scene.time.dt = omega_dt / omega
    sim = Simulation(model)
    n = sim.n_owned
    sim.u.x.array[:n] = phi.array_r
    sim.u.x.scatter_forward()
    sim.setup_dynamic()
    top = [sim.probes.values(sim.u)[0, 2]]
    for _ in range(steps):
        sim.step()
        top.append(sim.probes.values(sim.u)[0, 2])
    top = np.array(top)
    return omega, scene.time.dt, top / top[0], sim


@pytest.mark.parametrize("degree", [1, 2])  # P2: consistent mass
@pytest.mark.parametrize("omega_dt", [0.2, 1.0])
def test_newmark_no_amplitude_decay_and_theoretical_period_elongation(omega_dt, degree):
    omega, dt, q, _ = _free_vibration({"scheme": "newmark"}, {}, omega_dt, 200, degree)
    wbar = newmark_discrete_frequency(omega, dt)
    n = np.arange(q.size)
    np.testing.assert_allclose(q, np.cos(n * wbar * dt), atol=1e-7)
    assert decay_per_step(q) == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8])
def test_generalized_alpha_decay_per_step_matches_spectral_radius(rho_inf):
    scheme = {"scheme": "generalized-alpha", "rho_inf": rho_inf}
    omega, dt, q, sim = _free_vibration(scheme, {}, 3.0, 40)
    expected = sim.integrator.spectral_radius(omega)
    assert expected < 0.999  # the case really dissipates
    assert decay_per_step(q) == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("a, b", [(4.0, 0.0), (0.0, 4e-4), (2.0, 2e-4)])
def test_rayleigh_damping_ratio_matches_a_over_2w_plus_b_w_over_2(a, b):
    # small omega dt: the scheme's own (tiny) error is far below the 1 % asked
    omega, dt, q, sim = _free_vibration({"scheme": "newmark"}, {"a": a, "b": b}, 0.05, 400)
    xi_expected = a / (2 * omega) + b * omega / 2
    assert 0.005 < xi_expected < 0.3
    # |lambda| = exp(-xi omega dt) per step for the damped oscillator
    xi_measured = -np.log(decay_per_step(q, span=100)) / (omega * dt)
    assert xi_measured == pytest.approx(xi_expected, rel=1e-2)
