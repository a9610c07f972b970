"""The scene planner: what it decides, that it says so, and that each skip keeps the answer."""

from __future__ import annotations

import numpy as np
import pytest

from fenics_brainshift.runner import run
from fenics_brainshift.runner.build import mesh_from_spec as build_mesh
from fenics_brainshift.runner.plan import make_plan
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi


def cube(level, mode="auto", **extra):
    """A 20 mm gelatin-like cube (T1 = 4 H / c_s ~ 0.12 s) in a draining fluid."""
    data = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [3, 3, 3]},
        "material": {"E": 3000.0, "nu": 0.45, "density": 1040.0},
        "fixed": [{"where": "z < 1e-9"}],
        "fluid": {"density": 1000.0, "level": level},
        "time": {"mode": mode, "dt": 0.02, "end": 2.0},
        "damping": {"a": 5.0},
        "solver": {"kind": "cholesky"},
        "probes": {"top": [0.01, 0.01, 0.02]},
    }
    data.update(extra)
    return scene_from_dict(data)


def plan_of(scene):
    return make_plan(scene, build_mesh(scene.mesh, COMM))


def test_slow_drain_is_solved_quasi_statically():
    plan = plan_of(cube([[0.0, 0.03], [2.0, 0.0]]))
    assert plan.mode == "quasi-static"
    assert 0.05 < plan.lowest_period_s < 0.2
    assert "change slowly" in plan.reasons[0]


@pytest.mark.parametrize(
    "level, extra, mode, reason",
    [
        ([[0.0, 0.03], [0.2, 0.0]], {}, "dynamic", "lowest periods"),
        ([[0.0, 0.03], [2.0, 0.0]], {"remove": [{"at": 1.0, "where": "z > 0.015"}]}, "dynamic", "[[remove]]"),
        ([[0.0, 0.03], [2.0, 0.0]], {"fixed": []}, "dynamic", "no [[fixed]]"),
    ],
)
def test_fast_changes_removal_or_no_support_need_dynamics(level, extra, mode, reason):
    plan = plan_of(cube(level, **extra))
    assert plan.mode == mode and reason in plan.reasons[0]


def test_an_explicit_mode_wins():
    assert plan_of(cube([[0.0, 0.03], [2.0, 0.0]], mode="dynamic")).mode == "dynamic"


def test_plan_is_logged_and_kept_in_the_summary(shared_tmp, caplog):
    import logging

    # the package logger does not propagate once the CLI configured it: listen on it directly
    logger = logging.getLogger("fenics_brainshift")
    level = logger.level
    logger.addHandler(caplog.handler)
    logger.setLevel(logging.INFO)
    try:
        summary = run(cube([[0.0, 0.03], [2.0, 0.0]]), shared_tmp / "out", COMM).summary
    finally:
        logger.removeHandler(caplog.handler)
        logger.setLevel(level)
    assert summary["mode"] == "quasi-static" and summary["plan"]["mode"] == "quasi-static"
    assert summary["steps"] == 2  # the two breakpoints, no time stepping
    if COMM.rank == 0:
        assert any(r.getMessage().startswith("plan: quasi-static") for r in caplog.records)


def test_stiffness_band_is_exact_for_quasi_static_without_follower(shared_tmp):
    r = 0.44 / 2.37  # the paper's G = 2.37 +- 0.44 kPa
    fluid = {"density": 1000.0, "level": 0.012, "follower": False}
    data = column_dict(6, fluid=fluid)
    data["material"] = {"G": 2370.0, "nu": 0.45, "density": 1040.0, "G_sd": 440.0}
    summary = run(scene_from_dict(data), shared_tmp / "band", COMM).summary
    band = summary["stiffness_band"]
    assert band["exact"] and band["relative_sd"] == pytest.approx(r)
    for k, G in enumerate((2370.0 * (1 - r), 2370.0 * (1 + r))):
        data["material"] = {"G": G, "nu": 0.45, "density": 1040.0}
        solved = run(scene_from_dict(data), shared_tmp / f"band{k}", COMM).summary
        expected = band["probes"]["top"][0 if k == 0 else 2]
        np.testing.assert_allclose(solved["probes"]["top"], expected, rtol=1e-9, atol=1e-15)
        assert solved["max_displacement_m"] == pytest.approx(band["max_displacement_m"][0 if k == 0 else 2], rel=1e-9)


def test_reusing_the_fluid_load_keeps_the_answer():
    """A body resting at its (follower) equilibrium under a constant level: the surface does
    does not move, so the load assembled for the static answer serves every step; without
    reuse every step reassembles it. The answers agree to the follower tolerance."""
    from fenics_brainshift.runner import Simulation, build_model

    finals, counts = {}, {}
    for tol in (0.0, 1e-8):
        scene = cube(0.012, mode="dynamic", time={"mode": "dynamic", "dt": 0.02, "end": 1.0})
        scene.fluid.reuse_tol = tol
        scene.fluid.follower_tol = 1e-9  # a static answer exact enough that the surface then rests
        model = build_model(scene, COMM)
        static = Simulation(scene, COMM, model)
        static.solve_to_settled(0.0)
        sim = Simulation(scene, COMM, model)
        sim.u.x.array[:] = static.u.x.array
        sim.setup()
        before = (model.fluid.assemblies, sim.solves.count)
        for _ in range(20):
            sim.step()
        counts[tol] = (model.fluid.assemblies - before[0], sim.solves.count - before[1])
        # compared at a probe: two builds of one scene may be partitioned differently (0.9, MPI)
        finals[tol] = sim.probe_values()
    assert counts[0.0] == (20, 20)  # one assembly and one solve per step
    assert counts[1e-8] == (0, 20)  # the load of the static answer serves every step
    scale = np.abs(finals[0.0]).max()
    assert np.abs(finals[0.0] - finals[1e-8]).max() <= 1e-6 * scale
