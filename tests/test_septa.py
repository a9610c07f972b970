"""The dural septa ([[septum]]: physics/septa.py, physics/constraints.py) against exact answers.

- A plane septum along an axis is the sliding support of that plane: the same displacement to
  round-off (linear and neo-Hookean, settled states and time steps, follower CSF load).
- A tilted block confined between two tilted septa and swelling uniformly, held in its
  mid-planes by two more: the exact answer is homogeneous (P1 holds it exactly): no motion
  along the confined axis, a free expansion across it (linear: e = (g - 1)(1 + nu);
  neo-Hookean: the stretch s that makes sigma_yy = 0, found by a root finder from the
  hand-derived Cauchy stress), turned with the block. The septa's nodal forces are the
  consistent forces of the uniform traction on the end faces: p A / 3 per triangle at each of
  its corners (a hand-worked distribution, not only the total), and sum to p A along the
  septum's normal.
- A block resting on a floor septum in a draining CSF: the floor carries the weight less the
  buoyancy of the submerged volume (Archimedes), the side septa nothing.
- A septum that holds no node is refused, as a support that holds nothing is; bad keys are one
  line; --set septum.NAME.enabled=false leaves it out.
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from dolfinx import fem, io
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import assemble_vector
from mpi4py import MPI
from scipy.optimize import brentq

from fenics_brainshift.errors import InputError
from fenics_brainshift.physics.material import lame_parameters
from fenics_brainshift.physics.surface import surface_facets
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.scene import load_scene, scene_from_dict

from conftest import COMM

pytestmark = pytest.mark.mpi
E_MOD, NU, RHO = 3000.0, 0.3, 1000.0
MU, LMBDA = lame_parameters(E_MOD, NU)
SIZE = np.array([0.03, 0.02, 0.01])  # m
PLANES = [("x", [1.0, 0.0, 0.0]), ("y", [0.0, 1.0, 0.0]), ("z", [0.0, 0.0, 1.0])]


def _box_scene(septa: bool, model: str, mode: str):
    data = {
        "name": "septa",
        "mesh": {"shape": "box", "size": [0.05, 0.04, 0.03], "cells": [5, 4, 3]},
        "material": {"E": E_MOD, "nu": 0.45, "model": model},
        "gravity": {"vector": [0.0, 0.0, -9.81]},
        "fluid": {"level": [[0.0, 0.04], [1.0, 0.01]], "follower": True},
        "time": {"mode": mode, "end": 1.0, "dt": 0.1},
        "solver": {"kind": "cholesky"},
    }
    if septa:
        data["septum"] = [{"name": f"wall_{a}", "point": [0, 0, 0], "normal": n} for a, n in PLANES]
    else:
        data["fixed"] = [{"where": f"{a} < 1e-9", "axes": a} for a, _ in PLANES]
    return scene_from_dict(data)


@pytest.mark.parametrize(
    "model, mode",
    [("linear", "quasi-static"), ("linear", "dynamic"), ("neo-hookean", "quasi-static"), ("neo-hookean", "dynamic")],
)
def test_an_axis_septum_is_the_sliding_support_of_its_plane(model, mode):
    sliding, septum = (run(_box_scene(s, model, mode), raise_on_stop=True) for s in (False, True))
    a, b = _by_position(sliding.displacement), _by_position(septum.displacement)
    assert np.abs(a).max() > 5e-4  # it moves: a millimetre
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


def _by_position(u) -> np.ndarray:
    """The owned nodes' values of u on every rank, ordered by position (two runs on two ranks
    may partition the mesh differently)."""
    V = u.function_space
    owned = V.dofmap.index_map.size_local
    X = np.concatenate(COMM.allgather(V.tabulate_dof_coordinates()[:owned]))
    values = np.concatenate(COMM.allgather(u.x.array.reshape(-1, 3)[:owned]))
    return values[np.lexsort(np.round(X, 12).T)]


def _rotation() -> np.ndarray:
    """A turn about a skew axis: no septum normal is along an axis."""
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    angle = 0.7
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _tilted_block(folder, cells=(3, 2, 2)) -> str:
    """The block [0, SIZE] turned by _rotation() about the origin, as an XDMF mesh file."""
    path = str(folder / "tilted.xdmf")
    block = dmesh.create_box(COMM, [np.zeros(3), SIZE], list(cells), dmesh.CellType.tetrahedron)
    block.geometry.x[:] = block.geometry.x @ _rotation().T
    with io.XDMFFile(COMM, path, "w") as f:
        f.write_mesh(block)
    return path


def _confined_scene(path: str, model: str, theta: float):
    R = _rotation()
    ex, ey, ez = R.T  # the block's axes, turned
    half = R @ (SIZE / 2)
    septa = [
        {"name": "low_end", "point": [0.0, 0.0, 0.0], "normal": ex.tolist()},
        {"name": "high_end", "point": (R @ [SIZE[0], 0, 0]).tolist(), "normal": ex.tolist()},
        {"name": "mid_y", "point": half.tolist(), "normal": ey.tolist()},
        {"name": "mid_z", "point": half.tolist(), "normal": ez.tolist()},
    ]
    return scene_from_dict(
        {
            "name": "confined",
            "mesh": {"file": path},
            "material": {"E": E_MOD, "nu": NU, "density": RHO, "model": model},
            "gravity": {"vector": [0.0, 0.0, 0.0]},
            "septum": septa,
            "swelling": [{"where": "x < 1", "volume_change": theta}],
            "time": {"mode": "quasi-static"},
            "solver": {"kind": "cholesky"},
        }
    )


def _stretch_and_end_traction(model: str, theta: float) -> tuple[float, float]:
    """(the stretch s across the confined axis, the septum's traction on an end face per
    reference area, Pa) of the homogeneous state F = diag(1, s, s), by hand."""
    g = (1.0 + theta) ** (1.0 / 3.0)
    if model == "linear":  # eps = diag(0, e, e), eps_g = (g - 1) I, sigma_yy = 0
        eps_g = g - 1.0
        return 1.0 + eps_g * (1.0 + NU), E_MOD * eps_g
    # neo-Hookean of F_e = F / g: sigma = mu / J (B - I) + lmbda ln J / J I (J, B of F_e)

    def sigma(s, i):
        stretch = (1.0 / g, s / g)[i]
        J = s * s / g**3
        return MU / J * (stretch**2 - 1.0) + LMBDA * np.log(J) / J

    s = brentq(lambda s: sigma(s, 1), 0.5, 2.0, xtol=1e-15)
    return s, -sigma(s, 0) * s * s  # the first Piola traction: J sigma_xx / F_xx


@pytest.mark.parametrize("model, theta", [("linear", 0.04), ("neo-hookean", 0.08), ("neo-hookean", -0.06)])
def test_tilted_septa_hold_a_confined_swelling_block_exactly(model, theta, shared_tmp):
    scene = _confined_scene(_tilted_block(shared_tmp), model, theta)
    sim = Simulation(scene, COMM)
    sim.solve_to_settled(0.0)
    R = _rotation()
    s, traction = _stretch_and_end_traction(model, theta)
    X = sim.model.V.tabulate_dof_coordinates() @ R  # the block's own frame (reference)
    expected = np.zeros_like(X)
    expected[:, 1:] = (s - 1.0) * (X[:, 1:] - SIZE[1:] / 2)
    u = sim.u.x.array.reshape(-1, 3) @ R
    assert np.abs(expected).max() > 1e-4
    tol = 1e-10 if model == "linear" else 1e-8
    assert np.abs(u - expected).max() <= tol * np.abs(expected).max()
    # the end septa's nodal forces: traction * (area of the face's triangles at the node) / 3
    report = {r["name"]: r for r in sim.septa_report()}
    area = SIZE[1] * SIZE[2]
    scale = abs(traction) * area  # N
    for name, sign in (("low_end", 1.0), ("high_end", -1.0)):
        total = np.array(report[name]["force_N"]) @ R
        assert np.allclose(total, [sign * traction * area, 0.0, 0.0], rtol=1e-8, atol=1e-10 * scale)
        assert report[name]["largest_motion_across_m"] <= 1e-12
    for name in ("mid_y", "mid_z"):  # symmetry: nothing to carry
        assert np.abs(report[name]["force_N"]).max() <= 1e-8 * scale
    _check_distribution(sim, traction, R)


def _check_distribution(sim, traction: float, R: np.ndarray) -> None:
    """The low end's force at each node against traction * (the area of the end face's
    triangles at it) / 3, whichever way the grid's squares are split. In serial only: on two
    ranks a node on the partition's edge has face triangles on the other rank too (the
    totals above are checked on both)."""
    if COMM.size > 1:
        return
    model = sim.model
    v = ufl.TestFunction(model.V)
    r = assemble_vector(fem.form(model.constitutive.internal_force(sim.u, v)))
    loads = r.duplicate()
    model.load_into(0.0, loads, sim.u)
    r.axpy(-1.0, loads)
    nodes, forces = model.constraints.reactions(r)[0]  # low_end
    facets = surface_facets(model.V)
    on_end = np.all(np.abs(facets.x_vertices @ R[:, 0]) < 1e-12, axis=1)  # X = 0 at all three corners
    corners = facets.x_vertices[on_end]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    share = np.zeros(model.V.dofmap.index_map.size_local)
    np.add.at(share, facets.vertex_dofs[on_end].ravel(), np.repeat(traction * areas / 3.0, 3))
    assert sorted(nodes) == sorted(np.flatnonzero(share))  # the septum's nodes are the end face's
    along = forces @ R  # in the block's frame
    assert np.allclose(along[:, 0], share[nodes], rtol=1e-8, atol=0.0)
    assert np.abs(along[:, 1:]).max() <= 1e-8 * abs(traction) * SIZE[1] * SIZE[2]


def test_a_floor_septum_carries_the_weight_less_the_buoyancy():
    data = {
        "name": "floor",
        "mesh": {"shape": "box", "size": [0.04, 0.03, 0.02], "cells": [4, 3, 2]},
        "material": {"E": E_MOD, "nu": 0.45, "density": 1040.0},
        "gravity": {"vector": [0.0, 0.0, -9.81]},
        "fluid": {"density": 1000.0, "level": 0.012, "follower": False},
        "septum": [
            {"name": "floor", "point": [0, 0, 0], "normal": [0, 0, 1]},
            {"name": "side_x", "point": [0, 0, 0], "normal": [1, 0, 0]},
            {"name": "side_y", "point": [0, 0, 0], "normal": [0, 1, 0]},
        ],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
    }
    sim = Simulation(scene_from_dict(data), COMM)
    sim.solve_to_settled(0.0)
    report = {r["name"]: r for r in sim.septa_report()}
    volume, submerged = 0.04 * 0.03 * 0.02, 0.04 * 0.03 * 0.012  # the level clips the box exactly
    net = 9.81 * (1040.0 * volume - 1000.0 * submerged)  # weight less Archimedes' buoyancy, N
    assert sim.forces()["submerged_volume_m3"] == pytest.approx(submerged, rel=1e-12)
    assert np.allclose(report["floor"]["force_N"], [0.0, 0.0, net], rtol=1e-9, atol=1e-9 * net)
    for side in ("side_x", "side_y"):  # the fluid presses each side face as hard as its opposite
        assert np.abs(report[side]["force_N"]).max() <= 1e-9 * net


def test_a_septum_that_holds_nothing_is_refused():
    data = {
        "name": "outside",
        "mesh": {"shape": "box", "size": [0.04, 0.03, 0.02], "cells": [2, 2, 2]},
        "material": {"E": E_MOD, "nu": 0.45},
        "fixed": [{"where": "z < 1e-9"}],
        "septum": [{"name": "away", "point": [0.0, 0.0, 0.5], "normal": [0, 0, 1]}],
    }
    with pytest.raises(InputError, match=r"\[\[septum\]\] away holds no node"):
        Simulation(scene_from_dict(data), COMM)
    data["septum"] = [{"name": "cut_off", "point": [0.02, 0, 0], "normal": [1, 0, 0], "where": "z > 1"}]
    with pytest.raises(InputError, match="holds no node"):
        Simulation(scene_from_dict(data), COMM)


@pytest.mark.parametrize(
    "septum, message",
    [
        ({"point": [0, 0, 0]}, "exactly one of normal"),
        ({"normal": [1, 0, 0]}, "needs point"),
        ({"normal": [0, 0, 0], "point": [0, 0, 0]}, "must not be zero"),
        ({"normal": [1, 0, 0], "file": "a.stl", "point": [0, 0, 0]}, "exactly one of"),
        ({"label": 3}, "needs \\[mesh\\] file to be a label volume"),
        ({"file": "no_such.stl"}, "file not found"),
        ({"normal": [1, 0, 0], "point": [0, 0, 0], "reach": -1}, "reach must be > 0"),
        ({"normal": [1, 0, 0], "point": [0, 0, 0], "name": "two words"}, "name must be a word"),
        ({"normal": [1, 0, 0], "point": [0, 0, 0], "where": "import os"}, "where"),
        ({"normal": [1, 0, 0], "point": [0, 0, 0], "colour": "red"}, "unknown key 'colour'"),
    ],
)
def test_bad_septa_are_one_line(septum, message):
    data = {
        "mesh": {"shape": "box", "size": [0.04, 0.03, 0.02], "cells": [2, 2, 2]},
        "material": {"E": E_MOD, "nu": 0.45},
        "fixed": [{"where": "z < 1e-9"}],
        "septum": [septum],
    }
    with pytest.raises(InputError, match=message):
        scene_from_dict(data)


def test_set_turns_a_named_septum_off(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(
        '[mesh]\nshape = "box"\nsize = [0.04, 0.03, 0.02]\ncells = [2, 2, 2]\n'
        '[material]\nE = 3000.0\n[[fixed]]\nwhere = "z < 1e-9"\n'
        '[[septum]]\nname = "falx"\npoint = [0.02, 0, 0]\nnormal = [1, 0, 0]\n'
        '[[septum]]\nname = "tent"\npoint = [0, 0, 0.01]\nnormal = [0, 0, 1]\n'
    )
    assert [s.name for s in load_scene(path).septa] == ["falx", "tent"]
    assert [s.name for s in load_scene(path, ["septum.falx.enabled=false"]).septa] == ["tent"]
    assert load_scene(path, ["septum.tent.normal=[0, 1, 0]"]).septa[1].normal == (0.0, 1.0, 0.0)
    with pytest.raises(InputError, match=r"or a name \(falx, tent\)"):
        load_scene(path, ["septum.falks.enabled=false"])


def _block(**sections) -> dict:
    data = {
        "name": "block",
        "mesh": {"shape": "box", "size": [0.04, 0.03, 0.02], "cells": [4, 3, 2]},
        "material": {"E": E_MOD, "nu": 0.45, "density": RHO},
        "gravity": {"vector": [0.0, 0.0, -9.81]},
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
    }
    data.update(sections)
    return data


@pytest.mark.parametrize("mode", ["quasi-static", "dynamic"])
def test_a_septum_and_the_skull_share_the_load(mode):
    """A block in a corner of three septa swells by 5 % against the skull (its own surface
    dilated by 0.1 mm) under a slanting gravity: skull and septa together balance the weight
    (the swelling is internal), the skull carries the confinement (what the septa push
    across, it pushes back), and neither is passed. Time-stepped (the contact's lagged fixed
    point solves with a factor of K and the pressed nodes' blocks: they must be projected
    too), the septa hold to round-off as well."""
    g = np.array([-4.0, 0.0, -8.0])
    data = _block(
        gravity={"vector": g.tolist()},
        skull={"gap": 1e-4, "tolerance": 1e-7},
        swelling=[{"where": "x < 1", "volume_change": 0.05}],
        septum=[
            {"name": n, "point": [0, 0, 0], "normal": v}
            for n, v in (("x0", [1, 0, 0]), ("y0", [0, 1, 0]), ("floor", [0, 0, 1]))
        ],
    )
    if mode == "dynamic":
        data["time"] = {"mode": "dynamic", "scheme": "generalized-alpha", "rho_inf": 0.5, "dt": 0.05, "end": 0.3}
        data["damping"] = {"a": 5.0, "b": 0.01}
    summary = run(scene_from_dict(data), raise_on_stop=True).summary
    if mode == "dynamic":  # generalized-alpha balances at its intermediate times, not at t_n+1
        assert summary["skull_contact"]["pressed_nodes"] > 0
        assert summary["skull_contact"]["max_penetration_m"] <= 1e-7
        assert max(s["largest_motion_across_m"] for s in summary["septa"]) <= 1e-12
        return
    weight = RHO * 0.04 * 0.03 * 0.02 * g  # N, the body's weight
    septa = {s["name"]: np.array(s["force_N"]) for s in summary["septa"]}
    skull = np.array(summary["skull_contact"]["force_N"])
    assert summary["skull_contact"]["pressed_nodes"] > 0
    assert np.allclose(skull + sum(septa.values()), -weight, rtol=1e-6, atol=1e-6 * np.linalg.norm(weight))
    assert np.linalg.norm(skull) > 2 * np.linalg.norm(weight)  # the confinement, not only the weight
    assert summary["skull_contact"]["max_penetration_m"] <= 1e-7
    for s in summary["septa"]:
        assert s["largest_motion_across_m"] <= 1e-12


def test_a_septum_within_reach_of_a_face_holds_it(shared_tmp):
    """A septum 0.5 mm outside a face with reach = 1 mm holds that face's nodes (a fissure's
    tissue touching it), as the septum in the face's plane does; a surface file of the plane
    holds the same nodes the plane does."""
    rollers = [{"name": n, "point": [0, 0, 0], "normal": v} for n, v in (("x0", [1, 0, 0]), ("y0", [0, 1, 0]))]
    floor = {"name": "floor", "point": [0, 0, 0], "normal": [0, 0, 1]}
    plane = run(scene_from_dict(_block(septum=rollers + [floor])), raise_on_stop=True)
    reach = dict(floor, point=[0, 0, -0.0005], reach=0.001)
    reached = run(scene_from_dict(_block(septum=rollers + [reach])), raise_on_stop=True)
    stl = shared_tmp / "floor.stl"
    if COMM.rank == 0:
        stl.write_text(
            "solid floor\n"
            + "".join(
                "facet normal 0 0 1\nouter loop\n"
                + "".join(f"vertex {x} {y} 0\n" for x, y in tri)
                + "endloop\nendfacet\n"
                for tri in (((-1, -1), (1, -1), (1, 1)), ((-1, -1), (1, 1), (-1, 1)))
            )
            + "endsolid floor\n"
        )
    COMM.barrier()
    surface = run(scene_from_dict(_block(septum=rollers + [{"name": "floor", "file": str(stl)}])), raise_on_stop=True)
    a = _by_position(plane.displacement)
    assert np.abs(a).max() > 1e-4
    for other in (reached, surface):
        assert np.abs(_by_position(other.displacement) - a).max() <= 1e-10 * np.abs(a).max()


def test_the_boundary_of_a_label_is_a_septum(shared_tmp):
    """[[septum]] label: a block of two labels (1, and 3 from x = 23 mm: image voxel i spans
    2i -/+ 1 mm) hangs from its top face and is pulled sideways, along x and y; the septum on
    label 3's boundary, limited to the face between the labels, holds that face's nodes in x
    while they slide in y with the rest of the block."""
    import nibabel as nib

    if COMM.rank == 0:
        labels = np.zeros((20, 20, 20), dtype=np.uint8)
        labels[6:14, 6:14, 6:14] = 1  # the block: 11 .. 27 mm
        labels[12:14, 6:14, 6:14] = 3  # its right end, from x = 23 mm
        nib.save(nib.Nifti1Image(labels, np.diag([2.0, 2.0, 2.0, 1.0])), str(shared_tmp / "halves.nii.gz"))
    COMM.barrier()
    inner = "abs(x - 0.023) < 0.0005 and y > 0.0125 and y < 0.0255 and z > 0.0125 and z < 0.0255"
    data = {
        "mesh": {"file": str(shared_tmp / "halves.nii.gz"), "labels": [1, 3], "voxel": 0.002, "unit": "mm"},
        "material": {"E": E_MOD, "nu": 0.45, "density": RHO},
        "gravity": {"vector": [9.81, 9.81, 0.0]},
        "fixed": [{"where": "z > 0.0269"}],
        "time": {"mode": "quasi-static"},
        "solver": {"kind": "cholesky"},
        "septum": [{"name": "between", "label": 3, "where": inner}],
    }
    held = run(scene_from_dict(data), comm=COMM, raise_on_stop=True)
    septum = held.summary["septa"][0]
    assert septum["nodes"] == 7 * 7  # the face's interior nodes, 13 .. 25 mm in y and z
    assert septum["largest_motion_across_m"] <= 1e-12
    assert septum["largest_slide_m"] > 1e-4  # they swing along y with the block
    del data["septum"]
    free = run(scene_from_dict(data), comm=COMM, raise_on_stop=True)
    X = free.displacement.function_space.tabulate_dof_coordinates()
    face = (np.abs(X[:, 0] - 0.023) < 5e-4) & (np.abs(X[:, 1] - 0.019) < 6.5e-3) & (np.abs(X[:, 2] - 0.019) < 6.5e-3)
    swing = COMM.allreduce(
        float(np.abs(free.displacement.x.array.reshape(-1, 3)[face, 0]).max(initial=0.0)), op=MPI.MAX
    )
    assert swing > 1e-4  # without it the face moves across by a tenth of a millimetre or more


def test_a_resection_beside_a_septum_keeps_it_held():
    """Cells removed at a septum leave nodes with no tissue (their rows get a unit diagonal,
    then the projection): the run goes on, the septum still holds, and the removed piece's
    weight is gone from what the floor carries."""
    data = _block(
        septum=[
            {"name": n, "point": [0, 0, 0], "normal": v}
            for n, v in (("x0", [1, 0, 0]), ("y0", [0, 1, 0]), ("floor", [0, 0, 1]))
        ],
        remove=[{"at": 0.1, "where": "x < 0.0101 and y < 0.0101"}],
        time={"mode": "dynamic", "dt": 0.05, "end": 1.5},
        damping={"a": 20.0, "b": 0.005},
    )
    summary = run(scene_from_dict(data), raise_on_stop=True).summary
    septa = {s["name"]: s for s in summary["septa"]}
    assert all(s["largest_motion_across_m"] <= 1e-12 for s in septa.values())
    left = 1.0 - summary["removed_fraction"]
    assert 0.85 < left < 0.95
    weight = RHO * 0.04 * 0.03 * 0.02 * 9.81 * left
    assert septa["floor"]["force_N"][2] == pytest.approx(weight, rel=1e-3)  # settled by the end


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_tilted_septa_hold_with_an_iterative_solver(model, shared_tmp):
    """AMG-preconditioned solves (and Newton's inexact ones, its forcing up to 1e-2) do not keep
    range(P) by themselves: every answer is projected, so the septa hold to round-off and the
    confined block is exact to the solver's tolerance (an unprojected Newton let 10 % of |u|
    cross)."""
    data = _confined_scene(_tilted_block(shared_tmp), model, 0.05)
    data.solver.kind, data.solver.rtol = "cg-gamg", 1e-12
    sim = Simulation(data, COMM)
    sim.solve_to_settled(0.0)
    R = _rotation()
    s, _ = _stretch_and_end_traction(model, 0.05)
    X = sim.model.V.tabulate_dof_coordinates() @ R
    expected = np.zeros_like(X)
    expected[:, 1:] = (s - 1.0) * (X[:, 1:] - SIZE[1:] / 2)
    u = sim.u.x.array.reshape(-1, 3) @ R
    assert np.abs(u - expected).max() <= 1e-6 * np.abs(expected).max()
    assert max(r["largest_motion_across_m"] for r in sim.septa_report()) <= 1e-14


def test_septa_that_leave_a_rigid_motion_free_are_refused():
    """A floor septum alone lets the block slide: a settled state has no unique answer (it came
    out as a slide of 1e11 m, "ok"); the free motion is named. With the side septa too, it runs."""
    floor = {"name": "floor", "point": [0, 0, 0], "normal": [0, 0, 1]}
    with pytest.raises(InputError, match=r"free to move along"):
        Simulation(scene_from_dict(_block(septum=[floor], gravity={"vector": [1.0, 0.0, -9.81]})), COMM)
    sides = [
        {"name": "x0", "point": [0, 0, 0], "normal": [1, 0, 0]},
        {"name": "y0", "point": [0, 0, 0], "normal": [0, 1, 0]},
    ]
    with pytest.raises(InputError, match=r"free to move along \(0, 1, 0\)"):  # nothing holds y
        Simulation(
            scene_from_dict(_block(septum=[floor, sides[0], dict(sides[0], name="x1", point=[0.04, 0, 0])])), COMM
        )
    held = [{"where": "x < 1e-9 and y < 1e-9 and z < 1e-9"}]  # one corner pinned: the block turns about it
    with pytest.raises(InputError, match=r"free to turn about an axis along"):
        Simulation(scene_from_dict(_block(fixed=held)), COMM)
    Simulation(scene_from_dict(_block(septum=[floor] + sides)), COMM)
    clamp_free = _block(fixed=[{"where": "z < 1e-9", "axes": "z"}])  # rollers only: it slides and turns
    with pytest.raises(InputError, match="free to"):
        Simulation(scene_from_dict(clamp_free), COMM)


def test_an_open_patch_holds_only_the_tissue_under_it(shared_tmp):
    """A surface file that is an open sheet (a falx segmented as a patch): past its free edge its
    extended plane is no septum (the sign of the distance flips there too, and the nodes past
    the edge were held, along the way to the edge). The patch x = 10.5 mm over y <= 7.5 mm holds
    what the plane with where = "y < 0.0075" holds."""
    rollers = [{"name": n, "point": [0, 0, 0], "normal": v} for n, v in (("y0", [0, 1, 0]), ("floor", [0, 0, 1]))]
    stl = shared_tmp / "patch.stl"
    if COMM.rank == 0:
        corners = ((0.0105, -0.01, -0.01), (0.0105, 0.0075, -0.01), (0.0105, 0.0075, 0.04), (0.0105, -0.01, 0.04))
        stl.write_text(
            "solid patch\n"
            + "".join(
                "facet normal 1 0 0\nouter loop\n"
                + "".join(f"vertex {x} {y} {z}\n" for x, y, z in (corners[a], corners[b], corners[c]))
                + "endloop\nendfacet\n"
                for a, b, c in ((0, 1, 2), (0, 2, 3))
            )
            + "endsolid patch\n"
        )
    COMM.barrier()
    cube = {
        "mesh": {"shape": "box", "size": [0.02, 0.02, 0.02], "cells": [4, 4, 4]},
        "gravity": {"vector": [-9.81, 0, 0]},
    }
    patch = run(
        scene_from_dict(_block(septum=rollers + [{"name": "patch", "file": str(stl)}], **cube)), raise_on_stop=True
    )
    plane = run(
        scene_from_dict(
            _block(
                septum=rollers
                + [{"name": "patch", "point": [0.0105, 0, 0], "normal": [1, 0, 0], "where": "y < 0.0075"}],
                **cube,
            )
        ),
        raise_on_stop=True,
    )
    assert patch.summary["septa"][2]["nodes"] == plane.summary["septa"][2]["nodes"] == 2 * 5
    a, b = _by_position(plane.displacement), _by_position(patch.displacement)
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


def test_a_support_carries_what_it_holds_before_a_septum_does():
    """A floor septum on the clamped bottom face: the clamp carries the weight (least squares
    over both had given the septum half)."""
    data = _block(septum=[{"name": "floor", "point": [0, 0, 0], "normal": [0, 0, 1]}], fixed=[{"where": "z < 1e-9"}])
    sim = Simulation(scene_from_dict(data), COMM)
    sim.solve_to_settled(0.0)
    assert np.abs(sim.septa_report()[0]["force_N"]).max() <= 1e-12


@pytest.mark.parametrize("normal", [[1e200, 0.0, 0.0], [1e-170, 0.0, 0.0], [1e308, 1e308, 0.0]])
def test_a_normal_of_any_size_is_its_direction(normal):
    """[1e200, 0, 0] overflowed to a zero normal, so its nodes were held along nothing."""
    sim = Simulation(
        scene_from_dict(
            _block(septum=[{"name": "s", "point": [0.02, 0, 0], "normal": normal}], fixed=[{"where": "z < 1e-9"}])
        ),
        COMM,
    )
    direction = (
        np.array(normal) / np.linalg.norm(np.array(normal) / 1e200) / 1e200 if normal[0] > 1 else np.array([1.0, 0, 0])
    )
    c = sim.model.constraints
    assert len(c.nodes) > 0
    for dirs in c.directions:
        assert np.allclose(np.abs(dirs[0][1]), np.abs(direction / np.linalg.norm(direction)))


def test_an_empty_septum_file_is_one_line(shared_tmp):
    stl = shared_tmp / "empty.stl"
    if COMM.rank == 0:
        stl.write_text("solid x\nendsolid x\n")
    COMM.barrier()
    with pytest.raises(InputError, match=r"\[\[septum\]\] s file: .*(holds no triangles|could not be read)"):
        Simulation(
            scene_from_dict(_block(septum=[{"name": "s", "file": str(stl)}], fixed=[{"where": "z < 1e-9"}])), COMM
        )
