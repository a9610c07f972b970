"""Slips a user makes that used to pass (exit 0 and a wrong answer, a traceback, or a message
naming the wrong fix): each is now one line naming the field and the likely slip, before
anything is written. Every row but the NaN gap failed on the code before its check."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fenics_brainshift.data import MESHES
from fenics_brainshift.errors import InputError
from fenics_brainshift.images import read_markups
from fenics_brainshift.images.targets import read_target
from fenics_brainshift.runner import Simulation, run
from fenics_brainshift.scene import load_scene, scene_from_dict

from conftest import COMM, subprocess_env

CUBE = {
    "name": "cube",
    "mesh": {"shape": "box", "size": [0.05, 0.05, 0.025], "cells": [4, 4, 2]},
    "material": {"E": 3000.0, "nu": 0.45},
    "fixed": [{"where": "z < 1e-9"}],
    "time": {"mode": "quasi-static"},
}


def _markups(path, position) -> str:
    path.write_text(
        json.dumps(
            {
                "markups": [
                    {
                        "type": "Fiducial",
                        "coordinateSystem": "LPS",
                        "controlPoints": [
                            {"label": "F-1", "position": [1.0, 2.0, 3.0]},
                            {"label": "F-2", "position": position},
                        ],
                    }
                ]
            }
        )
    )
    return str(path)


@pytest.mark.parametrize(
    "position, words",
    [
        (float("nan"), "no position of 3 numbers"),  # json writes NaN as a bare word Python reads back
        ([1.0, float("nan"), 3.0], "not finite"),
        ([1.0, float("inf"), 3.0], "not finite"),
        (["1", "2", "3"], "no position of 3 numbers"),
        ([1.0, 2.0], "no position of 3 numbers"),
    ],
)
def test_markups_whose_positions_are_not_three_finite_numbers(tmp_path, position, words):
    with pytest.raises(InputError, match=words):
        read_markups(_markups(tmp_path / "p.mrk.json", position), "--target")


@pytest.mark.parametrize(
    "document, words",
    [
        ({"markups": [1]}, "markups entry 0 is not an object"),
        ({"markups": ["x"]}, "markups entry 0 is not an object"),
        ({"markups": [{"controlPoints": [{"position": [10**400, 0, 0]}]}]}, "no position of 3 numbers"),
    ],
)
def test_markups_whose_structure_is_not_slicers(tmp_path, document, words):
    """Entries that are not objects raised an AttributeError, an integer past float range an
    OverflowError: tracebacks."""
    path = tmp_path / "p.mrk.json"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match=words):
        read_markups(path, "--target")


def test_a_point_never_placed_in_slicer_is_left_out_as_slicer_does(tmp_path, caplog):
    """Slicer lists a point that was added but never placed with "position": "" and
    positionStatus "undefined" (vtkMRMLMarkupsJsonStorageNode; "missing" for one skipped while
    placing, Slicer 5), and leaves it out when it reads the file; the whole file was refused
    ("no position of 3 numbers"). A file of none placed is."""
    points = [
        {"label": "F-1", "position": [1.0, 2.0, 3.0], "positionStatus": "defined"},
        {"label": "F-2", "position": "", "positionStatus": "undefined"},
        {"label": "F-3", "position": [4.0, 5.0, 6.0], "positionStatus": "defined"},
        {"label": "F-4", "position": "", "positionStatus": "missing"},
    ]  # (skipped: Slicer 5)
    import logging

    path = tmp_path / "p.mrk.json"
    path.write_text(json.dumps({"markups": [{"coordinateSystem": "LPS", "controlPoints": points}]}))
    logger = logging.getLogger("fenics_brainshift")  # (it does not propagate once the CLI configured it)
    logger.addHandler(caplog.handler)
    try:
        labels, ras = read_markups(path, "--target")
    finally:
        logger.removeHandler(caplog.handler)
    assert labels == ["F-1", "F-3"] and ras.tolist() == [[-1.0, -2.0, 3.0], [-4.0, -5.0, 6.0]]
    assert "2 control point(s) never placed" in caplog.text
    path.write_text(json.dumps({"markups": [{"coordinateSystem": "LPS", "controlPoints": points[1:2]}]}))
    with pytest.raises(InputError, match=r"holds no control points that were placed \(1 never placed\)"):
        read_markups(path, "--target")


@pytest.mark.parametrize(
    "rows, words",
    [
        ("x,y,z\n1,2,3\nnan,2,3\n", "line 3: x = nan is not a finite number"),
        ("x,y,z\n1,2,3\n1,inf,3\n", "line 3: y = inf is not a finite number"),
        ("x,y,z\n1,2,3\n1,2\n", "line 3: z is missing"),
        ("x,y,z\n1,2,3,4\n", "line 2 has more values than the header"),
        ("x,y,z\n1,two,3\n", "line 2: y is not a number"),
        ("x,y,z,x_pre,y_pre,z_pre\n1,2,3,1,2,\n", "line 2: z_pre is missing"),
    ],
)
def test_csv_targets_with_bad_rows(tmp_path, rows, words):
    """A NaN in a CSV target crashed inside PETSc (signal 11); short rows raised a TypeError."""
    path = tmp_path / "t.csv"
    path.write_text(rows)
    with pytest.raises(InputError, match=words):
        read_target(path)


@pytest.mark.mpi
@pytest.mark.parametrize(
    "override, words",
    [
        ("skull.gap=inf", "gap must be a positive distance"),
        ("skull.gap=nan", "gap must be a positive distance"),
        ("skull.gap=3", "gap = 3 m against a 0.075 m body"),
        ("skull.tolerance=0.5", "tolerance = 0.5 m would let the body pass 500 mm"),
        ("skull.tolerance=0.0005", "tolerance = 0.0005 m would let the body pass"),  # a tenth of the 3 mm gap at most
        ("mesh.size=[170.0, 170.0, 85.0]", "the body is 255 m across"),
        ("mesh.size=[0.0005, 0.0005, 0.0005]", "the body is 0.000866 m across"),
    ],
)
def test_absurd_values_are_refused_before_the_solve(override, words):
    data = json.loads(json.dumps(CUBE))
    data["skull"] = {"gap": 0.003}
    section, rest = override.split(".", 1)
    key, value = rest.split("=")
    data[section][key] = json.loads(value.replace("inf", "Infinity").replace("nan", "NaN"))
    if section == "mesh":
        del data["skull"]
    with pytest.raises(InputError, match=words):
        Simulation(scene_from_dict(data), COMM)


@pytest.mark.mpi
def test_a_mesh_file_in_mm_read_as_metres_names_the_unit():
    """The phantom's .msh in mm, declared m: a 0.17 km body, which used to end in "use [fluid]
    follower = false"."""
    data = dict(CUBE, mesh={"file": str(MESHES / "phantom_ellipsoid_mm.msh"), "unit": "m"}, fixed=[{"where": "z < 0"}])
    with pytest.raises(InputError, match=r"is it in mm\? give \[mesh\] unit = \"mm\""):
        Simulation(scene_from_dict(data), COMM)


@pytest.mark.mpi
def test_probe_names_keep_probes_csv_readable(shared_tmp):
    """A Slicer label with a comma or a line break split probes.csv's header."""
    data = dict(CUBE, probes={"A,1": [0.025, 0.025, 0.025], "B\n2": [0.0, 0.0, 0.025]})
    run(scene_from_dict(data), shared_tmp / "out", COMM)
    header = (shared_tmp / "out" / "probes.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["t", "level"] and "A_1_x" in header and "B_2_z" in header and len(header) == 8


@pytest.mark.parametrize(
    "nu, degree, warned", [(0.4999, 1, True), (0.499, 1, True), (0.4925, 1, False), (0.4999, 2, False)]
)
def test_p1_near_incompressibility_is_warned(nu, degree, warned):
    """P1 at nu = 0.4999999 made the paper's cube 57x too stiff with exit 0 and no word."""
    sim = Simulation(
        load_scene("cube", [f"material.nu={nu}", f"element.degree={degree}", "mesh.cells=[4, 4, 2]"]), COMM
    )
    assert bool(sim.plan.warnings) == warned
    if warned:
        assert "degree = 2" in sim.plan.warnings[0]


@pytest.mark.parametrize(
    "argv, words",
    [
        (
            ["fit", "cube", "--target", "t.csv", "--params", "material.G", "--noise", "inf"],
            "--noise: inf is not a finite",
        ),
        (
            ["fit", "cube", "--target", "t.csv", "--params", "material.G", "--noise", "nan"],
            "--noise: nan is not a finite",
        ),
        (["warp", "run", "--image", "x.nii.gz", "-o", "y.nii.gz", "--blend", "inf"], "--blend: inf is not a finite"),
        (["warp", "run", "--image", "x.nii.gz", "-o", "y.nii.gz", "--blend", "nan"], "--blend: nan is not a finite"),
        # compare ran on and wrote NaN into compare.json, or blamed --search
        (["compare", "a.stl", "b.stl", "c.stl", "--radius", "nan"], "--radius: nan is not a finite"),
        (["compare", "a.stl", "b.stl", "c.stl", "--depth", "inf"], "--depth: inf is not a finite"),
        (["compare", "a.stl", "b.stl", "c.stl", "--up", "nan", "1", "0"], "--up: nan is not a finite"),
        (["compare", "a.stl", "b.stl", "c.stl", "--roi", "nan", "1", "0", "1"], "--roi: nan is not a finite"),
        (["mesh", "m.nii.gz", "--voxel", "inf"], "--voxel: inf is not a finite"),
        (["update", "atlas", "--target", "t.csv", "--noise", "nan"], "--noise: nan is not a finite"),
    ],
)
def test_command_line_numbers_that_are_not_finite(tmp_path, monkeypatch, capsys, argv, words, serial_only):
    """Every number of every command, before anything is read or written."""
    from fenics_brainshift.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.csv").write_text("x,y,z\n1,2,3\n")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1


def _interrupt_at(monkeypatch, number: int) -> None:
    """Ctrl-C (KeyboardInterrupt) in the run's time step ``number``."""
    from fenics_brainshift.runner.simulation import Simulation as Sim

    original, calls = Sim.step, {"n": 0}

    def step(self):
        calls["n"] += 1
        if calls["n"] == number:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(Sim, "step", step)


def test_ctrl_c_keeps_the_last_good_state_says_interrupted_and_exits_130(tmp_path, monkeypatch, capsys, serial_only):
    """Ctrl-C printed a 30-line traceback and left no summary.json, or the earlier run's "ok"."""
    from fenics_brainshift.cli import main

    out = tmp_path / "out"
    args = ["run", "cube", "--out", str(out), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.dt=0.1"]
    assert main(args + ["--set", "time.end=0.5"]) == 0  # a complete run first, into the same folder
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    _interrupt_at(monkeypatch, 4)
    assert main(args + ["--set", "time.end=2.0"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("brainshift: interrupted (Ctrl-C); the last good state, t = 0.3 s")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["final_time"] == pytest.approx(0.3)
    times = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1)[:, 0]
    assert times[-1] == pytest.approx(0.3)  # the new run's rows only


@pytest.mark.mpi
def test_a_re_run_clears_the_earlier_runs_files_and_only_those(shared_tmp):
    """A fine-surface series of an earlier, longer run survived a re-run (ParaView's series then
    mixed two runs); the user's own files stay."""
    out = shared_tmp / "out"
    if COMM.rank == 0:
        out.mkdir()
        for name in ("surface_0007.vtk", "surface_0007.stl", "deformed.png", "notes.txt"):
            (out / name).write_text("earlier")
    COMM.barrier()
    run(scene_from_dict(CUBE), out, COMM)
    assert not any((out / n).exists() for n in ("surface_0007.vtk", "surface_0007.stl", "deformed.png"))
    assert (out / "notes.txt").read_text() == "earlier"
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    # the last state saved whole (gathered from every rank) is the XDMF's last state
    from fenics_brainshift.outputs.run_folder import read_last_state, read_saved_state

    points, tets, u, _ = read_last_state(out / "displacement.xdmf")
    saved_points, saved_tets, saved_u, _, _ = read_saved_state(out)
    order = np.lexsort(np.round(points, 9).T[::-1])
    np.testing.assert_allclose(saved_points, points[order], atol=1e-12)
    np.testing.assert_allclose(saved_u, u[order], atol=1e-15)
    row = np.argsort(order)  # the XDMF's vertex -> its saved row
    assert {tuple(sorted(c)) for c in saved_tets} == {tuple(sorted(c)) for c in row[tets]}


def test_a_second_run_into_a_folder_in_use_is_refused(tmp_path, capsys, serial_only):
    """Two runs into one --out interleaved their files; the second is refused, naming the
    first's process, and touches nothing. A run killed with SIGKILL leaves no stale lock."""
    import fcntl
    import signal
    import subprocess
    import sys

    from fenics_brainshift.cli import main

    out = tmp_path / "out"
    args = ["run", "cube", "--out", str(out), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.mode=quasi-static"]
    assert main(args) == 0
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"""
import fcntl, os, sys, time
f = open({str(out / ".brainshift.lock")!r}, "a+")
fcntl.flock(f, fcntl.LOCK_EX)
f.truncate(0); f.write("pid %d" % os.getpid()); f.flush()
print("held", flush=True)
time.sleep(60)
""",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        last = err.splitlines()[-1]  # (after the run's log lines)
        assert f"another brainshift process (pid {holder.pid}) is writing into it" in last and "Traceback" not in err
        assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before  # nothing touched
        from conftest import mpirun  # and on two ranks: one line, from rank 0

        done = subprocess.run(
            mpirun() + [sys.executable, "-m", "fenics_brainshift.cli"] + args,
            capture_output=True,
            text=True,
            env=subprocess_env(),
            timeout=300,
        )
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
        assert done.stderr.count(f"another brainshift process (pid {holder.pid}) is writing into it") == 1
        assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert main(args) == 0  # the killed holder's lock went with it
    with open(out / ".brainshift.lock") as f:  # and a finished run holds none
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)


@pytest.mark.parametrize(
    "message, is_write",
    [
        ("Failed to write HDF5 local dataset into hyperslab.", True),  # DOLFINx 0.5's HDF5Interface
        ("Failed to create HDF5 file.", True),
        ("Could not write VTKFile. Does the directory exists and do you have read/write permissions?", True),
        ("itk::ERROR: ImageFileWriter(0x55d1): Error writing out.nii.gz", True),
        ("Cannot write sub-Functions to VTK file.", False),  # a program's error: a traceback
        ("Write mesh before function!", False),
        ("Newton solver did not converge because maximum number of iterations reached", False),
    ],
)
def test_only_a_writer_failing_is_called_a_file_not_written(message, is_write):
    """The terminal's "a file could not be written" is for a full disk or a folder gone, not
    for every error whose text mentions writing."""
    from fenics_brainshift.errors import write_failed

    assert write_failed(RuntimeError(message)) is is_write


@pytest.mark.parametrize("raised", ["OSError", "RuntimeError"])
def test_a_full_disk_mid_run_is_one_line_and_never_ok(tmp_path, monkeypatch, capsys, serial_only, raised):
    """No space left while writing the fields: a traceback before; now one line naming the file,
    exit 1, and the folder's summary says "running" (not an earlier run's "ok"). DOLFINx's
    HDF5 writer says it with a RuntimeError, not an OSError (a real 64 KB tmpfs: a traceback)."""
    import errno

    from fenics_brainshift.cli import main
    from fenics_brainshift.outputs.xdmf import FieldWriter

    out = tmp_path / "out"
    args = ["run", "cube", "--out", str(out), "--set", "mesh.cells=[4, 4, 2]", "--set", "time.mode=quasi-static"]
    assert main(args) == 0

    def full(self, *a, **k):
        if raised == "OSError":
            raise OSError(errno.ENOSPC, "No space left on device", str(out / "displacement.h5"))
        raise RuntimeError(f"Failed to write HDF5 global dataset to {out / 'displacement.h5'}\nmore lines")

    monkeypatch.setattr(FieldWriter, "write", full)
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    last = err.splitlines()[-1]  # (after the run's log lines)
    words = "No space left on device" if raised == "OSError" else "a file could not be written (Failed to write HDF5"
    assert words in last and "displacement.h5" in last and "Traceback" not in err
    assert json.loads((out / "summary.json").read_text())["status"] == "running"


def test_a_fit_never_mixes_with_what_its_folder_held(tmp_path, capsys, serial_only):
    """`fit --no-run` into an earlier fit's folder left the new fit.json and fitted.toml beside
    the old fitted run (its "ok" summary and its displacement: warp would warp the old fit), and
    wrote before taking the folder's lock; a later `run` into the folder left the fit's files
    beside its own. Now the fit clears the folder's run and earlier fit under the lock (but the
    scene it fits: a fitted.toml fitted again where it lies), `run OUT/fitted.toml` runs where
    it was fitted, and any other run into a fit's folder is refused (a copy of fitted.toml
    carries the folder: removing the fit would lose it)."""
    import shutil

    from fenics_brainshift.cli import main

    out = tmp_path / "F"
    small = ["--set", "mesh.cells=[4, 4, 2]", "--set", "time.mode=quasi-static"]
    assert main(["run", "cube", "--out", str(out)] + small) == 0  # an earlier run in the folder
    pre = np.array([[25.0, 25.0, 25.0], [10.0, 10.0, 25.0], [40.0, 40.0, 25.0], [10.0, 40.0, 25.0]])
    rows = ["x,y,z,x_pre,y_pre,z_pre"] + [",".join(f"{v:g}" for v in [*(p - [0, 0, 2.0]), *p]) for p in pre]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    fit = [
        "fit",
        "cube",
        "--target",
        str(tmp_path / "t.csv"),
        "--params",
        "material.G",
        "--noise",
        "0.5",
        "--out",
        str(out),
        "--no-run",
    ] + small
    assert main(fit) == 0
    assert not (out / "displacement.xdmf").exists() and not (out / "probes.csv").exists()
    assert json.loads((out / "summary.json").read_text())["kind"] == "fit"
    assert load_scene(out / "fitted.toml").material.G != load_scene("cube").material.G  # the new fit's
    assert "material.G" in json.loads((out / "fit.json").read_text())["parameters"]
    assert main(["run", str(out / "fitted.toml")]) == 0  # into its own folder: the fit stays
    assert (out / "fitted.toml").exists() and (out / "fit.json").exists()
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    refit = ["fit", str(out / "fitted.toml")] + fit[2:]  # fitted again where it lies (it was deleted first)
    assert main(refit) == 0 and load_scene(out / "fitted.toml").material.G > 0
    shutil.copy(out / "fitted.toml", tmp_path / "variant.toml")  # [output] folder = F
    capsys.readouterr()
    for other in (["run", str(tmp_path / "variant.toml")], ["run", "cube", "--out", str(out)] + small):
        before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
        assert main(other) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert f"--out '{out}' holds a fit (fit.json): run its fitted.toml there, choose another --out, or " in err[-1]
        assert {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.name != ".brainshift.lock"} == {
            k: v for k, v in before.items() if k != ".brainshift.lock"
        }
    assert main(["run", "cube", "--out", str(out), "--overwrite"] + small) == 0  # asked for: the fit goes
    assert not (out / "fit.json").exists() and not (out / "fitted.toml").exists()


def _stl(path, triangles) -> str:
    """A binary STL of the given triangles (T, 3, 3), none for an empty file."""
    import meshio

    t = np.asarray(triangles, dtype=float).reshape(-1, 3, 3)
    meshio.write(
        str(path), meshio.Mesh(t.reshape(-1, 3), [("triangle", np.arange(3 * len(t)).reshape(-1, 3))]), binary=True
    )
    return str(path)


@pytest.mark.parametrize(
    "triangles, words",
    [
        ([], "holds no triangles"),
        ([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]] * 4, "holds no triangle with an area"),
    ],
)
def test_empty_or_degenerate_surfaces_are_one_line_as_skull_or_target(tmp_path, capsys, triangles, words, serial_only):
    """A skull or a measured surface with no facets, or only zero-area ones: one line naming the
    file, exit 2, nothing written."""
    from fenics_brainshift.cli import main

    surface = _stl(tmp_path / "s.stl", triangles)
    out = tmp_path / "out"
    small = ["--set", "mesh.cells=[4, 4, 2]", "--set", "time.mode=quasi-static"]
    for argv in (
        ["run", "cube", "--out", str(out), "--set", f"skull.file={surface}"] + small,
        ["fit", "cube", "--target", surface, "--params", "material.G", "--out", str(out)] + small,
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and "s.stl" in err[0], err
        assert not out.exists()


def test_a_full_disk_during_fit_is_one_line_and_never_ok(tmp_path, monkeypatch, capsys, serial_only):
    """No space left while the fit writes fit.json: one line naming the file, exit 1; the
    folder's summary says "running" (the fit cleared it first), not an earlier run's "ok"."""
    import errno

    from fenics_brainshift.cli import main
    from fenics_brainshift.fit import report as command

    out = tmp_path / "F"
    small = ["--set", "mesh.cells=[4, 4, 2]", "--set", "time.mode=quasi-static"]
    assert main(["run", "cube", "--out", str(out)] + small) == 0
    (tmp_path / "t.csv").write_text(
        "x,y,z,x_pre,y_pre,z_pre\n25,25,23,25,25,25\n10,10,23,10,10,25\n40,40,23,40,40,25\n"
    )

    def full(out_folder, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(out_folder / "fit.json"))

    monkeypatch.setattr(command, "write_fit_json", full)
    capsys.readouterr()
    assert (
        main(["fit", "cube", "--target", str(tmp_path / "t.csv"), "--params", "material.G", "--out", str(out)] + small)
        == 1
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert "No space left on device" in err[-1] and "fit.json" in err[-1] and not any("Traceback" in e for e in err)
    assert json.loads((out / "summary.json").read_text())["status"] == "running"
    assert not (out / "displacement.xdmf").exists()


def test_a_run_killed_by_sigkill_leaves_its_last_complete_state_readable(tmp_path, serial_only):
    """A run killed without warning (the out-of-memory killer, a power cut) left displacement.h5
    unreadable, and with it the last good state. Now last_state.npz holds the latest complete
    state: the same, to round-off, as a run that ends at that time writes in its XDMF, and
    `warp` takes it, saying the run was killed and when."""
    import signal
    import subprocess
    import sys
    import time

    import meshio

    from fenics_brainshift.outputs.run_folder import read_saved_state
    from fenics_brainshift.warp.deformed import DeformedMesh, killed_run_time

    killed = tmp_path / "killed"
    scene = ["cube", "--set", "mesh.cells=[4, 4, 2]", "--set", "time.dt=0.01", "--set", "output.pictures=false"]
    command = [sys.executable, "-m", "fenics_brainshift.cli", "run", *scene, "--set", "time.end=100", "--out"]
    process = subprocess.Popen([*command, str(killed)], env=subprocess_env(), stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if read_saved_state(killed)[4] >= 0.2:
                    break
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
    assert json.loads((killed / "summary.json").read_text())["status"] == "running"
    t = killed_run_time(killed)
    assert t is not None and t >= 0.2
    # the same scene run to that time and ended normally: its XDMF's last state
    whole = tmp_path / "whole"
    subprocess.run([*command[:-2], f"time.end={t!r}", "--out", str(whole)], env=subprocess_env(), check=True)
    with meshio.xdmf.TimeSeriesReader(str(whole / "displacement.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        when, data, _ = reader.read_data(reader.num_steps - 1)
    assert when == pytest.approx(t)
    saved = DeformedMesh.from_run(killed)
    order = np.lexsort(np.round(points, 9).T[::-1])
    np.testing.assert_allclose(saved.points, 1e3 * points[order], atol=1e-9)  # (saved sorted so)
    np.testing.assert_allclose(saved.displacement, 1e3 * data["displacement"][order], atol=1e-9)
    assert np.abs(saved.displacement).max() > 0.5  # a state that moved (mm)


@pytest.mark.mpi
def test_the_saved_last_state_of_a_resection_keeps_the_cells_that_are_left(shared_tmp):
    """last_state.npz gathered the tissue flags in the ranks' cell order and the tetrahedra in
    the stored one: a killed resection run's warp dropped the wrong cells. The cells it keeps are
    the XDMF's (matched by their centroids), on one rank and on two."""
    from fenics_brainshift.outputs.run_folder import read_last_state, read_saved_state

    from conftest import column_dict

    data = column_dict(4, time={"mode": "dynamic", "dt": 0.01, "end": 0.03}, remove=[{"at": 0.0, "where": "z > 0.075"}])
    out = shared_tmp / "out"
    run(scene_from_dict(data), out, COMM)

    def kept(points, tets, tissue):
        centroids = points[tets[np.asarray(tissue) >= 0.5]].mean(axis=1)
        return set(map(tuple, np.round(centroids * 1e9).astype(np.int64)))

    series = kept(*(lambda p, t, u, tissue: (p, t, tissue))(*read_last_state(out / "displacement.xdmf")))
    points, tets, _, tissue, _ = read_saved_state(out)
    assert tissue is not None and 0 < int((tissue < 0.5).sum()) < len(tets)
    assert kept(points, tets, tissue) == series
