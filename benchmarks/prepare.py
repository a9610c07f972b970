"""`brainshift prepare` on a scanner-sized synthetic patient: the time from a DICOM folder to
scene.toml (by stage), then `run` and `warp` to the predicted intra-operative T1, on one core;
and what the registration recovers against the known truth.

The patient (patients/synthetic.py): the ICBM152 T1 inside FSL's whole MNI152 head (scalp, skull,
neck: patients/synthetic.py's with_head; --stripped: the brain alone, as a skull-stripped
research scan), of a head 0.9 times the template's size,
turned by (8, -6, 10) degrees and shifted, deformed by a known smooth field of 3 mm amplitude,
with a bias field and 3 % noise, on a 1 mm, 256 x 256 x 176 grid tilted by (15, 5, -10)
degrees, written as an MR DICOM series of int16 slices. Measured against the known transform:
the brain mask (Dice, volume) and 2000 points in the brain (the registration's map against the
known one, mm in the template). One process, one rank, OMP_NUM_THREADS=1 and SimpleITK on one
thread. Writes benchmarks/results/prepare.{json,md} and the prepared overview.png as
benchmarks/results/prepare_overview.png (docs/patients.md shows it); --stripped,
prepare_stripped.*.

    OMP_NUM_THREADS=1 python benchmarks/prepare.py [--stripped]

With --real T1 (a DICOM folder, NIfTI or NRRD of a real scan), the same path on it instead,
with what can be measured without a truth (brain volume, correlation, times): writes
benchmarks/results/prepare_NAME.{json,md} and prepare_NAME_overview.png (--name, default
real). --tumour SEG [--tumour-segment S] carries a tumour segmentation too: its volume and its
share inside the brain found, and the label map warped with the T1.

    OMP_NUM_THREADS=1 python benchmarks/prepare.py --real FOLDER          # a scanner's head T1
    OMP_NUM_THREADS=1 python benchmarks/prepare.py --real t1n.nii.gz --tumour segmentation.nii.gz \
        --tumour-segment 1,3 --name brats                                    # a stripped glioma case
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import SimpleITK as sitk

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.cli import main  # noqa: E402
from fenics_brainshift.data.templates import mni_brain_mask, mni_head, mni_t1  # noqa: E402
from fenics_brainshift.patients.synthetic import synthetic_patient, with_head, write_dicom_series  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def timed(argv: list[str]) -> float:
    began = time.perf_counter()
    code = main(argv)
    if code != 0:
        raise SystemExit(f"{' '.join(argv[:2])} failed with exit {code}")
    return time.perf_counter() - began


def main_(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, nargs=3, default=[256, 256, 176])
    p.add_argument("--spacing", type=float, nargs=3, default=[1.0, 1.0, 1.0])
    p.add_argument("--stripped", action="store_true", help="the brain alone, no head around it")
    p.add_argument("--real", help="a real T1 instead of the synthetic patient")
    p.add_argument("--tumour", help="with --real: its tumour segmentation")
    p.add_argument("--tumour-segment", help="with --tumour: the tumour's segments")
    p.add_argument("--name", default="real", help="with --real: the results' name, prepare_NAME.*")
    args = p.parse_args(argv)
    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(1)  # one core, as the budget says
    if args.real:
        return real(args.real, args.name, args.tumour, args.tumour_segment)
    template = sitk.ReadImage(str(mni_t1()), sitk.sitkFloat32)
    if not args.stripped:
        template = with_head(
            template,
            sitk.ReadImage(str(mni_head()), sitk.sitkFloat32),
            sitk.ReadImage(str(mni_head(brain_mask=True))),
            sitk.ReadImage(str(mni_brain_mask())),
        )
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        patient = synthetic_patient(template, spacing=args.spacing, size=args.size)
        write_dicom_series(patient.image, tmp / "dicom")
        seconds = {"prepare": timed(["prepare", str(tmp / "dicom"), "-o", str(tmp / "P")])}
        record = json.loads((tmp / "P" / "prepare.json").read_text())
        RESULTS.mkdir(exist_ok=True)
        name = "prepare_stripped" if args.stripped else "prepare"
        (RESULTS / f"{name}_overview.png").write_bytes((tmp / "P" / "overview.png").read_bytes())
        seconds["run"] = timed(["run", str(tmp / "P" / "scene.toml"), "--out", str(tmp / "P" / "run")])
        seconds["warp"] = timed(
            [
                "warp",
                str(tmp / "P" / "run"),
                "--image",
                str(tmp / "P" / "t1.nii.gz"),
                "-o",
                str(tmp / "P" / "t1_intra.nii.gz"),
            ]
        )
        summary = json.loads((tmp / "P" / "run" / "summary.json").read_text())
        grid = sitk.ReadImage(str(tmp / "P" / "t1.nii.gz"))
        mask = sitk.Cast(sitk.ReadImage(str(mni_brain_mask())), sitk.sitkFloat32)
        truth = sitk.GetArrayFromImage(sitk.Resample(mask, grid, patient.known, sitk.sitkLinear, 0.0)) >= 0.5
        found = sitk.GetArrayFromImage(sitk.ReadImage(str(tmp / "P" / "labels.nii.gz"))) > 0
        found_map = sitk.ReadTransform(str(tmp / "P" / "patient_to_template.h5"))
        kji = np.argwhere(truth)
        kji = kji[np.random.default_rng(0).choice(len(kji), 2000, replace=False)]
        points = [grid.TransformIndexToPhysicalPoint([int(i), int(j), int(k)]) for k, j, i in kji]
        error = np.array(
            [np.linalg.norm(np.subtract(patient.known.TransformPoint(q), found_map.TransformPoint(q))) for q in points]
        )
    voxel_ml = float(np.prod(args.spacing)) * 1e-3
    result = {
        "machine": machine_line(),
        "command": "OMP_NUM_THREADS=1 python benchmarks/prepare.py" + (" --stripped" if args.stripped else ""),
        "grid": {"size": args.size, "spacing_mm": args.spacing},
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
        "prepare_stages": record["seconds"],
        "registration": record["registration"],
        "dice": round(float(2 * (truth & found).sum() / (truth.sum() + found.sum())), 4),
        "volume_truth_ml": round(float(truth.sum()) * voxel_ml, 1),
        "volume_found_ml": round(float(found.sum()) * voxel_ml, 1),
        "map_error_mm": {
            "mean": round(float(error.mean()), 2),
            "p95": round(float(np.percentile(error, 95)), 2),
            "max": round(float(error.max()), 2),
        },
        "correlation": record["correlation"],
        "max_displacement_mm": round(summary["max_displacement_m"] * 1e3, 3),
    }
    stages = ", ".join(f"{s['stage']} {s['seconds']:.1f} s" for s in record["registration"])
    total = seconds["prepare"] + seconds["run"] + seconds["warp"]
    lines = [
        "# `brainshift prepare`: a DICOM series to a scene, and on to the predicted intra-operative T1",
        "",
        f"Machine: {result['machine']}. Command: `{result['command']}` (one process, one thread).",
        "",
        f"Synthetic patient (benchmarks/prepare.py's docstring), "
        f"{'the brain alone (skull-stripped)' if args.stripped else 'with scalp, skull and neck'}: "
        f"{' x '.join(map(str, args.size))} voxels of "
        f"{' x '.join(f'{s:g}' for s in args.spacing)} mm, oblique, as an MR DICOM series.",
        "",
        "| Step | Seconds | Goal |",
        "|---|---|---|",
        f"| `prepare` (DICOM folder to scene.toml) | {seconds['prepare']:.1f} | at most 120 |",
        f"| of which registration: {stages} | {record['seconds']['registration']:.1f} | |",
        f"| `run` (settled states, skull, septa, 5 mm mesh) | {seconds['run']:.1f} | |",
        f"| `warp` (the T1 to the intra-operative prediction) | {seconds['warp']:.1f} | |",
        f"| the whole path | {total:.1f} | at most 180 |",
        "",
        "| Against the known truth | Found | Goal |",
        "|---|---|---|",
        f"| brain mask: Dice | {result['dice']:.3f} | at least 0.95 |",
        f"| brain volume | {result['volume_found_ml']:.0f} ml against {result['volume_truth_ml']:.0f} ml "
        f"({result['volume_found_ml'] / result['volume_truth_ml'] - 1:+.1%}) | within 3 % |",
        f"| 2000 points in the brain: map error mean / 95th percentile / max | {error.mean():.2f} / "
        f"{np.percentile(error, 95):.2f} / {error.max():.2f} mm | within 2 mm |",
        f"| correlation of the T1 and the registered template in the brain | {record['correlation']:.2f} | above 0.5 |",
        "",
    ]
    (RESULTS / f"{name}.json").write_text(json.dumps(result, indent=2) + "\n")
    (RESULTS / f"{name}.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


def real(t1: str, name: str, tumour: str | None, segments: str | None) -> int:
    """prepare, run and warp on a real T1: times, the brain's volume and the correlation (and
    the tumour's volume, its share in the brain, and the labels warped)."""
    extra = (["--tumour", tumour] if tumour else []) + (["--tumour-segment", segments] if segments else [])
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        seconds = {"prepare": timed(["prepare", t1, "-o", str(tmp / "P"), *extra])}
        record = json.loads((tmp / "P" / "prepare.json").read_text())
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / f"prepare_{name}_overview.png").write_bytes((tmp / "P" / "overview.png").read_bytes())
        seconds["run"] = timed(["run", str(tmp / "P" / "scene.toml"), "--out", str(tmp / "P" / "run")])
        seconds["warp"] = timed(
            [
                "warp",
                str(tmp / "P" / "run"),
                "--image",
                str(tmp / "P" / "t1.nii.gz"),
                "-o",
                str(tmp / "P" / "t1_intra.nii.gz"),
            ]
        )
        summary = json.loads((tmp / "P" / "run" / "summary.json").read_text())
        moved = None
        if tumour:
            timed(
                [
                    "warp",
                    str(tmp / "P" / "run"),
                    "--image",
                    str(tmp / "P" / "labels.nii.gz"),
                    "-o",
                    str(tmp / "P" / "labels_intra.nii.gz"),
                    "--labels",
                ]
            )
            before, after = (
                sitk.GetArrayFromImage(sitk.ReadImage(str(tmp / "P" / f))) == 2
                for f in ("labels.nii.gz", "labels_intra.nii.gz")
            )
            spacing = np.array(sitk.ReadImage(str(tmp / "P" / "labels.nii.gz")).GetSpacing())[::-1]
            shift = (np.argwhere(after).mean(axis=0) - np.argwhere(before).mean(axis=0)) * spacing
            moved = {
                "voxels_before": int(before.sum()),
                "voxels_after": int(after.sum()),
                "centroid_shift_mm": round(float(np.linalg.norm(shift)), 2),
            }
    command = (
        f"OMP_NUM_THREADS=1 python benchmarks/prepare.py --real {t1}"
        + "".join(f" {a}" for a in extra)
        + (f" --name {name}" if name != "real" else "")
    )
    result = {
        "machine": machine_line(),
        "command": command,
        "grid": record["grid"],
        "head_first": record["head_first"],
        "bounded_by_stripping": record.get("bounded_by_stripping", False),
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
        "registration": record["registration"],
        "brain_litres": record["brain_litres"],
        "correlation": record["correlation"],
        "tumour": record.get("tumour"),
        "tumour_warped": moved,
        "max_displacement_mm": round(summary["max_displacement_m"] * 1e3, 3),
    }
    (RESULTS / f"prepare_{name}.json").write_text(json.dumps(result, indent=2) + "\n")
    stages = ", ".join(f"{s['stage']} {s['seconds']:.1f} s" for s in record["registration"])
    total = sum(seconds.values())
    kind = (
        "; the whole head placed first"
        if record["head_first"]
        else "; skull-stripped, the brain bounded by the scan's own stripping"
        if result["bounded_by_stripping"]
        else "; skull-stripped"
    )
    lines = [
        "# `brainshift prepare` on a real T1",
        "",
        f"Machine: {result['machine']}. Command: `{result['command']}` (one process, one thread).",
        "",
        f"T1: {' x '.join(map(str, record['grid']['size']))} voxels of "
        f"{' x '.join(f'{s:g}' for s in record['grid']['spacing_mm'])} mm{kind}.",
        "",
        "| Step | Seconds | Goal |",
        "|---|---|---|",
        f"| `prepare` | {seconds['prepare']:.1f} | at most 120 |",
        f"| of which registration: {stages} | {record['seconds']['registration']:.1f} | |",
        f"| `run` | {seconds['run']:.1f} | |",
        f"| `warp` | {seconds['warp']:.1f} | |",
        f"| the whole path | {total:.1f} | at most 180 |",
        "",
        f"Brain found: {record['brain_litres']:.2f} l (an adult's: 1.0-1.7 l); correlation with the registered "
        f"template in it (both smoothed by 2 mm): {record['correlation']:.2f} (a failed registration: below 0.5); "
        f"largest displacement of the settled state {result['max_displacement_mm']:.2f} mm.",
        "",
    ]
    if record.get("tumour"):
        lines += [
            f"Tumour ({segments or 'every label'}): {record['tumour']['ml']:.1f} ml, "
            f"{record['tumour']['inside_brain']:.1%} of it inside the brain found (the rest is meshed with "
            f"the brain); warped with `--labels`: {moved['voxels_before']} voxels before, "
            f"{moved['voxels_after']} after, its centroid moved {moved['centroid_shift_mm']:.2f} mm.",
            "",
        ]
    (RESULTS / f"prepare_{name}.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
