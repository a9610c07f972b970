"""Bad scene input: one clear line naming the field, exit code 2, no traceback, no output."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_brainshift.cli import main
from fenics_brainshift.data import MESHES
from fenics_brainshift.errors import InputError
from fenics_brainshift.scene.predicates import PredicateError, parse_predicate

from conftest import ROOT, column_dict, subprocess_env


def _toml(value, key=None) -> str:
    """A tiny TOML writer for the test scenes (strings, numbers, lists, tables)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    raise TypeError(value)


def write_scene(path: Path, data: dict) -> Path:
    lines = []
    for key, value in data.items():
        if not isinstance(value, (dict, list)) or (
            isinstance(value, list) and not all(isinstance(v, dict) for v in value)
        ):
            lines.append(f"{key} = {_toml(value)}")
    for key, value in data.items():
        if isinstance(value, dict):
            lines.append(f"[{key}]")
            lines += [f"{k} = {_toml(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                lines.append(f"[[{key}]]")
                lines += [f"{k} = {_toml(v)}" for k, v in item.items()]
    path.write_text("\n".join(lines) + "\n")
    tomllib.loads(path.read_text())  # the writer itself must be right
    return path


def _with(section: str, **changes) -> dict:
    data = column_dict(4)
    data[section] = {**data[section], **changes}
    return data


DYNAMIC = {"mode": "dynamic", "dt": 0.01, "end": 0.05}
BAD = [
    ("unknown key", _with("material", Ee=1.0), "[material] unknown key 'Ee'"),
    ("negative E", _with("material", E=-5.0), "[material] E must be > 0"),
    ("zero E", _with("material", E=0.0), "[material] E must be > 0"),
    ("nu = 0.5", _with("material", nu=0.5), "[material] nu must be in (-1, 0.4999]"),
    ("nu = 0.4999999", _with("material", nu=0.4999999), "(got 0.4999999); 0.5 is incompressible"),
    ("nu > 0.5", _with("material", nu=0.7), "[material] nu"),
    ("E as text", _with("material", E="soft"), "[material] E must be a finite number"),
    ("zero density", _with("material", density=0.0), "[material] density must be > 0"),
    ("dt = 0", _with("time", mode="dynamic", dt=0.0), "[time] dt must be > 0"),
    ("negative dt", _with("time", mode="dynamic", dt=-0.1), "[time] dt must be > 0"),
    ("bad scheme", _with("time", scheme="euler"), "[time] scheme must be one of"),
    ("rho_inf > 1", _with("time", rho_inf=1.5), "[time] rho_inf must be in [0, 1]"),
    ("bad solver", _with("solver", kind="magic"), "[solver] kind must be one of"),
    ("degree 3", _with("element", degree=3), "[element] degree must be 1 or 2"),
    ("lumped P2", _with("element", degree=2, mass="lumped"), '[element] mass = "lumped" is only for degree 1'),
    ("missing mesh file", {**column_dict(4), "mesh": {"file": "nowhere.msh"}}, "[mesh] file"),
    ("box without size rule", {**column_dict(4), "mesh": {"shape": "box"}}, "[mesh] a box needs"),
    ("gravity of 2", _with("gravity", vector=[0.0, -9.81]), "[gravity] vector must be a list of 3 numbers"),
    (
        "time backwards",
        {**column_dict(4), "fluid": {"density": 1000.0, "level": [[0.0, 0.05], [2.0, 0.02], [1.0, 0.0]]}},
        "[fluid] level[2] time 1 s must be later than 2 s",
    ),
    (
        "unknown section",
        {**column_dict(4), "materials": {"E": 1.0}},
        "unknown section [materials]; did you mean 'material'?",
    ),
    ("mistyped key", _with("material", densty=1000.0), "[material] unknown key 'densty'; did you mean 'density'?"),
    ("mistyped name", {**column_dict(4), "fixed": [{"where": "zz < 0.001"}]}, "unknown name 'zz'; did you mean 'z'?"),
    ("key in another case", _with("material", g=1000.0), "[material] unknown key 'g'; did you mean 'G'?"),
    ("fixed selects nothing", {**column_dict(4), "fixed": [{"where": "z < -1.0"}]}, "selects no node"),
    (
        "fixed eval attempt",
        {**column_dict(4), "fixed": [{"where": "__import__('os').system('true')"}]},
        "[[fixed]] where",
    ),
    ("fixed bad axes", {**column_dict(4), "fixed": [{"where": "z < 0.001", "axes": "w"}]}, "[[fixed]] axes"),
    ("probe outside", {**column_dict(4), "probes": {"far": [1.0, 1.0, 1.0]}}, "[probes] far"),
    (
        "remove selects nothing",
        {**column_dict(4), "time": DYNAMIC, "remove": [{"at": 0.0, "where": "z > 1.0"}]},
        '[[remove]] where = "z > 1.0" (at 0 s) selects no cell',
    ),
    (
        "remove takes everything",
        {**column_dict(4), "time": DYNAMIC, "remove": [{"at": 0.0, "where": "z > -1.0"}]},
        "would remove every remaining cell",
    ),
    (
        "remove after the end",
        {**column_dict(4), "time": DYNAMIC, "remove": [{"at": 9.0, "where": "z > 0.05"}]},
        "[[remove]] at = 9 s is not before [time] end",
    ),
    (
        "remove with both",
        {**column_dict(4), "time": DYNAMIC, "remove": [{"where": "z > 0.05", "label": 2}]},
        "[[remove]] give exactly one of",
    ),
    (
        "remove label of a box",
        {**column_dict(4), "time": DYNAMIC, "remove": [{"label": 2}]},
        "[[remove]] label needs [mesh] file to be a label volume",
    ),
    # slips a new user makes
    (
        "fixed holds every node (a bound in mm)",
        {**column_dict(4), "fixed": [{"where": "z < 40"}]},
        '[[fixed]] where = "z < 40" selects every node of the mesh',
    ),
    (
        "cells in the thousands",
        {**column_dict(4), "mesh": {"shape": "box", "size": [0.02, 0.02, 0.1], "cells": [3000, 3000, 3000]}},
        "[mesh] cells = [3000, 3000, 3000] (2.7e+10 nodes) would need about",
    ),
    (
        "element size in mm for metres",
        {**column_dict(4), "mesh": {"shape": "ellipsoid", "size": [0.07, 0.08, 0.06], "h": 1e-5}},
        "[mesh] h = 1e-05 m for a ellipsoid",
    ),
    (
        "voxel of a micrometre",
        {
            **column_dict(4),
            "fixed": [{"where": "y < -0.09"}],
            "probes": {},
            "mesh": {"file": str(MESHES / "mni152_brain_mask_2mm.nii.gz"), "unit": "mm", "voxel": 1e-6},
        },
        "is the voxel size in the right unit?",
    ),
    (
        "follower tolerance not a fraction",
        {**column_dict(4), "fluid": {"level": 0.05, "follower_tol": 2.0}},
        "[fluid] follower_tol is a fraction of the displacement and must be below 1",
    ),
    (
        "container smaller than the body",
        {**column_dict(4), "fluid": {"volume": 1e-5, "container_area": 1e-4}},
        "[fluid] container_area = 0.0001 m2 is not larger than the body's horizontal cross-section (0.0004 m2)",
    ),
    (
        "remove with the quadrature rule",
        {
            **column_dict(4),
            "time": DYNAMIC,
            "remove": [{"at": 0.0, "where": "z > 0.05"}],
            "fluid": {"level": 0.05, "rule": "quadrature", "follower": False},
        },
        "[[remove]] needs the fluid load on the surface left after the cut",
    ),
    (
        "follower with the quadrature rule",
        {**column_dict(4), "fluid": {"level": 0.05, "rule": "quadrature", "follower": True}},
        '[fluid] rule = "quadrature" integrates on the undeformed surface only',
    ),
    (
        "sqrt of two arguments",
        {**column_dict(4), "fixed": [{"where": "sqrt(x, y) < 0.001"}]},
        "sqrt() takes exactly 1 argument (got 2)",
    ),
    (
        "min of one argument",
        {**column_dict(4), "fixed": [{"where": "min(z) < 0.001"}]},
        "min() takes at least 2 arguments (got 1)",
    ),
    ("a constant that overflows", {**column_dict(4), "fixed": [{"where": "z < 10**400"}]}, "10 ** 400 is out of range"),
    (
        "PETSc option it cannot read",
        _with("solver", kind="cg-jacobi", options={"ksp_max_it": "many"}),
        "[solver] options: PETSc could not read them",
    ),
    (
        "PETSc option nothing uses",
        _with("solver", kind="cg-gamg", options={"ksp_maxit": 10}),
        "[solver] options: PETSc used none of ksp_maxit",
    ),
]


@pytest.mark.mpi
@pytest.mark.parametrize("label, data, expected", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_gives_one_line_error_and_no_output(shared_tmp, capsys, label, data, expected):
    from conftest import COMM

    scene = shared_tmp / f"scene_r{COMM.rank}.toml"  # every rank reads its own copy
    write_scene(scene, data)
    out = shared_tmp / "out"
    code = main(["run", str(scene), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2  # on every rank: the error is raised collectively
    if COMM.rank == 0:  # only rank 0 speaks
        assert expected in err, err
        assert len(err.splitlines()) == 1 and "Traceback" not in err
    else:
        assert err == ""
    COMM.barrier()
    assert not out.exists()


@pytest.mark.parametrize("content", [b"garbage, not a mesh\n", b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2"])
def test_corrupt_mesh_file_is_named(tmp_path, capsys, serial_only, content):
    (tmp_path / "broken.msh").write_bytes(content)
    scene = write_scene(tmp_path / "scene.toml", {**column_dict(4), "mesh": {"file": "broken.msh"}})
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "[mesh] file 'broken.msh' could not be read" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_output_folder_that_cannot_be_written(tmp_path, capsys, serial_only):
    scene = write_scene(tmp_path / "scene.toml", column_dict(4))
    (tmp_path / "taken").write_text("a file, not a folder")
    for out, expected in (
        (tmp_path / "taken", "is an existing file"),
        (tmp_path / "taken" / "out", "cannot be written"),
    ):
        assert main(["run", str(scene), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert expected in err and len(err.splitlines()) == 1, err
    assert (tmp_path / "taken").read_text() == "a file, not a folder"


def test_unreadable_surface_is_named(tmp_path, capsys, serial_only):
    (tmp_path / "broken.stl").write_bytes(b"solid nothing\nthis is not an STL\n")
    scene = write_scene(
        tmp_path / "scene.toml",
        {
            **column_dict(4),
            "mesh": {"shape": "box", "size": [0.02, 0.02, 0.1], "cells": [1, 1, 4], "surface": "broken.stl"},
        },
    )
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "[mesh] surface: 'broken.stl' could not be read as a surface" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_hypre_missing_from_petsc_is_bad_input(tmp_path, capsys, serial_only, monkeypatch):
    from fenics_brainshift.linalg import solver

    has = solver.has_package
    monkeypatch.setattr(solver, "has_package", lambda name: False if name == "hypre" else has(name))
    scene = write_scene(tmp_path / "scene.toml", _with("solver", kind="cg-hypre"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 2
    assert "needs PETSc built with hypre" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_not_toml_and_missing_scene(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[material\nE = 1")
    assert main(["run", str(bad)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "none.toml")]) == 2
    assert "not found (bundled scenes" in capsys.readouterr().err
    assert main(["run", "cub"]) == 2  # a bundled scene's name mistyped
    assert "scene file 'cub' not found; did you mean 'cube'? (bundled scenes" in capsys.readouterr().err


def test_files_in_overrides_are_relative_to_the_current_directory(tmp_path, monkeypatch):
    """A file typed after --set is found where it was typed; one in a scene file next to it."""
    from fenics_brainshift import load_scene

    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    for folder in (here, there):
        (folder / "skull.stl").write_text("solid s\nendsolid s\n")  # only its existence is checked here
    data = column_dict(4)
    write_scene(
        there / "scene.toml", {**data, "time": {**data["time"], "mode": "quasi-static"}, "skull": {"file": "skull.stl"}}
    )
    monkeypatch.chdir(here)
    assert load_scene(there / "scene.toml").skull.file == str(there / "skull.stl")
    assert load_scene(there / "scene.toml", ["skull.file=skull.stl"]).skull.file == str(here / "skull.stl")
    bundled = ["time.mode=quasi-static", "skull.file=skull.stl"]
    assert load_scene("cube", bundled).skull.file == str(here / "skull.stl")
    (here / "skull.stl").unlink()
    with pytest.raises(InputError, match=f"skull. file not found: {here / 'skull.stl'}"):
        load_scene("cube", bundled)


def test_command_line_error_has_no_traceback(tmp_path, serial_only):
    scene = write_scene(tmp_path / "scene.toml", _with("material", E=-1.0))
    proc = subprocess.run(
        [sys.executable, "-m", "fenics_brainshift.cli", "run", str(scene), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        env=subprocess_env(),
        cwd=ROOT,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "brainshift: error: [material] E must be > 0 (got -1)"
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os')",
        "x.real < 1",
        "open('f')",
        "lambda: 1",
        "[x][0] < 1",
        "z == 1",
        "'a' < 'b'",
        "x < y < ",
        "exec('1')",
        "q < 1",
        "x + 1",
    ],
)
def test_predicates_reject_everything_but_arithmetic_conditions(text):
    with pytest.raises(PredicateError):
        parse_predicate(text)


def test_predicates_evaluate_vectorised():
    x = np.array([[0.0, 0.5, 1.0], [0.0, 0.2, 0.9], [0.0, 0.0, 0.3]])
    assert parse_predicate("z < 0.01 and y < 0.1 or y > 0.5").__call__(x).tolist() == [True, False, True]
    assert parse_predicate("0.1 < x <= 0.5 and not y > 0.3").__call__(x).tolist() == [False, True, False]
    assert parse_predicate("sqrt((x - 1)**2 + y**2) < 1.0").__call__(x).tolist() == [False, True, True]
    assert parse_predicate("abs(x - 0.5) < 0.1 and -z > -1").__call__(x).tolist() == [False, True, False]
