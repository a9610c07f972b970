"""Finite-deformation materials and Newton's method, against closed forms and 1-D references
computed here independently of the code under test."""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from mpi4py import MPI
from scipy.integrate import quad
from scipy.optimize import brentq

from fenics_brainshift import compat
from fenics_brainshift.errors import SolverError
from fenics_brainshift.physics.material import Hyperelastic, lame_parameters
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.runner.build import mesh_from_spec
from fenics_brainshift.scene import MeshSpec, load_scene, scene_from_dict

from conftest import COMM, column_dict

pytestmark = pytest.mark.mpi
MU, LMBDA = lame_parameters(3000.0, 0.45)


def _neo_hookean_piola(F: np.ndarray) -> np.ndarray:
    """P = mu (F - F^-T) + lambda ln(J) F^-T, written out by hand."""
    Finv_T = np.linalg.inv(F).T
    return MU * (F - Finv_T) + LMBDA * np.log(np.linalg.det(F)) * Finv_T


def _face_force(F: np.ndarray, degree: int, axis: int) -> np.ndarray:
    """Internal nodal forces of u = (F - I) X on a unit block, summed over the nodes of the face
    X[axis] = 1 (global), and the largest force at a node off the boundary."""
    mesh = mesh_from_spec(MeshSpec(shape="box", size=(1.0, 1.0, 1.0), cells=(2, 2, 2)), COMM)
    V = compat.vector_space(mesh, degree)
    u = fem.Function(V)
    u.interpolate(lambda x: (F - np.eye(3)) @ x)
    f = fem.form(Hyperelastic(MU, LMBDA).internal_force(u, ufl.TestFunction(V)))
    b = assemble_vector(f)
    b.ghostUpdate(addv=2, mode=1)  # ADD, REVERSE
    n = V.dofmap.index_map.size_local
    x = V.tabulate_dof_coordinates()[:n]
    nodal = b.getArray(readonly=True).reshape(-1, 3)
    on_face = np.isclose(x[:, axis], 1.0)
    inside = np.all((x > 1e-9) & (x < 1 - 1e-9), axis=1)
    interior = COMM.allreduce(float(np.abs(nodal[inside]).max(initial=0.0)), op=MPI.MAX)
    return COMM.allreduce(nodal[on_face].sum(axis=0), op=MPI.SUM), interior


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("stretch", [0.7, 1.3, 2.0])
def test_uniaxial_stress_of_neo_hookean_block(degree, stretch):
    # the lateral stretch t that leaves the sides free of traction, from the closed form
    t = brentq(lambda t: _neo_hookean_piola(np.diag([stretch, t, t]))[1, 1], 0.2, 2.0, xtol=1e-15)
    F = np.diag([stretch, t, t])
    total, interior = _face_force(F, degree, axis=0)
    P11 = _neo_hookean_piola(F)[0, 0]
    assert total == pytest.approx([P11, 0.0, 0.0], abs=1e-10 * abs(P11))  # unit face: force = P11
    assert interior <= 1e-10 * abs(P11)  # a homogeneous stress has no divergence


@pytest.mark.parametrize("degree", [1, 2])
def test_simple_shear_of_neo_hookean_block(degree):
    gamma = 0.8
    F = np.eye(3) + gamma * np.outer([1, 0, 0], [0, 1, 0])
    total, interior = _face_force(F, degree, axis=1)
    # J = 1: P = mu (F - F^-T), so the face Y = 1 carries (mu gamma, 0, 0)
    assert total == pytest.approx([MU * gamma, 0.0, 0.0], abs=1e-10 * MU)
    assert interior <= 1e-10 * MU


def _column_top(E: float, degree: int, layers: int, model: str, g: float = 9.81) -> float:
    data = column_dict(
        layers, degree, gravity=(0.0, 0.0, -g), material={"E": E, "nu": 0.3, "density": 1000.0, "model": model}
    )
    sim = Simulation(scene_from_dict(data), COMM)
    sim.solve_to_settled(0.0)
    return float(sim.probe_values()[0, 2])


def test_standing_column_under_its_weight_against_the_1d_equilibrium():
    """A laterally confined neo-Hookean column sags by a fifth of its height. In 1-D,
    F = diag(1, 1, lambda(Z)) and P33 = mu (lambda - 1/lambda) + Lambda ln(lambda) / lambda
    must equal -rho g (H - Z) (free top, weight per reference volume); u(H) = int (lambda - 1)."""
    E, nu, rho, g, H = 500.0, 0.3, 1000.0, 9.81, 0.1
    mu, lam = lame_parameters(E, nu)

    def stretch(Z):
        return brentq(lambda s: mu * (s - 1 / s) + lam * np.log(s) / s + rho * g * (H - Z), 1e-3, 1.0, xtol=1e-15)

    exact = quad(lambda Z: stretch(Z) - 1.0, 0.0, H, epsabs=1e-14, epsrel=1e-12)[0]
    assert exact < -0.15 * H  # a large deformation: the linear answer is far off
    linear = -rho * g * H**2 / (2 * (lam + 2 * mu))
    assert abs(linear - exact) > 0.1 * abs(exact)
    tops = [_column_top(E, 2, n, "neo-hookean") for n in (8, 16)]
    errors = [abs(t - exact) for t in tops]
    assert errors[1] <= 1e-4 * abs(exact)
    assert np.log2(errors[0] / errors[1]) > 2.5  # P2: third order in the layer height


def test_small_loads_give_the_linear_answer_with_a_linear_deviation():
    ratios = {
        s: _column_top(5000.0, 1, 4, "neo-hookean", 9.81 * s) / _column_top(5000.0, 1, 4, "linear", 9.81 * s)
        for s in (0.02, 0.01)
    }
    deviation = {s: r - 1.0 for s, r in ratios.items()}
    assert abs(deviation[0.01]) < 1e-3
    assert deviation[0.02] / deviation[0.01] == pytest.approx(2.0, rel=0.02)  # first order in the load


def _block_in_oil(model: str, degree: int = 1, nu: float = 0.48) -> dict:
    """The gelatin block of the paper, glued to the floor, oil standing 20 mm high."""
    return {
        "mesh": {"shape": "box", "size": [0.05, 0.05, 0.025], "cells": [6, 6, 3]},
        "material": {"E": 729.0, "nu": nu, "density": 1048.0, "model": model},
        "fluid": {"density": 975.0, "level": 0.02},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "element": {"degree": degree},
        "probes": {"top": [0.025, 0.025, 0.025]},
    }


@pytest.mark.parametrize(
    "model, degree, nu", [("neo-hookean", 1, 0.48), ("saint-venant-kirchhoff", 1, 0.48), ("neo-hookean", 2, 0.4999)]
)
def test_newton_converges_quadratically_with_the_follower_tangent(model, degree, nu):
    scene = scene_from_dict(_block_in_oil(model, degree, nu))
    sim = Simulation(scene, COMM)
    sim.solve_to_settled(0.0)
    history = np.array(sim.static.history) / sim.static.history[0]
    assert history[-1] < 1e-8 and sim.static.cuts == 0  # converged: |R| <= 1e-9 of the load
    # quadratic: once the residual is small, each step squares it (to the power 1.7 at least),
    # or reaches the round-off floor of the solve (1e-9 of the load)
    small = [k for k in range(len(history) - 1) if 1e-9 < history[k] < 1e-3]
    assert small and all(history[k + 1] <= max(history[k] ** 1.7, 1e-9) for k in small)
    if nu > 0.49:
        return  # the iteration counts of the nearly incompressible block are dominated by its damped phase
    # without the load's tangent the same solve converges only linearly: more iterations
    plain = Simulation(scene, COMM)
    plain._static().tangent.follower_load = False
    plain.solve_to_settled(0.0)
    assert plain.static.iterations > sim.static.iterations + 2
    assert plain.probe_values() == pytest.approx(sim.probe_values(), abs=1e-9)


def test_newton_on_the_linear_material_finds_the_fixed_point_answer():
    """The linear material with follower loading, solved by Newton with the load's tangent and
    by the (default) Anderson fixed point to a tight tolerance: one answer, and Newton's
    convergence is quadratic."""
    from fenics_brainshift.stepping.newton import NewtonStatic

    data = _block_in_oil("linear", 1, 0.48)
    data["fluid"]["follower_tol"] = 1e-10
    fixed_point = Simulation(scene_from_dict(data), COMM)
    fixed_point.solve_to_settled(0.0)
    newton = Simulation(scene_from_dict(data), COMM)
    newton.static = NewtonStatic(newton.model, newton.state, newton.solves)
    newton.static.setup()
    newton.solve_to_settled(0.0)
    history = np.array(newton.static.history) / newton.static.history[0]
    assert history[-1] < 1e-8 and newton.static.iterations <= 4
    a, b = fixed_point.probe_values(), newton.probe_values()
    assert np.abs(a).max() > 1e-4  # the block sinks by a fraction of a millimetre
    np.testing.assert_allclose(b, a, atol=1e-8 * np.abs(a).max())


def test_archimedes_holds_on_the_deformed_surface(shared_tmp):
    from test_hydrostatics import submerged_volume

    scene = load_scene(
        "cube",
        [
            "mesh.cells=[6, 6, 3]",
            "time.mode=quasi-static",
            "fluid.volume=100e-6",
            "material.model=neo-hookean",
            "output.pictures=false",
        ],
    )
    result = run(scene)
    mesh, u = result.mesh, result.displacement
    # move the mesh to the deformed shape (P1: the vertices carry the displacement), then clip
    x = mesh.geometry.x
    moved = x.copy()
    V1 = compat.vector_space(mesh, 1)
    w = fem.Function(V1)
    w.interpolate(u)
    coords = V1.tabulate_dof_coordinates()
    from scipy.spatial import cKDTree

    nearest = cKDTree(coords).query(x)[1]
    moved += w.x.array.reshape(-1, 3)[nearest]
    mesh.geometry.x[:] = moved
    volume = submerged_volume(mesh, np.array([0.0, 0.0, 1.0]), result.summary["final_level_m"])
    mesh.geometry.x[:] = x
    assert result.summary["fluid_force_N"][2] == pytest.approx(975.0 * 9.81 * volume, rel=1e-10)


def test_a_rigid_rotation_of_the_scene_rotates_the_answer(shared_tmp):
    """Mesh, gravity, support and fluid turned by 40 degrees about (1, 1, 1): the displacement
    turns with them (neo-Hookean, large sag, follower fluid load)."""
    import meshio

    from fenics_brainshift.meshing.hexgrid import structured_box

    axis = np.ones(3) / np.sqrt(3.0)
    angle = np.radians(40.0)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    size, cells = (0.02, 0.02, 0.04), (2, 2, 4)
    if COMM.rank == 0:
        points, tets = structured_box(size, cells)
        meshio.write(shared_tmp / "turned.xdmf", meshio.Mesh(points @ R.T, [("tetra", tets)]))
    COMM.barrier()
    top = np.array([0.01, 0.01, 0.04])
    common = {
        "material": {"E": 300.0, "nu": 0.4, "density": 1040.0, "model": "neo-hookean"},
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
    }
    upright = scene_from_dict(
        {
            **common,
            "mesh": {"shape": "box", "size": list(size), "cells": list(cells)},
            "gravity": {"vector": [0.0, 0.0, -9.81]},
            "fixed": [{"where": "z < 1e-9"}],
            "fluid": {"density": 1000.0, "level": 0.02},
            "probes": {"top": list(top)},
        }
    )
    up = R @ np.array([0.0, 0.0, 1.0])
    turned = scene_from_dict(
        {
            **common,
            "mesh": {"file": str(shared_tmp / "turned.xdmf")},
            "gravity": {"vector": list(-9.81 * up)},
            "fixed": [{"where": f"{float(up[0])!r} * x + {float(up[1])!r} * y + {float(up[2])!r} * z < 1e-9"}],
            "fluid": {"density": 1000.0, "level": 0.02},
            "probes": {"top": list(R @ top)},
        }
    )
    a, b = (run(s).probes["top"] for s in (upright, turned))
    assert np.linalg.norm(a) > 1e-3  # millimetres of sag: a large deformation of a 40 mm block
    np.testing.assert_allclose(b, R @ np.array(a), atol=1e-8 * np.linalg.norm(a))


def _swinging_column(model: str, dt: float, g: float = 9.81):
    """A confined column under suddenly applied gravity, undamped, for half a second."""
    data = column_dict(
        4,
        gravity=(0.0, 0.0, -g),
        material={"E": 3000.0, "nu": 0.3, "density": 1000.0, "model": model},
        time={"mode": "dynamic", "dt": dt, "end": 0.5},
    )
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    tops = [sim.probe_values()[0, 2]]
    for _ in range(int(round(0.5 / dt))):
        sim.step()
        tops.append(sim.probe_values()[0, 2])
    t, kinetic, stored, work = np.array(sim.dynamic.energy.history).T
    return np.array(tops), np.abs(kinetic + stored - work).max() / (kinetic + stored).max()


def test_newmark_with_neo_hookean_balances_energy_to_second_order_in_dt():
    """kinetic + stored - work is conserved exactly by Newmark only for a linear material; for
    the neo-Hookean column (sagging by a fifth, swinging) its error falls as dt^2."""
    errors = [_swinging_column("neo-hookean", dt)[1] for dt in (0.02, 0.01, 0.005)]
    assert errors[0] < 0.02
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 1.6), rates
    assert _swinging_column("linear", 0.01)[1] < 1e-12  # exact for the linear material


def test_nonlinear_dynamics_tends_to_linear_dynamics_for_small_loads():
    nonlinear, _ = _swinging_column("neo-hookean", 0.01, g=9.81e-3)
    linear, _ = _swinging_column("linear", 0.01, g=9.81e-3)
    assert np.abs(linear).max() > 1e-6
    np.testing.assert_allclose(nonlinear, linear, atol=2e-3 * np.abs(linear).max())


def test_a_time_step_newton_cannot_solve_is_cut_in_halves():
    """Newton refused every whole step (as if it had failed): each is then solved as two
    half steps, so the run equals one made with dt / 2, state, work and energy alike."""

    def run_with(dt: float, refuse_whole_steps: bool):
        data = column_dict(
            4,
            gravity=(0.0, 0.0, -9.81),
            material={"E": 3000.0, "nu": 0.3, "density": 1000.0, "model": "neo-hookean"},
            time={"mode": "dynamic", "dt": dt, "end": 0.2},
        )
        sim = Simulation(scene_from_dict(data), COMM)
        sim.setup()
        stepper = sim.dynamic
        if refuse_whole_steps:
            solve_step = stepper._newton_step

            def refusing(t_new):
                if stepper.integrator.dt > 0.75 * dt:
                    raise SolverError("refused, for the test")
                return solve_step(t_new)

            stepper._newton_step = refusing
        tops = []
        for _ in range(int(round(0.2 / dt))):
            sim.step()
            tops.append(sim.probe_values()[0, 2])
        return np.array(tops), stepper.energy.work, stepper.cuts, sim.state.t

    cut, work_cut, cuts, t_end = run_with(0.02, refuse_whole_steps=True)
    halves, work_halves, _, _ = run_with(0.01, refuse_whole_steps=False)
    assert cuts == 10 and t_end == pytest.approx(0.2, abs=1e-12)
    assert np.abs(cut).max() > 1e-3  # a column sagging millimetres
    np.testing.assert_allclose(cut, halves[1::2], atol=1e-7 * np.abs(halves).max())
    assert work_cut == pytest.approx(work_halves, rel=1e-6)


_TWO_STEPPERS = """
import sys
sys.path.insert(0, {tests!r})
from mpi4py import MPI
from conftest import column_dict
from fenics_brainshift.runner import Simulation
from fenics_brainshift.scene import scene_from_dict
for layers in (3, 4):  # two steppers in one process, each compiling its forms afresh
    data = column_dict(layers, material={{"E": 3000.0, "nu": 0.3, "density": 1000.0, "model": "neo-hookean"}},
                       time={{"mode": "dynamic", "dt": 0.01, "end": 0.02}})
    sim = Simulation(scene_from_dict(data), MPI.COMM_WORLD)
    sim.setup()
    sim.step()
    print("top", layers, sim.probe_values()[0, 2])
"""


def test_neo_hookean_time_steps_on_an_empty_form_cache(tmp_path, serial_only):
    """Debian 12's FFCx rewrote the mesh's coordinate element when it compiled a form missing
    from the cache; Arguments made before and after then hashed differently and Newton's step
    form failed ("Found different Arguments with same number and part") - on a cold cache only,
    so the steppers are built in a process whose cache is new."""
    import subprocess
    import sys

    from conftest import ROOT, subprocess_env

    env = {**subprocess_env(), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    code = _TWO_STEPPERS.format(tests=str(ROOT / "tests"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.count("top") == 2
    assert list((tmp_path / "cache").rglob("*.so")), "nothing was compiled: the test did not test"


_ONE_COMPILE = """
from mpi4py import MPI
import ufl
from dolfinx import fem
from fenics_brainshift import compat
from fenics_brainshift.runner.build import mesh_from_spec
from fenics_brainshift.scene import MeshSpec
mesh = mesh_from_spec(MeshSpec(shape="box", size=(1.0, 1.0, 1.0), cells=(1, 1, 1)), MPI.COMM_WORLD)
V = compat.vector_space(mesh, 1)
before = ufl.TestFunction(V)
element = repr(mesh.ufl_domain().ufl_coordinate_element())
fem.form(ufl.inner(ufl.grad(before), ufl.grad(ufl.TrialFunction(V))) * ufl.dx)  # a compile: the cache is new
after = ufl.TestFunction(V)
print(repr(mesh.ufl_domain().ufl_coordinate_element()) == element, before == after, hash(before) == hash(after))
"""


def test_a_compile_leaves_the_mesh_coordinate_element_as_it_was(tmp_path, serial_only):
    """Every mesh the package makes carries its coordinate element's variant from the start,
    so an Argument made after a compile is the same (equal and same hash) as one made before
    (in a process with a new cache, so that the compile happens, and leaves no module in
    the user's cache)."""
    import subprocess
    import sys

    from conftest import subprocess_env

    env = {**subprocess_env(), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-c", _ONE_COMPILE], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["True", "True", "True"], proc.stdout
    assert list((tmp_path / "cache").rglob("*.so")), "nothing was compiled: the test did not test"


@pytest.mark.parametrize("model", ["neo-hookean", "saint-venant-kirchhoff"])
@pytest.mark.parametrize("mode", ["quasi-static", "dynamic"])
def test_a_stiff_body_converges_to_the_linear_answer(model, mode):
    """E = 3 GPa: strains of 1e-9, where the target 1e-9 |F| lay below the residual's round-off
    (Newton stopped: exit 3, "no equilibrium"). Its target is now the round-off floor at least,
    and at such strains every material is the linear one (to the strain, 1e-9 relative)."""
    sets = ["mesh.cells=[4, 4, 2]", "material.E=3e9", f"time.mode={mode}", "time.end=0.2", "output.pictures=false"]
    finite = run(load_scene("cube", sets + [f"material.model={model}"]))
    linear = run(load_scene("cube", sets + ["material.model=linear"]))
    assert finite.summary["status"] == "ok"
    top, reference = (np.array(r.summary["probes"]["top_centre"]) for r in (finite, linear))
    assert abs(reference[2]) > 1e-10  # m: a sag to compare (E = 3 kPa sags 1e6 times more)
    assert np.linalg.norm(top - reference) < 1e-6 * np.linalg.norm(reference)
