"""Time-integration theory on the single-degree-of-freedom oscillator (plain arrays)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fenics_brainshift.stepping.integrators import TimeIntegrator, initial_stiffness_weight, newmark_discrete_frequency

from conftest import decay_per_step


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


def _loaded_from_rest(ti: TimeIntegrator, omega: float, a_r: float, b_r: float, steps: int, averaged: bool):
    """q'' + (a_r + b_r omega^2) q' + omega^2 q = 1 from rest; a0 instantaneous (= 1) or averaged
    over the first half step, as DynamicStepper starts. Returns omega^2 q_n (1 when settled)."""
    weight = initial_stiffness_weight(ti.dt, b_r) if averaged else 0.0
    u, v, a = np.array([0.0]), np.array([0.0]), np.array([1.0 / (1.0 + weight * omega**2)])
    cm, ck = ti.effective_coefficients(a_r, b_r)
    out = []
    for _ in range(steps):
        wm, wk = ti.rhs_vectors(u, v, a, a_r, b_r)
        du = (1.0 - wm - omega**2 * wk) / (cm + omega**2 * ck)  # F_n = F_{n+1} = 1
        ti.update(u, v, a, du)
        out.append(omega**2 * u[0])
    return np.array(out)


def _loaded_from_rest_exact(omega: float, a_r: float, b_r: float, t: np.ndarray) -> np.ndarray:
    """The closed form of the same problem, omega^2 q(t) (roots of r^2 + c r + omega^2)."""
    c = a_r + b_r * omega**2
    root = np.sqrt(complex(c * c - 4 * omega**2))
    r1, r2 = (-c + root) / 2, (-c - root) / 2
    return np.real(1.0 + (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r1 - r2))


@pytest.mark.parametrize("scheme", ["newmark", "generalized-alpha"])
def test_a_load_at_rest_with_stiff_damping_gives_no_spurious_displacement(scheme):
    """The brain's surface nodes start with a huge a0 (pressure outside, gravity inside) in modes
    that stiffness damping kills within 1/(b omega^2) << dt. Generalized-alpha (rho_inf = 0.5)
    turned the instantaneous a0 into a displacement independent of omega (the 8 mm brain moved
    30 mm per node in one step); a0 averaged over the first half step keeps every mode within
    a fraction of its static answer, and the resolved modes as accurate as before."""
    dt, a_r, b_r, steps = 0.2, 0.02, 0.02, 10
    ti = TimeIntegrator.newmark(dt) if scheme == "newmark" else TimeIntegrator.generalized_alpha(dt, 0.5)
    t = dt * np.arange(1, steps + 1)
    for omega in (100.0, 1e3, 1e5):  # stiffly damped: b omega^2 dt = 40 ... 4e7
        error = np.max(
            np.abs(_loaded_from_rest(ti, omega, a_r, b_r, steps, True) - _loaded_from_rest_exact(omega, a_r, b_r, t))
        )
        assert error < 0.25, (omega, error)
    resolved = 1.0  # omega dt = 0.2: the averaged a0 differs from a0 by 0.2 %
    exact = _loaded_from_rest_exact(resolved, a_r, b_r, t)
    averaged = np.max(np.abs(_loaded_from_rest(ti, resolved, a_r, b_r, steps, True) - exact))
    instantaneous = np.max(np.abs(_loaded_from_rest(ti, resolved, a_r, b_r, steps, False) - exact))
    assert averaged < 0.011 and averaged < 1.05 * instantaneous
    if scheme == "generalized-alpha":  # what the averaging is for
        spurious = _loaded_from_rest(ti, 1e5, a_r, b_r, 1, False)[0]
        assert abs(spurious) > 1e5
