"""Time-integration theory on the single-degree-of-freedom oscillator (plain arrays)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import decay_per_step
from fenics_brainshift.stepping.integrators import TimeIntegrator, newmark_discrete_frequency


def _oscillate(ti: TimeIntegrator, omega: float, steps: int, xi: float = 0.0):
    """q'' + 2 xi omega q' + omega^2 q = 0 from q = 1 at rest, with the package's own update."""
    u, v, a = np.array([1.0]), np.array([0.0]), np.array([-(omega**2)])
    c = 2 * xi * omega
    cm, ck = ti.effective_coefficients(c, 0.0)
    out = [u[0]]
    for _ in range(steps):
        wm, wk = ti.rhs_vectors(u, v, a, c, 0.0)
        du = -(wm + omega**2 * wk) / (cm + omega**2 * ck)
        ti.update(u, v, a, du)
        out.append(u[0])
    return np.array(out)


@pytest.mark.parametrize("omega_dt", [0.1, 1.0, 10.0, 1000.0])
def test_newmark_average_acceleration_is_undamped_with_known_period_elongation(omega_dt):
    dt, omega = 0.01, omega_dt / 0.01
    ti = TimeIntegrator.newmark(dt)
    assert ti.spectral_radius(omega) == pytest.approx(1.0, abs=1e-12)
    q = _oscillate(ti, omega, 400)
    wbar = newmark_discrete_frequency(omega, dt)
    n = np.arange(q.size)
    np.testing.assert_allclose(q, np.cos(n * wbar * dt), atol=1e-10)
    # period elongation T_bar/T - 1 ~ (omega dt)^2 / 12 for small omega dt
    if omega_dt <= 0.1:
        assert omega / wbar - 1 == pytest.approx(omega_dt**2 / 12, rel=1e-2)


@pytest.mark.parametrize("rho_inf", [0.0, 0.3, 0.6, 0.9, 1.0])
def test_generalized_alpha_high_frequency_spectral_radius_is_rho_inf(rho_inf):
    ti = TimeIntegrator.generalized_alpha(0.01, rho_inf)
    assert ti.spectral_radius(1e8 / 0.01) == pytest.approx(rho_inf, abs=2e-3)
    # low frequencies are barely touched (second-order accuracy)
    assert ti.spectral_radius(0.01 / 0.01) > 0.9999


@pytest.mark.parametrize("rho_inf", [0.0, 0.3, 0.6, 0.9, 1.0])
@pytest.mark.parametrize("omega_dt", [1.0, 3.0, 10.0])
def test_generalized_alpha_measured_decay_per_step_is_the_spectral_radius(rho_inf, omega_dt):
    ti = TimeIntegrator.generalized_alpha(0.01, rho_inf)
    q = _oscillate(ti, omega_dt / 0.01, 60)
    assert decay_per_step(q) == pytest.approx(ti.spectral_radius(omega_dt / 0.01), rel=1e-6)


def test_generalized_alpha_rho_one_follows_newmark():
    dt, omega = 0.05, 7.0
    q_nm = _oscillate(TimeIntegrator.newmark(dt), omega, 200)
    q_ga = _oscillate(TimeIntegrator.generalized_alpha(dt, 1.0), omega, 200)
    np.testing.assert_allclose(q_ga, q_nm, atol=1e-12)


def test_second_order_accuracy():
    omega, T = 2 * math.pi, 1.3  # not at a peak, where the phase error would hide
    errors = []
    for steps in (50, 100, 200):
        ti = TimeIntegrator.generalized_alpha(T / steps, 0.5)
        errors.append(abs(_oscillate(ti, omega, steps)[-1] - math.cos(omega * T)))
    rate = np.polyfit(np.log([1 / 50, 1 / 100, 1 / 200]), np.log(errors), 1)[0]
    assert rate == pytest.approx(2.0, abs=0.1)
