"""Calibration: fit the level, G and the head pose to intra-operative points.

References independent of the fit's shortcuts: the truth is solved by a Simulation built from
a scene that carries the true values (its own gravity vector, G and level), not by the
forward model's in-place changes; and the in-place changes are checked against such
rebuilt scenes directly."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from mpi4py import MPI

from fenics_brainshift import load_scene
from fenics_brainshift.fit import ForwardModel, Target, fit, fit_parameters
from fenics_brainshift.fit.parameters import rotated_gravity
from fenics_brainshift.images import write_markups
from fenics_brainshift.outputs.fine_surface import SurfaceEmbedding
from fenics_brainshift.outputs.points import PointEvaluator
from fenics_brainshift.physics.surface import gathered_outward_surface
from fenics_brainshift.runner import Simulation, build

from conftest import mpirun, subprocess_env

COARSE = ["mesh.voxel=0.01", "time.mode=quasi-static"]
TRUTH = {"fluid.level": 0.040, "material.G": 3000.0, "gravity.angle_z": 8.0}


def _true_scene(values: dict, model: str = "linear"):
    g = rotated_gravity([0.0, -9.81, 0.0], values)
    sets = [f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]", f"material.model={model}"]
    if "fluid.level" in values:
        sets.append(f"fluid.level={values['fluid.level']}")
    if "material.G" in values:
        sets.append(f"material.G={values['material.G']}")
    return load_scene("brain", COARSE + sets)


def _settled(scene):
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    sim.solve_to_settled(scene.time.end)
    return sim


def _surface_points(sim) -> np.ndarray:
    surface, _ = gathered_outward_surface(sim.model.fluid.hydro.facets, sim.model.comm)
    return np.unique(surface, axis=0)


@pytest.mark.mpi
@pytest.mark.parametrize("model", ["linear", "neo-hookean"])
def test_in_place_changes_equal_a_rebuilt_scene(model):
    """G by scaled loads, the pose by re-assembled gravity and fluid, the level: the forward
    model's state equals that of a scene built with those values (same tolerance as the
    follower iteration / Newton)."""
    values = {"fluid.level": 0.045, "material.G": 4000.0, "gravity.angle_z": 10.0, "gravity.angle_x": -5.0}
    # (the neo-Hookean brain has no settled state after the full drain below G ~ 2090 Pa)
    forward = ForwardModel(load_scene("brain", COARSE + [f"material.model={model}"]))
    forward.solve({"material.G": 3000.0})  # somewhere else first: the state carries over
    forward.solve(values)
    reference = _settled(_true_scene(values, model))
    points = _surface_points(reference)[::7]
    ours = forward.positions(points)
    theirs = points + PointEvaluator(reference.model.mesh, points).values(reference.u)
    shift = np.abs(theirs - points).max()
    assert shift > 2e-3  # millimetres: a real test of the equality below
    assert np.abs(ours - theirs).max() < 2e-4 * shift
    forward.solve({})  # back to the scene's own values: nothing of the last call stays behind
    assert forward.model.fluid.level_at(forward.t) == pytest.approx(0.030)
    assert forward.model.load_scale == 1.0
    np.testing.assert_allclose(forward.model.gravity.g.value, [0.0, -9.81, 0.0], atol=1e-12)
    np.testing.assert_allclose(forward.model.fluid.hydro.up, [0.0, 1.0, 0.0], atol=1e-12)
    forward.destroy()
    reference.destroy()


@pytest.fixture(scope="module")
def truth():
    """(pre, measured with 0.5 mm noise, exact) at 30 points on the exposed (anterior) cortex,
    and 40 points of the true deformed cortex there with 0.5 mm noise (for point to surface):
    vertices of the scene's fine surface (the segmented cortex, not the voxel mesh's staircase)
    moved by the true shift."""
    scene = _true_scene(TRUTH)
    sim = _settled(scene)
    surface = _surface_points(sim)
    exposed = surface[surface[:, 1] > 0.03]
    rng = np.random.default_rng(3)
    pre = exposed[rng.choice(len(exposed), 30, replace=False)]
    exact = pre + PointEvaluator(sim.model.mesh, pre).values(sim.u)
    cortex, triangles = build.fine_surface(scene)
    moved = cortex + SurfaceEmbedding(sim.model.mesh, cortex, triangles).values(sim.u)
    scan = moved[rng.choice(np.flatnonzero(cortex[:, 1] > 0.03), 40, replace=False)]
    sim.destroy()
    return (
        pre,
        exact + rng.normal(scale=0.5e-3, size=exact.shape),
        exact,
        scan + rng.normal(scale=0.5e-3, size=scan.shape),
    )


def test_a_fit_recovers_the_truth_within_its_uncertainty_and_predicts_held_out_points(truth):
    pre, measured, exact, _ = truth
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, list(TRUTH), forward.heights())
    result = fit(forward, Target(measured[:20], pre[:20], [str(i) for i in range(20)]), params, noise=0.5e-3)
    for p, value, sd, ok in zip(params, result.values, result.std, result.constrained):
        assert ok, p.name
        assert abs(value - TRUTH[p.name]) < 3.0 * sd, (p.name, value, sd)
    assert result.as_dict()["residual_rms_mm"] < 1.0 < result.as_dict()["prior_residual_rms_mm"]
    # held out: the fitted state predicts the other 10 points better than the scene did
    fitted_error = np.linalg.norm(forward.positions(pre[20:]) - exact[20:], axis=1).mean()
    forward.solve({})
    prior_error = np.linalg.norm(forward.positions(pre[20:]) - exact[20:], axis=1).mean()
    assert fitted_error < 0.3 * prior_error
    assert result.solves < 80
    forward.destroy()


def test_two_outliers_do_not_pull_the_fit(truth):
    """Two of 20 points mis-tracked by 10 mm: the soft-l1 loss keeps the fit within three
    standard deviations (those of the fit without the outliers) of the truth."""
    pre, measured, _, _ = truth
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, list(TRUTH), forward.heights())
    labels = [str(i) for i in range(20)]
    clean = fit(forward, Target(measured[:20], pre[:20], labels), params, noise=0.5e-3)
    measured = measured[:20].copy()
    measured[[3, 11]] += [0.0, 0.010, 0.0]
    robust = fit(forward, Target(measured, pre[:20], labels), params, noise=0.5e-3)
    for p, value, sd in zip(params, robust.values, clean.std):
        assert abs(value - TRUTH[p.name]) < 3.0 * sd, (p.name, value, sd)
    assert sorted(np.argsort(robust.residuals)[-2:]) == [3, 11]  # the outliers stand out
    forward.destroy()


def test_points_that_do_not_move_constrain_nothing():
    """Points on the occipital pin (held by the support) see no shift: level and G are
    reported as not constrained, not as confident numbers."""
    forward = ForwardModel(load_scene("brain", COARSE))
    surface, _ = gathered_outward_surface(forward.model.fluid.hydro.facets, forward.model.comm)
    pinned = np.unique(surface, axis=0)
    pinned = pinned[pinned[:, 1] < -0.0985][:15]
    params = fit_parameters(forward.scene, ["fluid.level", "material.G"], forward.heights())
    result = fit(forward, Target(pinned + 1e-4, pinned, [str(i) for i in range(len(pinned))]), params, noise=0.5e-3)
    assert result.constrained == [False, False]
    assert result.as_dict()["parameters"]["material.G"]["std"] is None
    forward.destroy()


def test_point_to_surface_on_the_cortex_recovers_the_level_and_stiffness(truth):
    """Points scanned on the true deformed cortex, with no correspondence: the level and G are
    found within their stated uncertainty, measured against the fine surface. (Against the
    10 mm voxel mesh's boundary, up to 8.7 mm off the cortex, the same points gave a level of
    -70 mm and G = 24 kPa, neither constrained.)"""
    _, _, _, scan = truth
    g = rotated_gravity([0.0, -9.81, 0.0], TRUTH)
    forward = ForwardModel(load_scene("brain", COARSE + [f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]"]))
    names = ["fluid.level", "material.G"]
    params = fit_parameters(forward.scene, names, forward.heights())
    result = fit(forward, Target(scan, None, [str(i) for i in range(len(scan))]), params, noise=0.5e-3)
    assert "fine surface" in forward.measured_surface
    assert result.constrained == [True, True]
    for name, value, sd in zip(names, result.values, result.std):
        assert abs(value - TRUTH[name]) < 3.0 * sd, (name, value, sd)
    assert result.as_dict()["residual_rms_mm"] < 0.8  # the noise's 0.5 mm per axis, along the normal
    forward.destroy()


def test_fit_command_writes_a_scene_that_runs_and_agrees_on_two_ranks(tmp_path, truth):
    pre, measured, _, _ = truth
    labels = [f"P{i}" for i in range(20)]
    write_markups(tmp_path / "pre.mrk.json", labels, pre[:20] * 1e3)
    write_markups(tmp_path / "intra.mrk.json", labels[::-1], measured[:20][::-1] * 1e3)  # order does not matter
    fits = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        command = [
            sys.executable,
            "-m",
            "fenics_brainshift.cli",
            "fit",
            "brain",
            "--target",
            str(tmp_path / "intra.mrk.json"),
            "--pre",
            str(tmp_path / "pre.mrk.json"),
            "--params",
            "fluid.level,material.G,gravity.angle_z",
            "--noise",
            "0.5",
            "--out",
            str(out),
            *[a for s in COARSE for a in ("--set", s)],
        ]
        if ranks > 1:
            command = mpirun() + ["-n", "2"] + command
        done = subprocess.run(command, capture_output=True, text=True, env=subprocess_env(), timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        assert "point-to-point, 20 points" in done.stdout
        fits[ranks] = json.loads((out / "fit.json").read_text())
        summary = json.loads((out / "summary.json").read_text())
        fitted = load_scene(out / "fitted.toml")
        assert fitted.material.G == pytest.approx(fits[ranks]["parameters"]["material.G"]["fitted"])
        assert fitted.output.folder == str(out.resolve())  # run again, it writes there, not over out_brain
        assert summary["status"] == "ok"
    for name, p in fits[1]["parameters"].items():
        assert fits[2]["parameters"][name]["fitted"] == pytest.approx(p["fitted"], rel=1e-4, abs=1e-4), name


@pytest.mark.parametrize(
    "args, words",
    [
        (["--params", "material.E"], "'material.E' cannot be fitted"),
        (["--params", "material.G,material.G"], "given twice"),
        (["--target", "missing.mrk.json"], "--target: no file"),
        (["--pre", "other.mrk.json"], "no namesake in --pre"),
        (["--noise", "0"], "--noise: 0 mm; a point's measurement noise is 0.01-50 mm"),
        (["--noise", "1e300"], "--noise: 1e+300 mm; a point's measurement noise"),
        (["--target", "metres.mrk.json"], "positions in metres?"),
        (["--pre", "twice.mrk.json"], "the label(s) a name more than one point"),
        (["--frame", "LPS"], "--frame is for a CSV or surface target"),
        (
            [
                "--target",
                "one_intra.mrk.json",
                "--pre",
                "one_pre.mrk.json",
                "--params",
                "fluid.level,material.G,gravity.angle_x,gravity.angle_z",
            ],
            "1 point pairs, 3 values each, cannot fit 4 parameters",
        ),  # (exit 0 with four "+-" values)
        (["--target", "garbage.csv", "--pre", None], "'garbage.csv' is not UTF-8 text"),  # (a traceback)
    ],
)
def test_bad_fit_input_is_one_line(tmp_path, capsys, args, words):
    from fenics_brainshift.cli import main

    points = np.array([[10.0, 40.0, 20.0], [-15.0, 50.0, 25.0]])  # mm, on the frontal lobe
    write_markups(tmp_path / "pre.mrk.json", ["a", "b"], points)
    write_markups(tmp_path / "other.mrk.json", ["c", "d"], points)
    write_markups(tmp_path / "intra.mrk.json", ["a", "b"], points + 1.0)
    write_markups(tmp_path / "metres.mrk.json", ["a", "b"], points * 1e-3)
    write_markups(tmp_path / "twice.mrk.json", ["a", "a"], points)
    write_markups(tmp_path / "one_pre.mrk.json", ["a"], points[:1])
    write_markups(tmp_path / "one_intra.mrk.json", ["a"], points[:1] + 1.0)
    (tmp_path / "garbage.csv").write_bytes(bytes(range(256)) * 4)
    base = {
        "--target": str(tmp_path / "intra.mrk.json"),
        "--pre": str(tmp_path / "pre.mrk.json"),
        "--params": "fluid.level",
        "--out": str(tmp_path / "out"),
    }
    for key, value in zip(args[::2], args[1::2]):
        if value is None:
            del base[key]
        else:
            base[key] = str(tmp_path / value) if key in ("--target", "--pre") else value
    argv = ["fit", "brain", *[a for kv in base.items() for a in kv], "--set", "mesh.voxel=0.01"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "fit.json").exists()


def test_a_damaged_vtk_target_is_one_line_on_the_terminal(tmp_path, capfd):
    """VTK's reader printed six coloured warnings of its own (to the C stderr, past Python's)
    before the one-line refusal."""
    from fenics_brainshift.cli import main

    (tmp_path / "garbage.vtk").write_bytes(b"# vtk DataFile Version 4.2\n" + bytes(range(256)) * 8)
    argv = [
        "fit",
        "cube",
        "--target",
        str(tmp_path / "garbage.vtk"),
        "--params",
        "material.G",
        "--no-run",
        "--out",
        str(tmp_path / "out"),
    ]
    assert main(argv) == 2
    err = capfd.readouterr().err.strip()
    assert "'garbage.vtk' could not be read as a surface" in err and len(err.splitlines()) == 1, err


@pytest.mark.mpi
def test_fit_slips_are_refused_alike_on_two_ranks(shared_tmp):
    """The fit's checks on 1 and 2 ranks (every rank raises the same InputError, none hangs):
    too few values for the parameters, a --pre point outside the body, a CSV that is not text,
    a NaN in a CSV target, and a Slicer CSV with a byte-order mark read as it should be."""
    from fenics_brainshift.errors import InputError
    from fenics_brainshift.images.targets import read_target

    points = np.array([[10.0, 40.0, 20.0], [-15.0, 50.0, 25.0]]) * 1e-3
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(
        forward.scene, ["fluid.level", "material.G", "gravity.angle_x", "gravity.angle_z"], forward.heights()
    )
    with pytest.raises(InputError, match="1 point pairs, 3 values each, cannot fit 4 parameters"):
        fit(forward, Target(points[:1] + 1e-3, points[:1], ["a"]), params, 0.5e-3)
    with pytest.raises(InputError, match=r"--pre: 1 point\(s\) \(b\) lie outside the body"):
        fit(forward, Target(points + 1e-3, points + [[0, 0, 0], [0, 0.3, 0]], ["a", "b"]), params[:1], 0.5e-3)
    forward.destroy()
    if MPI.COMM_WORLD.rank == 0:
        (shared_tmp / "garbage.csv").write_bytes(bytes(range(256)) * 4)
        (shared_tmp / "nan.csv").write_text("x, y, z\n10, 40, 20\nnan, 50, 25\n")
        (shared_tmp / "bom.csv").write_bytes("x,y,z\n10,40,20\n-15,50,25\n".encode("utf-8-sig"))
        (shared_tmp / "latin1.csv").write_bytes("label,x,y,z\npr\u00e4zentral,10,40,20\n".encode("latin-1"))
    MPI.COMM_WORLD.barrier()
    with pytest.raises(InputError, match="'garbage.csv' is not UTF-8 text"):
        read_target(shared_tmp / "garbage.csv")
    with pytest.raises(InputError, match=r"'latin1.csv' is not UTF-8 text \(byte 0xe4 at 14\): save it as UTF-8"):
        read_target(shared_tmp / "latin1.csv")  # (it said "not a text CSV file": it is one, in Latin-1)
    with pytest.raises(InputError, match="line 3: x = nan is not a finite number"):
        read_target(shared_tmp / "nan.csv")
    assert np.allclose(read_target(shared_tmp / "bom.csv").measured, points)  # (refused: "it has y, z, \ufeffx")


@pytest.mark.mpi
def test_in_place_stiffness_with_the_skull_equals_a_rebuilt_scene():
    """With skull contact each evaluation grows its loads from rest: G by scaled loads still
    equals a scene built with that G, and nothing passes the skull."""
    skull = ["skull.gap=0.003"]
    forward = ForwardModel(load_scene("brain", COARSE + skull))
    forward.solve({"material.G": 2000.0})
    forward.solve({"material.G": 3500.0})
    reference = _settled(load_scene("brain", COARSE + skull + ["material.G=3500"]))
    points = _surface_points(reference)[::7]
    ours = forward.positions(points)
    theirs = points + PointEvaluator(reference.model.mesh, points).values(reference.u)
    shift = np.abs(theirs - points).max()
    assert shift > 2e-3
    assert np.abs(ours - theirs).max() < 1e-3 * shift
    contact = forward.sim.contact
    assert contact.report(forward.sim.u)["max_penetration_m"] <= contact.tolerance
    forward.destroy()
    reference.destroy()


@pytest.mark.mpi  # (a fit's slip, refused alike on two ranks)
def test_a_parameter_on_its_bound_is_flagged_not_measured():
    """A true head turn of 45 degrees against the +-30 degree bound came back as 29.997 +- 8.5,
    "constrained"; it is now at its upper bound, with no standard deviation."""
    turned = dict(TRUTH, **{"gravity.angle_z": 45.0})
    sim = _settled(_true_scene(turned))
    surface = _surface_points(sim)
    pre = surface[surface[:, 1] > 0.03][::9][:20]
    measured = pre + PointEvaluator(sim.model.mesh, pre).values(sim.u)
    sim.destroy()
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, list(TRUTH), forward.heights())
    result = fit(forward, Target(measured, pre, [str(i) for i in range(len(pre))]), params, noise=0.5e-3)
    forward.destroy()
    entry = result.as_dict()["parameters"]["gravity.angle_z"]
    assert entry["at_bound"] == "upper" and entry["fitted"] == pytest.approx(30.0, abs=0.01)
    assert entry["constrained"] is False and entry["std"] is None


@pytest.mark.mpi  # (a fit's slip, refused alike on two ranks)
def test_a_fit_that_does_not_explain_the_data_says_so(truth):
    """Points 55 mm off (a frame slip) at a stated noise of 0.5 mm: a fitted scene with exit 0
    and no word; now a warning in fit.json and the report."""
    pre, measured, _, _ = truth
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, ["fluid.level", "material.G"], forward.heights())
    result = fit(
        forward, Target(measured[:20] + [0.055, 0.0, 0.0], pre[:20], [str(i) for i in range(20)]), params, noise=0.5e-3
    )
    assert "does not explain the data" in result.as_dict()["warning"]
    clean = fit(forward, Target(measured[:20], pre[:20], [str(i) for i in range(20)]), params, noise=0.5e-3)
    assert "warning" not in clean.as_dict()
    # another brain's shift, 3 mm per coordinate at a stated 1 mm: under 10x the noise (the old
    # rule said nothing), far past what the noise explains (a chi-square recomputed here)
    from scipy.stats import chi2

    other = measured[:20] + np.random.default_rng(4).normal(0.0, 3e-3, (20, 3))
    result = fit(forward, Target(other, pre[:20], [str(i) for i in range(20)]), params, noise=1e-3)
    rms = float(np.sqrt(np.mean(result.residuals**2)))
    assert rms < 10 * 1e-3
    assert chi2.sf(np.sum((result.residuals / 1e-3) ** 2), 3 * 20 - 2) < 1e-3
    assert "does not explain the data" in result.as_dict()["warning"] and "chi-square" in result.as_dict()["warning"]
    forward.destroy()


@pytest.mark.mpi  # (a fit's slip, refused alike on two ranks)
def test_pre_points_outside_the_body_are_refused(truth):
    """Points 30 mm above the cube had their shift extrapolated from the nearest cell, silently."""
    from fenics_brainshift.errors import InputError

    pre, measured, _, _ = truth
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, ["material.G"], forward.heights())
    away = pre[:10] + [0.0, 0.05, 0.0]  # 50 mm in front of the exposed cortex
    with pytest.raises(InputError, match=r"--pre: 10 point\(s\) .* lie outside the body"):
        fit(forward, Target(measured[:10], away, [f"P{i}" for i in range(10)]), params, noise=0.5e-3)
    forward.destroy()


@pytest.mark.mpi  # (a fit's slip, refused alike on two ranks)
@pytest.mark.parametrize("kind", ["point-to-point", "point-to-surface"])
def test_measurements_far_from_the_prediction_are_refused(truth, kind):
    """Measured points 150 mm off (the scanner's frame, not the image's) were fitted and came
    back as a warning at best; half of them past a quarter of the body from the prediction is
    a frame or unit slip, refused before the fit."""
    from fenics_brainshift.errors import InputError

    pre, measured, _, scan = truth
    forward = ForwardModel(load_scene("brain", COARSE))
    params = fit_parameters(forward.scene, ["material.G"], forward.heights())
    off = np.array([0.0, 0.0, 0.15])
    target = (
        Target(measured[:10] + off, pre[:10], [f"P{i}" for i in range(10)])
        if kind == "point-to-point"
        else Target(scan + off, None, [f"s{i}" for i in range(len(scan))])
    )
    with pytest.raises(InputError, match=r"--target: half the points lie more than .* mm from .*a frame or unit slip"):
        fit(forward, target, params, noise=0.5e-3)
    forward.destroy()
