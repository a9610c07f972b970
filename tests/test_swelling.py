"""Shrinkage and swelling ([[swelling]]: physics/growth.py) against closed forms.

- A free block (symmetry rollers only) with a uniform volume change takes exactly its new
  volume, without stress: u = (g - 1) X, g = (1 + theta)^(1/3), in the linear model (its
  eigenstrain) and the neo-Hookean one (F = F_e F_g).
- A swelling sphere bonded inside a thick spherical shell (an octant of it, symmetry planes),
  against the Lame solution with eigenstrain: u = A r in the core, C r + D / r^2 in the shell,
  sigma_rr continuous at r = a and zero at r = b; the radial displacement of the interface
  converges at second order, and the core's pressure with it.
- The neo-Hookean answer tends to the linear one for small volume changes (a first-order gap).
- A schedule: settled states at its breakpoints; a time-stepped, damped run ends at them.
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem
from mpi4py import MPI

from fenics_brainshift.errors import InputError
from fenics_brainshift.physics.material import lame_parameters
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM

pytestmark = pytest.mark.mpi
E_MOD, NU = 3000.0, 0.3
MU, LMBDA = lame_parameters(E_MOD, NU)
A_CORE, B_SHELL = 0.01, 0.02  # m
ROLLERS = [{"where": "x < 1e-9", "axes": "x"}, {"where": "y < 1e-9", "axes": "y"}, {"where": "z < 1e-9", "axes": "z"}]


def _scene(mesh: dict, swelling: list, model: str = "linear", degree: int = 1, **sections):
    data = {
        "name": "swelling",
        "mesh": mesh,
        "material": {"E": E_MOD, "nu": NU, "density": 1000.0, "model": model},
        "gravity": {"vector": [0.0, 0.0, 0.0]},
        "fixed": ROLLERS,
        "swelling": swelling,
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "element": {"degree": degree},
    }
    data.update(sections)
    return scene_from_dict(data)


def _settled(scene, t: float = 0.0) -> Simulation:
    sim = Simulation(scene, COMM)
    sim.solve_to_settled(t)
    return sim


def _volume(sim, deformed: bool) -> float:
    """The body's volume, of the reference or the deformed configuration (int det F dX)."""
    u = sim.u
    J = ufl.det(ufl.Identity(3) + ufl.grad(u)) if deformed else 1.0
    return COMM.allreduce(fem.assemble_scalar(fem.form(J * ufl.dx(domain=sim.model.mesh))), op=MPI.SUM)


BLOCK = {"shape": "box", "size": [0.02, 0.03, 0.01], "cells": [2, 3, 2]}


@pytest.mark.parametrize(
    "model, degree, theta",
    [("linear", 1, 0.05), ("neo-hookean", 1, -0.04), ("neo-hookean", 2, 0.05), ("saint-venant-kirchhoff", 1, 0.03)],
)
def test_a_free_block_takes_its_new_volume_without_stress(model, degree, theta, shared_tmp):
    scene = _scene(
        BLOCK,
        [{"where": "z > -1", "volume_change": theta}],
        model,
        degree,
        output={"fields": ["displacement", "von_mises"], "pictures": False},
    )
    result = run(scene, out=shared_tmp / model)
    sim = result.simulation
    g = (1 + theta) ** (1 / 3)
    X = sim.model.V.tabulate_dof_coordinates()
    n = sim.model.V.dofmap.index_map.size_local
    np.testing.assert_allclose(sim.u.x.array.reshape(-1, 3)[:n], (g - 1) * X[:n], atol=1e-9 * abs(g - 1) * 0.03)
    assert _volume(sim, True) == pytest.approx((1 + theta) * _volume(sim, False), rel=1e-9)
    written = sim  # the von Mises field the run wrote: the stress with the growth taken off
    from fenics_brainshift.outputs.xdmf import FieldWriter

    writer = FieldWriter(
        shared_tmp / f"{model}-vm", written.model.mesh, written.model.V, ("von_mises",), written.model.constitutive
    )
    writer.write(0.0, sim.u, sim.state.v)
    writer.close()
    assert np.abs(writer.von_mises.x.array).max() < 1e-6 * MU * abs(theta)


def _octant_of_a_shell(path, h: float) -> None:
    """An octant of the sphere r < B_SHELL with the core r < A_CORE meshed conformally."""
    if COMM.rank == 0:
        import gmsh

        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        occ = gmsh.model.occ
        shell, _ = occ.intersect([(3, occ.addSphere(0, 0, 0, B_SHELL))], [(3, occ.addBox(0, 0, 0, *[B_SHELL] * 3))])
        core, _ = occ.intersect([(3, occ.addSphere(0, 0, 0, A_CORE))], [(3, occ.addBox(0, 0, 0, *[A_CORE] * 3))])
        occ.fragment(shell, core)
        occ.synchronize()
        gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
        gmsh.finalize()
    COMM.barrier()


def _lame(theta: float) -> tuple[float, float]:
    """(u_r at r = a, the core's pressure) of the Lame solution with eigenstrain e = g - 1."""
    k3 = 3 * LMBDA + 2 * MU
    e = (1 + theta) ** (1 / 3) - 1
    D = k3 * e * A_CORE**3 / (k3 + 4 * MU)
    C = 4 * MU * D / (k3 * B_SHELL**3)
    A = C + D / A_CORE**3
    return A * A_CORE, -k3 * (A - e)


def _interface_and_pressure(sim, theta: float) -> tuple[float, float]:
    """(largest relative error of u_r over the interface's nodes, against the closed form; the
    core's pressure from its mean volumetric strain, -(3 lambda + 2 mu)(tr eps / 3 - e))."""
    exact_u, _ = _lame(theta)
    X = sim.model.V.tabulate_dof_coordinates()
    n = sim.model.V.dofmap.index_map.size_local
    r = np.linalg.norm(X[:n], axis=1)
    on = np.abs(r - A_CORE) < 1e-3 * A_CORE
    u = sim.u.x.array.reshape(-1, 3)[:n]
    ur = np.einsum("ij,ij->i", u[on], X[:n][on]) / r[on]
    error = COMM.allreduce(float(np.abs(ur - exact_u).max(initial=0.0)), op=MPI.MAX) / exact_u
    e = (1 + theta) ** (1 / 3) - 1
    core = (sim.model.growth.stretch - 1.0) / e  # 1 in the core, 0 in the shell
    mesh = sim.model.mesh
    integrals = [
        COMM.allreduce(fem.assemble_scalar(fem.form(f * ufl.dx(domain=mesh))), op=MPI.SUM)
        for f in (core * ufl.div(sim.u), core)
    ]
    mean_strain = integrals[0] / integrals[1] / 3
    return error, -(3 * LMBDA + 2 * MU) * (mean_strain - e)


@pytest.mark.parametrize("degree", [1, 2])
def test_a_swelling_sphere_in_a_shell_against_the_lame_solution(degree, shared_tmp):
    theta = 0.03
    errors, pressures = [], []
    for h in (0.004, 0.002, 0.001):
        path = shared_tmp / f"octant_{h}.msh"
        if not path.exists():
            _octant_of_a_shell(path, h)
        sim = _settled(
            _scene(
                {"file": str(path)},
                [{"where": f"x**2 + y**2 + z**2 < {A_CORE**2}", "volume_change": theta}],
                degree=degree,
            )
        )
        error, pressure = _interface_and_pressure(sim, theta)
        errors.append(error)
        pressures.append(pressure)
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < (0.015 if degree == 1 else 0.004), errors
    assert rates[-1] > 1.7, (errors, rates)  # second order (P2 too: the faceted sphere's geometry)
    exact_p = _lame(theta)[1]
    pressure_errors = np.abs(np.array(pressures) - exact_p) / exact_p
    assert pressure_errors[-1] < 0.02 and pressure_errors[-1] < pressure_errors[0], pressure_errors


def test_the_neo_hookean_answer_tends_to_the_linear_one_for_small_volume_changes(shared_tmp):
    path = shared_tmp / "octant_0.004.msh"
    if not path.exists():
        _octant_of_a_shell(path, 0.004)

    def nodal(sim) -> np.ndarray:
        """Every node's displacement, gathered and ordered by position (partitions differ)."""
        n = sim.model.V.dofmap.index_map.size_local
        rows = np.hstack([sim.model.V.tabulate_dof_coordinates()[:n], sim.u.x.array.reshape(-1, 3)[:n]])
        rows = np.concatenate(COMM.allgather(rows))
        return rows[np.lexsort(np.round(rows[:, :3], 12).T)][:, 3:]  # tabulated positions differ at round-off

    gaps = []
    for theta in (2e-3, 1e-3):
        answers = [
            nodal(
                _settled(
                    _scene(
                        {"file": str(path)},
                        [{"where": f"x**2 + y**2 + z**2 < {A_CORE**2}", "volume_change": theta}],
                        model,
                    )
                )
            )
            for model in ("linear", "neo-hookean")
        ]
        gaps.append(np.abs(answers[1] - answers[0]).max() / np.abs(answers[0]).max())
    assert gaps[1] < 1e-3
    assert gaps[0] / gaps[1] == pytest.approx(2.0, rel=0.05)  # the relative gap is first order in theta


def test_a_schedule_gives_settled_states_at_its_breakpoints_and_time_steps_follow_it():
    """Half the change by t = 1 s, all by 2 s: quasi-static solves at 0, 1 and 2 s, the block's
    volume (1 + f theta) V each time; a damped, time-stepped run of the same ends there too."""
    theta, schedule = 0.06, [[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]]
    region = [{"where": "z > -1", "volume_change": theta, "schedule": schedule}]
    result = run(_scene(BLOCK, region, probes={"corner": [0.02, 0.03, 0.01]}))
    assert result.history.times == [0.0, 1.0, 2.0]
    corners = np.array(result.history.probes)[:, 0, 0]
    expected = [0.02 * ((1 + f * theta) ** (1 / 3) - 1) for f in (0.0, 0.5, 1.0)]
    np.testing.assert_allclose(corners, expected, atol=1e-12)
    dynamic = run(
        _scene(
            BLOCK,
            region,
            probes={"corner": [0.02, 0.03, 0.01]},
            damping={"a": 20.0},
            time={"mode": "dynamic", "dt": 0.05, "end": 4.0},
        )
    )
    assert dynamic.summary["probes"]["corner"][0] == pytest.approx(expected[-1], rel=1e-3)
    assert "swelling" in dynamic.summary["plan"] and "eigenstrain" in dynamic.summary["plan"]["swelling"]


@pytest.mark.parametrize(
    "swelling, message",
    [
        ({"where": "z > -1", "volume_change": 5.0}, "between -1 and 1"),
        ({"where": "z > 1.0", "volume_change": 0.05}, "selects no cell"),
        ({"label": 2, "volume_change": 0.05}, "needs [mesh] file to be a label volume"),
        (
            {"where": "z > -1", "volume_change": 0.05, "schedule": [[0.0, 0.0], [60.0, 5.0]]},
            "a fraction of volume_change",
        ),
        ({"volume_change": 0.05}, "exactly one of where"),
    ],
)
def test_bad_swelling_input_is_refused_naming_the_field(swelling, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("]", r"\]")) as info:
        _settled(_scene(BLOCK, [swelling]))
    assert "[[swelling]]" in str(info.value)


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_a_swelling_confined_column_under_its_weight_against_the_1d_equilibrium(model):
    """The laterally confined column (tests/conftest.py) swelling by 10 % and loaded by its
    weight: in 1-D, F = diag(1, 1, s(Z)), F_e = F / g, and the axial stress per reference area
    must carry the weight above, P33 = -rho g (H - Z). Linear: P33 = (lambda + 2 mu) s' -
    (3 lambda + 2 mu) (g - 1) with s' = s - 1; neo-Hookean: P = g^2 P_e(F_e) (det(F_g) psi(F_e)
    per reference volume), P_e33 = mu (c - 1/c) + lambda ln(a^2 c) / c, a = 1/g, c = s/g.
    u(H) = int (s - 1) dZ. P2 on 16 layers holds the linear answer exactly."""
    from scipy.integrate import quad
    from scipy.optimize import brentq

    from conftest import column_dict

    theta, H, rho_g = 0.1, 0.1, 1000.0 * 9.81
    mu, lam = lame_parameters(5000.0, 0.3)
    g = (1 + theta) ** (1 / 3)
    data = column_dict(16, degree=2, material={"E": 5000.0, "nu": 0.3, "density": 1000.0, "model": model})
    data["swelling"] = [{"where": "z > -1", "volume_change": theta}]
    top = _settled(scene_from_dict(data)).probe_values()[0, 2]

    def axial(s):
        if model == "linear":
            return (lam + 2 * mu) * (s - 1) - (3 * lam + 2 * mu) * (g - 1)
        c = s / g
        return g**2 * (mu * (c - 1 / c) + lam * np.log(c / g**2) / c)

    def stretch(Z):
        return brentq(lambda s: axial(s) + rho_g * (H - Z), 0.3, 2.0, xtol=1e-15)

    exact = quad(lambda Z: stretch(Z) - 1.0, 0.0, H, epsabs=1e-14, epsrel=1e-12)[0]
    assert abs(exact) > 5e-4  # weight and swelling do not cancel: the top moves by 0.6 mm (linear) or more
    assert top == pytest.approx(exact, rel=1e-9 if model == "linear" else 1e-4)


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_a_swelling_block_presses_the_skull_under_a_falling_csf_level(model):
    """The free block swells by 5 % inside a skull 0.1 mm out (the gap skull) while CSF drains
    around it (follower load): it reaches the skull, which holds it within the tolerance, so
    its corner moves less than the free swelling would take it."""
    theta = 0.05
    scene = _scene(
        BLOCK,
        [{"where": "z > -1", "volume_change": theta}],
        model,
        gravity={"vector": [0.0, 0.0, -9.81]},
        fluid={"density": 1000.0, "level": [[0.0, 0.012], [1.0, 0.004]]},
        skull={"gap": 1e-4},
        probes={"corner": [0.02, 0.03, 0.01]},
    )
    result = run(scene)
    contact = result.summary["skull_contact"]
    assert result.summary["status"] == "ok" and contact["pressed_nodes"] > 0
    assert 0 <= contact["max_penetration_m"] <= contact["tolerance_m"]
    free = ((1 + theta) ** (1 / 3) - 1) * np.array([0.02, 0.03, 0.01])
    corner = np.array(result.summary["probes"]["corner"])
    assert np.all(corner < free) and np.all(corner > 0.0)


def test_removed_cells_do_not_grow_and_what_is_left_swells_freely():
    """The top half of a swelling block is removed at t = 0: the half that is left (on its
    rollers) swells freely, u = (g - 1) X, once the damped motion has died out; the removed
    cells push nothing (their growth load carries the tissue indicator). Generalized-alpha
    damps the plate's thickness modes, which dt does not resolve and Newmark keeps."""
    theta = 0.04
    scene = _scene(
        BLOCK,
        [{"where": "z > -1", "volume_change": theta}],
        damping={"a": 20.0},
        remove=[{"at": 0.0, "where": "z > 0.005"}],
        probes={"corner": [0.02, 0.03, 0.005]},
        time={"mode": "dynamic", "dt": 0.02, "end": 3.0, "scheme": "generalized-alpha", "rho_inf": 0.5},
    )
    result = run(scene)
    g = (1 + theta) ** (1 / 3)
    np.testing.assert_allclose(result.summary["probes"]["corner"], (g - 1) * np.array([0.02, 0.03, 0.005]), rtol=1e-4)
