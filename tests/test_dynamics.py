"""The FEM time loop against time-integration theory, on the lowest mode of the column.

The discrete eigenvector phi (K phi = w^2 M phi) is found by inverse iteration with PETSc, so
the test runs the same under mpirun. Started from u = phi at rest with no load, the FEM
response stays in that mode, and its top displacement must follow the single-degree-of-
freedom theory at the discrete frequency w exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from fenics_brainshift.runner import Simulation, build_model
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.stepping.integrators import newmark_discrete_frequency

from conftest import COMM, column_dict, decay_per_step, lowest_mode

pytestmark = pytest.mark.mpi
H = 0.1


def _free_vibration(scheme: dict, damping: dict, omega_dt: float, steps: int, degree: int = 1):
    data = column_dict(
        16,
        degree,
        height=H,
        gravity=(0.0, 0.0, 0.0),
        time={"mode": "dynamic", "dt": 1.0, "end": 1.0, **scheme},
        damping=damping,
    )
    scene = scene_from_dict(data)
    model = build_model(scene, COMM)
    omega, phi, _ = lowest_mode(model)
    scene.time.dt = omega_dt / omega
    sim = Simulation(scene, COMM, model)
    n = sim.state.n_owned
    sim.u.x.array[:n] = phi.array_r
    sim.u.x.scatter_forward()
    sim.setup()
    top = [sim.probe_values()[0, 2]]
    for _ in range(steps):
        sim.step()
        top.append(sim.probe_values()[0, 2])
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


def _chung_hulbert_spectral_radius(rho_inf: float, omega_dt: float) -> float:
    """Spectral radius of generalized-alpha on u'' + w^2 u = 0, from the scheme's equations
    written out here (Chung & Hulbert 1993, eqs. 3-5 and 25), not from the package:
    (1-am) a1 + am a0 + W^2 [(1-af) u1 + af u0] = 0, u1 = u0 + v0 + (1/2-b) a0 + b a1,
    v1 = v0 + (1-g) a0 + g a1 in units with dt = 1 (W = omega dt)."""
    am, af = (2 * rho_inf - 1) / (rho_inf + 1), rho_inf / (rho_inf + 1)
    g, b = 0.5 - am + af, 0.25 * (1 - am + af) ** 2
    W2 = omega_dt**2
    # unknowns (u1, v1, a1) = lhs^-1 rhs (u0, v0, a0)
    lhs = np.array([[(1 - af) * W2, 0.0, 1 - am], [1.0, 0.0, -b], [0.0, 1.0, -g]])
    rhs = np.array([[-af * W2, 0.0, -am], [1.0, 1.0, 0.5 - b], [0.0, 1.0, 1 - g]])
    return float(np.max(np.abs(np.linalg.eigvals(np.linalg.solve(lhs, rhs)))))


@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8])
def test_chung_hulbert_radius_tends_to_rho_inf(rho_inf):
    """The hand-written recurrence has the published limit: rho(W -> infinity) = rho_inf."""
    assert _chung_hulbert_spectral_radius(rho_inf, 1e10) == pytest.approx(rho_inf, abs=1e-5)


@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8])
def test_generalized_alpha_decay_per_step_matches_spectral_radius(rho_inf):
    scheme = {"scheme": "generalized-alpha", "rho_inf": rho_inf}
    omega, dt, q, sim = _free_vibration(scheme, {}, 3.0, 40)
    expected = _chung_hulbert_spectral_radius(rho_inf, omega * dt)
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
