"""A plain (non-editable) install works from anywhere: the bundled scenes and brain ship as
package data, and the commands that use them find them."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

from conftest import ROOT, subprocess_env


def _copy_source(dest):
    """The source tree without environments, outputs and build leftovers, so the build leaves
    the checkout clean (a copy without .git too: the Debian 13 and Docker trees have none).
    Links stay links, as in a clone: the package's data/meshes points at the top-level meshes/."""
    shutil.copytree(
        ROOT,
        dest,
        symlinks=True,
        ignore=shutil.ignore_patterns(
            ".git", ".venv", "out_*", "bench_results", "__pycache__", "build", "*.egg-info", ".pytest_cache"
        ),
    )


def test_wheel_install_runs_the_bundled_scenes_from_elsewhere(tmp_path, serial_only):
    src, env_dir, work = tmp_path / "src", tmp_path / "env", tmp_path / "work"
    _copy_source(src)
    work.mkdir()
    env = subprocess_env()
    env.pop("VIRTUAL_ENV", None)
    # Debian's interpreter, as the install script uses: a venv made from the checkout's .venv
    # would see the checkout's editable install as a system package, and pip would remove it
    subprocess.run(
        ["/usr/bin/python3", "-m", "venv", "--system-site-packages", "--without-pip", str(env_dir)], check=True, env=env
    )
    python = env_dir / "bin" / "python"

    def call(*cmd, cwd=work):
        proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
        return proc.stdout

    # no dependencies from the network: the checkout's environment already has them
    call(python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", src, "-q")
    where = call(python, "-c", "import fenics_brainshift, sys; print(fenics_brainshift.__file__)")
    assert str(env_dir) in where and str(ROOT) not in where
    meshes = Path(where.strip()).parent / "data" / "meshes"
    assert meshes.is_dir() and not meshes.is_symlink() and (meshes / "mni152_brain_mask_2mm.nii.gz").is_file()
    call(
        env_dir / "bin" / "brainshift",
        "--no-progress",
        "run",
        "cube",
        "--out",
        "cube",
        "--set",
        "mesh.cells=[4, 4, 2]",
        "--set",
        "time.end=0.1",
        "--set",
        "output.pictures=false",
    )
    assert json.loads((work / "cube" / "summary.json").read_text())["status"] == "ok"
    call(env_dir / "bin" / "brainshift", "--no-progress", "bench", "--smoke", "--scene", "brain", "--out", "bench")
    assert (work / "bench" / "time_vs_error_brain.csv").is_file()


def test_the_release_is_one_number_everywhere():
    """The version `brainshift --version` and `info` print is the Docker image's label and the
    changelog's latest release."""
    import re

    from fenics_brainshift import __version__
    from fenics_brainshift.commands import info

    label = re.search(r'org\.opencontainers\.image\.version="([^"]+)"', (ROOT / "docker" / "Dockerfile").read_text())
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\]", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert label and label.group(1) == __version__
    assert released and released[0] == __version__
    assert re.match(r"^\d+\.\d+\.\d+$", __version__)
    assert "fenics_brainshift" in info.main(None, None)[0] and __version__ in info.main(None, None)[0]
