"""The bundled brain resting on a label skull with no occipital pin (docs/limits.md): the MNI
brain (5 mm voxels) held at the brain stem alone, supine, the CSF drained from 85 to 30 mm,
inside a skull that is the boundary of the brain mask and a CSF label 8 mm around it (made
here from meshes/mni152_brain_mask_2mm.nii.gz by a distance transform; `[skull] label =
[1, 2]`, marching cubes). Without the pin the brain pivots about the stem onto the back of
the skull, which holds it over a large area with its staircase of voxels. Settled states at
the schedule's breakpoints (quasi-static), linear and neo-Hookean: whether each run settles,
its solve time, the deepest node past the skull, the multiplier updates, the force the skull
carries and the run's validity (largest strain, rotation). With a scalar contact multiplier
(not a pressure vector) the linear run stopped at t = 10 s.
Writes benchmarks/results/contact_label_skull.md. One rank.

    python benchmarks/contact_label_skull.py [--models linear,neo-hookean]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import nibabel as nib
import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import logs  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.runner import run  # noqa: E402
from fenics_brainshift.scene import scene_from_dict  # noqa: E402
from fenics_brainshift.scene.toml import scene_data  # noqa: E402

CSF_MM = 8.0  # the CSF label's thickness around the brain mask


def labels(folder: Path) -> Path:
    """The brain mask as label 1 and everything within CSF_MM of it as label 2 (NIfTI)."""
    image = nib.load(str(ROOT / "meshes" / "mni152_brain_mask_2mm.nii.gz"))
    brain = np.asarray(image.dataobj) > 0.5
    distance = ndimage.distance_transform_edt(~brain, sampling=image.header.get_zooms()[:3])
    volume = np.where(brain, 1, np.where(distance <= CSF_MM, 2, 0)).astype(np.uint8)
    path = folder / "brain_csf.nii.gz"
    nib.save(nib.Nifti1Image(volume, image.affine), str(path))
    return path


def scene(label_file: Path, model: str):
    data, base = scene_data("brain")
    data["mesh"].update({"file": str(label_file), "labels": [1]})
    data["mesh"].pop("surface", None)
    data["fixed"] = [f for f in data["fixed"] if f["name"] == "brain_stem"]
    data["time"] = {"mode": "quasi-static"}
    data["material"]["model"] = model
    data["skull"] = {"label": [1, 2]}
    data["output"] = {"pictures": False}
    return scene_from_dict(data, base=base)


def one(label_file: Path, model: str, out: Path) -> dict:
    t = time.perf_counter()
    result = run(scene(label_file, model), out=out, raise_on_stop=False)
    seconds = time.perf_counter() - t
    s = result.summary
    contact, validity = s.get("skull_contact", {}), s.get("validity", {})
    return {
        "model": model,
        "status": s["status"],
        "final_time": s.get("final_time"),
        "seconds": seconds,
        "deepest_um": contact.get("max_penetration_m", float("nan")) * 1e6,
        "updates": contact.get("multiplier_updates"),
        "force_N": contact.get("force_N", [np.nan] * 3),
        "strain": validity.get("max_green_lagrange_strain", np.nan),
        "past": validity.get("volume_past_limit", np.nan),
        "rotation": validity.get("max_rotation_deg", np.nan),
        "max_mm": s.get("max_displacement_m", np.nan) * 1e3,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="linear,neo-hookean")
    args = parser.parse_args()
    logs.configure("WARNING")
    folder = Path(tempfile.mkdtemp(prefix="brainshift-label-skull-"))
    label_file = labels(folder)
    rows = [one(label_file, m, folder / m) for m in args.models.split(",")]
    lines = [
        "# The bundled brain on a label skull, held at the brain stem alone",
        "",
        f"{machine_line()}; one rank; `python benchmarks/contact_label_skull.py --models {args.models}`. "
        f"The MNI brain at 5 mm voxels, supine, drained from 85 to 30 mm, held at the brain stem only, inside "
        f"the boundary of the mask and a CSF label {CSF_MM:g} mm around it (`[skull] label = [1, 2]`), "
        "[skull] tolerance 1e-5 m; settled states at the schedule's breakpoints. Time: the whole run. "
        "Strain: the largest Green-Lagrange principal strain; past 5 %: the volume's fraction.",
        "",
        "| model | status | reached t (s) | time (s) | deepest past the skull (um) | multiplier updates | "
        "skull's force (N) | max u (mm) | strain | past 5 % | rotation (deg) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['status']} | {r['final_time']} | {r['seconds']:.1f} | {r['deepest_um']:.2f} | "
            f"{r['updates']} | ({', '.join(f'{v:.3f}' for v in r['force_N'])}) | {r['max_mm']:.2f} | "
            f"{r['strain']:.3f} | {r['past'] * 100:.1f} % | {r['rotation']:.1f} |"
        )
    out = ROOT / "benchmarks" / "results" / "contact_label_skull.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
