"""The command line: every subcommand through main([...]), its outputs and its error paths,
and the pictures a run makes (produced, and not blank)."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from conftest import ROOT, column_dict
from fenics_brainshift.data import MESHES
from fenics_brainshift.data import scene_path
from fenics_brainshift.cli import main
from test_scene_errors import write_scene

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
    assert main(["--no-progress", "run", str(scene_path("cube")), "--out", str(out), "--pictures",
                 "--set", "mesh.cells=[6, 6, 3]", "--set", "time.end=0.5"]) == 0
    assert "max |u|" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["gravity_vector"] == [0.0, 0.0, -9.81]
    for name in ("deformed.png", "probes.png"):
        _not_blank(out / name)


def test_pictures_of_a_resection_leave_the_removed_cells_out(tmp_path):
    from fenics_brainshift.outputs.pictures import read_last_state

    data = column_dict(4, time={"mode": "dynamic", "dt": 0.01, "end": 0.03},
                       remove=[{"at": 0.0, "where": "z > 0.075"}], output={"pictures": True})
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
    assert main(["--log-level", "WARNING", "bench", "--scene", "cube", "--smoke", "--out", str(tmp_path),
                 "--only", p1["config"]]) == 0
    again = {r["config"]: r for r in csv.DictReader(open(tmp_path / "time_vs_error_cube.csv"))}
    assert list(again) == names
    assert float(again[p1["config"]]["total_s"]) != 1234.5
    assert all(float(r["total_s"]) == 1234.5 for name, r in again.items() if name != p1["config"])
    assert main(["--log-level", "WARNING", "bench", "--scene", "cube", "--smoke", "--out", str(tmp_path),
                 "--only", "P9 nothing"]) == 2
    table = (tmp_path / "time_vs_error_cube.md").read_text()
    assert "| configuration |" in table and "*" in table  # the Pareto front is marked
    _not_blank(tmp_path / "time_vs_error_cube.png")


def test_mesh_and_compare_error_paths(tmp_path, capsys):
    assert main(["mesh", str(tmp_path / "missing.nii.gz"), "--voxel", "5", "-o", str(tmp_path / "m.xdmf")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["mesh", str(MESHES / "mni152_brain_mask_2mm.nii.gz"), "--voxel", "-1"]) == 2
    assert "--voxel" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "a.stl"), str(tmp_path / "b.stl"), str(tmp_path / "c.vtk")]) == 2
    assert "compare:" in capsys.readouterr().err
    assert not (tmp_path / "m.xdmf").exists()


def test_unknown_subcommand_and_bad_flag_exit_with_usage(capsys):
    for argv in (["fly"], ["run"], ["bench", "--scene", "moon"]):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        assert "usage:" in capsys.readouterr().err


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
