"""The patient's folder as `brainshift prepare` writes it: the T1, the labels and the Slicer
segmentation, the registration's transform, the inner skull and the septa as STL (RAS mm),
scene.toml with the reasons beside its values, and the overview picture; written into a
temporary folder beside it and moved into place only when whole."""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import SimpleITK as sitk

from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..surfaces.files import write_slicer_stl
from .anatomy import BRAIN_SCENE
from .overview import write_overview
from .skull import inner_skull
from .slicer import write_segmentation

PREPARE_RECORD = "prepare.json"
SUPPORT = "brain_stem"  # the bundled scene's support a patient scene fixes (the occipital pin gives way to the skull)


@contextlib.contextmanager
def written_in_place(out: Path):
    """A temporary folder beside OUT, moved into its place when the block ends well (an earlier
    prepare's folder replaced: check_output), removed otherwise: never half a folder."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.resolve().parent))
    aside = tmp.with_name(tmp.name + ".earlier")
    try:
        tmp.chmod(0o755)  # mkdtemp's is the owner's alone; the folder is the user's to share
        yield tmp
        if out.exists():  # the earlier folder set aside, deleted only once the new one is in place
            os.replace(out, aside)
        try:
            os.replace(tmp, out)
        except OSError:
            if aside.exists():
                os.replace(aside, out)
            raise
    finally:
        for left in (tmp, aside):
            if left.exists():
                shutil.rmtree(left)


def check_output(out: Path) -> None:
    """-o refused before anything is read: a link, the folder one is in, a folder prepare did not
    make, or one whose parent is missing."""
    if out.is_symlink():
        raise InputError(f"-o: '{out}' is a link; give the folder itself (or a new one)")
    if Path.cwd().resolve().is_relative_to(out.resolve()):
        raise InputError(
            f"-o: '{out}' is the folder you are in (or holds it): it would be replaced; give a new "
            f"folder beside it, or run from elsewhere"
        )
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / PREPARE_RECORD).is_file())):
        raise InputError(f"-o: '{out}' exists and is not a folder `brainshift prepare` made; give a new folder")
    if not out.resolve().parent.is_dir():
        raise InputError(f"-o: the folder '{out.resolve().parent}' does not exist")


def write_folder(
    folder: Path,
    patient,
    labels,
    present,
    brain,
    anatomy,
    registration,
    args,
    gravity,
    levels,
    tumour,
    forced: str | None,
) -> None:
    """Every file of the prepared folder but prepare.json, into ``folder`` (the temporary one)."""
    sitk.WriteImage(_stored(patient), str(folder / "t1.nii.gz"))
    label_image = sitk.GetImageFromArray(labels)
    label_image.CopyInformation(patient)
    sitk.WriteImage(label_image, str(folder / "labels.nii.gz"))
    write_segmentation(folder / "anatomy.seg.nrrd", labels, patient, present)
    sitk.WriteTransform(registration.transform, str(folder / "patient_to_template.h5"))
    skull, triangles = inner_skull(
        folder / "anatomy.seg.nrrd", list(present.values()), brain, patient, args.voxel, args.gap
    )
    write_slicer_stl(folder / "skull.stl", skull, triangles)
    septa = {}
    for name, (points_lps, tri) in anatomy.septa.items():
        if len(tri) == 0:
            continue
        points = registration.to_patient(points_lps) @ LPS_TO_RAS
        write_slicer_stl(folder / f"{name}.stl", points, tri)
        septa[name] = f"{name}.stl"
    probes = {name: registration.to_patient(p[None, :])[0] @ LPS_TO_RAS for name, p in anatomy.probes.items()}
    probes["craniotomy"] = np.asarray(levels["centre_mm"])
    (folder / "scene.toml").write_text(scene_text(args, present, gravity, levels, septa, probes, forced))
    write_overview(
        folder / "overview.png",
        patient,
        labels,
        present,
        f"{Path(args.t1).name}: the brain found and the carried labels",
    )


def _stored(image: sitk.Image) -> sitk.Image:
    """The T1 as int16 when its values are (a scanner's), else float32: half the file, faster."""
    values = sitk.GetArrayViewFromImage(image)
    if np.all(values == np.rint(values)) and values.min() >= -32768 and values.max() <= 32767:
        return sitk.Cast(image, sitk.sitkInt16)
    return image


def _position_words(position: str, levels: dict) -> str:
    if "head_turned_from_supine_deg" in levels:
        return f"{position}: the head turned {levels['head_turned_from_supine_deg']:.0f} degrees from supine"
    return f"{position}, along the head's anatomy"


def scene_text(args, present: dict, gravity, levels: dict, septa: dict, probes: dict, forced: str | None = None) -> str:
    """scene.toml, with the reasons beside the values."""
    import tomllib

    bundled = tomllib.loads(BRAIN_SCENE.read_text())
    material = bundled["material"]
    supports = [n for n in present.values() if n == SUPPORT]
    q = json.dumps
    vec = lambda v: "[" + ", ".join(f"{float(x):.6g}" for x in v) + "]"  # noqa: E731
    lines = [
        f"# A patient scene made by `brainshift prepare` from {q(Path(args.t1).name)} "
        f"({datetime.date.today().isoformat()}).",
        "# Frame: the T1's RAS (x right, y anterior, z superior), metres; the files are in mm. See",
        "# docs/patients.md; prepare.json says how the registration went.",
    ]
    if forced:
        lines += [f"# WARNING: made with --force: {forced}"]
    lines += [
        'name = "patient"',
        "",
        "[mesh]",
        'file = "anatomy.seg.nrrd"   # brain, tumour and supports, carried from the ICBM152 template',
        'unit = "mm"',
        f"voxel = {args.voxel * 1e-3:g}       # m: the embedding mesh's voxel",
        "fill = 0.5",
        f"labels = [{', '.join(q(n) for n in present.values())}]",
        "",
        "[material]          # the bundled brain's (the paper's Table II)",
        f"G = {material['G']}",
        f"nu = {material['nu']}",
        f"density = {material['density']}",
        "",
        f"[gravity]           # {_position_words(args.position, levels)}",
        f"vector = {vec(gravity)}",
        "",
        "[fluid]             # CSF from above the brain down to the craniotomy rim's lowest point",
        f"# levels: m along up in the T1's frame; the start {levels['start_above_rim_mm']:.0f} mm above the rim's "
        f"lowest point, drained at it (the brain spans {levels['brain_bottom_above_rim_mm']:.0f} to "
        f"{levels['brain_top_above_rim_mm']:.0f} mm about it)",
        "density = 1000.0",
        f"level = [[0.0, {levels['start_level_m']:.5f}], [10.0, {levels['rim_level_m']:.5f}]]",
        'rule = "consistent"',
        "follower = true",
        "",
    ]
    for name in supports:
        lines += ["[[fixed]]", f'name = "{name}"', f'label = "{name}"   # carried from the bundled scene', ""]
    lines += [
        f"[skull]             # the inner skull: the brain's surface {args.gap:g} mm out (the CSF layer)",
        'file = "skull.stl"',
        "tolerance = 0.0001   # m: 0.1 mm past the skull is settled (the default 0.01 mm stalled Newton on a",
        "                     # coarse voxel mesh's corners)",
        "",
    ]
    for name, file in septa.items():
        lines += ["[[septum]]", f'name = "{name}"', f'file = "{file}"   # the bundled scene\'s plane, carried', ""]
    lines += [
        "[time]",
        'mode = "quasi-static"   # the settled states after the drain',
        "",
        "[solver]",
        'kind = "cholesky"',
        "",
        "[probes]              # m, RAS: the bundled scene's, carried, and the craniotomy's centre",
    ]
    lines += [f"{name} = {vec(np.asarray(p) * 1e-3)}" for name, p in probes.items()]
    # relative to where the command runs, as every scene's: PATIENT/run from where prepare ran
    lines += [
        "",
        "[output]",
        f"folder = {q((Path(args.output) / 'run').as_posix())}",
        'fields = ["displacement", "von_mises"]',
        "",
    ]
    return "\n".join(lines)
