"""Guards and the energy balance they rest on.

Newmark's average acceleration conserves E - W exactly (E = kinetic + strain, W = trapezoid
work of the loads), with or without a moving fluid level; damping only lowers it. Each guard
(NaN/Inf, a diverged Krylov solve, energy from nowhere) is triggered on purpose and must stop
the run with one line and the last good state written.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_scene_errors import write_scene

from fenics_brainshift.cli import main
from fenics_brainshift.errors import SolverError
from fenics_brainshift.runner import Simulation
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.stepping import DynamicStepper, TimeIntegrator

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi


def _column(**sections):
    data = column_dict(
        8,
        fluid={"density": 1030.0, "level": [[0.0, 0.12], [0.05, 0.04]], "follower": False},
        time={"mode": "dynamic", "dt": 0.005, "end": 0.1},
        **sections,
    )
    return data


def _balance_history(data, steps=20):
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    for _ in range(steps):
        sim.step()
    t, kinetic, strain, work = np.array(sim.dynamic.energy.history).T
    return kinetic + strain - work, kinetic + strain


def test_newmark_conserves_energy_minus_work_exactly():
    balance, energy = _balance_history(_column())
    assert energy.max() > 0
    np.testing.assert_allclose(balance, 0.0, atol=1e-10 * energy.max())


def test_damping_only_lowers_the_balance():
    balance, energy = _balance_history(_column(damping={"a": 20.0, "b": 0.002}))
    assert np.all(np.diff(balance) <= 1e-12 * energy.max())
    assert balance[-1] < -0.01 * energy.max()


def test_unstable_scheme_is_stopped_by_the_energy_guard():
    # Newmark with beta = 0.05 is only conditionally stable (omega dt < 2.24): with this dt
    # the column's highest modes grow; the guard must fire before anything overflows
    sim = Simulation(scene_from_dict(_column(damping={})), COMM)
    stepper = DynamicStepper(sim.model, sim.state, TimeIntegrator(0.005, beta=0.05, gamma=0.5), (0.0, 0.0), sim.solves)
    stepper.setup()
    with pytest.raises(SolverError, match="energy grew without a source"):
        for _ in range(200):
            snapshot = sim.state.snapshot()
            stepper.step()
    assert np.all(np.isfinite(sim.u.x.array))
    stepper.restore(snapshot)
    assert np.all(np.isfinite(sim.u.x.array))
    assert stepper.energy.history[-1][0] > snapshot[0]  # the step that fired came after the snapshot


def test_nan_load_is_stopped_before_it_reaches_the_state():
    sim = Simulation(scene_from_dict(_column()), COMM)
    sim.setup()
    sim.step()
    good = sim.u.x.array.copy()
    sim.model.gravity.vector.array[:] = np.nan
    with pytest.raises(SolverError, match="no longer finite"):
        sim.step()
    np.testing.assert_array_equal(sim.u.x.array, good)


def test_diverged_krylov_solve_stops_the_run_with_reason_and_last_state(shared_tmp, capsys):
    data = _column(solver={"kind": "cg-jacobi", "rtol": 1e-12, "max_it": 3})
    scene = shared_tmp / "scene.toml"
    if COMM.rank == 0:
        write_scene(scene, data)
    COMM.barrier()
    out = shared_tmp / "out"
    code = main(["--log-level", "WARNING", "run", str(scene), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 3
    if COMM.rank == 0:
        assert "DIVERGED_MAX_IT" in err and "after 3 iterations" in err, err
        assert len(err.splitlines()) == 1 and "Traceback" not in err
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"].startswith("stopped: ")
        assert (out / "displacement.xdmf").is_file() and (out / "probes.csv").is_file()
