"""Build meshes/mni152_brain_mask_2mm.nii.gz and meshes/mni152_brain_surface.ply.

Source: the ICBM 2009a nonlinear symmetric template's grey- and white-matter probability maps
as nilearn's wheel carries them (nilearn/datasets/data/mni_icbm152_{gm,wm}_tal_nlin_sym_09a_
converted.nii.gz; 1 mm, MNI space, RAS mm). The wheel is downloaded from PyPI into a
temporary folder and read as a zip: nilearn itself is not installed.

Brain mask: gm + wm >= 0.5 at 1 mm, the largest face-connected part, holes filled, then
2 x 2 x 2 blocks kept where at least half their voxels are brain (2 mm voxels). Surface:
marching cubes of the 1 mm mask at level 0.5 (skimage), in the template's mm coordinates,
written as binary PLY (3D Slicer, ParaView and meshio read it).

    .venv/bin/python scripts/make_brain.py [--nilearn-version 0.14.1]
"""

from __future__ import annotations

import argparse
import gzip
import io
import sys
from pathlib import Path

import nibabel as nib
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fenics_brainshift.data.templates import brain_from_tissue, largest_part, template_bytes  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "meshes"


def fetch(version: str) -> dict[str, nib.Nifti1Image]:
    raw = template_bytes(["gm", "wm"], version)
    return {key: nib.Nifti1Image.from_bytes(gzip.decompress(data)) for key, data in raw.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--nilearn-version", default="0.14.1")
    args = p.parse_args(argv)
    images = fetch(args.nilearn_version)
    gm, wm = (np.asarray(images[k].dataobj, dtype=np.float32) for k in ("gm", "wm"))
    affine = images["gm"].affine
    brain = brain_from_tissue(gm, wm)
    print(f"1 mm brain mask: {brain.sum()} voxels = {brain.sum() / 1e3:.0f} ml, shape {brain.shape}")

    # 2 mm: blocks of 2 x 2 x 2 voxels, brain where at least half of the block is
    shape = [s - s % 2 for s in brain.shape]
    b = brain[: shape[0], : shape[1], : shape[2]].reshape(shape[0] // 2, 2, shape[1] // 2, 2, shape[2] // 2, 2)
    mask2 = largest_part(b.mean(axis=(1, 3, 5)) >= 0.5).astype(np.uint8)
    affine2 = affine.copy()
    affine2[:3, :3] = affine[:3, :3] * 2
    affine2[:3, 3] = affine[:3, 3] + affine[:3, :3] @ np.full(3, 0.5)  # centre of each 2 mm block
    img = nib.Nifti1Image(mask2, affine2)
    img.header.set_xyzt_units("mm")
    nib.save(img, OUT / "mni152_brain_mask_2mm.nii.gz")
    print(f"2 mm mask: {int(mask2.sum())} voxels = {mask2.sum() * 8 / 1e3:.0f} ml, shape {mask2.shape}")

    from skimage.measure import marching_cubes

    padded = np.pad(brain.astype(np.float32), 1)
    verts, faces, _, _ = marching_cubes(padded, level=0.5, step_size=3, allow_degenerate=False)
    verts = (verts - 1.0) @ affine[:3, :3].T + affine[:3, 3]
    write_ply(OUT / "mni152_brain_surface.ply", verts, faces)
    print(f"surface: {len(verts)} vertices, {len(faces)} triangles")
    return 0


def write_ply(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY: float32 vertices, uint8-counted int32 faces."""
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment ICBM 2009a brain surface, mm (MNI)\n"
        f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face_rows = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_rows["n"], face_rows["v"] = 3, faces
    buffer = io.BytesIO()
    buffer.write(header.encode("ascii"))
    buffer.write(np.asarray(verts, dtype="<f4").tobytes())
    buffer.write(face_rows.tobytes())
    path.write_bytes(buffer.getvalue())


if __name__ == "__main__":
    sys.exit(main())
