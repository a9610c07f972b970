"""The ICBM152 2009a template files nilearn's wheel carries, fetched from PyPI on first use.

The bundled brain (meshes/) was made from the template's grey- and white-matter maps
(scripts/make_brain.py); the T1 image that matches it, for `brainshift warp` and
demos/warp.py, is not shipped (1.6 MB) but taken from the same wheel: ``pip download`` from
the package index the install already uses, read as a zip (nilearn is not installed), the
member kept in a cache folder. Its copyright notice: meshes/LICENSE-ICBM152.txt.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from ..errors import InputError

NILEARN_VERSION = "0.14.1"
MEMBER = "nilearn/datasets/data/mni_icbm152_{}_tal_nlin_sym_09a_converted.nii.gz"  # gm, wm, t1


def cache_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "fenics-brainshift"


def template_bytes(kinds: list[str], version: str = NILEARN_VERSION) -> dict[str, bytes]:
    """The gzipped NIfTI bytes of each kind ("gm", "wm", "t1") from nilearn's wheel."""
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                               f"nilearn=={version}", "-d", tmp], capture_output=True, text=True)
        wheels = list(Path(tmp).glob("nilearn-*.whl"))
        if done.returncode != 0 or not wheels:
            raise InputError(f"could not download nilearn {version}'s wheel from the package index (pip said: "
                             f"{done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'nothing'}); "
                             f"give the image yourself")
        with zipfile.ZipFile(wheels[0]) as zf:
            return {kind: zf.read(MEMBER.format(kind)) for kind in kinds}


def mni_t1(cache: Path | None = None) -> Path:
    """The ICBM152 2009a T1 (1 mm, 197 x 233 x 189, MNI RAS mm), downloaded once."""
    path = (cache or cache_folder()) / "mni_icbm152_t1_tal_nlin_sym_09a.nii.gz"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        tmp.write_bytes(template_bytes(["t1"])["t1"])
        os.replace(tmp, path)
    return path
