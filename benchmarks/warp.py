"""`brainshift warp` of a 1 mm whole-head volume against SimpleITK resampling with the written
transform, in one process.

The 5 mm brain settles after the drain (quasi-static); the ICBM152 T1 (1 mm, 197 x 233 x 189 =
8.7 M voxels, fetched once from nilearn's wheel) is warped by it: the exact inversion on the
grid (Warp.compute), the sampling (Warp.apply), the write; then SimpleITK reads the image and
the transform and resamples, on one thread and on its default threads. Both warped images are
compared (float64, so that no rounding of uint8 hides a difference). Writes
benchmarks/results/warp.{csv,md}.

    python benchmarks/warp.py [--repeat 3] [--voxel 0.005]
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs, run  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.data.templates import mni_t1  # noqa: E402
from fenics_brainshift.images import read_volume, write_like  # noqa: E402
from fenics_brainshift.warp import DeformedMesh, Warp, write_itk_transform  # noqa: E402


def main(argv=None) -> None:
    import SimpleITK as sitk

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--voxel", type=float, default=0.005)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "warp"))
    args = p.parse_args(argv)
    logs.configure("WARNING")
    image = mni_t1()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        result = run(
            load_scene("brain", [f"mesh.voxel={args.voxel}", "time.mode=quasi-static", "output.pictures=false"]),
            tmp / "run",
            MPI.COMM_SELF,
        )
        nodes = result.summary["nodes"]
        for _ in range(args.repeat):
            row = {}
            t0 = time.perf_counter()
            volume = read_volume(image)
            body = DeformedMesh.from_run(tmp / "run")
            row["read_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            warp = Warp.compute(volume, body)
            row["invert_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            warped = warp.apply()
            row["sample_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            write_like(volume, warped, tmp / "intra.nii.gz")
            row["write_s"] = time.perf_counter() - t0
            row["warp_total_s"] = sum(row[k] for k in ("read_s", "invert_s", "sample_s", "write_s"))
            t0 = time.perf_counter()
            write_itk_transform(warp, tmp / "warp.h5")
            row["transform_write_s"] = time.perf_counter() - t0
            row["transform_mb"] = (tmp / "warp.h5").stat().st_size / 1e6
            field = sitk.DisplacementFieldTransform(sitk.ReadTransform(str(tmp / "warp.h5"))).GetDisplacementField()
            row["field_voxels"] = int(np.prod(field.GetSize()))
            write_itk_transform(warp, tmp / "warp32.h5", float32=True)
            row["transform_float32_mb"] = (tmp / "warp32.h5").stat().st_size / 1e6
            for threads in (1, 0):
                if threads:
                    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(threads)
                else:
                    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(
                        sitk.ProcessObject.GetGlobalDefaultNumberOfThreads()
                    )
                t0 = time.perf_counter()
                pre = sitk.ReadImage(str(image), sitk.sitkFloat64)
                transform = sitk.ReadTransform(str(tmp / "warp.h5"))
                resampled = sitk.Resample(pre, pre, transform, sitk.sitkLinear, 0.0)
                key = "sitk_1_thread_s" if threads else "sitk_threads_s"
                row[key] = time.perf_counter() - t0
            ours = warp.apply(np.asarray(volume.data, dtype=np.float64))
            theirs = sitk.GetArrayFromImage(resampled).transpose(2, 1, 0)
            core = (slice(2, -2),) * 3
            row["largest_difference"] = float(np.abs(ours[core] - theirs[core]).max())
            row["voxels"] = int(volume.data.size)
            row["moved_voxels"] = int(warp.moved().sum())
            row["inside_voxels"] = int(warp.inside.sum())
            rows.append(row)
            print({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}, flush=True)
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    out = Path(args.out)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        "# Warping a 1 mm whole-head volume\n",
        f"{machine_line()}; one rank; `python benchmarks/warp.py`; medians of {args.repeat} runs.\n",
        f"The ICBM152 T1 ({med['voxels'] / 1e6:.1f} M voxels, 1 mm) warped by the settled "
        f"{args.voxel * 1e3:g} mm brain "
        f"({nodes} nodes): {med['moved_voxels'] / 1e6:.2f} M voxels move, {med['inside_voxels'] / 1e6:.2f} M lie in "
        f"the deformed brain.\n",
        "| step | seconds |",
        "|---|---:|",
        f"| read image + run's last state | {med['read_s']:.2f} |",
        f"| exact inverse on the grid (`Warp.compute`) | {med['invert_s']:.2f} |",
        f"| linear sampling (`Warp.apply`) | {med['sample_s']:.2f} |",
        f"| write NIfTI | {med['write_s']:.2f} |",
        f"| **`brainshift warp` total** | **{med['warp_total_s']:.2f}** |",
        f"| write the ITK transform (.h5, {med['transform_mb']:.0f} MB) | {med['transform_write_s']:.2f} |",
        f"| SimpleITK read + Resample with that transform, 1 thread | {med['sitk_1_thread_s']:.2f} |",
        f"| the same, SimpleITK's default threads | {med['sitk_threads_s']:.2f} |",
        "",
        f"Largest difference between the two warped images (float64, away from the 2-voxel border): "
        f"{med['largest_difference']:.2g} (intensities 0-255).\n",
        f"The transform's field covers the voxels that move and one around them: "
        f"{med['field_voxels'] / 1e6:.2f} M of the grid's {med['voxels'] / 1e6:.1f} M, stored gzip-compressed: "
        f"{med['transform_mb']:.0f} MB in float64, {med['transform_float32_mb']:.0f} MB with `--transform-float32` "
        f"(the whole grid uncompressed: {med['voxels'] * 24 / 1e6:.0f} MB). SimpleITK's resampling with it "
        f"is the difference above: ITK moves no point outside a displacement field's grid.\n",
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.md and .csv")


if __name__ == "__main__":
    main()
