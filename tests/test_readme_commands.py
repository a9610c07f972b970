"""Every command of the README's quick start runs, as written, at smoke size.

The commands are read from README.md itself (the ```sh block after "Then:"), so a command
that is changed there is run as changed; each gets only the overrides that make it small
(coarse meshes, short times), and the files it names (a mask, a T1, point lists, surfaces)
are made here. A command this test does not know fails it: add its smoke size below."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

from fenics_brainshift.cli import main

from conftest import ROOT, mpirun, subprocess_env

SMALL_BRAIN = ["--set", "mesh.voxel=0.015", "--set", "output.pictures=false"]
SMALL_CUBE = ["--set", "mesh.cells=[4, 4, 2]", "--set", "output.pictures=false"]
SHORT = ["--set", "time.end=0.4"]  # dynamic runs: two steps of the bundled scenes' dt = 0.2 s


def readme_commands() -> list[list[str]]:
    """The quick start's brainshift commands, as argument lists (comments dropped)."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"Then:\n\n```sh\n(.*?)```", text, re.S)
    assert block, "README.md: the quick start's second sh block (after 'Then:') is gone"
    return [shlex.split(line, comments=True) for line in block.group(1).splitlines() if line.strip()]


def smoke_size(argv: list[str]) -> list[str]:
    """The command made small: the overrides for its subcommand and scene."""
    command, rest = argv[0], argv[1:]
    if command == "run":
        small = SMALL_CUBE if rest[0] == "cube" else SMALL_BRAIN
        quasi_static = "time.mode=quasi-static" in rest
        return argv + small + ([] if quasi_static else SHORT)
    if command == "fit":
        return argv + SMALL_BRAIN + ["--set", "time.mode=quasi-static"]
    if command == "bench":
        return [a if a != "--quick" else "--smoke" for a in argv]
    if command in ("mesh", "warp", "compare", "scenes", "info"):
        return argv  # their inputs are small already (made below)
    pytest.fail(f"README command 'brainshift {command}' has no smoke size in tests/test_readme_commands.py")


def _inputs(folder: Path) -> None:
    """The files the README's commands name, made small: a brain mask, a T1, the measured
    points before and after the shift, and the pre-/intra-operative surfaces (mm, RAS)."""
    import meshio

    from fenics_brainshift.fit.synthetic import measurements
    from fenics_brainshift.images import write_markups

    affine = np.diag([2.0, 2.0, 2.0, 1.0])
    affine[:3, 3] = -40.0
    ijk = np.stack(np.meshgrid(*[np.arange(40)] * 3, indexing="ij"), axis=-1)
    inside = np.linalg.norm(ijk * 2.0 - 40.0, axis=-1) < 30.0
    nib.save(nib.Nifti1Image(inside.astype(np.uint8), affine), str(folder / "brain_mask.nii.gz"))
    t1_affine = np.diag([4.0, 4.0, 4.0, 1.0])
    t1_affine[:3, 3] = [-90.0, -126.0, -72.0]
    rng = np.random.default_rng(0)
    nib.save(
        nib.Nifti1Image(rng.uniform(0, 1000, (46, 55, 46)).astype(np.float32), t1_affine), str(folder / "T1.nii.gz")
    )
    pre, intra = measurements(
        SMALL_BRAIN[1::2] + ["time.mode=quasi-static"], {"fluid.level": 0.04, "material.G": 3000.0}, 12, 0.5e-3, seed=1
    )
    labels = [f"P{i}" for i in range(len(pre))]
    write_markups(folder / "pre.mrk.json", labels, pre * 1e3)
    write_markups(folder / "intra.mrk.json", labels, intra * 1e3)
    surface = meshio.read(ROOT / "meshes" / "mni152_brain_surface.ply")
    triangles = [("triangle", surface.cells_dict["triangle"])]
    meshio.write(folder / "PRE.stl", meshio.Mesh(surface.points, triangles))
    meshio.write(folder / "INTRA.stl", meshio.Mesh(surface.points + [0.0, -3.0, 0.0], triangles))


def test_every_quick_start_command_runs_at_smoke_size(tmp_path, monkeypatch, serial_only):
    commands = readme_commands()
    assert len(commands) >= 10, commands
    _inputs(tmp_path)
    monkeypatch.chdir(tmp_path)
    brainshift = Path(sys.executable).with_name("brainshift")
    assert brainshift.is_file(), f"{brainshift}: the install script's entry point is missing"
    for words in commands:
        assert "brainshift" in " ".join(words[:4]), words
        at = next(i for i, w in enumerate(words) if w.endswith("brainshift"))
        argv = smoke_size(words[at + 1 :])
        if words[0] == "mpirun":  # as written: mpirun -n 2 .venv/bin/brainshift ...
            cmd = mpirun()[:1] + words[1:at] + ["--oversubscribe", str(brainshift), "--no-progress", *argv]
            proc = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env(), timeout=900)
            assert proc.returncode == 0, (words, proc.stderr[-3000:])
            assert json.loads(Path(argv[argv.index("--out") + 1], "summary.json").read_text())["ranks"] == 2
        else:
            assert main(["--log-level", "WARNING", "--no-progress", *argv]) == 0, words
    # what the commands wrote, as the README says they do
    for written in (
        "out_cube/summary.json",
        "out_cube_hypre/summary.json",
        "out_brain_nh/summary.json",
        "out_brain_skull/summary.json",
        "out_mesh/brain5.xdmf",
        "out_warp/T1_intra.nii.gz",
        "out_warp/warp.h5",
        "out_fit/fit.json",
        "out_compare/compare.json",
        "out_bench/time_vs_error_cube.csv",
    ):
        assert Path(written).is_file(), written
    # every output in a folder of its own that git ignores (out_*/), none in the checkout's root
    assert all(p.name.startswith("out_") for p in Path(".").iterdir() if p.is_dir()), sorted(Path(".").iterdir())
    made = {"brain_mask.nii.gz", "T1.nii.gz", "pre.mrk.json", "intra.mrk.json", "PRE.stl", "INTRA.stl"}
    assert {p.name for p in Path(".").iterdir() if p.is_file()} <= made


def test_every_bench_configuration_is_a_scene_that_loads():
    """`brainshift bench` at every level: each configuration's overrides make a valid scene
    (the quick cube sweep once kept follower loading on for the reference rule, which the
    scene check refuses, and stopped at once)."""
    from fenics_brainshift.bench.configs import BENCHES
    from fenics_brainshift.bench.sweep import LEVELS
    from fenics_brainshift.scene import load_scene

    for _bench, make in BENCHES.items():
        for level in LEVELS:
            scene_file, base, _, reference, configs = make(level)
            for config in (reference, *configs):
                load_scene(scene_file, base + config.overrides)  # raises InputError if refused
