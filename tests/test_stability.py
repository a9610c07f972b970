"""Stability under stress (the fast cases; benchmarks/stability.py runs the long ones).

- Any dt from 1e-4 s to 10 s: Newmark's average acceleration keeps the energy balance exact,
  so a load applied suddenly from rest can at most double the static answer in the energy
  norm (|u|_K <= 2 |u_static|_K, from 1/2 |u|_K^2 <= F.u = (u_static, u)_K).
- nu up to 0.4999 with P1 and P2: finite answers, Krylov iterations within bounds.
- A body at rest in equilibrium stays there for 10^4 undamped steps (no drift).
"""

from __future__ import annotations

import numpy as np
import pytest

from fenics_brainshift import compat
from fenics_brainshift.runner import Simulation, build_model
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi


def _cube(nu=0.45, degree=1, solver="cholesky", dt=0.01, end=0.1, **sections):
    """A 20 mm cube clamped at the floor, sides free: a shape that bends, unlike the column."""
    data = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [3, 3, 3]},
        "material": {"E": 3000.0, "nu": nu, "density": 1000.0},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "dynamic", "dt": dt, "end": end},
        "solver": {"kind": solver},
        "element": {"degree": degree},
        "probes": {"top": [0.01, 0.01, 0.02]},
    }
    data.update(sections)
    return scene_from_dict(data)


def _energy_norm(K, f) -> float:
    vec = compat.petsc_vec(f)
    K_vec = vec.duplicate()
    K.mult(vec, K_vec)
    return float(np.sqrt(max(vec.dot(K_vec), 0.0)))


def _static(scene, model=None):
    """The static answer; pass the model to share its mesh (two builds of one scene may be
    partitioned differently under MPI, so their vectors do not match)."""
    sim = Simulation(scene, COMM, model)
    sim.solve_to_settled(0.0)
    return sim


@pytest.mark.parametrize("dt", [1e-4, 1e-2, 1.0, 10.0])
def test_sudden_load_at_most_doubles_the_static_answer_for_any_dt(dt):
    scene = _cube(dt=dt, end=40 * dt)
    model = build_model(scene, COMM)
    static = _static(scene, model)
    sim = Simulation(scene, COMM, model)
    sim.setup()
    K = model.assemble(model.stiffness_form(), with_bcs=False)
    u_static = _energy_norm(K, static.u)
    peak = 0.0
    for _ in range(40):
        sim.step()
        peak = max(peak, _energy_norm(K, sim.u))
    assert np.all(np.isfinite(sim.u.x.array))
    assert peak <= 2.0 * u_static * (1 + 1e-8)
    if dt == 1e-2:  # 40 steps span several periods of the slowest mode (~0.08 s) and resolve it
        assert peak > 1.5 * u_static


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("nu", [0.3, 0.49, 0.4999])
def test_near_incompressible_amg_steps_match_the_direct_solver(nu, degree):
    """Five steps with CG + GAMG land where the same steps with a Cholesky factor do: the
    iterative solver stays right, not only finite, as nu -> 0.5."""
    tops = {}
    for solver in ("cg-gamg", "cholesky"):
        sim = Simulation(_cube(nu=nu, degree=degree, solver=solver, end=0.05), COMM)
        sim.setup()
        for _ in range(5):
            sim.step()
        assert np.all(np.isfinite(sim.u.x.array))
        tops[solver] = sim.probe_values()[0]
    assert np.abs(tops["cholesky"]).max() > 1e-5  # it moves (5 steps into the sudden load)
    assert np.abs(tops["cg-gamg"] - tops["cholesky"]).max() <= 1e-6 * np.abs(tops["cholesky"]).max()


def test_p1_locks_against_p2_as_nu_approaches_one_half():
    """The cube's sag under its weight: P1's stiffening grows as nu -> 0.5; P2 stays close to
    itself. (benchmarks/stability.py prints the table.)"""
    sag = {}
    for degree in (1, 2):
        for nu in (0.3, 0.4999):
            sim = _static(_cube(nu=nu, degree=degree, time={"mode": "quasi-static"}))
            sag[degree, nu] = -sim.probe_values()[0, 2]
    # measured on this 3 x 3 x 3 grid: P1/P2 = 0.97 at nu = 0.3, 0.33 at nu = 0.4999
    assert sag[1, 0.3] / sag[2, 0.3] > 0.9
    assert sag[1, 0.4999] / sag[2, 0.4999] < 0.5


def test_body_at_rest_stays_at_rest_for_ten_thousand_steps():
    data = column_dict(3, time={"mode": "dynamic", "dt": 0.01, "end": 100.0})
    scene = scene_from_dict(data)
    model = build_model(scene, COMM)
    static = _static(scene, model)
    sim = Simulation(scene, COMM, model)
    sim.u.x.array[:] = static.u.x.array
    sim.setup()
    for _ in range(10_000):
        sim.step()
    drift = np.abs(sim.u.x.array - static.u.x.array).max()
    assert drift <= 1e-10 * np.abs(static.u.x.array).max()
    assert np.abs(sim.state.v.x.array).max() <= 1e-10 * np.abs(static.u.x.array).max() / scene.time.dt
