"""The von Mises stress a run writes is its own material's: the small-strain stress of a
linear run, the Cauchy stress of a hyperelastic one, the tissue's after a resection.

References written out here with numpy, independent of the UFL forms: the linear stress
2 mu eps + lambda tr(eps) I, the neo-Hookean Cauchy stress mu / J (B - I) + lambda ln(J) / J I,
Saint Venant-Kirchhoff's F (lambda tr(E) I + 2 mu E) F^T / J; and simple shear in closed form."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from scipy.optimize import brentq

from fenics_brainshift.outputs.xdmf import FieldWriter
from fenics_brainshift.physics.material import lame_parameters
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM

pytestmark = pytest.mark.mpi
E_MOD, NU = 3000.0, 0.45
MU, LMBDA = lame_parameters(E_MOD, NU)


def cauchy(F: np.ndarray, model: str, mu: float = MU, lmbda: float = LMBDA) -> np.ndarray:
    J = np.linalg.det(F)
    if model == "linear":
        eps = 0.5 * (F + F.T) - np.eye(3)
        return 2 * mu * eps + lmbda * np.trace(eps) * np.eye(3)
    if model == "neo-hookean":
        return mu / J * (F @ F.T - np.eye(3)) + lmbda * np.log(J) / J * np.eye(3)
    E = 0.5 * (F.T @ F - np.eye(3))
    return F @ (lmbda * np.trace(E) * np.eye(3) + 2 * mu * E) @ F.T / J


def von_mises(sigma: np.ndarray) -> float:
    dev = sigma - np.trace(sigma) / 3 * np.eye(3)
    return float(np.sqrt(1.5 * np.sum(dev * dev)))


def _box(model: str, **sections) -> dict:
    data = {
        "name": "box",
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [2, 2, 2]},
        "material": {"E": E_MOD, "nu": NU, "density": 1000.0, "model": model},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "output": {"fields": ["displacement", "von_mises"], "pictures": False},
    }
    data.update(sections)
    return data


def _written_von_mises(model: str, F: np.ndarray, folder) -> np.ndarray:
    """The von Mises field the run's writer makes of u = (F - I) X, cell by cell (owned)."""
    sim = Simulation(scene_from_dict(_box(model)), COMM)
    sim.state.u.interpolate(lambda x: (F - np.eye(3)) @ x)
    writer = FieldWriter(folder, sim.model.mesh, sim.model.V, ("von_mises",), sim.model.constitutive)
    writer.write(0.0, sim.state.u, sim.state.v)
    writer.close()
    return writer.von_mises.x.array[: sim.model.mesh.topology.index_map(3).size_local]


@pytest.mark.parametrize("model", ["linear", "neo-hookean", "saint-venant-kirchhoff"])
def test_simple_shear_and_uniaxial_stretch(model, shared_tmp):
    gamma = 0.8
    shear = np.eye(3) + gamma * np.outer([1, 0, 0], [0, 1, 0])
    values = _written_von_mises(model, shear, shared_tmp)
    assert values == pytest.approx(von_mises(cauchy(shear, model)), rel=1e-10)
    if model == "neo-hookean":  # J = 1, sigma = mu (B - I): von Mises mu sqrt(gamma^4 + 3 gamma^2)
        assert values == pytest.approx(MU * np.sqrt(gamma**4 + 3 * gamma**2), rel=1e-10)
        assert abs(np.sqrt(3) * MU * gamma / values[0] - 1) > 0.09  # the linear value is 10 % off
    # uniaxial stretch 1.3 with traction-free sides: sigma = diag(s11, 0, 0), von Mises |s11|
    t = brentq(lambda t: cauchy(np.diag([1.3, t, t]), model)[1, 1], 0.3, 1.5, xtol=1e-15)
    stretch = np.diag([1.3, t, t])
    assert abs(cauchy(stretch, model)[2, 2]) < 1e-9 * MU
    values = _written_von_mises(model, stretch, shared_tmp)
    assert values == pytest.approx(abs(cauchy(stretch, model)[0, 0]), rel=1e-10)


def _cells_and_fields(path):
    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        points, cells = reader.read_points_cells()
        data = [reader.read_data(k) for k in range(reader.num_steps)]
    _, point_data, cell_data = data[-1]
    return points, cells[0].data, point_data["displacement"], np.ravel(cell_data["von_mises"][0])


def _cell_gradients(points, tets, u) -> np.ndarray:
    """F = I + grad u of each P1 tetrahedron, from its corners' displacements."""
    X = points[tets]
    dX = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))
    du = np.transpose(u[tets][:, 1:] - u[tets][:, :1], (0, 2, 1))
    return np.eye(3) + du @ np.linalg.inv(dX)


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_a_run_writes_its_own_material_stress(model, shared_tmp):
    """A block sagging under its own weight on a clamped floor, run end to end: each cell's
    written von Mises stress against the model's stress of the written displacement."""
    result = run(scene_from_dict(_box(model, gravity={"vector": [9.81, 0.0, -9.81]})), out=shared_tmp / model)
    if COMM.rank:
        return
    points, tets, u, written = _cells_and_fields(shared_tmp / model / "displacement.xdmf")
    expected = [von_mises(cauchy(F, model)) for F in _cell_gradients(points, tets, u)]
    assert np.max(np.linalg.norm(u, axis=1)) > 1e-3  # a large enough sag for the models to differ
    np.testing.assert_allclose(written, expected, rtol=1e-8)
    assert result.summary["status"] == "ok"


def test_removed_cells_carry_no_stress_and_the_rest_the_tissue_s(shared_tmp):
    """After a resection the stress is the tissue's: zero in the removed cells (the plain
    G and lambda gave them the stress of their leftover strain)."""
    data = _box(
        "linear",
        gravity={"vector": [0.0, 0.0, -9.81]},
        remove=[{"at": 0.0, "where": "z > 0.015"}],
        time={"mode": "dynamic", "dt": 0.01, "end": 0.05},
    )
    data["mesh"]["cells"] = [2, 2, 4]
    run(scene_from_dict(data), out=shared_tmp / "r")
    if COMM.rank:
        return
    points, tets, u, written = _cells_and_fields(shared_tmp / "r" / "displacement.xdmf")
    removed = points[tets].mean(axis=1)[:, 2] > 0.015
    assert removed.any() and (~removed).any()
    assert np.all(written[removed] == 0.0)
    expected = [von_mises(cauchy(F, "linear")) for F in _cell_gradients(points, tets[~removed], u)]
    np.testing.assert_allclose(written[~removed], expected, rtol=1e-8)
