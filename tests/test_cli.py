"""The command line: every subcommand through main([...]), its outputs and its error paths,
and the pictures a run makes (produced, and not blank)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_scene_errors import write_scene

from fenics_brainshift.cli import main
from fenics_brainshift.data import MESHES, scene_path

from conftest import column_dict, subprocess_env

pytestmark = pytest.mark.usefixtures("serial_only")


def _not_blank(path) -> None:
    import matplotlib.image

    image = matplotlib.image.imread(str(path))
    assert image.ndim == 3 and min(image.shape[:2]) >= 300
    assert image[..., :3].std() > 0.05, f"{path} is (nearly) one colour"
    assert len(np.unique(image[..., :3].reshape(-1, 3), axis=0)) > 50, f"{path} has almost no content"


def test_info_lists_versions_and_extras(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for key in ("dolfinx", "petsc", "scalar_type", "mpi", "mumps", "blas", "extra pyvista", "extra tqdm"):
        assert key in out, key


def test_help_explains_every_subcommand(capsys):
    for command in ("run", "mesh", "compare", "bench", "info"):
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"])
        assert exit_info.value.code == 0
        assert "usage: brainshift" in capsys.readouterr().out


def test_run_with_pictures(tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(
            [
                "--no-progress",
                "run",
                str(scene_path("cube")),
                "--out",
                str(out),
                "--pictures",
                "--set",
                "mesh.cells=[6, 6, 3]",
                "--set",
                "time.end=0.5",
            ]
        )
        == 0
    )
    assert "max |u|" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["gravity_vector"] == [0.0, 0.0, -9.81]
    for name in ("deformed.png", "probes.png"):
        _not_blank(out / name)


def test_pictures_of_a_resection_leave_the_removed_cells_out(tmp_path):
    from fenics_brainshift.outputs.run_folder import read_last_state

    data = column_dict(
        4,
        time={"mode": "dynamic", "dt": 0.01, "end": 0.03},
        remove=[{"at": 0.0, "where": "z > 0.075"}],
        output={"pictures": True},
    )
    scene = write_scene(tmp_path / "scene.toml", data)
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 0
    points, tets, u, tissue = read_last_state(tmp_path / "out" / "displacement.xdmf")
    assert tissue is not None and 0 < np.count_nonzero(tissue < 0.5) < len(tets)
    _not_blank(tmp_path / "out" / "deformed.png")


def test_bench_smoke_writes_table_csv_and_pareto_plot(tmp_path, capsys):
    assert main(["--log-level", "WARNING", "bench", "--scene", "cube", "--smoke", "--out", str(tmp_path)]) == 0
    assert "bench cube" in capsys.readouterr().out
    rows = list(csv.DictReader(open(tmp_path / "time_vs_error_cube.csv")))
    names = [r["config"] for r in rows]
    assert "paper-equivalent" in names and "naive loop" in names
    for r in rows:
        assert float(r["total_s"]) > 0 and float(r["max_error_mm"]) >= float(r["rms_error_mm"]) >= 0
    p2 = next(r for r in rows if r["config"].startswith("P2"))
    p1 = next(r for r in rows if r["config"].startswith("P1"))
    assert float(p2["max_error_mm"]) < float(p1["max_error_mm"])  # P2 is closer to the P2 reference

    # --only re-runs one configuration and keeps the others' rows exactly as they were
    marked = [dict(r) for r in rows]
    for r in marked:
        r["total_s"] = "1234.5"  # a value no run measures
    with open(tmp_path / "time_vs_error_cube.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(marked[0]))
        writer.writeheader()
        writer.writerows(marked)
    assert (
        main(
            [
                "--log-level",
                "WARNING",
                "bench",
                "--scene",
                "cube",
                "--smoke",
                "--out",
                str(tmp_path),
                "--only",
                p1["config"],
            ]
        )
        == 0
    )
    again = {r["config"]: r for r in csv.DictReader(open(tmp_path / "time_vs_error_cube.csv"))}
    assert list(again) == names
    assert float(again[p1["config"]]["total_s"]) != 1234.5
    assert all(float(r["total_s"]) == 1234.5 for name, r in again.items() if name != p1["config"])
    assert (
        main(
            [
                "--log-level",
                "WARNING",
                "bench",
                "--scene",
                "cube",
                "--smoke",
                "--out",
                str(tmp_path),
                "--only",
                "P9 nothing",
            ]
        )
        == 2
    )
    table = (tmp_path / "time_vs_error_cube.md").read_text()
    assert "| configuration |" in table and "*" in table  # the Pareto front is marked
    _not_blank(tmp_path / "time_vs_error_cube.png")


BRAIN_MASK, BRAIN_SURFACE = MESHES / "mni152_brain_mask_2mm.nii.gz", MESHES / "mni152_brain_surface.ply"


def _subcommand_failures(tmp: Path) -> list[tuple[list[str], str]]:
    """(argv, what the one-line error must say) for each kind of failure of each subcommand
    but `run` (whose table is in test_scene_errors.py)."""
    (tmp / "a_file").write_text("not a folder")
    (tmp / "garbage.stl").write_text("solid x\nnot a surface\n")
    return [
        (["mesh", str(tmp / "missing.nii.gz"), "--voxel", "5", "-o", str(tmp / "m.xdmf")], "mesh: input"),
        (["mesh", str(tmp / "a_file"), "-o", str(tmp / "m.xdmf")], "use a label volume"),
        (["mesh", str(BRAIN_MASK), "--voxel", "-1", "-o", str(tmp / "m.xdmf")], "--voxel and --scale must be > 0"),
        (["mesh", str(BRAIN_MASK), "--fill", "2", "-o", str(tmp / "m.xdmf")], "--fill must be in [0, 1]"),
        (["mesh", str(BRAIN_MASK), "--parts", "0", "-o", str(tmp / "m.xdmf")], "--parts must be >= 1"),
        (["mesh", str(BRAIN_MASK), "-o", str(tmp / "m.vtk")], "must end in .xdmf"),
        (["mesh", str(BRAIN_MASK), "-o", str(tmp / "a_file" / "m.xdmf")], "folder of -o"),
        # a folder that refuses even root, who passes every permission check
        (["mesh", str(BRAIN_MASK), "--voxel", "20", "-o", "/proc/nope/brain.xdmf"], "cannot be written"),
        (["run", "cube", "--out", "/proc/nope"], "cannot be written"),
        # metres given for a millimetre surface: a grid of 10^13 voxels
        (
            ["mesh", str(BRAIN_SURFACE), "--voxel", "0.005", "-o", str(tmp / "m.xdmf")],
            "is the voxel size in the right unit?",
        ),
        (
            ["mesh", str(BRAIN_MASK), "--voxel", "0.005", "-o", str(tmp / "m.xdmf")],
            "is the voxel size in the right unit?",
        ),
        (["mesh", str(tmp / "garbage.stl"), "-o", str(tmp / "m.xdmf")], "could not be read as a surface"),
        (
            ["compare", str(tmp / "a.stl"), str(BRAIN_SURFACE), str(BRAIN_SURFACE), "-o", str(tmp / "c.json")],
            "compare: '",
        ),
        (
            [
                "compare",
                str(BRAIN_SURFACE),
                str(BRAIN_SURFACE),
                str(BRAIN_SURFACE),
                "--radius",
                "0",
                "-o",
                str(tmp / "c.json"),
            ],
            "must be > 0",
        ),
        (
            [
                "compare",
                str(BRAIN_SURFACE),
                str(BRAIN_SURFACE),
                str(BRAIN_SURFACE),
                "-o",
                str(tmp / "a_file" / "c.json"),
            ],
            "folder of -o",
        ),
        (
            ["compare", str(tmp / "garbage.stl"), str(BRAIN_SURFACE), str(BRAIN_SURFACE), "-o", str(tmp / "c.json")],
            "could not be read as a surface",
        ),
        # the default --scales take SIM in metres: a mm SIM is 1000x the others (it said "raise --search")
        (
            ["compare", str(BRAIN_SURFACE), str(BRAIN_SURFACE), str(BRAIN_SURFACE), "-o", str(tmp / "c.json")],
            "compare: SIM is 284 m across against the others' 0.284 m with --scales 0.001 0.001 1: is its scale 0.001?",
        ),
        (["bench", "--scene", "cube", "--smoke", "--out", str(tmp / "a_file")], "is an existing file"),
        (
            ["bench", "--scene", "cube", "--smoke", "--out", str(tmp / "b"), "--only", "P9 nothing"],
            "--only: no configuration named 'P9 nothing'",
        ),
        (["run", "no-such-scene"], "scene file 'no-such-scene' not found"),
    ]


def test_every_subcommand_fails_with_one_line_and_writes_nothing(tmp_path, capsys, serial_only):
    for argv, expected in _subcommand_failures(tmp_path):
        before = sorted(p.name for p in tmp_path.rglob("*"))
        assert main(["--log-level", "WARNING", *argv]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert expected in err and len(err.splitlines()) == 1 and "Traceback" not in err, (argv, err)
        assert sorted(p.name for p in tmp_path.rglob("*")) == before, argv  # nothing written


def test_compiler_command_lines_stay_out_of_the_terminal(tmp_path, serial_only):
    """A fresh form cache compiles C; the gcc lines must not reach a user of the Python API."""
    env = {**subprocess_env(), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    code = (
        "from fenics_brainshift import load_scene, run; "
        "run(load_scene('cube', ['mesh.cells=[2, 2, 1]', 'time.mode=quasi-static']))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "gcc" not in proc.stdout + proc.stderr and "build_ext" not in proc.stdout + proc.stderr
    assert list((tmp_path / "cache").rglob("*.so")), "nothing was compiled: the test did not test"


def test_unknown_subcommand_and_bad_flag_are_one_line_naming_the_help(capsys):
    """argparse printed its whole usage before the error; now one line, as every input error."""
    for argv, words in (
        (["fly"], "invalid choice: 'fly'"),
        (["run"], "required: scene"),
        (["bench", "--scene", "moon"], "(see brainshift bench --help)"),
        (["run", "cube", "--bogus"], "unrecognized arguments: --bogus"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("brainshift: error: ") and words in err[0], err


def test_progress_bar_only_on_a_terminal_or_when_asked(monkeypatch):
    from fenics_brainshift.outputs import progress as prog

    monkeypatch.setattr(prog, "ENABLED", None)
    monkeypatch.setattr("sys.stderr.isatty", lambda: False, raising=False)
    quiet = prog.progress(range(3), "x")
    assert list(quiet) == [0, 1, 2] and type(quiet).__name__ == "_Silent"
    monkeypatch.setattr(prog, "ENABLED", True)
    bar = prog.progress(range(3), "x")
    assert type(bar).__name__ == "tqdm" and list(bar) == [0, 1, 2]
    bar.set_postfix_str("t=1 s")
    bar.close()
    monkeypatch.setattr(prog, "ENABLED", False)
    assert type(prog.progress(range(3), "x")).__name__ == "_Silent"


def test_help_says_each_default_once_and_prints_percent_as_percent(capsys, serial_only):
    """`brainshift bench --help` showed "(default: False)" for flags, "(default: None)", and
    compare's "Error %%" (argparse formats help strings, not descriptions)."""
    for command in ("run", "mesh", "warp", "fit", "atlas", "update", "compare", "bench"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "%%" not in text and "(default: False)" not in text and "(default: None)" not in text, command
        assert "(default: [])" not in text, command
        for option in text.split(" --")[1:]:
            assert option.count("default") <= 1, (command, option)
