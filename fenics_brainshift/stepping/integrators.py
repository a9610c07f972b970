"""Newmark average acceleration and generalized-alpha (Chung & Hulbert 1993), written once.

Equilibrium is enforced at the generalized mid-point

    M a_{n+1-am} + C v_{n+1-af} + K u_{n+1-af} = F_{n+1-af},   x_{n+1-a} = (1-a) x_{n+1} + a x_n,

with the Newmark relations for u, v, a. The unknown is the increment du = u_{n+1} - u_n:

    K_eff du = F_{n+1-af} - M (m_vec + a_r c_vec) - K (u_n + b_r c_vec),
    K_eff    = [(1-am) c0 + a_r (1-af) gamma/(beta dt)] M + (1-af) [1 + b_r gamma/(beta dt)] K,

where C = a_r M + b_r K (Rayleigh) and m_vec, c_vec collect the known parts of the
acceleration and velocity at the mid-point. Every function below works on numpy arrays,
so the same update serves the owned values of a DOLFINx Function and a test's plain arrays.
K_eff is constant for a linear material and fixed dt: it is assembled and factored once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class TimeIntegrator:
    """The generalized-alpha (and Newmark) coefficients of a time step dt: alpha_m, alpha_f,
    beta, gamma."""

    dt: float
    alpha_m: float = 0.0
    alpha_f: float = 0.0
    beta: float = 0.25
    gamma: float = 0.5

    @classmethod
    def newmark(cls, dt: float) -> TimeIntegrator:
        """Average constant acceleration (beta = 1/4, gamma = 1/2): the paper's scheme."""
        return cls(dt)

    @classmethod
    def generalized_alpha(cls, dt: float, rho_inf: float) -> TimeIntegrator:
        """Second-order accurate, unconditionally stable, high-frequency spectral radius rho_inf.
        rho_inf = 1 gives no numerical dissipation (the same trajectory as newmark)."""
        am = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
        af = rho_inf / (rho_inf + 1.0)
        gamma = 0.5 - am + af
        beta = 0.25 * (1.0 - am + af) ** 2
        return cls(dt, am, af, beta, gamma)

    # -- coefficients -------------------------------------------------------------------
    @property
    def c0(self) -> float:  # d a_{n+1} / d du
        return 1.0 / (self.beta * self.dt**2)

    @property
    def cv(self) -> float:  # d v_{n+1} / d du
        return self.gamma / (self.beta * self.dt)

    def effective_coefficients(self, a_rayleigh: float, b_rayleigh: float) -> tuple[float, float]:
        """(cM, cK) with K_eff = cM M + cK K."""
        cm = (1.0 - self.alpha_m) * self.c0 + a_rayleigh * (1.0 - self.alpha_f) * self.cv
        ck = (1.0 - self.alpha_f) * (1.0 + b_rayleigh * self.cv)
        return cm, ck

    # -- the step, on arrays --------------------------------------------------------------
    def _a_known(self, v, a):
        """a_{n+1} without its du part."""
        return -(1.0 / (self.beta * self.dt)) * v - (0.5 / self.beta - 1.0) * a

    def _v_known(self, v, a):
        """v_{n+1} without its du part."""
        return v + self.dt * ((1.0 - self.gamma) * a + self.gamma * self._a_known(v, a))

    def rhs_vectors(self, u, v, a, a_rayleigh: float, b_rayleigh: float):
        """(w_m, w_k) with rhs = F_mid - M w_m - K w_k."""
        m_vec = (1.0 - self.alpha_m) * self._a_known(v, a) + self.alpha_m * a
        c_vec = (1.0 - self.alpha_f) * self._v_known(v, a) + self.alpha_f * v
        return m_vec + a_rayleigh * c_vec, u + b_rayleigh * c_vec

    def load_weights(self) -> tuple[float, float]:
        """(w_new, w_old): F_mid = w_new F_{n+1} + w_old F_n."""
        return 1.0 - self.alpha_f, self.alpha_f

    def update(self, u, v, a, du) -> None:
        """Advance u, v, a (arrays, in place) by the solved increment du."""
        a_new = self.c0 * du + self._a_known(v, a)
        v += self.dt * ((1.0 - self.gamma) * a + self.gamma * a_new)
        u += du
        a[...] = a_new

    # -- theory, for tests and for choosing dt ---------------------------------------------
    def amplification_matrix(self, omega: float, xi: float = 0.0) -> np.ndarray:
        """The 3x3 matrix A with (u, dt v, dt^2 a)_{n+1} = A (u, dt v, dt^2 a)_n for the
        single-degree-of-freedom oscillator a + 2 xi omega v + omega^2 u = 0."""
        dt = self.dt
        state = np.eye(3)
        out = np.empty((3, 3))
        for j in range(3):
            u, v, a = state[0, j], state[1, j] / dt, state[2, j] / dt**2
            w_m, w_k = self.rhs_vectors(u, v, a, 2.0 * xi * omega, 0.0)
            cm, ck = self.effective_coefficients(2.0 * xi * omega, 0.0)
            du = -(w_m + omega**2 * w_k) / (cm + omega**2 * ck)
            uu, vv, aa = np.array([u]), np.array([v]), np.array([a])
            self.update(uu, vv, aa, du)
            out[:, j] = [uu[0], vv[0] * dt, aa[0] * dt**2]
        return out

    def spectral_radius(self, omega: float, xi: float = 0.0) -> float:
        return float(np.max(np.abs(np.linalg.eigvals(self.amplification_matrix(omega, xi)))))


def initial_stiffness_weight(dt: float, b_rayleigh: float) -> float:
    """w in (M + w K) a0 = F(0) - C v0 - K u0: the initial acceleration averaged over the first
    half step, dt/2 times the stiffness-proportional damping (why: DynamicStepper)."""
    return 0.5 * dt * b_rayleigh


def newmark_discrete_frequency(omega: float, dt: float) -> float:
    """Average acceleration is exactly energy-conserving with frequency 2/dt arctan(omega dt/2):
    the period grows by the factor omega / this (period elongation)."""
    return 2.0 / dt * math.atan(omega * dt / 2.0)
