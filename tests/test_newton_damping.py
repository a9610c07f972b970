"""Rayleigh damping C = a M + b K in Newton's time steps (stepping/newton_dynamic.py), with
b > 0, against the closed form and against the linear stepper (stepping/dynamic.py).

The laterally confined column, neo-Hookean, under 1e-4 of gravity (strains ~1e-5:
linear to ~1e-5), is started at its static sag plus its lowest mode phi (K phi = w^2 M phi,
by inverse iteration), at rest. Its top then oscillates in that mode alone, the modal
equation q'' + (a + b w^2) q' + w^2 q = 0, and per step the oscillation shrinks by |lambda|
of the scheme's amplification matrix for it, written out here from the scheme's equations
(Newmark, or generalized-alpha: Chung & Hulbert 1993). The top's increments q_{n+1} - q_n
carry the same |lambda| without the static offset.
"""

from __future__ import annotations

import numpy as np
import pytest
from dolfinx.fem.petsc import set_bc
from mpi4py import MPI

from fenics_brainshift.runner import Simulation, build_model
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict, decay_per_step, lowest_mode

pytestmark = pytest.mark.mpi
STEPS = 80
OMEGA_DT = 0.4


def _mode_and_sag(model):
    """(w, phi, static sag u_s = K^-1 F of the linear(ised) model), all PETSc."""
    omega, phi, solver = lowest_mode(model)
    F = model.gravity.vector.copy()
    set_bc(F, model.bcs)
    sag = F.duplicate()
    solver.solve(F, sag)
    return omega, phi, sag


def _closed_form_decay(omega_dt: float, c_dt: float, scheme: dict) -> float:
    """|lambda| of the oscillatory pair for q'' + c q' + w^2 q = 0 (units dt = 1, W = w dt):
    (1-am) a1 + am a0 + C [(1-af) v1 + af v0] + W^2 [(1-af) u1 + af u0] = 0,
    u1 = u0 + v0 + (1/2 - beta) a0 + beta a1, v1 = v0 + (1 - gamma) a0 + gamma a1."""
    if scheme["scheme"] == "newmark":
        am = af = 0.0
    else:
        r = scheme["rho_inf"]
        am, af = (2 * r - 1) / (r + 1), r / (r + 1)
    gamma, beta = 0.5 - am + af, 0.25 * (1 - am + af) ** 2
    W2, C = omega_dt**2, c_dt
    lhs = np.array([[(1 - af) * W2, (1 - af) * C, 1 - am], [1.0, 0.0, -beta], [0.0, 1.0, -gamma]])
    rhs = np.array([[-af * W2, -af * C, -am], [1.0, 1.0, 0.5 - beta], [0.0, 1.0, 1 - gamma]])
    eig = np.linalg.eigvals(np.linalg.solve(lhs, rhs))
    return float(np.abs(eig[np.abs(eig.imag) > 1e-12]).max())


def _run(material: str, scheme: dict, a: float, b: float):
    """(w, dt, the top's z per step, the stepper) from u = sag + phi (top amplitude ~ the sag)."""
    data = column_dict(
        8,
        gravity=(0.0, 0.0, -9.81e-4),
        material={"E": 5000.0, "nu": 0.3, "density": 1000.0, "model": material},
        time={"mode": "dynamic", "dt": 1.0, "end": 1.0, **scheme},
        damping={"a": a, "b": b},
    )
    scene = scene_from_dict(data)
    model = build_model(scene, COMM)
    omega, phi, sag = _mode_and_sag(model)
    scene.time.dt = OMEGA_DT / omega
    sim = Simulation(scene, COMM, model)
    n = sim.state.n_owned
    ratio = COMM.allreduce(float(np.abs(sag.array_r).max(initial=0.0)), op=MPI.MAX) / COMM.allreduce(
        float(np.abs(phi.array_r).max(initial=0.0)), op=MPI.MAX
    )
    sim.u.x.array[:n] = sag.array_r + ratio * phi.array_r
    sim.u.x.scatter_forward()
    sim.setup()
    top = [sim.probe_values()[0, 2]]
    for _ in range(STEPS):
        sim.step()
        top.append(sim.probe_values()[0, 2])
    return omega, scene.time.dt, np.array(top), sim.dynamic


@pytest.mark.parametrize(
    "scheme, a, b",
    [
        ({"scheme": "newmark"}, 2.0, 1.5e-3),
        ({"scheme": "generalized-alpha", "rho_inf": 0.8}, 0.0, 2.0e-3),
    ],
)
def test_newton_steps_with_stiffness_damping_decay_as_the_closed_form_and_the_linear_stepper(scheme, a, b):
    omega, dt, top, stepper = _run("neo-hookean", scheme, a, b)
    assert type(stepper).__name__ == "NewtonDynamicStepper"  # the path under test
    c = a + b * omega**2
    expected = _closed_form_decay(omega * dt, c * dt, scheme)
    without_b = _closed_form_decay(omega * dt, a * dt, scheme)
    assert b * omega**2 / 2 > 0.03 * omega and without_b - expected > 0.01  # b really damps here
    measured = decay_per_step(np.diff(top), span=40)
    assert measured == pytest.approx(expected, rel=1e-4), (measured, expected, without_b)
    # the linear stepper (one factor of K_eff, no Newton) on the same column: the same steps
    omega_linear, _, top_linear, linear = _run("linear", scheme, a, b)
    assert type(linear).__name__ == "DynamicStepper"
    assert omega_linear == pytest.approx(omega, rel=1e-12)
    swing = np.abs(np.diff(top_linear)).max()
    assert np.abs(np.diff(top) - np.diff(top_linear)).max() < 1e-3 * swing
