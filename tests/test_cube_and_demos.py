"""The cube demo end to end: serial and mpirun give the same probe; outputs are readable."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from fenics_brainshift.cli import main
from fenics_brainshift.data import scene_path
from fenics_brainshift.scene import load_scene

from conftest import ROOT, mpirun, run_group, subprocess_env

pytestmark = pytest.mark.usefixtures("serial_only")


def _run(out, ranks: int, *cmd):
    cmd = [sys.executable, *cmd]
    if ranks > 1:
        cmd = mpirun() + cmd
    proc = run_group(cmd, 900, env=subprocess_env(), cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def _run_scene(out, ranks: int, *overrides):
    sets = [a for o in overrides for a in ("--set", o)]
    _run(out, ranks, "-m", "fenics_brainshift.cli", "run", str(scene_path("cube")), "--out", str(out), *sets)
    return json.loads((out / "summary.json").read_text())


def test_cube_scene_same_probe_on_one_and_two_ranks(tmp_path):
    overrides = ("mesh.cells=[10, 10, 5]", "time.end=1.0")
    one = _run_scene(tmp_path / "one", 1, *overrides)
    two = _run_scene(tmp_path / "two", 2, *overrides)
    assert (one["ranks"], two["ranks"]) == (1, 2)
    assert one["nodes"] == two["nodes"] == 11 * 11 * 6
    assert one["frame"] is None  # a box: no anatomy to mark in the pictures
    # the follower iteration stops at 1e-6 of |u| each step; one and two ranks (CHOLMOD and
    # MUMPS, other sums) stop at different iterates within that
    tol = 1e-6
    for key in ("top_centre",):
        a, b = np.array(one["probes"][key]), np.array(two["probes"][key])
        assert a[2] < -1e-4  # it sags
        assert np.abs(a - b).max() <= tol * np.abs(a).max()
    a, b = np.array(one["surfaces"]["top"]), np.array(two["surfaces"]["top"])
    assert np.abs(a - b).max() <= tol * np.abs(a).max()
    assert two["max_displacement_m"] == pytest.approx(one["max_displacement_m"], rel=tol)
    assert two["final_level_m"] == pytest.approx(one["final_level_m"], rel=1e-9)
    for key in (
        "dolfinx_version",
        "ranks",
        "nodes",
        "cells",
        "dofs",
        "steps",
        "setup_s",
        "step_s_median",
        "solve_s_total",
        "final_time",
        "max_displacement_m",
        "probes",
        "fluid_force_N",
        "gravity_force_N",
        "submerged_volume_m3",
        "final_level_m",
    ):
        assert key in one, key
    # the weight is exactly rho g V; the buoyancy is rho_oil g V_submerged, pointing up
    assert one["gravity_force_N"][2] == pytest.approx(-1048.0 * 9.81 * 0.05 * 0.05 * 0.025, rel=1e-12)
    # the oil's volume is conserved: V_oil = A (level - floor) - V_submerged, so the buoyancy
    # follows from the scene's volume and the level alone (Archimedes with the container)
    scene = load_scene("cube", list(overrides))
    submerged = 0.01 * (one["final_level_m"] - 0.0) - scene.fluid.volume(one["final_time"])
    assert submerged > 0
    assert one["fluid_force_N"][2] == pytest.approx(975.0 * 9.81 * submerged, rel=1e-9)
    assert np.abs(one["fluid_force_N"][:2]).max() <= 1e-9 * one["fluid_force_N"][2]


def test_cube_demo_figures_serial_and_mpi(tmp_path):
    args = ("--cells", "6x6x3", "--grids", "4x4x2", "6x6x3")
    outputs = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        stdout = _run(out, ranks, str(ROOT / "demos" / "cube.py"), "--out", str(out), *args)
        assert "top mean u_z" in stdout
        for name in ("fig6_top_vs_volume", "fig7_mesh_sizes"):
            assert (out / f"{name}.csv").is_file()
            png = (out / f"{name}.png").read_bytes()
            assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
        outputs[ranks] = np.loadtxt(out / "fig6_top_vs_volume.csv", delimiter=",", skiprows=1)
    fig6 = outputs[1]
    assert fig6[:, 0].tolist() == [175, 150, 125, 100, 75, 50, 25, 10]
    assert np.all(np.diff(fig6[:, 1]) < 0)  # the level falls
    assert np.all(np.diff(fig6[:, 2]) < 0)  # and the top sinks further each time
    np.testing.assert_allclose(outputs[2], outputs[1], rtol=1e-6, atol=1e-6)
    fig7 = np.loadtxt(tmp_path / "r1" / "fig7_mesh_sizes.csv", delimiter=",", skiprows=1)
    # the dynamic run settles onto the quasi-static answer of the same grid (6x6x3)
    np.testing.assert_allclose(fig6[1:, 2], fig7[1:, 2], rtol=1e-3)


def test_cube_outputs_open_in_meshio(tmp_path):
    import meshio

    summary = _run_scene(tmp_path / "o", 1, "mesh.cells=[6, 6, 3]", "time.end=0.2")
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "o" / "displacement.xdmf")) as reader:
        points, cells = reader.read_points_cells()
        times = []
        for k in range(reader.num_steps):
            t, point_data, cell_data = reader.read_data(k)
            times.append(t)
        assert {"displacement", "velocity"} <= set(point_data)
        assert "von_mises" in cell_data
    assert points.shape == (7 * 7 * 4, 3)
    assert times[0] == 0.0 and times[-1] == pytest.approx(0.2)
    u = point_data["displacement"]
    assert np.abs(u).max() == pytest.approx(summary["max_displacement_m"], rel=0.5)
    header = (tmp_path / "o" / "probes.csv").read_text().splitlines()[0].split(",")
    assert header == [
        "t",
        "level",
        "top_centre_x",
        "top_centre_y",
        "top_centre_z",
        "top_mean_x",
        "top_mean_y",
        "top_mean_z",
    ]
    csv = np.loadtxt(tmp_path / "o" / "probes.csv", delimiter=",", skiprows=1)
    assert csv[-1, 0] == pytest.approx(0.2)


def test_quasi_static_mode_matches_settled_dynamics(tmp_path):
    """With the load held, the damped dynamic answer settles onto the static one."""
    from test_scene_errors import write_scene

    from conftest import column_dict

    data = column_dict(8, 1, fluid={"density": 1000.0, "level": [[0.0, 0.05], [1.0, 0.05]]})
    static = write_scene(tmp_path / "s.toml", data)
    assert main(["run", str(static), "--out", str(tmp_path / "s")]) == 0
    dyn = dict(data, time={"mode": "dynamic", "dt": 0.01, "end": 3.0}, damping={"a": 20.0, "b": 0.0})
    dynamic = write_scene(tmp_path / "d.toml", dyn)
    assert main(["run", str(dynamic), "--out", str(tmp_path / "d")]) == 0
    s = json.loads((tmp_path / "s" / "summary.json").read_text())
    d = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert s["mode"] == "quasi-static" and s["steps"] == 2
    assert d["probes"]["top"][2] == pytest.approx(s["probes"]["top"][2], rel=1e-4)


def test_info_command(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "dolfinx" in out and "petsc" in out and "scalar_type" in out


def test_phantom_mesh_file_in_mm_sags_posteriorly(tmp_path):
    """demos/phantom.toml: a .msh in millimetres, supine gravity in RAS (-y)."""
    out = tmp_path / "ph"
    code = main(["run", str(scene_path("phantom")), "--out", str(out), "--set", "time.mode=quasi-static"])
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["mode"] == "quasi-static" and s["steps"] == 3  # one solve per level breakpoint
    assert 1000 < s["nodes"] < 1100  # meshes/phantom_ellipsoid_mm.msh, scaled to metres
    frontal = s["probes"]["frontal"]
    assert frontal[1] < -2e-3  # sinks towards posterior by millimetres
    assert abs(frontal[1]) > 5 * abs(frontal[0])
    # weight: rho g V along -y, V a little under the ellipsoid's 4/3 pi abc
    volume = -s["gravity_force_N"][1] / (1036.0 * 9.81)
    assert volume == pytest.approx(4 / 3 * np.pi * 0.07 * 0.085 * 0.06, rel=0.05)


def test_resection_demo_serial_and_mpi(tmp_path):
    """The resection demo on a coarse brain (10 mm voxels, 1 s steps): the lesion goes at 12 s,
    the run ends cleanly, the plot is written and 1 and 2 ranks agree."""
    quick = ("--set", "mesh.voxel=0.01", "--set", "time.dt=1.0")
    summaries = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        stdout = _run(out, ranks, str(ROOT / "demos" / "resection.py"), "--out", str(out), *quick)
        assert "removed" in stdout and (out / "cavity.png").stat().st_size > 10_000
        summaries[ranks] = json.loads((out / "summary.json").read_text())
    one, two = summaries[1], summaries[2]
    assert one["status"] == "ok" and one["removals"][0]["t"] == pytest.approx(12.0)
    assert one["removals"][0]["cells"] == two["removals"][0]["cells"] > 0
    assert one["removed_fraction"] == pytest.approx(two["removed_fraction"], rel=1e-12)
    for name in ("cavity_roof", "cavity_floor"):
        a, b = np.array(one["probes"][name]), np.array(two["probes"][name])
        assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max()  # the follower iteration tolerance


def test_resection_demo_with_skull_serial_and_mpi(tmp_path):
    """--skull 3: the skull, not the occipital pin, holds the brain through the drain and the
    resection (generalized-alpha); nothing passes it by more than the tolerance, it carries part
    of the net weight (the brain stem the rest) and 1 and 2 ranks agree."""
    quick = ("--skull", "3", "--set", "mesh.voxel=0.01", "--set", "time.dt=1.0")
    summaries = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        stdout = _run(out, ranks, str(ROOT / "demos" / "resection.py"), "--out", str(out), *quick)
        assert "skull: carries" in stdout
        summaries[ranks] = json.loads((out / "summary.json").read_text())
    one, two = summaries[1], summaries[2]
    assert one["status"] == "ok" and one["scheme"].startswith("generalized-alpha")
    assert one["removals"][0]["cells"] == two["removals"][0]["cells"] > 0
    for s in (one, two):
        contact = s["skull_contact"]
        assert 0 <= contact["max_penetration_m"] <= contact["tolerance_m"] and contact["pressed_nodes"] > 20
        net_weight = -(s["gravity_force_N"][1] + s["fluid_force_N"][1])  # along -y, N
        assert 0.2 * net_weight < contact["force_N"][1] < net_weight  # the skull pushes up (+y)
    # each step with contact settles to 1e-5 of |u|, and over 18 of them one and two ranks stop
    # at different iterates; two runs on two ranks alone differ by up to 8e-6 of it (the
    # partition and MUMPS's parallel factorisation are not repeatable bit for bit)
    a, b = (np.array(s["probes"]["cavity_roof"]) for s in (one, two))
    assert np.abs(a - b).max() <= 5e-5 * np.abs(a).max()


def test_hyperelastic_demo_serial_and_mpi(tmp_path):
    """Linear against neo-Hookean on a coarse brain: the soft linear brain has no equilibrium,
    the neo-Hookean one has; the linear runs past 5 % strain are flagged; 1 and 2 ranks agree."""
    import csv

    tables = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        _run(out, ranks, str(ROOT / "demos" / "hyperelastic.py"), "--voxel", "0.012", "--out", str(out))
        assert (out / "comparison.png").stat().st_size > 10_000
        with open(out / "comparison.csv") as f:
            tables[ranks] = {(r["case"], r["model"]): r for r in csv.DictReader(f)}
    one, two = tables[1], tables[2]
    assert one[("G = 500 Pa", "linear")]["status"] != "ok"
    assert all(one[(c, "neo-hookean")]["status"] == "ok" for c in ("G = 2370 Pa", "G = 500 Pa", "brain stem only"))
    assert one[("brain stem only", "linear")]["warning"] == "True"
    for key, row in one.items():
        if row["status"] == "ok":
            assert float(two[key]["max_mm"]) == pytest.approx(float(row["max_mm"]), rel=1e-6), key


def test_skull_demo_serial_and_mpi(tmp_path):
    """The brain held by the brain stem alone sags further without the skull than with it;
    with the skull nothing passes it; 1 and 2 ranks agree."""
    import csv

    tables = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        _run(out, ranks, str(ROOT / "demos" / "skull.py"), "--voxel", "0.012", "--out", str(out))
        assert (out / "comparison.png").stat().st_size > 10_000
        with open(out / "comparison.csv") as f:
            tables[ranks] = {r["case"]: r for r in csv.DictReader(f)}
    one, two = tables[1], tables[2]
    assert all(r["status"] == "ok" for r in one.values())
    free, held = one["brain stem only, no skull"], one["brain stem only, skull"]
    assert float(free["max_mm"]) > 1.3 * float(held["max_mm"])
    assert int(held["pressed_nodes"]) > 0 and float(held["penetration_um"]) <= 10.0  # the 1e-5 m tolerance
    for case, row in one.items():
        assert float(two[case]["max_mm"]) == pytest.approx(float(row["max_mm"]), rel=1e-4), case


def test_warp_demo_serial_and_mpi(tmp_path):
    """demos/warp.py on a coarse brain (10 mm voxels): the ICBM152 T1 (fetched from nilearn's
    wheel, or the cache) lies on the bundled brain (brighter inside its mask than around it),
    the predicted image has the T1's grid and differs where the brain moved, 1 and 2 ranks
    write the same image, and the picture is written."""
    import nibabel as nib

    from fenics_brainshift.data import MESHES
    from fenics_brainshift.data.templates import mni_t1

    t1 = nib.load(str(mni_t1()))
    mask = nib.load(str(MESHES / "mni152_brain_mask_2mm.nii.gz"))
    centres = np.argwhere(np.asarray(mask.dataobj) > 0) @ mask.affine[:3, :3].T + mask.affine[:3, 3]
    ijk = np.rint(centres @ np.linalg.inv(t1.affine)[:3, :3].T + np.linalg.inv(t1.affine)[:3, 3]).astype(int)
    data = np.asarray(t1.dataobj, dtype=float)
    assert data[tuple(ijk.T)].mean() > 3 * data.mean()  # the brain of the mask is the brain of the T1

    images = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        stdout = _run(out, ranks, str(ROOT / "demos" / "warp.py"), "--out", str(out), "--set", "mesh.voxel=0.01")
        assert "voxels moved" in stdout and (out / "warp.png").stat().st_size > 50_000
        assert (out / "warp.h5").stat().st_size > 1_000_000
        images[ranks] = nib.load(str(out / "t1_intra.nii.gz"))
    one, two = (np.asarray(images[r].dataobj) for r in (1, 2))
    assert np.array_equal(images[1].affine, t1.affine) and one.shape == data.shape
    assert np.array_equal(one, two)
    assert (one != np.asarray(t1.dataobj)).sum() > 100_000


def test_fit_demo(tmp_path):
    """demos/fit.py on a coarse brain: the fitted scene predicts the held-out points better
    than the scene, and the picture is written."""
    import re

    out = tmp_path / "fit"
    stdout = _run(out, 1, str(ROOT / "demos" / "fit.py"), "--out", str(out), "--set", "mesh.voxel=0.01")
    prior, fitted = map(float, re.search(r"mean error ([\d.]+) mm with the scene, ([\d.]+) mm fitted", stdout).groups())
    assert fitted < 0.5 * prior
    assert (out / "fit.png").stat().st_size > 10_000 and (out / "fitted.toml").is_file()


def test_update_demo(tmp_path):
    """demos/update.py on a coarse brain: the update's error against the full model's truth, at
    every node and in the deep tissue, is a fraction of the scene's; the picture is written."""
    import re

    out = tmp_path / "update"
    stdout = _run(out, 1, str(ROOT / "demos" / "update.py"), "--out", str(out), "--set", "mesh.voxel=0.01")
    for region in ("exposed cortex", "deep tissue below it", "every node"):
        prior, updated = map(float, re.search(rf"{region} +([\d.]+) +([\d.]+)", stdout).groups())
        assert updated < 0.3 * prior, region
    assert (out / "update.png").stat().st_size > 10_000 and (out / "update.json").is_file()


def test_update_demo_after_a_resection(tmp_path):
    """demos/update.py --resection on a coarse brain: near the cavity's wall the update across
    the atlas's stages (pairs and the wall's points) is nearer the full model's resected truth
    than the update without them (the pairs alone), and both far nearer than the prediction;
    the slice through the cavity is drawn."""
    import re

    out = tmp_path / "resection"
    stdout = _run(
        out, 1, str(ROOT / "demos" / "update.py"), "--resection", "--out", str(out), "--set", "mesh.voxel=0.01"
    )
    error = {
        name: float(re.search(rf"{name} +([\d.]+)", stdout).group(1))
        for name in ("prediction", "update, no stages", "update, stages")
    }
    assert error["update, stages"] < error["update, no stages"] < 0.5 * error["prediction"], error
    assert re.search(r"stage chosen [1-3] ", stdout)
    assert (out / "cavity.png").stat().st_size > 10_000 and (out / "update_stages" / "update.json").is_file()


def test_brain_demo_shrinks_the_brain_towards_its_supports(tmp_path):
    """--shrink 2: the whole brain loses 2 % of its volume over the drain; settled, the frontal
    pole (far from the occipital and brain-stem supports) moves further back (-y) than without,
    by about the shrinkage's own pull over its distance from the supports (2/3 % of ~0.17 m)."""
    poles = {}
    for shrink in ("0", "2"):
        out = tmp_path / f"s{shrink}"
        _run(
            out,
            1,
            str(ROOT / "demos" / "brain.py"),
            "--quasi-static",
            "--shrink",
            shrink,
            "--out",
            str(out),
            "--set",
            "mesh.voxel=0.012",
            "--set",
            "output.pictures=false",
        )
        poles[shrink] = np.array(json.loads((out / "summary.json").read_text())["probes"]["frontal_pole"])
    extra = poles["2"][1] - poles["0"][1]
    assert -2.0e-3 < extra < -0.5e-3, extra


def test_brain_demo_with_the_septa_holds_a_brain_lying_on_its_side(tmp_path):
    """--septa turns on the scene's falx and tentorium: lying on the right side the falx holds
    the midline, so the frontal pole moves far less than without (at 5 mm: 2.5 against 20.8 mm,
    benchmarks/results/septa_effect.md), and the demo says what each septum carries."""
    side = [
        "--set",
        "gravity.vector=[9.81, 0.0, 0.0]",
        "--set",
        "fluid.level=[[0.0, 0.08], [10.0, 0.02], [16.0, 0.02]]",
    ]
    poles, printed = {}, {}
    for flag in ([], ["--septa"]):
        out = tmp_path / ("septa" if flag else "none")
        printed[bool(flag)] = _run(
            out,
            1,
            str(ROOT / "demos" / "brain.py"),
            "--quasi-static",
            *flag,
            "--out",
            str(out),
            "--set",
            "mesh.voxel=0.012",
            "--set",
            "output.pictures=false",
            *side,
        )
        summary = json.loads((out / "summary.json").read_text())
        poles[bool(flag)] = np.linalg.norm(summary["probes"]["frontal_pole"])
    assert poles[True] < 0.3 * poles[False], poles
    assert "falx:" in printed[True] and "tentorium:" in printed[True] and "falx:" not in printed[False]
