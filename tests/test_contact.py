"""Frictionless contact with a rigid skull (surfaces/skull.py, physics/contact.py): exact
reactions, sliding supports, nothing past the skull, bad skulls refused."""

from __future__ import annotations

import re

import meshio
import numpy as np
import pytest
from dolfinx import fem
from mpi4py import MPI

from fenics_brainshift import compat
from fenics_brainshift.errors import InputError
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.scene import scene_from_dict
from fenics_brainshift.surfaces.skull import RigidSkull
from fenics_brainshift.surfaces.triangles import closest_points_on_triangles

from conftest import COMM

pytestmark = pytest.mark.mpi

L, H = 0.05, 0.025  # the paper's gelatin block, m
E, NU, RHO, RHO_OIL, LEVEL = 729.0, 0.48, 1048.0, 975.0, 0.02


def _box_surface(lo, hi, path, drop_face: bool = False) -> str:
    """A closed box (12 triangles, outward), written by rank 0; every rank gets the path."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    P = np.array(
        [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0], [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
    )
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]]
    if drop_face:
        quads = quads[1:]
    tris = [[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads]
    if COMM.rank == 0:
        meshio.write(str(path), meshio.Mesh(P, [("triangle", np.array(tris))]), binary=True)
    COMM.barrier()
    return str(path)


def _block(bottom: list, skull: dict | None, model: str = "linear", g: float = 9.81) -> dict:
    data = {
        "mesh": {"shape": "box", "size": [L, L, H], "cells": [6, 6, 3]},
        "material": {"E": E, "nu": NU, "density": RHO, "model": model},
        "gravity": {"vector": [0.0, 0.0, -g]},
        "fluid": {"density": RHO_OIL, "level": LEVEL, "follower": False},
        "fixed": [{"where": "x < 1e-9", "axes": "x"}, {"where": "y < 1e-9", "axes": "y"}] + bottom,
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "probes": {"top": [L, L, H], "bottom": [L, L, 0.0], "centre": [L / 2, L / 2, 0.0]},
    }
    if skull is not None:
        data["skull"] = skull
    return data


@pytest.fixture
def floor(shared_tmp):
    """A closed box whose floor is the plane z = 0, where the block stands."""
    return _box_surface((-0.1, -0.1, 0.0), (0.15, 0.15, 0.2), shared_tmp / "floor.stl")


def test_closest_points_on_triangles_against_an_optimiser():
    from scipy.optimize import minimize

    rng = np.random.default_rng(3)
    for _ in range(50):
        a, b, c, p = rng.normal(size=(4, 3))
        q = closest_points_on_triangles(p, a, b, c)
        res = minimize(
            lambda z: np.sum((a + z[0] * (b - a) + z[1] * (c - a) - p) ** 2),
            [0.3, 0.3],
            bounds=[(0, 1), (0, 1)],
            constraints=[{"type": "ineq", "fun": lambda z: 1 - z[0] - z[1]}],
            method="SLSQP",
            options={"ftol": 1e-15},
        )
        assert np.linalg.norm(q - p) == pytest.approx(
            np.linalg.norm(a + res.x[0] * (b - a) + res.x[1] * (c - a) - p), abs=1e-7
        )


def test_distance_field_of_a_cube_inside_and_of_its_dilation():
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]]
    tris = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    y = np.array([[0.5, 0.5, 0.1], [0.2, 0.7, 0.5], [0.5, 0.5, -0.05], [1.1, 1.1, 0.5]])
    phi, grad = RigidSkull(pts, tris).phi(y)
    np.testing.assert_allclose(phi, [0.1, 0.2, -0.05, -np.sqrt(0.02)], atol=1e-12)
    np.testing.assert_allclose(grad[0], [0, 0, 1], atol=1e-12)  # away from the floor
    phi, grad = RigidSkull(pts, tris, gap=0.1).phi(y)  # the skull 0.1 outside the cube
    np.testing.assert_allclose(phi, [0.2, 0.3, 0.05, 0.1 - np.sqrt(0.02)], atol=1e-12)
    np.testing.assert_allclose(grad[2], [0, 0, 1], atol=1e-12)  # back towards the cube


def test_block_on_a_rigid_floor_carries_weight_minus_buoyancy_and_slides(floor):
    """Only the floor holds the block up; x and y are held on two faces (no rigid sliding).
    The floor's force is the weight less Archimedes' buoyancy, and the block deforms as one
    whose bottom is held vertically but free to slide (the same supports)."""
    sim = Simulation(scene_from_dict(_block([], {"file": floor, "tolerance": 1e-6})), COMM)
    sim.solve_to_settled(0.0)
    report = sim.static.contact.report(sim.state.u)
    weight, buoyancy = RHO * 9.81 * L * L * H, RHO_OIL * 9.81 * L * L * LEVEL
    assert report["force_N"][2] == pytest.approx(weight - buoyancy, rel=1e-9)
    assert abs(report["force_N"][0]) < 1e-9 and abs(report["force_N"][1]) < 1e-9
    assert report["max_penetration_m"] <= 1e-6
    sliding = Simulation(scene_from_dict(_block([{"where": "z < 1e-9", "axes": "z"}], None)), COMM)
    sliding.solve_to_settled(0.0)
    a, b = sim.probe_values(), sliding.probe_values()
    assert np.abs(b).max() > 1e-3  # the block sags and bulges by millimetres
    np.testing.assert_allclose(a, b, atol=2e-6)  # the penetration left, within the tolerance
    assert abs(a[1, 0] - b[1, 0]) < 2e-6 and abs(a[1, 0]) > 1e-4  # the bottom slid outwards as freely


def test_neo_hookean_block_on_the_floor(floor):
    sim = Simulation(scene_from_dict(_block([], {"file": floor}, model="neo-hookean")), COMM)
    sim.solve_to_settled(0.0)
    report = sim.static.contact.report(sim.state.u)
    assert report["force_N"][2] == pytest.approx(RHO * 9.81 * L * L * H - RHO_OIL * 9.81 * L * L * LEVEL, rel=1e-9)
    assert report["max_penetration_m"] <= 1e-5


def test_nothing_passes_a_skull_made_from_a_gap_under_a_large_load():
    """The block hangs from its top face in a skull 1 mm outside it; gravity 50 g would pull
    it centimetres down: the skull stops it within the tolerance, and the summary says so."""
    data = _block([], {"gap": 0.001, "tolerance": 1e-6}, g=50 * 9.81)
    data["fixed"] = [{"where": f"z > {H} - 1e-9"}]
    del data["fluid"]
    result = run(scene_from_dict(data), comm=COMM)
    contact = result.summary["skull_contact"]
    assert contact["max_penetration_m"] <= 1e-6 and contact["pressed_nodes"] > 0
    free = _block([], None, g=50 * 9.81)
    free["fixed"] = data["fixed"]
    del free["fluid"]
    assert abs(run(scene_from_dict(free), comm=COMM).probes["centre"][2]) > 0.003  # would fall through
    assert result.probes["centre"][2] == pytest.approx(-0.001, abs=2e-6)  # resting on the skull below
    assert contact["contact_from_s"] == 0.0 and contact["states_without_contact"] == 0


def test_the_summary_counts_the_multiplier_updates_of_every_settled_state(monkeypatch):
    """Two settled states pressed on the skull (the buoyancy falls between them), to a tight
    tolerance: summary.json's multiplier_updates is the run's total, counted here apart."""
    from fenics_brainshift.physics.contact import SkullContact

    calls = []
    update = SkullContact.update_multipliers
    monkeypatch.setattr(SkullContact, "update_multipliers", lambda self, u: (calls.append(1), update(self, u)))
    data = _block([], {"gap": 0.001, "tolerance": 1e-7}, g=50 * 9.81)
    data["fixed"] = [{"where": f"z > {H} - 1e-9"}]
    data["fluid"]["level"] = [[0.0, 0.015], [1.0, 0.005]]
    result = run(scene_from_dict(data), comm=COMM)
    contact = result.summary["skull_contact"]
    assert contact["max_penetration_m"] <= 1e-7 and contact["contact_from_s"] == 0.0
    assert contact["multiplier_updates"] == len(calls) >= 2


def test_a_skull_from_labels_of_the_label_volume(shared_tmp):
    """[skull] label: the boundary of the labels inside the skull, by marching cubes. A block of
    label 1 hangs from its top face over three image voxels of CSF (label 2); 8 g would pull its
    bottom 6 mm past the labels' floor, which lies on the face between image voxels 2 and 3:
    z = 5 mm (image voxel i spans 2i -/+ 1 mm). With the skull its bottom rests on that plane."""
    import nibabel as nib

    if COMM.rank == 0:
        labels = np.zeros((20, 20, 20), dtype=np.uint8)
        labels[4:16, 4:16, 3:17] = 2
        labels[6:14, 6:14, 6:14] = 1  # the block: 11 .. 27 mm, its bottom 6 mm over the floor
        nib.save(nib.Nifti1Image(labels, np.diag([2.0, 2.0, 2.0, 1.0])), str(shared_tmp / "head.nii.gz"))
    COMM.barrier()
    data = {
        "mesh": {"file": str(shared_tmp / "head.nii.gz"), "labels": [1], "voxel": 0.002, "unit": "mm"},
        "material": {"E": E, "nu": NU, "density": RHO},
        "gravity": {"vector": [0.0, 0.0, -8 * 9.81]},
        "fixed": [{"where": "z > 0.0269"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "skull": {"label": [1, 2], "tolerance": 1e-6},
        "probes": {"bottom": [0.019, 0.019, 0.011]},
    }
    result = run(scene_from_dict(data), comm=COMM)
    contact = result.summary["skull_contact"]
    assert contact["max_penetration_m"] <= 1e-6 and contact["pressed_nodes"] > 0
    assert 0.011 + result.probes["bottom"][2] == pytest.approx(0.005, abs=2e-6)
    del data["skull"]
    assert 0.011 + run(scene_from_dict(data), comm=COMM).probes["bottom"][2] < 0.004  # would pass the floor


def test_contact_is_skipped_while_nothing_reaches_the_skull():
    """A skull 10 mm out of a block that sags a few millimetres: every settled state is solved
    without contact (the plan says so), and the answer is the contact-free one exactly."""
    data = _block([], {"gap": 0.010}, g=5 * 9.81)
    data["fixed"] = [{"where": f"z > {H} - 1e-9"}]
    data["fluid"]["level"] = [[0.0, 0.03], [1.0, 0.01]]
    result = run(scene_from_dict(data), comm=COMM)
    contact = result.summary["skull_contact"]
    assert contact["states_without_contact"] == 2 and contact["contact_from_s"] is None
    assert "skipped while the contact-free answer stays clear" in result.summary["plan"]["contact"]
    del data["skull"]
    free = run(scene_from_dict(data), comm=COMM)
    assert abs(free.probes["centre"][2]) > 1e-3  # it does sag
    # the same solves (two builds may be partitioned differently on N ranks: round-off)
    np.testing.assert_allclose(result.probes["centre"], free.probes["centre"], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "label, skull, message",
    [
        ("gap not positive", {"gap": 0.0}, "[skull] gap must be a positive distance"),
        ("both", {"gap": 0.001, "file": "x.stl"}, "[skull] give exactly one of file"),
        ("not a surface", {"file": "skull.nii.gz"}, "[skull] file must be a closed triangulated surface"),
        ("missing", {"file": "/nonexistent/skull.stl"}, "[skull] file not found"),
        ("label of no volume", {"label": [1, 2]}, "[skull] label needs [mesh] file to be a label volume"),
        ("label not a label", {"label": [1.5]}, "[skull] label must be a label value"),
    ],
)
def test_bad_skull_sections_are_named(label, skull, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("]", r"\]")):
        scene_from_dict(_block([], skull))


def test_time_stepping_needs_a_dissipative_scheme_with_contact():
    data = _block([], {"gap": 0.001})
    data["time"] = {"mode": "dynamic", "dt": 0.01, "end": 0.1}  # Newmark
    with pytest.raises(InputError, match="time stepping with contact needs .time. scheme = .generalized-alpha."):
        scene_from_dict(data)


def test_a_block_dropped_on_the_floor_settles_where_the_static_contact_puts_it(floor):
    """Time stepping with contact (generalized-alpha, damped): the block, released at rest
    touching the floor, sinks, bounces and settles; at the end the floor carries weight
    less buoyancy and the block has the settled state's shape."""
    static = Simulation(scene_from_dict(_block([], {"file": floor, "tolerance": 1e-6})), COMM)
    static.solve_to_settled(0.0)
    data = _block([], {"file": floor, "tolerance": 1e-6})
    data["time"] = {"mode": "dynamic", "scheme": "generalized-alpha", "rho_inf": 0.5, "dt": 0.02, "end": 1.5}
    data["damping"] = {"a": 20.0, "b": 0.0}
    result = run(scene_from_dict(data), comm=COMM)
    contact = result.summary["skull_contact"]
    assert contact["force_N"][2] == pytest.approx(RHO * 9.81 * L * L * H - RHO_OIL * 9.81 * L * L * LEVEL, rel=1e-3)
    assert contact["max_penetration_m"] <= 1e-6
    settled = static.probe_values()
    np.testing.assert_allclose(
        [result.probes["top"], result.probes["bottom"]], settled[:2], atol=1e-3 * np.abs(settled).max()
    )


def test_an_open_skull_or_one_crossing_the_body_is_refused(shared_tmp):
    open_box = _box_surface((-0.1, -0.1, 0.0), (0.15, 0.15, 0.2), shared_tmp / "open.stl", drop_face=True)
    with pytest.raises(InputError, match=r"is not a closed surface: it has 4 open edge"):
        Simulation(scene_from_dict(_block([], {"file": open_box})), COMM)
    crossing = _box_surface((-0.1, -0.1, 0.005), (0.15, 0.15, 0.2), shared_tmp / "crossing.stl")
    with pytest.raises(InputError, match=r"the body's surface is 5 mm past the skull at t = 0"):
        Simulation(scene_from_dict(_block([], {"file": crossing})), COMM)


def test_the_contact_pressure_is_written_with_the_fields(floor, shared_tmp):
    """displacement.xdmf carries contact_pressure: the floor's pressure on the bottom nodes,
    nothing on the top; summed over the nodes' areas it gives the floor's force."""
    import meshio

    out = shared_tmp / "contact_out"
    result = run(scene_from_dict(_block([], {"file": floor, "tolerance": 1e-6})), out, COMM)
    if COMM.rank != 0:
        return
    with meshio.xdmf.TimeSeriesReader(str(out / "displacement.xdmf")) as reader:
        points, cells = reader.read_points_cells()
        _, point_data, _ = reader.read_data(reader.num_steps - 1)
    p = point_data["contact_pressure"].ravel()
    bottom, top = points[:, 2] < 1e-9, points[:, 2] > H - 1e-9
    assert np.all(p[top] == 0.0) and np.all(p[bottom] > 0.0)
    force = result.summary["skull_contact"]["force_N"][2]
    # each node's area: a third of every surface triangle it is a corner of (a node on the
    # bottom's rim also has its share of the side faces, and presses with all of it)
    tets = cells[0].data
    faces = np.sort(
        np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]]), axis=1
    )
    unique, count = np.unique(faces, axis=0, return_counts=True)
    faces = unique[count == 1]  # the surface
    area = 0.5 * np.linalg.norm(
        np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]]), axis=1
    )
    assert area.sum() == pytest.approx(2 * L * L + 4 * L * H)
    share = np.zeros(len(points))
    np.add.at(share, faces.ravel(), np.repeat(area / 3.0, 3))
    assert np.sum(p * share) == pytest.approx(force, rel=1e-6)


def test_a_piece_cut_free_lands_on_its_cut_face(floor):
    """The block's bottom layer is removed at the start: the rest falls 8 mm onto the floor
    and lands on the face the cut made, which meets the skull like the original surface
    (nothing passes the floor), and the floor then carries the rest's weight less buoyancy."""
    data = _block([], {"file": floor, "tolerance": 1e-6})
    cut = H / 3  # one layer of cells
    data["remove"] = [{"at": 0.0, "where": f"z < {cut} - 1e-9"}]
    data["time"] = {"mode": "dynamic", "scheme": "generalized-alpha", "rho_inf": 0.5, "dt": 0.02, "end": 1.5}
    data["damping"] = {"a": 20.0, "b": 0.0}
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    while sim.t < 1.5 - 1e-9:
        sim.step()
    x = sim.model.V.tabulate_dof_coordinates() + sim.state.u.x.array.reshape(-1, 3)
    held = sim.model.tissue.present  # cells left; their nodes:
    cells = compat.dofmap_array(sim.model.V)
    nodes = np.unique(cells[held[: len(cells)]])
    lowest = COMM.allreduce(float(x[nodes, 2].min()), op=MPI.MIN)
    assert lowest == pytest.approx(0.0, abs=1e-6)  # on the floor, not through it
    # dead fluid load (follower off): buoyancy of the piece where it was, up to the level
    weight, buoyancy = RHO * 9.81 * L * L * (H - cut), RHO_OIL * 9.81 * L * L * (LEVEL - cut)
    assert sim.contact.report(sim.state.u)["force_N"][2] == pytest.approx(weight - buoyancy, rel=1e-3)


def test_a_skull_file_in_another_unit_than_the_mesh_is_refused(shared_tmp):
    """A skull 5 mm around the block (m) written in mm: 1000x the block's size and metres from
    it at rest, a skull that would do nothing (it ran with status ok); the bundled phantom (mm)
    with its skull written in m: 1000x too small. Both refused, the field and the unit named;
    the same skull in the mesh's unit is accepted."""
    from fenics_brainshift import load_scene

    mm = _box_surface((-10.0, -10.0, -5.0), (60.0, 60.0, 35.0), shared_tmp / "skull_mm.stl")
    with pytest.raises(
        InputError,
        match=r"^\[skull\] file 'skull_mm.stl' is 107 m across against a 0.075 m body, "
        r"5 m from it at rest: is it in mm\? give the skull in the mesh's unit \(m\)",
    ):
        Simulation(scene_from_dict(_block([], {"file": mm})), COMM)
    metres = _box_surface((-0.01, -0.01, -0.005), (0.06, 0.06, 0.035), shared_tmp / "skull_m.stl")
    sim = Simulation(scene_from_dict(_block([], {"file": metres})), COMM)
    assert sim.contact.clearance(fem.Function(sim.model.V)) == pytest.approx(0.005)
    phantom = _box_surface((-0.075, -0.09, -0.005), (0.075, 0.09, 0.125), shared_tmp / "phantom_skull_m.stl")
    with pytest.raises(
        InputError,
        match=r"^\[skull\] file 'phantom_skull_m.stl' is 0.000268 m across against a "
        r"0.251 m body: is it in m\? give the skull in the mesh's unit \(mm\)",
    ):
        Simulation(load_scene("phantom", ["time.mode=quasi-static", f"skull.file={phantom}"]), COMM)


def test_brainshift_run_refuses_a_skull_in_mm_for_a_scene_in_m(shared_tmp, capsys):
    """`brainshift run` with `--set skull.file=` a skull in mm: exit 2, one line, nothing written."""
    from test_scene_errors import write_scene

    from fenics_brainshift.cli import main

    mm = _box_surface((-10.0, -10.0, -5.0), (60.0, 60.0, 35.0), shared_tmp / "skull_mm.stl")
    scene = write_scene(shared_tmp / f"block_r{COMM.rank}.toml", _block([], None))  # every rank its own copy
    out = shared_tmp / "out"
    code = main(["run", str(scene), "--out", str(out), "--set", f"skull.file={mm}"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    if COMM.rank == 0:
        assert (
            "[skull] file 'skull_mm.stl' is 107 m across against a 0.075 m body, 5 m from it at rest: is it in mm?"
        ) in err
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    else:
        assert err == ""
    COMM.barrier()
    assert not out.exists()


def _cantilever(floor: str, tolerance: float, solve: bool = True) -> Simulation:
    """A 100 x 10 x 10 mm cantilever clamped at x = 0 whose weight would bend its free end 10 mm
    down, over a floor 2 mm below it (the settled state, solved)."""
    data = {
        "mesh": {"shape": "box", "size": [0.1, 0.01, 0.01], "cells": [20, 2, 2]},
        "material": {"E": 1e6, "nu": 0.3, "density": 1000.0},
        "gravity": {"vector": [0.0, 0.0, -9.81]},
        "fixed": [{"where": "x < 1e-9"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "skull": {"file": floor, "tolerance": tolerance},
        "probes": {"tip": [0.1, 0.005, 0.0]},
    }
    sim = Simulation(scene_from_dict(data), COMM)
    if solve:
        sim.solve_to_settled(0.0)
    return sim


def _held_on_walls(sim, lo, hi) -> np.ndarray:
    """The same body's linear equilibrium with every node the skull pushes held on the walls of
    the box [lo, hi] it is pushed by, every other component free (frictionless), solved by
    PETSc's LU with no contact code; checked to be the contact solution (each held component's
    reaction pushes into the box, and no surface node is outside it). A wall pushes a node
    along its axis only, so a node pushed along x from below is held on x = lo[0]; a node in
    an edge of the box, pushed by two walls, is held on both. The displacement's owned entries."""
    from dolfinx.fem.petsc import set_bc
    from petsc4py import PETSc

    model, contact = sim.model, sim.contact
    state = contact._state(sim.state.u)
    force = (contact.weights * state.p)[:, None] * state.normal  # each node's share, as each rank holds it
    largest = COMM.allreduce(float(np.abs(force).max(initial=0.0)), op=MPI.MAX)
    node, axis = np.nonzero(np.abs(force) > 1e-6 * largest)
    wall = np.where(force[node, axis] > 0, np.asarray(lo)[axis], np.asarray(hi)[axis])
    nodes = contact.nodes[node]
    K = model.assemble(model.stiffness_form(), with_bcs=True)
    F = K.createVecRight()
    model.load_into(0.0, F)
    set_bc(F, model.bcs)
    held = F.duplicate()
    held.set(0.0)
    index = model.V.dofmap.index_map
    local_to_global = index.local_to_global(np.arange(index.size_local + index.num_ghosts, dtype=np.int32))
    held.setValues((3 * local_to_global[nodes] + axis).astype(np.int32), wall - contact.X[node, axis])
    held.assemblyBegin(), held.assemblyEnd()
    K0 = K.copy()
    K.zeroRowsColumnsLocal((3 * nodes + axis).astype(np.int32), 1.0, held, F)
    ksp = PETSc.KSP().create(COMM)
    ksp.setOperators(K)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    u = F.duplicate()
    ksp.solve(F, u)
    reaction = K0.createVecLeft()
    K0.mult(u, reaction)
    model.load_into(0.0, F)
    set_bc(F, model.bcs)
    reaction.axpy(-1.0, F)
    owned = index.size_local
    mine = nodes < owned
    inward = np.where(wall == np.asarray(lo)[axis], 1.0, -1.0)
    assert np.all(inward[mine] * reaction.array_r.reshape(-1, 3)[nodes[mine], axis[mine]] > 0.0)  # walls push in
    surface = contact.nodes < owned
    y = contact.X[surface] + u.array_r.reshape(-1, 3)[contact.nodes[surface]]
    assert np.all(y >= np.asarray(lo) - 1e-12) and np.all(y <= np.asarray(hi) + 1e-12)  # nothing outside
    return u.array_r.copy()


def test_a_cantilever_settles_on_a_floor_at_tight_tolerances(shared_tmp):
    """Its weight bends the cantilever's free end onto a floor 2 mm below. At tolerance 1e-8 m
    it stopped with exit 3 (Newton failed with the load cut to 1/1024: the whole step put
    the falling end millimetres past the floor, and each halving only halved the distance
    left), though the equilibrium exists. Now it settles at 3e-7, 1e-7 and 1e-8 m, within
    each tolerance of the floor, and at 1e-8 within 2e-8 m everywhere of the solve that
    holds the pressed nodes on the floor (the contact solution, solved with no contact code)."""
    floor = _box_surface((-0.05, -0.05, -0.002), (0.2, 0.06, 0.05), shared_tmp / "cantilever_floor.stl")
    tips = {}
    for tolerance in (3e-7, 1e-7, 1e-8):
        sim = _cantilever(floor, tolerance)
        report = sim.contact.report(sim.state.u)
        assert report["max_penetration_m"] <= tolerance and report["pressed_nodes"] > 0
        tips[tolerance] = sim.probe_values()[0, 2]
        assert tips[tolerance] == pytest.approx(-0.002, abs=tolerance)
    assert tips[1e-8] == pytest.approx(tips[3e-7], abs=3e-7 + 1e-8)
    free = sim.model.V.dofmap.index_map.size_local * 3
    ref = _held_on_walls(sim, (-0.05, -0.05, -0.002), (0.2, 0.06, 0.05))
    np.testing.assert_allclose(sim.state.u.x.array[:free], ref, rtol=0, atol=2e-8)


def test_a_step_without_descent_goes_as_far_as_the_first_contact(shared_tmp):
    """What Newton's watched step may take (contact.step_limit): the whole body moved 8 mm
    down reaches the floor 2 mm below it (the kink, at rest without multipliers) at a quarter
    of the way; tilted down towards the free end, where the end does; moved up or sideways,
    the whole step; with multipliers of 1 mm times the penalty, 1 mm above the floor (the
    STL's single precision: 1e-7)."""
    floor = _box_surface((-0.05, -0.05, -0.002), (0.2, 0.06, 0.05), shared_tmp / "cantilever_floor.stl")
    sim = _cantilever(floor, 1e-8, solve=False)
    x = sim.model.V.tabulate_dof_coordinates()
    du = fem.Function(sim.model.V)
    for values, expected in (([0.0, 0.0, -0.008], 0.25), ([0.0, 0.0, 0.008], 1.0), ([0.003, 0.0, 0.0], 1.0)):
        du.x.array.reshape(-1, 3)[:] = values
        assert sim.contact.step_limit(sim.state.u, du) == pytest.approx(expected, rel=1e-7)
    du.x.array.reshape(-1, 3)[:] = 0.0
    du.x.array.reshape(-1, 3)[:, 2] = -0.01 * x[:, 0] / 0.1  # 10 mm down at the free end
    assert sim.contact.step_limit(sim.state.u, du) == pytest.approx(0.2, rel=1e-7)
    sim.contact.multipliers[:] = [0.0, 0.0, 0.001 * sim.contact.penalty]  # pushing up: the kink 1 mm off the floor
    assert sim.contact.step_limit(sim.state.u, du) == pytest.approx(0.1, rel=1e-7)


def test_a_settled_state_not_found_in_contact_says_what_the_skull_had_to_do_with_it(floor, monkeypatch):
    """Newton forced to fail on the block on the floor: the one-line message names the
    tolerance and how deep the deepest node was where the last try stopped (not only a missing
    support or a lost stability)."""
    from fenics_brainshift.errors import SolverError
    from fenics_brainshift.stepping.newton import NewtonStatic

    newton = NewtonStatic._newton
    monkeypatch.setattr(NewtonStatic, "_newton", lambda self, t, factor: newton(self, t, factor) and False)
    sim = Simulation(scene_from_dict(_block([], {"file": floor, "tolerance": 1e-6})), COMM)
    # (Newton converged each time and was told it had not: the deepest node is within the
    # tolerance, the advice says so and only supposes the skull's shape)
    with pytest.raises(
        SolverError,
        match=r"with skull contact: the deepest node \d\.\d+e-0\d m past the skull where "
        r"Newton stopped, \[skull\] tolerance = 1e-06 m \(the deepest node is "
        r"within it, a looser one will not help; the skull's shape where the body "
        r"presses it may be the cause, docs/limits.md\)$",
    ) as failure:
        sim.solve_to_settled(0.0)
    assert "\n" not in str(failure.value)


@pytest.mark.parametrize(
    "deepest, words",
    [
        (3e-4, r"the deepest node 0.0003 m past .* \(if the body is held, a looser tolerance may settle\)$"),
        (5e-7, r"the deepest node 5e-07 m past .* \(the deepest node is within it, a looser one will not help"),
        (None, r"\[skull\] tolerance = 1e-06 m \(if the body is held, a looser tolerance may settle\)$"),
    ],
)
def test_the_skull_advice_follows_how_deep_the_deepest_node_was(deepest, words):
    """A node deeper past the skull than the tolerance where Newton stopped: a looser one may
    settle; within it, the tolerance is not what stopped Newton; not known (a state not
    finite): the general advice."""
    from types import SimpleNamespace

    from fenics_brainshift.stepping.contact_verdict import contact_note

    assert re.search(words, contact_note(SimpleNamespace(tolerance=1e-6), deepest))
