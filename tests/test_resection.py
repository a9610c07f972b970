"""Resection: cells removed during a dynamic run, pieces cut free, and what must stay exact.

A block 20 x 20 x 60 mm on a clamped floor loses the layer 20 mm < z < 30 mm at t = 0. The
piece above is then free: its mass-weighted mean acceleration must be g dry and
(1 - rho_f / rho_s) g submerged (Archimedes on its new closed surface, the cut face included),
exactly in Newmark's arithmetic. The piece below must move as a 20 mm block that never had
anything above it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from mpi4py import MPI

from fenics_brainshift.errors import InputError
from fenics_brainshift.runner import Simulation, build_model, run
from fenics_brainshift.scene import scene_from_dict

from conftest import COMM

pytestmark = pytest.mark.mpi
W, RHO_S, G = 0.02, 1000.0, 9.81
DT, STEPS = 0.01, 12


def block(height: float, layers: int, fluid=None, remove=(), **sections) -> dict:
    data = {
        "name": "block",
        "mesh": {"shape": "box", "size": [W, W, height], "cells": [2, 2, layers]},
        "material": {"E": 3000.0, "nu": 0.45, "density": RHO_S},
        "gravity": {"vector": [0.0, 0.0, -G]},
        "fixed": [{"where": "z < 1e-9"}],
        "time": {"mode": "dynamic", "dt": DT, "end": DT * STEPS},
        "solver": {"kind": "cholesky"},
        "remove": list(remove),
    }
    if fluid is not None:
        data["fluid"] = fluid
    data.update(sections)
    return data


CUT = {"at": 0.0, "where": "0.02 < z < 0.03"}


def _upper_mean(sim, z_min: float, values=None) -> np.ndarray:
    """Mass-weighted mean displacement (or of ``values``, an array like u's) of the nodes
    above z_min (global), with the masses of the body as it is now."""
    n_blocks = sim.state.n_owned // 3
    z = sim.model.V.tabulate_dof_coordinates()[:n_blocks, 2]
    mass = sim.dynamic.M.getDiagonal().array_r.reshape(-1, 3)[:, 0]
    sel = z > z_min
    u = (sim.u.x.array if values is None else values)[: sim.state.n_owned].reshape(-1, 3)
    local = np.concatenate([(mass[sel, None] * u[sel]).sum(axis=0), [mass[sel].sum()]])
    total = COMM.allreduce(local, op=MPI.SUM)
    return total[:3] / total[3]


def _run(data: dict):
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    history = []
    for _ in range(STEPS):
        sim.step()
        history.append(sim.t)
    return sim


def test_free_piece_falls_with_g_when_dry_and_stays_unstrained():
    corners = {
        f"p{i}": [x, y, z]
        for i, (x, y, z) in enumerate(
            [(0, 0, 0.03), (W, 0, 0.03), (0, W, 0.06), (W, W, 0.06), (W / 2, W / 2, 0.045), (0, W / 2, 0.05)]
        )
    }
    sim = _run(block(0.06, 6, remove=[CUT], probes=corners))
    t = sim.t
    values = sim.probe_values()
    exact = -0.5 * G * t**2
    # Newmark integrates a constant acceleration exactly; every point moves alike: no strain
    np.testing.assert_allclose(values[:, 2], exact, rtol=1e-10)
    np.testing.assert_allclose(values[:, :2], 0.0, atol=1e-12 * abs(exact))
    np.testing.assert_allclose(_upper_mean(sim, 0.0295)[2], exact, rtol=1e-10)


def test_free_piece_sinks_with_reduced_gravity_under_water():
    rho_f = 400.0
    fluid = {"density": rho_f, "level": 1.0, "follower": False}
    sim = _run(block(0.06, 6, fluid=fluid, remove=[CUT]))
    expected = -0.5 * (1.0 - rho_f / RHO_S) * G * sim.t**2
    np.testing.assert_allclose(_upper_mean(sim, 0.0295)[2], expected, rtol=1e-9)
    assert abs(_upper_mean(sim, 0.0295)[0]) < 1e-9 * abs(expected)


@pytest.mark.parametrize("fluid", [None, {"density": 1030.0, "level": 0.015, "follower": False}])
def test_piece_below_is_the_block_that_never_had_a_top(fluid):
    probes = {"a": [W, W, 0.02], "b": [0.0, W / 2, 0.01], "c": [W / 2, W / 2, 0.02]}
    cut = _run(block(0.06, 6, fluid=fluid, remove=[CUT], probes=probes))
    short = _run(block(0.02, 2, fluid=fluid, probes=probes))
    u_cut, u_short = cut.probes.values(cut.u), short.probes.values(short.u)
    assert np.abs(u_short).max() > 1e-5
    np.testing.assert_allclose(u_cut, u_short, atol=1e-10 * np.abs(u_short).max())


def test_thirty_percent_removed_in_three_cuts_runs_to_the_end(shared_tmp):
    cuts = [
        {"at": 0.03, "where": "(x - 0.01)**2 + (y - 0.01)**2 + (z - 0.06)**2 < 0.008**2"},
        {"at": 0.05, "where": "x > 0.014 and z > 0.03"},
        {"at": 0.08, "where": "y < 0.006 and z < 0.045"},
    ]
    data = block(
        0.06,
        6,
        fluid={"density": 1030.0, "level": [[0.0, 0.07], [0.1, 0.02]]},
        remove=cuts,
        time={"mode": "dynamic", "dt": 0.005, "end": 0.15},
        mesh={"shape": "box", "size": [W, W, 0.06], "cells": [4, 4, 12]},
        damping={"a": 5.0},
        solver={"kind": "cg-gamg", "rtol": 1e-10},
    )
    summary = run(scene_from_dict(data), shared_tmp / "out", COMM).summary
    assert summary["status"] == "ok"
    assert summary["removed_fraction"] >= 0.30
    assert [r["cells"] > 0 for r in summary["removals"]] == [True, True, True]
    assert np.isfinite(summary["max_displacement_m"])
    if COMM.rank == 0:
        text = (shared_tmp / "out" / "displacement.xdmf").read_text()
        assert 'Name="tissue"' in text
        saved = json.loads((shared_tmp / "out" / "summary.json").read_text())
        assert saved["removed_fraction"] == summary["removed_fraction"]


def test_removal_by_label_of_the_label_volume(shared_tmp):
    import nibabel as nib

    if COMM.rank == 0:
        labels = np.zeros((12, 12, 12), dtype=np.uint8)
        labels[1:11, 1:11, 1:11] = 1
        # a "lesion" at the top: image voxel i spans (2i - 1, 2i + 1) mm, the 4 mm voxels of the mesh
        # start at 1 mm, so this is exactly 2 x 2 x 1 of them
        labels[5:9, 5:9, 9:11] = 2
        nib.save(nib.Nifti1Image(labels, np.diag([2.0, 2.0, 2.0, 1.0])), str(shared_tmp / "seg.nii.gz"))
    COMM.barrier()
    data = block(
        0.02,
        2,
        remove=[{"at": 0.0, "label": 2}],
        mesh={"file": str(shared_tmp / "seg.nii.gz"), "voxel": 0.004, "unit": "mm"},
    )
    data["fixed"] = [{"where": "z < 0.0041"}]
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    removed = sim.dynamic.removals[0]["cells"]
    assert removed == 5 * 4  # 4 voxels of 5 tetrahedra
    sim.step()


@pytest.mark.parametrize(
    "region, message",
    [
        ("z > 1.0", "selects no cell"),
        ("z > -1.0", "would remove every remaining cell"),
    ],
)
def test_removal_that_selects_nothing_or_everything_is_refused(region, message):
    with pytest.raises(InputError, match=message):
        build_model(scene_from_dict(block(0.02, 2, remove=[{"at": 0.0, "where": region}])), COMM)


def test_cells_left_hanging_by_an_edge_go_with_the_cut():
    """Removing the central tetrahedron of the top voxel of a two-voxel column leaves its two
    upper corner tetrahedra touching the rest by edges only: they are removed with it; the
    lower two keep a face on the voxel below and stay."""
    h = 0.01
    data = block(
        2 * h,
        2,
        remove=[{"at": 0.0, "where": f"sqrt((x - {h / 2})**2 + (y - {h / 2})**2 + (z - {1.5 * h})**2) < {h / 10}"}],
        mesh={"shape": "box", "size": [h, h, 2 * h], "cells": [1, 1, 2]},
    )
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    assert sim.dynamic.removals[0]["cells"] == 1 and sim.dynamic.removals[0]["isolated_cells"] == 2
    assert sim.model.tissue.removed_fraction == pytest.approx(0.3)
    sim.step()
    assert np.all(np.isfinite(sim.u.x.array))


DAMPED_OR_HYPERELASTIC = [
    pytest.param({"damping": {"a": 0.5, "b": 0.02}}, id="linear-stiffness-damped"),
    pytest.param(
        {
            "material": {"E": 3000.0, "nu": 0.45, "density": RHO_S, "model": "neo-hookean"},
            "damping": {"a": 0.5, "b": 0.02},
        },
        id="neo-hookean",
    ),
]


@pytest.mark.parametrize("sections", DAMPED_OR_HYPERELASTIC)
def test_a_resection_that_removes_nothing_leaves_the_trajectory_unchanged(sections):
    """The operators rebuilt mid-run as a resection rebuilds them, with nothing removed: the
    state must carry over, so the run is the run without it, to round-off. (The acceleration
    was recomputed from the start's formula: K0 u in place of the neo-Hookean internal force,
    the b K averaging of a damped body, which moved it by 8-33 % everywhere.)"""
    probes = {"top": [W, W, 0.04], "mid": [W / 2, 0.0, 0.02]}
    later = [{"at": 0.115, "where": "z > 0.035"}]  # never due: the body can be resected

    def trajectory(rebuild_at: int | None):
        sim = Simulation(scene_from_dict(block(0.04, 4, remove=later, probes=probes, **sections)), COMM)
        sim.setup()
        stepper, tops = sim.dynamic, []
        for n in range(STEPS):
            if n == rebuild_at:  # a removal of nothing is due now
                stepper.model.tissue.due = lambda t, tol: [0]
                stepper._remove_due_cells = lambda: True
            sim.step()
            stepper.model.tissue.due = lambda t, tol: []
            tops.append(sim.probe_values().copy())
        return np.array(tops)

    plain, rebuilt = trajectory(None), trajectory(5)
    assert np.abs(plain).max() > 1e-5
    np.testing.assert_allclose(rebuilt, plain, rtol=0, atol=1e-11 * np.abs(plain).max())


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_a_piece_cut_free_mid_run_falls_with_g(model):
    """Cut at t = 5 dt, while the block sags and swings (stiffness damping on): the piece
    above the cut is free from then on, its mass-weighted mean moves as
    u0 + v0 (t - tc) - g (t - tc)^2 / 2 from its mean state at the cut, exactly in Newmark's
    arithmetic (internal and stiffness-damping forces cancel over a free piece)."""
    tc = 5 * DT
    data = block(
        0.06,
        6,
        remove=[{"at": tc, "where": "0.02 < z < 0.03"}],
        damping={"b": 0.02},
        material={"E": 3000.0, "nu": 0.45, "density": RHO_S, "model": model},
    )
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    for _ in range(5):
        sim.step()
    at_cut = sim.u.x.array.copy(), sim.state.v.x.array.copy()
    for _ in range(STEPS - 5):
        sim.step()
    u0, v0 = (_upper_mean(sim, 0.0295, values)[2] for values in at_cut)  # the piece's masses
    dt = sim.t - tc
    assert sim.dynamic.removals and sim.dynamic.removals[0]["t"] == pytest.approx(tc)
    np.testing.assert_allclose(_upper_mean(sim, 0.0295)[2], u0 + v0 * dt - 0.5 * G * dt**2, rtol=1e-9)


@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
@pytest.mark.parametrize("fluid", [None, {"density": 1000.0, "level": 0.015, "rule": "consistent"}])
@pytest.mark.parametrize("pinned", [False, True])
def test_a_settled_state_after_a_cut_is_the_block_that_never_had_a_top(model, fluid, pinned):
    """Quasi-static: the cut frees the piece above, which nothing holds against every rigid
    motion (K singular on it; pinned: held at one corner node, about which it still turns):
    it is taken out with the cut and said so, and what is left settles as a 20 mm block built
    without it."""
    probes = {f"p{i}": [x, y, z] for i, (x, y, z) in enumerate([(0, 0, 0.02), (W, W, 0.02), (W / 2, 0, 0.01)])}
    quasi = {"mode": "quasi-static", "end": 1.0}
    material = {"E": 3000.0, "nu": 0.45, "density": RHO_S, "model": model}
    fixed = [{"where": "z < 1e-9"}] + ([{"where": "x < 1e-9 and y < 1e-9 and z > 0.06 - 1e-9"}] if pinned else [])
    cut = Simulation(
        scene_from_dict(block(0.06, 6, fluid, remove=[CUT], probes=probes, time=quasi, material=material, fixed=fixed)),
        COMM,
    )
    cut.setup()
    cut.solve_to_settled(1.0)
    (removal,) = cut.removals
    assert removal["cells"] == 2 * 2 * 5 and removal["free_cells"] == 3 * 2 * 2 * 5  # (5 tetrahedra a hexahedron)
    alone = Simulation(scene_from_dict(block(0.02, 2, fluid, probes=probes, time=quasi, material=material)), COMM)
    alone.solve_to_settled(1.0)
    expected = alone.probe_values()
    assert np.abs(expected).max() > 1e-5
    assert np.allclose(cut.probe_values(), expected, rtol=1e-9, atol=1e-12)
    assert cut.model.tissue.removed_fraction == pytest.approx(4 / 6)


def test_a_settled_cut_that_takes_the_supports_is_one_line():
    """The floor's layer cut away: nothing holds what is left, so there is no settled state."""
    data = block(0.06, 6, remove=[{"at": 0.0, "where": "z < 0.01"}], time={"mode": "quasi-static", "end": 1.0})
    sim = Simulation(scene_from_dict(data), COMM)
    sim.setup()
    with pytest.raises(InputError, match=r'\[\[remove\]\] where = "z < 0.01": no piece of what is left is held'):
        sim.solve_to_settled(1.0)
