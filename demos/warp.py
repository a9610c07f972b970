# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # The predicted intra-operative MRI
#
# The brain of `brain.py` (bundled MNI brain, 5 mm voxels, supine, CSF drained to the
# craniotomy rim) settles; then the ICBM152 T1 image the brain was made from is warped by
# the computed shift (`brainshift warp`), and the same map is written as an ITK transform
# that 3D Slicer applies to any image, segmentation or model (docs/slicer.md). The T1 comes
# from nilearn's wheel on the package index (downloaded once into ~/.cache/fenics-brainshift).
#
#     python demos/warp.py                      # writes out_demo_warp/
#     python demos/warp.py --set mesh.voxel=0.008   # a quicker, coarser brain
#
# out_demo_warp/: t1_pre.nii.gz (the template, for Slicer), t1_intra.nii.gz (predicted),
# warp.h5 (the transform), warp.png (slices: pre-operative, predicted, difference, with the
# brain's outline before and after), and the run's own files.

# +
import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, load_scene, logs, run
from fenics_brainshift.data.templates import mni_t1
from fenics_brainshift.images import read_volume, write_like
from fenics_brainshift.images.rasterize import rasterize
from fenics_brainshift.warp import DeformedMesh, Warp, write_itk_transform

# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Warp the pre-operative T1 by the brain's predicted shift.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="out_demo_warp", help="output folder")
    p.add_argument("--image", help="the pre-operative image (default: the ICBM152 T1, fetched once)")
    p.add_argument(
        "--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="scene overrides, as for brainshift run"
    )
    return p.parse_args(argv)


# ## Settle the brain, warp the image, draw the slices


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    logs.configure("INFO")
    comm = MPI.COMM_WORLD
    out = Path(args.out)
    try:
        image = Path(args.image) if args.image else (mni_t1() if comm.rank == 0 else None)
        image = comm.bcast(image, root=0)
        scene = load_scene("brain", ["time.mode=quasi-static", "output.pictures=false"] + args.set)
        run(scene, out, comm)
        volume = read_volume(image, "--image")
        body = DeformedMesh.from_run(out)
        warp = Warp.compute(volume, body, comm=comm)
    except (InputError, SolverError) as exc:
        if comm.rank == 0:
            print(f"warp.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    if comm.rank == 0:
        predicted = warp.apply()
        shutil.copyfile(image, out / "t1_pre.nii.gz")
        write_like(volume, predicted, out / "t1_intra.nii.gz")
        write_itk_transform(warp, out / "warp.h5")
        print(
            f"warp: {int(warp.moved().sum())} voxels moved, largest {warp.largest_mm():.2f} mm, in {warp.seconds:.1f} s"
        )
        picture(out / "warp.png", volume, predicted, body, warp)
        print(f"  wrote {out}/t1_intra.nii.gz, warp.h5, warp.png")
    comm.barrier()
    return 0


def brain_mask(volume, points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """The voxels a tetrahedral mesh covers (points RAS mm)."""
    voxel, _, _ = rasterize(volume.ras_to_index(points), tets, volume.data.shape)
    mask = np.zeros(volume.data.shape, dtype=bool)
    mask.reshape(-1)[voxel] = True
    return mask


def picture(path: Path, volume, predicted: np.ndarray, body, warp) -> None:
    """Sagittal and axial slices through the largest shift: pre-operative, predicted (with the
    brain's outline before, dashed, and after), and predicted minus pre-operative."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    before = brain_mask(volume, body.points, body.tets)
    after = warp.inside
    shift = np.linalg.norm(warp.v, axis=-1) * np.where(after, 1.0, 0.0)
    i, _, k = np.unravel_index(np.argmax(shift), shift.shape)
    pre = np.asarray(volume.data, dtype=float)
    diff = predicted.astype(float) - pre
    limit = np.percentile(np.abs(diff[after | before]), 99) or 1.0
    # index axes are R, A, S for this template (affine diagonal, positive)
    views = [
        (
            "sagittal",
            lambda a: a[i, :, :].T,
            ("P", "A", "I", "S"),
            f"x = {volume.index_to_ras(np.array([i, 0, 0]))[0]:.0f} mm",
        ),
        (
            "axial",
            lambda a: a[:, :, k].T,
            ("L", "R", "P", "A"),
            f"z = {volume.index_to_ras(np.array([0, 0, k]))[2]:.0f} mm",
        ),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(12, 8.5))
    for row, (name, cut, (left, right, bottom, top), where) in zip(axes, views):
        for ax, data, title, cmap, lim in (
            (row[0], pre, "pre-operative", "gray", None),
            (row[1], predicted.astype(float), "predicted (CSF drained)", "gray", None),
            (row[2], diff, "predicted - pre-operative", "RdBu_r", limit),
        ):
            shown = ax.imshow(cut(data), origin="lower", cmap=cmap, vmin=-lim if lim else None, vmax=lim)
            ax.contour(cut(before.astype(float)), [0.5], colors="tab:orange", linestyles="--", linewidths=0.9)
            ax.contour(cut(after.astype(float)), [0.5], colors="tab:cyan", linewidths=0.9)
            ax.set_title(f"{name} {where}: {title}", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
            for text, xy in ((left, (0.02, 0.5)), (right, (0.95, 0.5)), (bottom, (0.5, 0.02)), (top, (0.5, 0.93))):
                ax.text(*xy, text, transform=ax.transAxes, color="yellow", fontsize=11, weight="bold")
            if lim:
                fig.colorbar(shown, ax=ax, fraction=0.04, label="intensity difference (T1 units)")
    fig.suptitle(
        "Brain outline before (dashed orange) and after the shift (cyan); gravity towards posterior (supine)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# -


if __name__ == "__main__":
    sys.exit(main())
