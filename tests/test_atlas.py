"""The atlas (brainshift atlas) and the update (brainshift update): each mode is the settled state
a separately built scene reaches; an operation inside the atlas's span is recovered from 20
noisy points; the update's run folder is one that warp takes; bad input is one line."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mpi4py import MPI

from fenics_brainshift import load_scene
from fenics_brainshift.atlas import store
from fenics_brainshift.atlas.build import build
from fenics_brainshift.atlas.mode_solves import solve_family_mode, solve_from_prior
from fenics_brainshift.atlas.scenarios import parse_vary
from fenics_brainshift.atlas.update import update
from fenics_brainshift.data import scene_path
from fenics_brainshift.errors import InputError, SolverError
from fenics_brainshift.fit.parameters import rotated_gravity
from fenics_brainshift.images import write_markups
from fenics_brainshift.images.targets import Target
from fenics_brainshift.outputs.vertices import GlobalVertices
from fenics_brainshift.runner import Simulation
from fenics_brainshift.surfaces.triangles import closest_points_on_triangles

from conftest import high_water_mb, mpirun, subprocess_env

COARSE = ["mesh.voxel=0.01", "time.mode=quasi-static"]
VARY = ["fluid.level=0.02,0.03,0.04", "gravity.angle_z=-8,0,8"]
VARY_ARGS = [a for v in VARY for a in ("--vary", v)]
MASK = Path(__file__).parents[1] / "fenics_brainshift" / "data" / "meshes" / "mni152_brain_mask_2mm.nii.gz"


@pytest.fixture(scope="module")
def atlas():
    built, _ = build(load_scene("brain", COARSE), parse_vary(VARY), MPI.COMM_WORLD)
    return built


def _settled(scene) -> tuple[np.ndarray, np.ndarray]:
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    sim.solve_to_settled(scene.time.end)
    vertices = GlobalVertices(sim.model.mesh)
    u = vertices.values(sim.u)
    sim.destroy()
    return vertices.points, u


def test_a_mode_is_the_settled_state_of_a_scene_built_with_its_scenario(atlas):
    """Mode 'level 40 mm, head turned 8 degrees about z' against a scene with that gravity
    vector and level, built and solved on its own."""
    k = next(
        i
        for i, s in enumerate(atlas.scenarios)
        if s["kind"] == "family" and s["values"] == {"gravity.angle_z": 8.0, "fluid.level": 0.04}
    )
    g = rotated_gravity([0.0, -9.81, 0.0], {"gravity.angle_z": 8.0})
    points, u = _settled(load_scene("brain", COARSE + [f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]", "fluid.level=0.04"]))
    assert np.array_equal(points, atlas.points)
    scale = np.abs(u).max()
    assert scale > 3e-3  # a real sag, mm
    assert np.abs(atlas.vertex_modes[k] - u).max() < 1e-5 * scale  # (float32 storage, follower tolerance)
    assert np.abs(atlas.vertex_modes[k - 1] - u).max() > 0.05 * scale  # another mode is another state


def _shrunk_scene(tmp_path, sets):
    """The bundled brain with the whole brain shrunk by 4 % ([[swelling]])."""
    text = scene_path("brain").read_text() + '\n[[swelling]]\nvolume_change = -0.04\nwhere = "x > -1"\n'
    here = scene_path("brain").parent
    text = text.replace('file = "../', f'file = "{here.parent}/').replace(
        'surface = "../', f'surface = "{here.parent}/'
    )
    (tmp_path / "shrunk.toml").write_text(text)
    return load_scene(tmp_path / "shrunk.toml", sets)


def test_the_swelling_mode_is_the_change_a_swollen_scene_makes(atlas, tmp_path):
    """The whole-brain mode (4 % shrinkage at the scene's own level and pose) against the
    difference of two scenes solved on their own, one with a [[swelling]] of the whole brain."""
    _, u_shrunk = _settled(_shrunk_scene(tmp_path, COARSE))
    _, u_prior = _settled(load_scene("brain", COARSE))
    s = atlas.scenarios[-1]
    assert s["kind"] == "swelling" and s["step"] == pytest.approx(-0.04)
    change = u_shrunk - u_prior
    assert np.abs(change).max() > 1e-3
    assert np.abs(atlas.vertex_modes[-1] - change).max() < 1e-4 * np.abs(change).max() + 1e-8
    assert np.abs(atlas.prior_vertex - u_prior).max() < 1e-5 * np.abs(u_prior).max()  # (follower tolerance)


def _top(points: np.ndarray) -> np.ndarray:
    """The exposed cortex, supine (y up): the nodes above the 85th percentile of y. The voxel mesh
    has a whole plane of nodes at that percentile, whose y differ only by rounding, which changes
    with the machine's BLAS kernel. That plane is left out, not split by the rounding."""
    y = points[:, 1]
    return np.flatnonzero(y > np.percentile(y, 85) + 1e-6)  # (1 um: far above rounding, far below a voxel)


def _operation(atlas):
    """A state inside the span: 0.6 x (pose -8, level 30 mm) + 0.4 x (pose 0, level 40 mm),
    the whole brain shrunk by 2 % (the swelling mode's coefficient 0.5)."""
    c = np.zeros(len(atlas.scenarios))
    c[1], c[5], c[-1] = 0.6, 0.4, 0.5
    return c, np.tensordot(c, atlas.vertex_modes.astype(float), axes=1)


def test_an_operation_inside_the_span_is_recovered_to_the_noise_from_20_cortex_points(atlas):
    _, truth = _operation(atlas)
    rng = np.random.default_rng(0)
    points = atlas.points
    top = _top(points)
    picked = rng.choice(top, 20, replace=False)
    noise = 0.5e-3
    measured = points[picked] + truth[picked] + rng.normal(0.0, noise, (20, 3))
    result = update(atlas, Target(measured, points[picked], [f"p{i}" for i in range(20)]), noise)
    error = np.linalg.norm(result.displacement - truth, axis=1)
    prior_error = np.linalg.norm(atlas.prior_vertex - truth, axis=1)
    assert prior_error.mean() > 1e-3  # the scene's own prediction is off by a millimetre
    assert error.mean() < 0.7 * noise and error.max() < 2 * noise  # every node, not only the measured
    assert error.mean() < prior_error.mean() / 3
    # (the whole brain's volume change and G trade off against each other at cortex points: the
    # displacement is recovered, not each cause; test_a_stiffer_brain... checks G alone)
    assert -0.04 <= result.volume_changes(atlas)["brain"] < 0.0
    assert np.sqrt(np.mean(result.leave_one_out**2)) < 3 * noise
    # the spread means what it says: the true error is inside twice the reported spread at nearly
    # every node (this draw: 0.97 posterior, 0.94 bootstrap; over 12 noise draws at least 0.9 in 11
    # and 10 of them), and below the noise of one point
    assert 0 < result.spread.mean() < noise and result.spread_from == "posterior"
    assert np.mean(error < 2 * result.spread) > 0.9
    sampled = update(atlas, Target(measured, points[picked], [f"p{i}" for i in range(20)]), noise, samples=30)
    assert sampled.spread_from.startswith("bootstrap") and np.allclose(sampled.displacement, result.displacement)
    assert 0 < sampled.spread.mean() < noise and np.mean(error < 2 * sampled.spread) > 0.9
    # (the whole update: 44 ms in this order on an idle 2-core machine; the best of three, as a
    # loaded machine's scheduler can stall any one call past the guard)
    target = Target(measured, points[picked], [f"p{i}" for i in range(20)])
    best = min([result.seconds["total_ms"]] + [update(atlas, target, noise).seconds["total_ms"] for _ in range(2)])
    assert best < 100


def _cortex_points_one_slipped(atlas, slipped: int):
    """20 measured cortex points (0.5 mm noise) of the test's operation, one of them 8 mm off."""
    _, truth = _operation(atlas)
    rng = np.random.default_rng(0)
    points = atlas.points
    top = _top(points)
    picked = rng.choice(top, 20, replace=False)
    noise = 0.5e-3
    measured = points[picked] + truth[picked] + rng.normal(0.0, noise, (20, 3))
    measured[slipped] += [0.0, 0.008, 0.0]
    return truth, points, picked, noise, measured


def test_a_point_far_off_is_set_aside_and_the_update_is_made_without_it(atlas):
    """One of 20 cortex points 8 mm off (a pointer slip): it pulled every node's answer and
    passed silently. It is found by its left-out error, set aside, reported, and the update
    is the one made from the other 19 (a fit made by hand without it)."""
    truth, points, picked, noise, measured = _cortex_points_one_slipped(atlas, 7)
    labels = [f"p{i}" for i in range(20)]
    slipped = update(atlas, Target(measured, points[picked], labels), noise)
    assert slipped.outliers == [7] and "p7" in slipped.warning and "set aside" in slipped.warning
    keep = np.flatnonzero(np.arange(20) != 7)
    by_hand = update(
        atlas, Target(measured[keep], points[picked][keep], [labels[i] for i in keep]), noise, set_aside=False
    )
    np.testing.assert_allclose(slipped.displacement, by_hand.displacement, atol=1e-12)
    assert slipped.residual[7] > 0.006  # its error at the update made without it: the 8 mm slip
    kept_in = update(atlas, Target(measured, points[picked], labels), noise, set_aside=False)
    error = lambda r: np.linalg.norm(r.displacement - truth, axis=1).mean()  # noqa: E731
    assert error(slipped) < 0.7 * noise < error(kept_in)  # the slip, kept, pulls the answer off
    honest = update(atlas, Target(np.delete(measured, 7, axis=0), points[picked][keep], labels[:19]), noise)
    assert honest.outliers == []  # noise alone sets nothing aside


def test_a_point_not_among_those_left_out_is_judged_by_its_error_at_the_fit(atlas, monkeypatch):
    """A scan's thousands of points are left out only as a sample: the slip of a point outside
    it (its left-out error NaN) must still be found, by its error at the fit."""
    import fenics_brainshift.atlas.update as module

    _, points, picked, noise, measured = _cortex_points_one_slipped(atlas, 8)
    monkeypatch.setattr(module, "LEAVE_OUT_MAX", 10)
    labels = [f"p{i}" for i in range(20)]
    first = update(atlas, Target(measured, points[picked], labels), noise, set_aside=False)
    assert np.isnan(first.leave_one_out[8])  # not in the sample: the path this test is for
    slipped = update(atlas, Target(measured, points[picked], labels), noise)
    assert slipped.outliers == [8] and "p8" in slipped.warning


def test_a_stiffer_brain_is_the_family_scaled_down(atlas):
    """A linear body 1.25x stiffer sags 0.8x as far: the family's weights sum to G0/G."""
    c = np.zeros(len(atlas.scenarios))
    c[4] = 0.8  # (level 30 mm, no turn: the scene's own) at G = 1.25 G0
    truth = np.tensordot(c, atlas.vertex_modes.astype(float), axes=1)
    picked = _top(atlas.points)[::7][:20]
    pre = atlas.points[picked]
    result = update(atlas, Target(pre + truth[picked], pre, [f"p{i}" for i in range(len(pre))]), 0.1e-3)
    G0 = atlas.info["stiffness"]["G"]
    assert result.stiffness(atlas) == pytest.approx(1.25 * G0, rel=0.02)
    assert np.linalg.norm(result.displacement - truth, axis=1).max() < 0.05e-3


def test_a_stiffer_brain_of_the_full_model_is_found_within_ten_percent(atlas):
    """Truth: the scene at G = 1.25 G0 solved by the full model (follower pressure: not exactly
    0.8x the sag); 20 exact pairs on the cortex."""
    G0 = atlas.info["stiffness"]["G"]
    _, truth = _settled(load_scene("brain", COARSE + [f"material.G={1.25 * G0}"]))
    picked = _top(atlas.points)[::7][:20]
    pre = atlas.points[picked]
    result = update(atlas, Target(pre + truth[picked], pre, [f"p{i}" for i in range(len(pre))]), 0.1e-3, 0)
    assert result.stiffness(atlas) == pytest.approx(1.25 * G0, rel=0.10)
    assert result.stiffness_at_bound(atlas) is None
    error = np.linalg.norm(result.displacement - truth, axis=1)
    assert error.mean() < 0.2 * np.linalg.norm(atlas.prior_vertex - truth, axis=1).mean()


def test_points_on_the_moved_cortex_alone_recover_the_state(atlas):
    """Point to surface: 40 vertices of the moved fine surface, no correspondence given."""
    c, truth = _operation(atlas)
    moved = atlas.surface_points + np.tensordot(c, atlas.surface_modes.astype(float), axes=1)
    rng = np.random.default_rng(1)
    picked = rng.choice(np.flatnonzero(moved[:, 1] > np.percentile(moved[:, 1], 85)), 40, replace=False)
    result = update(atlas, Target(moved[picked], None, [f"s{i}" for i in range(40)]), 0.5e-3)
    assert np.abs(result.residual).max() < 1e-5
    assert result.prior_residual.mean() > 5e-4
    assert np.linalg.norm(result.displacement - truth, axis=1).mean() < 0.1e-3


def test_landmark_pairs_and_cortex_touches_are_fitted_together(atlas):
    """Two pairs and six touches of the moved cortex (too few of either kind alone): each
    point's residual is its own kind's, and together they recover the state."""
    from fenics_brainshift.atlas.locate import MeshLocator

    c, truth = _operation(atlas)
    moved = atlas.surface_points + np.tensordot(c, atlas.surface_modes.astype(float), axes=1)
    rng = np.random.default_rng(3)
    touched = rng.choice(np.flatnonzero(moved[:, 1] > np.percentile(moved[:, 1], 85)), 6, replace=False)
    top = _top(atlas.points)
    paired = rng.choice(top, 2, replace=False)
    pre = np.vstack([atlas.points[paired], np.full((6, 3), np.nan)])
    measured = np.vstack([atlas.points[paired] + truth[paired], moved[touched]])
    target = Target(measured, pre, ["a", "b"] + [f"s{i}" for i in range(6)])
    assert target.kind == "point-to-point and point-to-surface" and list(target.pairs) == [0, 1]
    for alone in (target.subset([0, 1]), dataclasses.replace(target.subset(range(2, 6)), pre=None)):
        with pytest.raises(InputError, match="too few"):
            update(atlas, alone, 0.5e-3)
    result = update(atlas, target, 0.5e-3)
    # independently of the update's rows: the pairs' error where the displacement takes them, the
    # touches' distance to the whole moved fine surface by brute force over its triangles
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(pre[:2])
    at = pre[:2] + np.einsum("nj,njd->nd", weight, result.displacement[index])
    assert np.allclose(result.residual[:2], np.linalg.norm(at - measured[:2], axis=1), atol=1e-9)
    surface = atlas.surface_points + result.surface_displacement
    tri = atlas.surface_triangles
    for k in range(6):
        y = measured[2 + k]
        q = closest_points_on_triangles(np.broadcast_to(y, (len(tri), 3)), *(surface[tri[:, i]] for i in range(3)))
        assert result.residual[2 + k] == pytest.approx(np.linalg.norm(q - y, axis=1).min(), abs=1e-9)
    assert result.prior_residual.max() > 1e-3 and result.residual.max() < 0.1e-3
    assert np.linalg.norm(result.displacement - truth, axis=1).mean() < 0.2e-3


def test_an_atlas_survives_its_files_and_refuses_another_mesh(atlas, tmp_path):
    store.write(tmp_path / "a", atlas)
    again = store.read(tmp_path / "a")
    assert np.array_equal(again.points, atlas.points) and again.scenarios == atlas.scenarios
    assert np.abs(again.vertex_modes - atlas.vertex_modes).max() < 1e-7
    other = dict(json.loads((tmp_path / "a" / "atlas.json").read_text()), mesh_id="0123456789abcdef")
    (tmp_path / "a" / "atlas.json").write_text(json.dumps(other))
    from fenics_brainshift.errors import InputError

    with pytest.raises(InputError, match="different meshes"):
        store.read(tmp_path / "a")
    store.write(tmp_path / "b", atlas)  # the same mesh and modes, another build's index
    (tmp_path / "a" / "atlas.json").write_text((tmp_path / "b" / "atlas.json").read_text())
    with pytest.raises(InputError, match="different builds"):
        store.read(tmp_path / "a")


@pytest.mark.parametrize(
    "damage, words",
    [
        ("a NaN in the regulariser", "the regulariser hold 1 numbers"),
        ("a cross term changed", "regulariser/cross is not what the build wrote"),
        ("an off-diagonal changed", "regulariser/gram is not what the build wrote"),
        ("a prior square changed", "regulariser@prior_square is not what the build wrote"),
        ("a NaN stiffness", "stiffness"),
        ("an infinite prior square", "prior square hold 1 numbers"),
        ("a NaN on the fine surface", "the fine surface hold 1 numbers"),
        ("a surface triangle past the points", "the fine surface's triangles name vertices 0 to 100000000"),
        ("a negative surface triangle", "the fine surface's triangles name vertices -5"),
        ("a boundary mode changed", "boundary/by_node is not what the build wrote"),
        ("a NaN in the boundary's modes", "the boundary's modes hold 1 numbers"),
    ],
)
def test_a_damaged_atlas_is_named_damaged_in_one_line(atlas, tmp_path, capsys, damage, words):
    """Bytes changed in what an update reads whole from atlas.h5, or a number in atlas.json (a
    copy gone wrong): each ended in a traceback or in an update from a wrong atlas; now the
    update refuses the atlas as damaged, naming what."""
    import h5py

    from fenics_brainshift.cli import main

    store.write(tmp_path / "a", atlas)
    with h5py.File(tmp_path / "a" / "atlas.h5", "r+") as f:
        if damage == "a NaN in the regulariser":
            f["regulariser/gram"][1, 2] = np.nan
        elif damage == "a cross term changed":
            f["regulariser/cross"][4] *= 1.01
        elif damage == "an off-diagonal changed":
            gram = f["regulariser/gram"][...]
            gram[1, 3] *= 10.0
            gram[3, 1] = gram[1, 3]  # (symmetric: only its record can tell)
            f["regulariser/gram"][...] = gram
        elif damage == "a prior square changed":
            f["regulariser"].attrs["prior_square"] *= 1 + 1e-12  # (the prior agrees to 1e-6: its record tells)
        elif damage == "an infinite prior square":
            f["regulariser"].attrs["prior_square"] = np.inf
        elif damage == "a NaN on the fine surface":
            f["surface/points"][2, 0] = np.nan
        elif damage == "a surface triangle past the points":
            f["surface/triangles"][3, 1] = 100_000_000
        elif damage == "a negative surface triangle":
            f["surface/triangles"][3, 1] = -5
        elif damage == "a boundary mode changed":
            f["boundary/by_node"][5, 1, 3] *= -1.0
        elif damage == "a NaN in the boundary's modes":
            f["boundary/modes"][3, 5, 1] = np.nan
    if damage == "a NaN stiffness":
        index = json.loads((tmp_path / "a" / "atlas.json").read_text())
        index["stiffness"]["G"] = float("nan")
        (tmp_path / "a" / "atlas.json").write_text(json.dumps(index))
    _markups(tmp_path, atlas, noise=0.3e-3)
    points = ["--target", str(tmp_path / "intra.mrk.json"), "--pre", str(tmp_path / "pre.mrk.json")]
    code = main(["update", str(tmp_path / "a"), *points, "--out", str(tmp_path / "u")])
    err = capsys.readouterr().err
    assert code == 2 and "is damaged" in err and words in err and "Traceback" not in err, err
    assert not (tmp_path / "u").exists()


def test_atlas_h5_metadata_is_checksummed_so_damage_there_is_one_line(atlas, tmp_path):
    """atlas.h5 is written in HDF5's 1.10 format (superblock and object headers checksummed)
    with fixed-length ids: byte flips in the default format's metadata crashed libhdf5 (a
    variable-length id read from the unchecked global heap) or hung it. Flips across the
    metadata now read as before or are refused in one line."""
    import h5py

    store.write(tmp_path / "a", atlas)
    h5 = tmp_path / "a" / "atlas.h5"
    with h5py.File(h5, "r") as f:
        assert f.id.get_create_plist().get_version()[0] >= 2  # (the superblock: 2 and up are checksummed)
        assert all(h5py.check_string_dtype(f.attrs.get_id(k).dtype).length for k in ("mesh_id", "build_id"))
        data = []  # (offset, size) of each dataset's values: the rest of the file is metadata
        f.visititems(
            lambda n, o: data.append((o.id.get_offset(), o.id.get_storage_size())) if hasattr(o, "shape") else None
        )  # noqa: E501
    clean = h5.read_bytes()
    in_data = np.zeros(len(clean), dtype=bool)
    for offset, size in data:
        if offset is not None:
            in_data[offset : offset + size] = True
    metadata = np.flatnonzero(~in_data)
    outcomes = set()
    for offset in metadata[:: max(1, len(metadata) // 40)]:
        damaged = bytearray(clean)
        damaged[offset] ^= 0x5A
        h5.write_bytes(bytes(damaged))
        try:
            read = store.read(tmp_path / "a")
            assert np.array_equal(read.points, atlas.points)
            outcomes.add("read")
        except InputError as exc:
            assert "\n" not in str(exc) and ("cannot be read" in str(exc) or "damaged" in str(exc)), str(exc)
            outcomes.add("refused")
    assert "refused" in outcomes


def test_stored_modes_read_as_numpy_indexes_or_not_at_all(atlas, tmp_path):
    """Every form the update uses reads what numpy's indexing of the modes gives (whole modes:
    an int, a negative int, a slice, a mask, an array; every mode at nodes: a 1-D or 2-D array,
    negative, repeated, with `:` or `...` before them); a form it does not read (numpy's
    `[..., k]` takes the components) is refused, not read another way."""
    store.write(tmp_path / "a", atlas)
    stored, plain = store.read(tmp_path / "a").vertex_modes, np.asarray(atlas.vertex_modes, dtype=np.float32)
    mask = np.zeros(len(plain), dtype=bool)
    mask[[1, 4]] = True
    nodes = np.array([[3, 3, -1], [0, 17, 5]])
    for key in (2, -1, slice(1, 5), mask, np.array([4, 0, 4]), (slice(None), nodes, slice(None)),
                (Ellipsis, nodes, slice(None)), (slice(None), np.array([-2, 9]))):  # fmt: skip
        np.testing.assert_array_equal(stored[key], plain[key])
    for key in ((Ellipsis, np.array([0, 1])), (slice(None), slice(2, 5), slice(None)), (0, 3)):
        with pytest.raises(TypeError):
            stored[key]


def test_a_served_atlas_is_held_against_a_copy_over_it_in_place(atlas, tmp_path):
    """`brainshift serve` holds every mode in memory (StoredModes.hold): another atlas copied
    over atlas.h5 in place (the same inode) changes no mode it serves; a group the checks name
    but the file no longer holds (a skull deleted) is damage."""
    import h5py

    store.write(tmp_path / "a", atlas)
    other = dataclasses.replace(atlas, vertex_modes=2.0 * np.asarray(atlas.vertex_modes), once={})
    store.write(tmp_path / "b", other)
    served = store.read(tmp_path / "a")
    served.vertex_modes.hold()
    with open(tmp_path / "a" / "atlas.h5", "r+b") as f:  # (cp's way: the same file, new bytes)
        f.write((tmp_path / "b" / "atlas.h5").read_bytes())
    np.testing.assert_array_equal(served.vertex_modes[3], np.asarray(atlas.vertex_modes[3], dtype=np.float32))
    store.write(tmp_path / "c", atlas)
    with h5py.File(tmp_path / "c" / "atlas.h5", "r+") as f:
        del f["surface"]
    with pytest.raises(InputError, match="is damaged: surface/.* is missing"):
        store.read(tmp_path / "c")


def _far_from(atlas, pre: np.ndarray, result) -> tuple[int, int]:
    """(a mode the update's weights leave at 0, an interior node in no cell of a point or probe)."""
    from fenics_brainshift.atlas.prepared import locator

    where = np.concatenate([pre, np.array(list(atlas.info["probes"].values()))])
    read = np.unique(locator(atlas).weights(where)[0])
    interior = np.setdiff1d(np.arange(len(atlas.points)), np.concatenate([read, atlas.boundary.vertices]))
    return int(np.flatnonzero(result["weights"] == 0)[0]), int(interior[len(interior) // 2])


@pytest.mark.parametrize("damage", ["a NaN at a point's node", "a sign at a point's node", "a used mode", "unread"])
def test_the_update_reads_and_checks_only_the_modes_it_uses(atlas, tmp_path, capsys, damage):
    """atlas.h5's modes are mapped, not read (mode_file.py): an update reads every mode at the
    nodes of its points' cells and the few modes its weights use, and checks each piece as it
    reads it. Damage there is named in one line; damage nowhere an update reads leaves its
    answer exactly as it was."""
    import mmap

    import h5py

    from fenics_brainshift.atlas.prepared import locator
    from fenics_brainshift.cli import main

    store.write(tmp_path / "a", atlas)
    pre, _ = _markups(tmp_path, atlas, noise=0.3e-3)
    points = ["--target", str(tmp_path / "intra.mrk.json"), "--pre", str(tmp_path / "pre.mrk.json")]
    args = ["update", str(tmp_path / "a"), *points, "--noise", "0.3", "--out"]
    assert main([*args, str(tmp_path / "clean")]) == 0
    clean = json.loads((tmp_path / "clean" / "update.json").read_text())
    weights = np.array(clean["weights"])
    read = store.read(tmp_path / "a")
    assert isinstance(read.vertex_modes._values.base, mmap.mmap)  # (mapped, not read)
    node = int(locator(atlas).weights(pre[:1])[0][0, 0])
    unused, far = _far_from(atlas, pre, {"weights": weights})
    with h5py.File(tmp_path / "a" / "atlas.h5", "r+") as f:
        modes = f["modes/vertex"]
        if damage == "a NaN at a point's node":
            modes[2, node, 1] = np.nan
        elif damage == "a sign at a point's node":
            modes[2, node, 1] = -modes[2, node, 1]
        elif damage == "a used mode":
            modes[int(np.argmax(weights)), far, 0] += 1e-6
        else:
            modes[unused, far, 0] += 1e-3
    code = main([*args, str(tmp_path / "u")])
    err = capsys.readouterr().err
    if damage == "unread":
        assert code == 0, err
        again = json.loads((tmp_path / "u" / "update.json").read_text())
        assert again["weights"] == clean["weights"] and again["residual_rms_mm"] == clean["residual_rms_mm"]
        return
    named = f"the modes at node {node}" if "point" in damage else f"mode {int(np.argmax(weights))} is not"
    assert code == 2 and "is damaged" in err and named in err and "Traceback" not in err, err
    assert not (tmp_path / "u").exists()


def test_an_update_reads_a_few_modes_and_nodes_of_a_mapped_atlas(atlas, atlas_folder, tmp_path):
    """What an update of a read atlas reads whole: the modes its weights use (the answer) and
    its posterior's free ones (the spread); at nodes: its points' cells' and the probes'. The
    rest stays on disk (and unchecked: nothing read, nothing used)."""
    from fenics_brainshift.atlas.update import update as run_update

    read = store.read(atlas_folder)
    pre, intra = _markups(tmp_path, atlas, noise=0.3e-3)
    target = Target(intra, pre, [f"P{i}" for i in range(20)])
    result = run_update(read, target, 0.3e-3)
    modes = read.vertex_modes
    assert 0 < modes._mode_ok.sum() <= np.count_nonzero(result.weights) + len(modes) // 4
    assert 0 < modes._node_ok.sum() <= 4 * len(pre)
    direct = run_update(atlas, target, 0.3e-3)  # (the built atlas in memory: its modes in float64)
    assert np.abs(result.displacement - direct.displacement).max() < 1e-6


@pytest.fixture(scope="module")
def atlas_folder(atlas, tmp_path_factory):
    folder = tmp_path_factory.mktemp("atlas") / "atlas"
    store.write(folder, atlas)
    return folder


def _markups(folder: Path, atlas, count: int = 20, noise: float = 0.0):
    _, truth = _operation(atlas)
    rng = np.random.default_rng(2)
    top = _top(atlas.points)
    picked = rng.choice(top, count, replace=False)
    labels = [f"P{i}" for i in range(count)]
    pre = atlas.points[picked]
    intra = pre + truth[picked] + rng.normal(0.0, noise, (count, 3))
    write_markups(folder / "pre.mrk.json", labels, pre * 1e3)
    write_markups(folder / "intra.mrk.json", labels[::-1], intra[::-1] * 1e3)  # matched by label
    return pre, intra


def test_update_writes_a_run_folder_that_warp_takes(atlas, atlas_folder, tmp_path):
    from fenics_brainshift.cli import main
    from fenics_brainshift.images.volumes import read_volume

    pre, intra = _markups(tmp_path, atlas, noise=0.3e-3)
    out = tmp_path / "upd"
    assert (
        main(
            [
                "update",
                str(atlas_folder),
                "--target",
                str(tmp_path / "intra.mrk.json"),
                "--pre",
                str(tmp_path / "pre.mrk.json"),
                "--noise",
                "0.3",
                "--out",
                str(out),
                "--image",
                str(MASK),
            ]
        )
        == 0
    )
    report = json.loads((out / "update.json").read_text())
    assert report["points"] == 20 and report["kind"] == "point-to-point"
    assert report["residual_rms_mm"] < 0.6 < report["prior_residual_rms_mm"]
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    hint = report["suggestion"]  # (theatre/suggest.py; tests/test_suggest.py checks its numbers)
    assert hint["targets"] == list(atlas.info["probes"]) and hint["expected_spread_mm"] < hint["targets_spread_mm"]
    from fenics_brainshift.images.frames import read_markups

    labels, moved = read_markups(out / "targets_updated.mrk.json")
    order = [int(label[1:]) for label in labels]  # (intra.mrk.json lists them in reverse)
    assert np.linalg.norm(moved * 1e-3 - intra[order], axis=1).max() < 2e-3
    spread = read_volume(out / "uncertainty.nii.gz")
    assert spread.data.max() > 0 and spread.data.shape == read_volume(MASK).data.shape
    assert (out / "update.png").stat().st_size > 20000  # three planes and the residuals
    import nibabel

    assert b"mm" in nibabel.load(out / "uncertainty.nii.gz").header["descrip"].tobytes()  # its unit said
    assert main(["warp", str(out), "--image", str(MASK), "-o", str(tmp_path / "intra.nii.gz")]) == 0
    assert (tmp_path / "intra.nii.gz").is_file()


def test_update_reports_a_slip_set_aside_and_keep_all_fits_it(atlas, atlas_folder, tmp_path):
    """The command line: a pointer slip among 20 markups is named in update.json, the headline
    compares prior and update over the same (kept) points, and --keep-all fits every point."""
    from fenics_brainshift.cli import main

    pre, intra = _markups(tmp_path, atlas, noise=0.3e-3)
    labels = [f"P{i}" for i in range(20)]
    intra[3] += [0.0, 0.008, 0.0]
    write_markups(tmp_path / "intra.mrk.json", labels, intra * 1e3)
    args = [
        "update",
        str(atlas_folder),
        "--target",
        str(tmp_path / "intra.mrk.json"),
        "--pre",
        str(tmp_path / "pre.mrk.json"),
        "--noise",
        "0.3",
        "--bootstrap",
        "0",
    ]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    report = json.loads((tmp_path / "a" / "update.json").read_text())
    assert report["set_aside"] == ["P3"]
    kept = [p for p in report["per_point"] if not p["set_aside"]]
    assert len(kept) == 19
    prior_kept = np.sqrt(np.mean([p["prior_mm"] ** 2 for p in kept]))
    assert report["prior_residual_rms_mm"] == pytest.approx(prior_kept, rel=1e-9)
    assert main(args + ["--keep-all", "--out", str(tmp_path / "b")]) == 0
    report = json.loads((tmp_path / "b" / "update.json").read_text())
    assert report["set_aside"] == [] and report["residual_rms_mm"] > 1.0  # the slip, fitted, pulls


def test_swapped_points_a_second_update_and_the_default_noise_are_said(atlas, atlas_folder, tmp_path, capsys):
    """--pre and --target swapped: the measured shift points against the scene's (hand-made:
    the known operation's points, reversed) and the report says so; a second update into the
    same folder is refused in one line unless --overwrite (or its old name --replace); the default
    noise is named."""
    from fenics_brainshift.cli import main

    _markups(tmp_path, atlas, noise=0.3e-3)
    right = [
        "update",
        str(atlas_folder),
        "--pre",
        str(tmp_path / "pre.mrk.json"),
        "--target",
        str(tmp_path / "intra.mrk.json"),
    ]
    assert main(right + ["--out", str(tmp_path / "a")]) == 0
    said = capsys.readouterr().out
    assert "are --pre and --target swapped" not in said and "1 mm per coordinate, the default" in said
    assert json.loads((tmp_path / "a" / "update.json").read_text())["noise_stated"] is False
    swapped = [
        "update",
        str(atlas_folder),
        "--pre",
        str(tmp_path / "intra.mrk.json"),
        "--target",
        str(tmp_path / "pre.mrk.json"),
        "--noise",
        "0.3",
    ]
    assert main(swapped + ["--out", str(tmp_path / "b")]) == 0
    assert "are --pre and --target swapped?" in capsys.readouterr().out
    assert "swapped" in json.loads((tmp_path / "b" / "update.json").read_text())["warning"]
    before = (tmp_path / "a" / "update.json").read_text()
    assert main(right + ["--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "holds an earlier update (20 points" in err and "--overwrite" in err and "Traceback" not in err
    assert (tmp_path / "a" / "update.json").read_text() == before
    assert main(right + ["--out", str(tmp_path / "a"), "--noise", "0.5", "--replace"]) == 0
    assert json.loads((tmp_path / "a" / "update.json").read_text())["noise_mm"] == 0.5
    capsys.readouterr()
    assert main(right + ["--out", str(atlas_folder), "--overwrite"]) == 2  # (beside the atlas: never)
    assert "holds an atlas (atlas.h5): give the update a folder of its own" in capsys.readouterr().err
    assert not (atlas_folder / "update.json").exists()


@pytest.mark.parametrize(
    "case, words",
    [
        ("no atlas", "holds no atlas"),
        ("too few", "too few for the update: give at least 3"),
        ("in metres", "outside the atlas's body"),
        ("noise", "--noise: 1e-300 mm; a point's measurement noise is 0.01-50 mm"),
        ("noise huge", "--noise: 1e+300 mm; a point's measurement noise is 0.01-50 mm"),
        ("bootstrap", "--bootstrap"),
        ("csv in metres", "positions in metres?"),
        ("image elsewhere", "does not overlap the atlas's brain"),
        ("partial pre columns", "but not all of x_pre"),
    ],
)
def test_bad_update_input_is_one_line(atlas, atlas_folder, tmp_path, capsys, case, words):
    from fenics_brainshift.cli import main

    pre, intra = _markups(tmp_path, atlas)
    args = [
        "update",
        str(atlas_folder),
        "--target",
        str(tmp_path / "intra.mrk.json"),
        "--pre",
        str(tmp_path / "pre.mrk.json"),
        "--out",
        str(tmp_path / "out"),
    ]
    if case == "no atlas":
        args[1] = str(tmp_path)
    elif case == "too few":
        write_markups(tmp_path / "pre.mrk.json", ["P0", "P1"], pre[:2] * 1e3)
        write_markups(tmp_path / "intra.mrk.json", ["P0", "P1"], intra[:2] * 1e3)
    elif case == "in metres":  # a slip of units: 1000x too small, every point near the origin
        write_markups(tmp_path / "pre.mrk.json", [f"P{i}" for i in range(20)], pre * 1e3 + 300.0)
    elif case == "noise":
        args += ["--noise", "1e-300"]
    elif case == "noise huge":
        args += ["--noise", "1e300"]
    elif case in ("csv in metres", "partial pre columns"):
        header = "x_pre, y_pre, z_pre, x, y, z" if case == "csv in metres" else "x_pre, y_pre, x, y, z"
        rows = np.hstack([pre, intra]) if case == "csv in metres" else np.hstack([pre[:, :2], intra])
        np.savetxt(tmp_path / "points.csv", rows, delimiter=",", header=header, comments="")  # metres / mm
        args = ["update", str(atlas_folder), "--target", str(tmp_path / "points.csv"), "--out", str(tmp_path / "out")]
    elif case == "image elsewhere":
        import nibabel

        affine = np.eye(4)
        affine[:3, 3] = 500.0  # mm: far from the brain
        nibabel.save(nibabel.Nifti1Image(np.zeros((10, 10, 10), np.float32), affine), tmp_path / "far.nii.gz")
        args += ["--image", str(tmp_path / "far.nii.gz")]
    else:
        args += ["--bootstrap", "-1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out" / "update.json").exists() and not (tmp_path / "out" / "displacement.h5").exists()


@pytest.mark.parametrize(
    "vary, words",
    [
        (["fluid.level"], "give KEY=VALUES"),
        (["material.E=1,2"], "cannot be varied"),
        (["fluid.level=20,30"], "in metres (mm / 1000)"),
        (["gravity.angle_x=90"], "angles are degrees"),
        (["swelling.tumour=-0.1,0.1"], "no such region"),
    ],
)
def test_bad_atlas_input_is_one_line(tmp_path, capsys, vary, words):
    from fenics_brainshift.cli import main

    argv = [
        "atlas",
        "brain",
        "-o",
        str(tmp_path / "a"),
        "--set",
        "mesh.voxel=0.01",
        *[a for v in vary for a in ("--vary", v)],
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("brainshift: error")]  # (beside the log)
    assert len(errors) == 1 and words in errors[0] and "Traceback" not in err, err
    assert not (tmp_path / "a" / "atlas.h5").exists()


def test_the_default_family_centres_on_the_drained_level_and_clips_it_to_the_body():
    """A scene that drains over 10 s with the default [time] end of 1 s (as `prepare` writes
    them) ends drained in a quasi-static run; the atlas's default levels and its prior take
    that level, not the one at 1 s, and levels above the body are clipped, not refused."""
    from fenics_brainshift.atlas.scenarios import clip_levels, family

    drained = load_scene("brain", ["time.mode=quasi-static", "time.end=1", "fluid.level=[[0, 0.085], [10, 0.03]]"])
    assert drained.settled_time == 10.0
    assert load_scene("brain").settled_time == 16.0  # the bundled scene's end is its schedule's
    levels = sorted({s["fluid.level"] for s in family(drained, {}, (-0.08, 0.07))})
    # 14 levels 5 mm apart from 45 mm below the drained 0.03 m to 20 mm above it (at 1 s: 0.0795)
    assert np.allclose(levels, np.linspace(0.03 - 0.045, 0.03 + 0.02, 14))
    clipped = sorted({s["fluid.level"] for s in clip_levels(family(drained, {}, (-0.08, 0.04)), (-0.08, 0.04))})
    assert max(clipped) == 0.04 and len(clipped) == 12


SKULL = ["skull.gap=0.002"]


@pytest.fixture(scope="module")
def skull_atlas():
    built, _ = build(load_scene("brain", COARSE + SKULL), parse_vary(VARY), MPI.COMM_WORLD)
    return built


def test_skull_rows_screened_by_the_distance_bound_are_those_of_every_node(skull_atlas):
    """The update asks which boundary nodes have less room than a margin, and how deep the
    deepest is past the skull, measuring the distance only where the Lipschitz bound from the
    first weights leaves doubt: the same nodes and depth as the distance at every node, at
    weights near and far from the first, inside the skull and well past it."""
    from fenics_brainshift.atlas.prepared import skull_rows as _skull
    from fenics_brainshift.atlas.rows import SKULL_MARGIN, SkullRows

    cached = _skull(skull_atlas)
    modes = skull_atlas.boundary.modes.astype(float)
    rows = SkullRows(cached.skull, cached.points, modes)  # (a reference of its own)

    def room_at_every_node(c):  # (by the skull itself, not through the rows' caches)
        return cached.skull.phi(cached.points + np.tensordot(c, modes, axes=1))[0]

    m = len(skull_atlas.scenarios)
    family = np.flatnonzero(skull_atlas.family)
    rng = np.random.default_rng(3)
    tries = [np.where(skull_atlas.family, 1.0 / len(family), 0.0)]  # the first: the reference
    for scale in (1.0, 1.0, 2.5, 4.0):  # convex combinations, and beyond them (past the skull)
        c = np.zeros(m)
        c[rng.choice(family, 3, replace=False)] = scale * rng.dirichlet(np.ones(3))
        tries.append(c)
    tries.append(np.eye(m)[family[-1]] * 3.0)
    deepest_seen = 0.0
    for c in tries:
        room = room_at_every_node(c)
        for margin in (SKULL_MARGIN, 0.0, 5e-3):
            assert np.array_equal(rows.near(c, margin), np.flatnonzero(room < margin))
        assert rows.deepest(c) == pytest.approx(max(0.0, -room.min()), abs=1e-15)
        deepest_seen = max(deepest_seen, rows.deepest(c))
    assert deepest_seen > 1e-3  # (some tries are past the skull: the check is not vacuous)
    fresh = SkullRows(cached.skull, cached.points, modes)  # a first question that is not finite
    nan = np.full(m, np.nan)
    fresh.near(nan)
    c = tries[-1]
    assert np.array_equal(fresh.near(c), np.flatnonzero(room_at_every_node(c) < SKULL_MARGIN))  # (no bound kept)


def test_skull_rows_are_the_room_linearised_at_the_weights(skull_atlas):
    """A skull row is phi(X + u(c)) >= -SKULL_SLACK linearised at c: at c itself C c - d is the
    room plus the slack, and at weights moved a little it follows the room measured by the
    skull to second order (the error falls 4x when the move halves); asked again at other
    weights (the rows keep the last weights' distances), the rows are those of the new weights."""
    from fenics_brainshift.atlas.prepared import skull_rows as _skull
    from fenics_brainshift.atlas.rows import SKULL_SLACK, SkullRows

    cached = _skull(skull_atlas)
    modes = skull_atlas.boundary.modes.astype(float)
    rows = SkullRows(cached.skull, cached.points, modes)
    family = np.flatnonzero(skull_atlas.family)
    rng = np.random.default_rng(5)

    def room(c, nodes):
        return cached.skull.phi(cached.points[nodes] + np.tensordot(c, modes[:, nodes], axes=1))[0]

    for _ in range(2):  # (the second: new weights after the first's distances were kept)
        c = np.zeros(len(modes))
        c[rng.choice(family, 3, replace=False)] = rng.dirichlet(np.ones(3))
        rows.near(c)
        nodes = np.sort(rng.choice(len(cached.points), 300, replace=False))
        C, d = rows.rows(c, nodes)
        assert np.allclose(C @ c - d, room(c, nodes) + SKULL_SLACK, rtol=0, atol=1e-12)
        move = np.zeros(len(modes))
        move[rng.choice(family, 3, replace=False)] = rng.normal(0.0, 1.0, 3)
        errors = []
        for h in (0.02, 0.01):
            exact = room(c + h * move, nodes) + SKULL_SLACK
            errors.append(np.abs(C @ (c + h * move) - d - exact))
        smooth = errors[1] > 1e-12  # (on a flat facet the room is linear: no error)
        assert smooth.sum() > 30
        ratio = np.median(errors[0][smooth] / errors[1][smooth])
        assert 3.0 < ratio < 5.0, ratio


def test_with_a_skull_a_mode_is_the_full_models_contact_state(skull_atlas, atlas):
    """Warm-started within a pose, mode 'level 40 mm, turned 8 degrees' equals the contact state
    of a scene built with them and solved from rest (the scene's 0.01 mm tolerance) to the
    modes' own (0.05 mm); every mode is inside the skull to it."""
    from fenics_brainshift.atlas.prepared import skull_rows as _skull

    k = next(
        i
        for i, s in enumerate(skull_atlas.scenarios)
        if s["kind"] == "family" and s["values"] == {"gravity.angle_z": 8.0, "fluid.level": 0.04}
    )
    g = rotated_gravity([0.0, -9.81, 0.0], {"gravity.angle_z": 8.0})
    _, u = _settled(
        load_scene("brain", COARSE + SKULL + [f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]", "fluid.level=0.04"])
    )
    assert np.abs(skull_atlas.vertex_modes[k] - u).max() < 0.05e-3
    rows = _skull(skull_atlas)
    family = np.flatnonzero(skull_atlas.family)
    room = [rows.room(np.eye(len(skull_atlas.scenarios))[i]).min() for i in family]
    tolerance = skull_atlas.info["contact_tolerance_m"]  # the scene's 0.01 mm, loosened for the modes
    assert tolerance == pytest.approx(0.05e-3)
    assert min(room) > -tolerance
    kept = skull_atlas.info["contact_compliance"]  # a column a direction a pressed node needed, G dense over them
    assert kept["columns"] > 0
    assert kept["megabytes"] == pytest.approx(8e-6 * kept["columns"] ** 2, abs=0.1)
    assert atlas.info["contact_compliance"] is None
    assert atlas.scenarios[k] == skull_atlas.scenarios[k]
    assert np.abs(skull_atlas.vertex_modes[k] - atlas.vertex_modes[k]).max() > 1e-3  # contact-free: a mm off


def test_with_a_skull_the_swelling_mode_is_the_change_a_swollen_scene_makes(skull_atlas, tmp_path):
    """The whole-brain mode with the skull (solved from the prior state, its multipliers too)
    against two scenes with the skull solved from rest on their own: at 10 mm their equilibrium
    is unique (from rest and from the prior agree to 2e-8 mm: `python benchmarks/skull_atlas.py
    --voxel 0.01 --gap 0.002 --levels 3`; not so at 5 mm, docs/update.md). The bookkeeping of
    the start is tested above."""
    _, u_shrunk = _settled(_shrunk_scene(tmp_path, COARSE + SKULL))
    _, u_prior = _settled(load_scene("brain", COARSE + SKULL))
    change = u_shrunk - u_prior
    assert skull_atlas.scenarios[-1]["kind"] == "swelling" and np.abs(change).max() > 1e-3
    assert np.abs(skull_atlas.prior_vertex - u_prior).max() < 0.05e-3  # (the contact's tolerance)
    assert np.abs(skull_atlas.vertex_modes[-1] - change).max() < 0.05e-3


class _Forward:
    """What solve_from_prior uses of a ForwardModel: its state, the multipliers, how it starts;
    each solve records them (and the first may fail)."""

    def __init__(self, skull=True, continued=False, fail_first=False):
        contact = SimpleNamespace(multipliers=np.full(2, 9.0)) if skull else None
        self.sim = SimpleNamespace(u=SimpleNamespace(x=SimpleNamespace(array=np.full(6, 9.0))), contact=contact)
        self.continued, self.from_rest, self.fail_first, self.calls = continued, True, fail_first, []

    def solve(self, values):
        contact = self.sim.contact
        self.calls.append(
            (self.sim.u.x.array.copy(), None if contact is None else contact.multipliers.copy(), self.from_rest)
        )
        if self.fail_first and len(self.calls) == 1:
            raise SolverError("Newton did not converge")


def test_a_swelling_mode_starts_from_the_prior_state_and_its_multipliers():
    """The state and the multipliers are put back to the prior's (copies), Newton starts from
    there; from rest again only for a linear body with the skull; otherwise the failure stands."""
    prior_u, prior_multipliers = np.arange(6.0), np.array([1.0, 2.0])
    forward = _Forward()
    solve_from_prior(forward, {}, prior_u, prior_multipliers)
    ((u, multipliers, from_rest),) = forward.calls
    assert np.array_equal(u, prior_u) and np.array_equal(multipliers, prior_multipliers) and not from_rest
    forward.sim.contact.multipliers[:] = -1.0
    assert np.array_equal(prior_multipliers, [1.0, 2.0])  # (the prior's own are not the solver's)
    forward = _Forward(fail_first=True)
    solve_from_prior(forward, {}, prior_u, prior_multipliers)
    assert [call[2] for call in forward.calls] == [False, True]
    for forward in (_Forward(skull=False, fail_first=True), _Forward(continued=True, fail_first=True)):
        with pytest.raises(SolverError):
            solve_from_prior(forward, {}, prior_u, None if forward.sim.contact is None else prior_multipliers)
        assert len(forward.calls) == 1


def test_a_mode_that_does_not_settle_from_the_last_is_solved_from_rest():
    """With the skull, a family mode whose Newton fails from the last mode is solved again
    from rest; without the skull, or already from rest, the failure stands."""
    forward = _Forward(fail_first=True)
    forward.from_rest = False
    solve_family_mode(forward, {})
    assert [call[2] for call in forward.calls] == [False, True]
    for forward in (_Forward(skull=False, fail_first=True), _Forward(fail_first=True)):
        forward.from_rest = forward.sim.contact is not None  # no skull: from the last; skull: already from rest
        with pytest.raises(SolverError):
            solve_family_mode(forward, {})
        assert len(forward.calls) == 1


def test_a_mode_settled_neither_way_is_left_out_and_named(monkeypatch):
    """One scenario that settles neither from the last mode nor from rest: the atlas holds the
    others, atlas.json names it, and the next mode starts from rest; more than MAX_SKIPPED of
    the family failing ends the build with the solver's message."""
    from fenics_brainshift.atlas import build as building

    real, starts = building.solve_family_mode, []

    def failing(forward, values):
        starts.append((values["fluid.level"], forward.from_rest))
        if values["fluid.level"] == 0.03:
            raise SolverError("Newton did not converge (a stand-in)")
        real(forward, values)

    monkeypatch.setattr(building, "solve_family_mode", failing)
    monkeypatch.setattr(building, "MAX_SKIPPED", 0.4)  # (of three modes: one may be left out)
    built, _ = build(load_scene("brain", COARSE + SKULL), parse_vary(["fluid.level=0.02,0.03,0.04"]), MPI.COMM_WORLD)
    if MPI.COMM_WORLD.rank == 0:
        assert [s["values"]["fluid.level"] for s in built.scenarios if s["kind"] == "family"] == [0.04, 0.02]
        assert [o["values"]["fluid.level"] for o in built.info["left_out"]] == [0.03]
        assert "a stand-in" in built.info["left_out"][0]["why"]
    assert starts == [(0.04, True), (0.03, False), (0.02, True)]  # (levels as the fluid drains)
    monkeypatch.setattr(building, "MAX_SKIPPED", 0.3)  # one of three is more than that
    with pytest.raises(SolverError, match="a stand-in"):
        build(load_scene("brain", COARSE + SKULL), parse_vary(["fluid.level=0.02,0.03,0.04"]), MPI.COMM_WORLD)
    monkeypatch.setattr(building, "MAX_SKIPPED", 0.4)
    with pytest.raises(SolverError, match="a stand-in"):  # without the skull no other start: never left out
        build(load_scene("brain", COARSE), parse_vary(["fluid.level=0.02,0.03,0.04"]), MPI.COMM_WORLD)


def test_the_update_keeps_the_brain_inside_the_skull(skull_atlas):
    """Points asking for 1.6 times a contact state's sag (past what the skull allows): without
    the skull's rows the fit follows them through the skull; with them it stops at the skull."""
    U = skull_atlas.vertex_modes.astype(float)
    c = np.zeros(len(U))
    c[1] = c[5] = 0.8
    truth = np.tensordot(c, U, axes=1)
    picked = _top(skull_atlas.points)[::5][:20]
    pre = skull_atlas.points[picked]
    target = Target(pre + truth[picked], pre, [f"p{i}" for i in range(len(pre))])
    through = update(skull_atlas, target, 0.3e-3, samples=0, keep_inside=False)
    inside = update(skull_atlas, target, 0.3e-3, samples=0)
    assert through.skull["deepest_past_mm"] > 1.0 and "passes the skull" in through.warning
    assert inside.skull["deepest_past_mm"] <= 0.15 and inside.skull["nodes_with_rows"] > 0  # (update.PAST_SKULL)
    assert inside.warning is None or "passes the skull" not in inside.warning


def test_an_update_whose_prior_is_past_the_skull_s_rows_starts_inside_them(skull_atlas, monkeypatch):
    """The prior's weights can be a little past the skull's rows linearised at them (a mix of
    settled states can be where none of them is: the 3 mm atlas's, whose every update then
    solved its first fit by NNLS from scratch, 0.4 s of 0.5), here made so by a deeper prior (one
    state of the family 1.5 times over). The first fit starts inside every row of its round
    (prepared.start_inside), every problem's anchor is inside its rows (rows taken again are
    eased to keep it so: rows.ease), and the weights are those of every refit solved from
    scratch (combine.WARM_START = False)."""
    from fenics_brainshift.atlas import combine
    from fenics_brainshift.atlas.active_set import ACTIVE
    from fenics_brainshift.atlas.prepared import prepare, prior_weights, skull_at_prior

    atlas = dataclasses.replace(skull_atlas, once={})  # (its own prepared state)
    deeper = prior_weights(atlas).copy()
    deeper[atlas.family] = 1.5 * np.eye(len(deeper))[np.flatnonzero(atlas.family)[4]][atlas.family]
    atlas.once["prior_weights"] = deeper
    prepare(atlas)
    C, d = skull_at_prior(atlas)[1].unit_rows
    assert np.count_nonzero(C @ deeper - d < -1e-6) > 2  # (the case guarded)
    U = atlas.vertex_modes.astype(float)
    picked = _top(atlas.points)[::5][:20]
    pre = atlas.points[picked]
    truth = np.tensordot(np.eye(len(U))[2], U, axes=1)
    target = Target(pre + truth[picked], None, [f"p{i}" for i in range(len(pre))])  # (on the surface: rounds)
    solves, solve = [], combine.Problem.solve

    def recorded(problem, alpha, rows=None, near=None):
        solves.append((problem, near))
        return solve(problem, alpha, rows, near)

    monkeypatch.setattr(combine.Problem, "solve", recorded)
    warm = update(atlas, target, 0.3e-3, samples=0)

    def inside(problem, c):
        C, d = problem.unit_rows
        return np.all(C @ c - d >= -ACTIVE * (1.0 + np.abs(d)))

    assert inside(solves[0][0], solves[0][1])  # the first fit's start
    assert all(inside(problem, problem.anchor) for problem, _ in solves)
    assert len({id(problem) for problem, _ in solves}) > 1  # (rows taken again: a second round)
    monkeypatch.setattr(combine, "WARM_START", False)
    scratch = update(atlas, target, 0.3e-3, samples=0)
    assert warm.alpha == scratch.alpha
    assert np.abs(warm.weights - scratch.weights).max() <= 1e-6


def test_an_atlas_built_on_two_ranks_is_the_one_built_on_one(atlas, tmp_path):
    """(A subprocess under mpirun of its own: serial pass only, mpirun cannot nest.)"""
    out = tmp_path / "a2"
    command = mpirun() + [
        sys.executable,
        "-m",
        "fenics_brainshift.cli",
        "atlas",
        "brain",
        "-o",
        str(out),
        *VARY_ARGS,
        *[a for s in COARSE for a in ("--set", s)],
    ]
    done = subprocess.run(command, capture_output=True, text=True, env=subprocess_env(), timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    two = store.read(out)
    assert two.info["ranks"] == 2
    assert np.abs(two.points - atlas.points).max() < 1e-12  # the same vertices in the same order

    def cells(t):  # the set of tetrahedra (a partition orders cells and their corners its own way)
        t = np.sort(t, axis=1)
        return t[np.lexsort(t.T[::-1])]

    assert np.array_equal(cells(two.tetrahedra), cells(atlas.tetrahedra))
    assert np.abs(two.vertex_modes - atlas.vertex_modes).max() < 1e-6 * np.abs(atlas.vertex_modes).max()


@pytest.mark.parametrize("ranks, per_mode", [(2, 1), (2, 2), (3, 1), (3, 3)])
def test_a_skull_atlas_built_on_two_or_three_ranks_is_the_one_built_on_one(skull_atlas, tmp_path, ranks, per_mode):
    """The contact modes and the swelling mode (solved from the prior state) built on two and
    three ranks equal those built on one, the fine surface's too. Groups of one rank (each
    solving whole poses, each pose from rest) give the numbers of one rank to round-off (a
    pose's start carried the last pose's contact pressures: 0.04 mm apart); one group of all
    the ranks (the mesh split in two or three) the same to the solver's round-off, the fine
    surface too (its points beyond the voxels took their values from whichever of two equally
    near cells each partition's round-off chose: 0.2 mm). (At 10 mm the contact state is
    unique, so this checks the ranks' agreement, not the start: that is the stand-in test
    above. Serial pass only, as above; three ranks on two cores oversubscribed.)"""
    out = tmp_path / "s2"
    command = mpirun(ranks) + [
        sys.executable,
        "-m",
        "fenics_brainshift.cli",
        "atlas",
        "brain",
        "-o",
        str(out),
        "--ranks-per-mode",
        str(per_mode),
        *VARY_ARGS,
        *[a for s in COARSE + SKULL for a in ("--set", s)],
    ]
    done = subprocess.run(command, capture_output=True, text=True, env=subprocess_env(), timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    two = store.read(out)
    assert two.info["ranks"] == ranks and two.info["ranks_per_mode"] == per_mode
    assert two.scenarios == skull_atlas.scenarios and two.scenarios[-1]["kind"] == "swelling"
    assert np.abs(two.points - skull_atlas.points).max() < 1e-12
    assert np.array_equal(two.tetrahedra, skull_atlas.tetrahedra)
    scale = np.abs(skull_atlas.vertex_modes).max()
    # round-off (1e-12 m seen), which may turn a float32 rounding of the stored modes (a relative
    # 6e-8); with the mesh split, the solver's
    rtol, atol = (2.5e-7, 1e-9 * scale) if per_mode == 1 else (0.0, 1e-6 * scale)
    stored = np.float32  # (the modes are stored in single precision: atlas/store.py)
    np.testing.assert_allclose(two.vertex_modes, skull_atlas.vertex_modes.astype(stored), rtol=rtol, atol=atol)
    np.testing.assert_allclose(two.surface_modes, skull_atlas.surface_modes.astype(stored), rtol=rtol, atol=atol)
    np.testing.assert_allclose(two.prior_vertex, skull_atlas.prior_vertex, rtol=rtol, atol=atol)


def test_the_atlas_says_what_its_chains_and_its_prior_cost(atlas):
    """atlas.json's clock (benchmarks/resolution.py extrapolates from it): the family modes group
    0 tried (those kept, counted as the scenarios count them, and those left out), and its
    seconds within the modes' seconds; and the largest memory a rank held."""
    info = atlas.info
    family = sum(s["kind"] == "family" for s in atlas.scenarios) + len(info["left_out"])
    groups = info["ranks"] // info["ranks_per_mode"]
    assert info["family_modes"] == family if groups == 1 else 0 < info["family_modes"] < family
    assert 0 < info["family_s"] and 0 < info["prior_and_swelling_s"]
    assert info["family_s"] + info["prior_and_swelling_s"] <= info["modes_s"] + 1e-3  # (each rounded to 1 ms)
    assert 50 <= info["peak_memory_mb_a_rank"] <= high_water_mb() + 1  # (built here earlier; the kernel says)


def test_chains_are_dealt_whole_to_groups_longest_first():
    """The modes' chains (a pose's levels) go whole to the least loaded group, group 0 carrying
    the prior and the swelling modes as a head start; every scenario dealt once."""
    from fenics_brainshift.atlas.build import _pose
    from fenics_brainshift.atlas.groups import chains, check, share

    grid = [{"gravity.angle_x": a, "fluid.level": lv} for a in (0, 5, 10) for lv in (0.01, 0.02, 0.03, 0.04)]
    grid += [{"gravity.angle_x": 15, "fluid.level": 0.01}]
    found = chains(grid, _pose)
    assert found == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11], [12]]
    dealt = share(found, 2, head_start=2)
    assert dealt == [[4, 5, 6, 7, 12], [0, 1, 2, 3, 8, 9, 10, 11]]  # loads 2+4+1 = 7 and 8
    assert sorted(i for d in dealt for i in d) == list(range(len(grid)))
    assert share(found, 1) == [list(range(len(grid)))]
    with pytest.raises(InputError, match="--ranks-per-mode 3: give a divisor of the 4 rank"):
        check(4, 3)


def _write_tag(path: Path, pre_mm: np.ndarray, intra_mm: np.ndarray) -> None:
    """An MNI tag file as the RESECT database ships its MRI-to-ultrasound landmarks."""
    lines = ["MNI Tag Point File", "Volumes = 2;", "% Volume 1: MRI, volume 2: ultrasound", "", "Points ="]
    for i, (a, b) in enumerate(zip(pre_mm, intra_mm)):
        lines.append(" " + " ".join(f"{v:.4f}" for v in (*a, *b)) + f' "{i + 1}"')
    path.write_text("\n".join(lines) + ";\n")


def test_landmark_pairs_of_an_mni_tag_file_update_as_markups_do(atlas, atlas_folder, tmp_path):
    from fenics_brainshift.images.targets import read_target

    pre, intra = _markups(tmp_path, atlas, noise=0.3e-3)
    _write_tag(tmp_path / "pairs.tag", pre * 1e3, intra * 1e3)
    tag = read_target(tmp_path / "pairs.tag")
    assert tag.labels[:2] == ["1", "2"]
    assert np.abs(tag.pre - pre).max() < 1e-7 and np.abs(tag.measured - intra).max() < 1e-7  # (4 decimals of mm)
    markups = read_target(tmp_path / "intra.mrk.json", tmp_path / "pre.mrk.json")
    a = update(atlas, tag, 0.3e-3, samples=0)
    order = np.argsort([int(label[1:]) for label in markups.labels])  # P0.. in reverse in the file
    b = update(atlas, Target(markups.measured[order], markups.pre[order], sorted(markups.labels)), 0.3e-3, samples=0)
    assert np.abs(a.displacement - b.displacement).max() < 1e-6


@pytest.mark.parametrize(
    "text, words",
    [
        ("MNI Tag Point File\nVolumes = 1;\nPoints =\n 1 2 3;\n", "must hold landmark pairs"),
        ("MNI Tag Point File\nVolumes = 2;\nPoints =\n 1 2 3 4 5 x;\n", "point 1 is not six finite numbers"),
        ("Tag file\n", "is not an MNI tag file"),
    ],
)
def test_a_bad_tag_file_is_one_line(tmp_path, text, words):
    from fenics_brainshift.errors import InputError
    from fenics_brainshift.images.targets import read_target

    (tmp_path / "bad.tag").write_text(text)
    with pytest.raises(InputError, match=words):
        read_target(tmp_path / "bad.tag")


def test_a_poses_next_level_starts_from_its_last_two_extrapolated():
    """build.predict_start by hand: levels 40 and 35 mm settled, the next at 30 mm starts from
    twice the last less the one before (its multipliers too, the pressure vectors: one turned
    past zero, pointing into the skull, is none); a jump back up
    or far ahead, or a scenario without a level, keeps the last state."""
    from types import SimpleNamespace

    from fenics_brainshift.atlas.mode_solves import predict_start

    def forward():
        return SimpleNamespace(
            sim=SimpleNamespace(
                u=SimpleNamespace(x=SimpleNamespace(array=np.array([5.0, 5.0]))),
                contact=SimpleNamespace(multipliers=np.full((2, 3), 9.0)),
            )
        )

    last = [
        (0.040, np.array([1.0, 2.0]), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 4.0]])),
        (0.035, np.array([2.0, 2.5]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])),
    ]
    f = forward()
    predict_start(f, last, {"fluid.level": 0.030, "gravity.angle_z": 6.0})
    assert f.sim.u.x.array == pytest.approx([3.0, 3.0]) and np.allclose(
        f.sim.contact.multipliers, [[2.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    )
    f = forward()
    predict_start(f, last, {"fluid.level": 0.0325})  # half a step ahead
    assert f.sim.u.x.array == pytest.approx([2.5, 2.75])
    for values in ({"fluid.level": 0.045}, {"fluid.level": 0.020}, {"gravity.angle_z": 6.0}):
        f = forward()
        predict_start(f, last, values)
        assert f.sim.u.x.array.tolist() == [5.0, 5.0] and f.sim.contact.multipliers.tolist() == [[9.0] * 3] * 2


def test_residuals_the_noise_cannot_explain_are_warned_of_by_their_chi_square(atlas):
    """Landmark pairs of another brain (a shift the atlas has no mode for, about 5 mm) against a
    stated noise of 1 mm left a residual 7x the noise without a word (the warning fired past
    10x). The chi-square of the residuals says it: by hand, sum (r / noise)^2 over 3 coordinates
    a pair against the chi-square distribution's upper tail. The honest points of the same
    operation, at their own noise, raise no warning."""
    from scipy.stats import chi2 as chi_square

    truth, points, picked, noise, measured = _cortex_points_one_slipped(atlas, 0)
    measured[0] -= [0.0, 0.008, 0.0]  # (no slip: the honest points)
    labels = [f"p{i}" for i in range(20)]
    honest = update(atlas, Target(measured, points[picked], labels), noise)
    assert honest.warning is None or "does not explain" not in honest.warning
    other = measured + np.random.default_rng(5).normal(0.0, 3e-3, measured.shape)  # another brain's shift
    result = update(atlas, Target(other, points[picked], labels), 1e-3, set_aside=False)
    by_hand = chi_square.sf(np.sum((result.residual / 1e-3) ** 2), 3 * len(result.residual))
    assert by_hand < 1e-3 and "does not explain the data" in result.warning and "chi-square" in result.warning
    assert float(np.sqrt(np.mean(result.residual**2))) < 10 * 1e-3  # (the old rule stayed silent)


def test_an_update_into_a_runs_folder_is_refused_and_the_run_kept(atlas, atlas_folder, tmp_path, capsys):
    """`update --out RUN` over a run's results replaced its displacement and summary without a
    word (a run into an update's folder was already refused); now refused, the run untouched;
    --overwrite, and only it, replaces one kind's results by the other's, whole."""
    import hashlib

    from fenics_brainshift.cli import main

    run = tmp_path / "run"
    assert main(["run", "cube", "--out", str(run), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.end=0.4"]) == 0
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.iterdir() if p.is_file()}
    _markups(tmp_path, atlas)
    code = main(["update", str(atlas_folder), "--target", str(tmp_path / "intra.mrk.json"), "--pre",
                 str(tmp_path / "pre.mrk.json"), "--out", str(run)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "holds a run's results" in err and "choose another --out, or --overwrite" in err, err
    after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.iterdir() if p.is_file()}
    assert after == before
    update_args = ["update", str(atlas_folder), "--target", str(tmp_path / "intra.mrk.json"), "--pre",
                   str(tmp_path / "pre.mrk.json"), "--out"]  # fmt: skip
    # a run's folder that lost its summary.json and displacement.xdmf: still a run's results
    import shutil

    partial = tmp_path / "partial"
    shutil.copytree(run, partial)
    (partial / "summary.json").unlink()
    (partial / "displacement.xdmf").unlink()
    assert main(update_args + [str(partial)]) == 2
    assert "holds a run's results (probes.csv, probes_final.mrk.json, displacement.h5)" in capsys.readouterr().err
    assert (partial / "probes.csv").is_file() and not (partial / "update.json").exists()
    # asked for: the run's files go, every one, and the update takes the folder
    update_args += [str(run)]
    assert main(update_args + ["--overwrite"]) == 0
    assert json.loads((run / "summary.json").read_text())["kind"] == "update" and (run / "update.json").is_file()
    assert not (run / "probes.csv").exists() and not (run / "last_state.npz").exists()
    # and back: a run over the update is refused, the update kept; with --overwrite the run's
    kept = (run / "update.json").read_text()
    capsys.readouterr()
    cube = ["run", "cube", "--out", str(run), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.end=0.4"]
    assert main(cube) == 2 and "holds an update (update.json): choose another --out, or --overwrite" in (
        capsys.readouterr().err
    )
    assert (run / "update.json").read_text() == kept
    assert main(cube + ["--overwrite"]) == 0
    assert not (run / "update.json").exists() and not (run / "uncertainty.nii.gz").exists()
    assert json.loads((run / "summary.json").read_text())["status"] == "ok" and (run / "probes.csv").is_file()


def test_an_update_as_it_runs_starts_no_dolfinx_and_runs_on_two_ranks(atlas, atlas_folder, tmp_path, serial_only):
    """`brainshift update` itself, not only its imports, starts neither DOLFINx nor PETSc (it
    imported them on rank 0 alone to write its STL: on two ranks PETSc's start waited for the
    other rank, which waited in a barrier, for ever); two ranks give the one rank's answer."""
    from conftest import mpirun, subprocess_env

    _markups(tmp_path, atlas, noise=0.3e-3)
    argv = ["update", str(atlas_folder), "--target", str(tmp_path / "intra.mrk.json"), "--pre",
            str(tmp_path / "pre.mrk.json"), "--noise", "0.3", "--out"]  # fmt: skip
    code = (
        "import sys\nfrom fenics_brainshift.cli import main\n"
        f"code = main({argv + [str(tmp_path / 'one')]!r})\n"
        "print(code, sorted(m for m in ('dolfinx', 'petsc4py', 'ufl', 'basix') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=subprocess_env(),
                          timeout=300)  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip().splitlines()[-1] == "0 []", done.stdout + done.stderr
    two = subprocess.run(mpirun() + [sys.executable, "-m", "fenics_brainshift.cli", *argv,
                                     str(tmp_path / "two")], capture_output=True, text=True,
                         env=subprocess_env(), timeout=300)  # fmt: skip
    assert two.returncode == 0, two.stderr
    one, both = (json.loads((tmp_path / d / "update.json").read_text()) for d in ("one", "two"))
    assert both["residual_rms_mm"] == pytest.approx(one["residual_rms_mm"], rel=1e-9)
    assert (tmp_path / "two" / "surface_final.stl").is_file() == (tmp_path / "one" / "surface_final.stl").is_file()


def test_pairs_whose_ras_numbers_are_declared_lps_are_warned_of_with_both_residuals(atlas, tmp_path, capsys):
    """Markups holding RAS numbers but saying LPS were fitted (13.3 -> 9.55 mm, exit 0, no word):
    read as declared, every point is mirrored in x and y. The update tries the other frame when
    the prediction misses by more than the noise explains, and warns with both residuals; the
    same points declared rightly raise no such warning."""
    from fenics_brainshift.cli import main

    _, truth = _operation(atlas)
    points = atlas.points
    top = _top(points)
    picked = np.random.default_rng(4).choice(top, 12, replace=False)
    labels = [f"P{i}" for i in range(12)]
    pre, intra = points[picked] * 1e3, (points[picked] + truth[picked]) * 1e3
    flip = np.array([-1.0, -1.0, 1.0])
    for name, factor in (("right", 1.0), ("slipped", flip)):
        write_markups(tmp_path / f"{name}_pre.mrk.json", labels, pre * factor)  # (slipped: the LPS file holds RAS)
        write_markups(tmp_path / f"{name}_intra.mrk.json", labels, intra * factor)
    said = {}
    for name in ("right", "slipped"):
        argv = ["update", str(tmp_path / "atlas"), "--target", str(tmp_path / f"{name}_intra.mrk.json"),
                "--pre", str(tmp_path / f"{name}_pre.mrk.json"), "--noise", "0.5",
                "--out", str(tmp_path / name)]  # fmt: skip
        if not (tmp_path / "atlas").exists():
            store.write(tmp_path / "atlas", atlas)
        code = main(argv)
        said[name] = (code, capsys.readouterr(), tmp_path / name / "update.json")
    code, out, _ = said["right"]
    assert code == 0 and "other frame" not in out.out + out.err
    code, out, report = said["slipped"]
    text = out.out + out.err
    assert code == 0 and "fit the prediction far better in the other frame" in text and "coordinateSystem" in text
    assert "other frame" in json.loads(report.read_text())["warning"]


def test_an_update_interrupted_before_its_record_can_be_made_again_in_its_folder(atlas, atlas_folder, tmp_path):
    """An update killed between its displacement and its update.json left a folder every later
    update refused as a run's; its summary says it was an update's, and a new one goes in."""
    from fenics_brainshift.cli import main

    _markups(tmp_path, atlas)
    argv = ["update", str(atlas_folder), "--target", str(tmp_path / "intra.mrk.json"), "--pre",
            str(tmp_path / "pre.mrk.json"), "--out", str(tmp_path / "u")]  # fmt: skip
    assert main(argv) == 0
    (tmp_path / "u" / "update.json").unlink()  # (as a kill left it: the run's files, the summary running)
    summary = json.loads((tmp_path / "u" / "summary.json").read_text())
    (tmp_path / "u" / "summary.json").write_text(json.dumps({**summary, "status": "running", "kind": "update"}))
    assert main(argv) == 0 and (tmp_path / "u" / "update.json").is_file()
