"""A patient's T1 to a scene `brainshift run` runs as it is (`brainshift prepare T1 -o PATIENT`).

The template's brain mask and the bundled scene's anatomy (anatomy.py) are carried onto the
patient's grid by one registration (registration.py); the inner skull is the brain's surface
offset by the CSF gap; gravity and the CSF level come from the position on the table and the
craniotomy (position.py). Everything is written into a temporary folder beside PATIENT and
moved into place at the end (folder.py): a failure leaves no half-written folder.
"""

from __future__ import annotations

import datetime
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import SimpleITK as sitk
from scipy import ndimage

from .. import json_text
from ..data.templates import largest_part, mni_brain_mask, mni_head, mni_t1
from ..errors import InputError
from ..images.frames import LPS_TO_RAS
from ..memory import peak_memory_mb
from .anatomy import template_anatomy
from .carry import index_to_lps, labels_on_patient
from .contrast import NAMES as CONTRAST_NAMES
from .contrast import described_contrast, disagrees, measured_family
from .fit_measures import fit_measures
from .folder import PREPARE_RECORD, SUPPORT, check_output, write_folder, written_in_place
from .gate import fit_problem, hints
from .overview import write_overview
from .position import (
    DEEP_RIM_MM,
    G,
    anatomical_gravity,
    craniotomy_levels,
    craniotomy_up_direction,
    is_craniotomy_up,
    over_tumour_centre,
    patient_direction,
)
from .registration import register, shows_head, stripped_region
from .series import read_t1, series_metadata
from .tumour import read_tumour, tumour_report

log = logging.getLogger(__name__)

BRAIN, TUMOUR = 1, 2  # label values; the carried supports follow from 3
DOWN_SIDE = 0.5  # a craniotomy centre below this share of the brain's height as the head lies: a warning
SUPPORT_REACH_MM = 20.0  # a support the brain lost is kept on the brain if it is this close to it,
SUPPORT_BAND_MM = 10.0  # on the brain's voxels within this of the nearest
SUPPORT_KEPT = 0.25  # a support with less than this share of its carried voxels in the brain is laid anew


def prepare(args) -> list[str]:
    """Prepare the patient's folder from the command's arguments (argparse's namespace of
    `brainshift prepare`); returns the report's lines. Refused (InputError) before anything is
    written, or with the overview picture and prepare.json alone when the gate refuses."""
    began = time.perf_counter()
    out, position, centre = _checked_arguments(args)
    times = {}
    t = time.perf_counter()
    patient = read_t1(args.t1)
    tumour = read_tumour(args.tumour, patient, args.tumour_segment) if args.tumour else None
    template = sitk.ReadImage(str(mni_t1()), sitk.sitkFloat32)
    template_brain_image = sitk.ReadImage(str(mni_brain_mask()))
    head = sitk.ReadImage(str(mni_head()), sitk.sitkFloat32) if shows_head(patient) else None
    times["read"] = time.perf_counter() - t

    t = time.perf_counter()
    registration = register(patient, template, deformable=not args.affine_only, head=head, brain=template_brain_image)
    times["registration"] = time.perf_counter() - t

    t = time.perf_counter()
    found = _brain_on_patient(args, patient, template_brain_image, registration, tumour, head is not None)
    report = {
        "t1": str(Path(args.t1).resolve()),
        "grid": _grid(patient),
        "head_first": head is not None,
        **found.report,
        "registration": registration.stages,
    }
    if tumour is not None:
        report["tumour"] = tumour_report(tumour, found.brain, patient)
        found.labels[tumour & (found.labels <= TUMOUR)] = TUMOUR  # a support keeps its voxels (the scene must be held)
        found.brain |= tumour
        found.names[TUMOUR] = "tumour"
    litres, ratio = _judged(args, out, patient, template, registration, found, report)

    surface_mm = _surface(largest_part(found.brain), patient, step=2)[0]  # (not a tumour's part off the brain)
    up, turned = -_gravity(position, registration), is_craniotomy_up(args.position)
    if centre is None and _over_tumour(args):
        centre = over_tumour_centre(tumour, patient, surface_mm, None if turned else up)
    if turned:  # the head turned so the craniotomy is uppermost
        supine_up = up
        up = craniotomy_up_direction(centre, largest_part(found.brain), patient)
    levels = craniotomy_levels(surface_mm, up, centre, args.craniotomy_radius)
    if turned:
        levels["head_turned_from_supine_deg"] = round(float(np.degrees(np.arccos(np.clip(up @ supine_up, -1, 1)))), 1)
        _warn_if_feet_up(up, registration, levels)
    if levels["centre_height"] < DOWN_SIDE:
        log.warning(
            "prepare: the craniotomy at (%s) mm lies on the brain's lower side as the head lies (--position "
            "%s; %.0f %% of the way up): the CSF would drain through it entirely and the brain sag away "
            "from it; check --position and --craniotomy",
            ", ".join(f"{v:.0f}" for v in levels["centre_mm"]),
            args.position,
            100 * levels["centre_height"],
        )
        report["craniotomy_on_lower_side"] = True
    if levels["brain_top_above_rim_mm"] > DEEP_RIM_MM and not turned:
        log.warning(
            "prepare: the craniotomy's rim lies %.0f mm below the brain's top as the head lies (--position %s): "
            "drained to it, most of the brain stands above the CSF; a surgeon turns the head to bring the "
            "craniotomy up: --position craniotomy-up",
            levels["brain_top_above_rim_mm"],
            args.position,
        )
        report["craniotomy_rim_deep"] = True
    gravity = -up * G
    times["anatomy"] = time.perf_counter() - t

    t = time.perf_counter()
    present = {v: n for v, n in found.names.items() if np.any(found.labels == v)}
    with written_in_place(out) as tmp:
        write_folder(
            tmp,
            patient,
            found.labels,
            present,
            found.brain,
            found.anatomy,
            registration,
            args,
            gravity,
            levels,
            tumour,
            report.get("forced"),
        )
        times["write"] = time.perf_counter() - t
        report.update(
            status="ok",
            position=args.position,
            gravity=[round(g, 6) for g in gravity],
            craniotomy=levels,
            labels={n: v for v, n in present.items()},
            seconds={k: round(v, 2) for k, v in times.items()},
            total_seconds=round(time.perf_counter() - began, 2),
            peak_memory_mb=round(peak_memory_mb()),
            made=datetime.datetime.now().isoformat(timespec="seconds"),
        )
        (tmp / PREPARE_RECORD).write_text(json_text.dumps(report) + "\n")
    return [
        f"prepared {out}: brain {litres:.2f} l, the template explains {100 * ratio:.0f} % of the scan's variance "
        f"in it, {time.perf_counter() - began:.0f} s; run it: brainshift run {out / 'scene.toml'}"
    ]


def _warn_if_feet_up(up: np.ndarray, registration, levels: dict) -> None:
    """A head turned so far that its vertex points below the horizontal (a craniotomy on the
    skull base): no table holds a patient so; warned of."""
    superior = _gravity(np.array([0.0, 0.0, 1.0]), registration)  # the head's superior, patient RAS
    if up @ superior < -0.3:
        log.warning(
            "prepare: --position craniotomy-up turns the head %.0f degrees from supine, its vertex below the "
            "horizontal (the craniotomy at (%s) mm faces the feet): check --craniotomy",
            levels["head_turned_from_supine_deg"],
            ", ".join(f"{v:.0f}" for v in levels["centre_mm"]),
        )


def _over_tumour(args) -> bool:
    return str(args.craniotomy).strip().lower() in ("tumour", "tumor")


def _checked_arguments(args) -> tuple[Path, np.ndarray, np.ndarray | None]:
    """(the output folder, the position's gravity, the craniotomy's centre or None) after the
    arguments' checks: nothing is read before they pass."""
    check_output(Path(args.output))
    out = Path(args.output).resolve()
    position = anatomical_gravity(args.position)
    if _over_tumour(args) and not args.tumour:
        raise InputError("--craniotomy tumour: give the tumour's segmentation with --tumour (or the centre as X,Y,Z)")
    centre = _point(args.craniotomy, "--craniotomy") if args.craniotomy and not _over_tumour(args) else None
    if is_craniotomy_up(args.position) and not args.craniotomy:
        raise InputError("--position craniotomy-up: give the craniotomy to bring up (--craniotomy X,Y,Z or tumour)")
    if not 0.5 <= args.gap <= 10.0:
        raise InputError(f"--gap: {args.gap:g} mm; the CSF layer between brain and skull is 0.5-10 mm (default 3)")
    if not 5.0 <= args.craniotomy_radius <= 60.0:
        raise InputError(
            f"--craniotomy-radius: {args.craniotomy_radius:g} mm; a craniotomy's radius is 5-60 mm (default 25)"
        )
    if not 2.0 <= args.voxel <= 10.0:
        raise InputError(f"--voxel: {args.voxel:g} mm; the mesh's voxel is 2-10 mm (default 5, the paper's)")
    return out, position, centre


@dataclass
class _Found:
    """The brain found on the patient's grid, with the labels carried there."""

    anatomy: object  # anatomy.Anatomy of the template
    names: dict  # label value -> name
    labels: np.ndarray  # the patient's label volume (z, y, x)
    brain: np.ndarray  # bool, the brain (and the tumour, once added)
    report: dict  # for prepare.json


def _brain_on_patient(args, patient, template_brain_image, registration, tumour, head_first: bool) -> _Found:
    """The template's brain and supports carried onto the patient, bounded by the scan's own
    skull stripping where it has one; a support the brain lost kept on its nearest face."""
    template_brain = sitk.GetArrayFromImage(template_brain_image) > 0
    anatomy = template_anatomy(template_brain_image, template_brain)
    names = {BRAIN: "brain"}
    masks = {BRAIN: template_brain}
    for n, (name, mask) in enumerate(anatomy.supports.items()):
        names[TUMOUR + 1 + n] = name
        masks[TUMOUR + 1 + n] = mask
    labels = labels_on_patient(masks, template_brain_image, patient, registration)
    carried = labels.copy()
    brain = labels > 0
    own = stripped_region(patient) if not head_first else None
    if own is not None:  # a stripped scan: its stripping bounds the template's brain
        brain &= own
    brain = ndimage.binary_fill_holes(largest_part(brain))
    labels[~brain] = 0
    labels[brain & (labels == 0)] = BRAIN
    moved_supports = _keep_supports(labels, carried, brain, patient, tumour)
    for value, mm in moved_supports.items():
        log.warning(
            "prepare: the %s lies %.0f mm off the brain found (the T1's stripping or field of view cut it): "
            "kept on the brain's face nearest to it",
            names[value].replace("_", " "),
            mm,
        )
    if not any(np.any(labels == v) for v, n in names.items() if n == SUPPORT):
        raise InputError(
            f"prepare: the brain stem, the scene's support, is not in '{Path(args.t1).name}' (below its "
            f"field of view or its skull stripping, more than {SUPPORT_REACH_MM:g} mm from the brain "
            f"found): without it the brain has no support; give a T1 that shows the brain stem"
        )
    report = {
        "bounded_by_stripping": own is not None,
        "supports_moved_mm": {names[v]: d for v, d in moved_supports.items()},
    }
    return _Found(anatomy, names, labels, brain, report)


def _judged(args, out: Path, patient, template, registration, found: _Found, report: dict) -> tuple[float, float]:
    """(brain litres, correlation ratio): the quality gate's measures and the contrast, in the
    report; a registration the gate refuses is refused with its picture (unless --force)."""
    voxel_ml = float(np.prod(patient.GetSpacing())) * 1e-3
    litres = float(found.brain.sum()) * voxel_ml * 1e-3
    measures = fit_measures(patient, template, registration, found.brain)
    correlation, ratio, moved = measures["correlation"], measures["ratio"], measures["ratio_moved"]
    described, source = (
        (args.contrast, "--contrast")
        if args.contrast != "auto"
        else described_contrast(args.t1, series_metadata(args.t1))
    )
    measured = measured_family(correlation)
    report.update(
        brain_litres=round(litres, 4),
        correlation=round(correlation, 4),
        correlation_ratio=round(ratio, 4),
        correlation_ratio_moved=round(moved, 4),
        contrast={"given": described, "from": source, "measured": measured},
    )
    log.info(
        "prepare: %s (from %s), measured %s; brain %.2f l, the template explains %.0f %% of the scan's "
        "variance in it (correlation %.2f)",
        CONTRAST_NAMES.get(described, "contrast not stated"),
        source,
        measured,
        litres,
        100 * ratio,
        correlation,
    )
    if disagrees(described, measured):
        log.warning(
            "prepare: the scan was said to be a %s (%s) but measures %s against the T1 template: check "
            "--contrast or the series",
            CONTRAST_NAMES[described],
            source,
            measured,
        )
    problem = fit_problem(litres, ratio, moved, args.t1)
    if problem and not args.force:
        present = {v: n for v, n in found.names.items() if np.any(found.labels == v)}
        _refuse(out, patient, found.labels, present, args, report, problem)
    if problem:
        log.warning("prepare: %s; going on as --force asks (recorded in scene.toml and prepare.json)", problem)
        report["forced"] = problem
    return litres, ratio


def _point(text: str, what: str) -> np.ndarray:
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise InputError(f"{what}: '{text}' is not three numbers X,Y,Z (RAS mm, as 3D Slicer shows them)")
    return np.array(values)


def _keep_supports(
    labels: np.ndarray, carried: np.ndarray, brain: np.ndarray, patient: sitk.Image, tumour: np.ndarray | None
) -> dict:
    """A support the brain found lost (the brain stem below a skull stripping's or a field of
    view's cut), or kept less than SUPPORT_KEPT of, is laid on the cut face: the brain's voxels
    (not the tumour's) within SUPPORT_BAND_MM of the nearest one to where it was carried, the
    face through which the stem goes on to the spinal cord (a sliver would pin the brain at a
    point, about which it turns). Unless that is more than SUPPORT_REACH_MM away. Returns
    {value: the distance (mm) it was moved}."""
    spacing = np.array(patient.GetSpacing())[::-1]
    moved = {}
    for value in np.unique(carried[carried > TUMOUR]):
        if np.count_nonzero(labels == value) >= SUPPORT_KEPT * np.count_nonzero(carried == value):
            continue
        distance = ndimage.distance_transform_edt(carried != value, sampling=spacing)
        free = brain & ((labels == BRAIN) | (labels == value))
        if tumour is not None:
            free &= ~tumour
        nearest = float(distance[free].min()) if free.any() else np.inf
        if nearest <= SUPPORT_REACH_MM:
            labels[free & (distance <= nearest + SUPPORT_BAND_MM)] = value
            moved[int(value)] = round(nearest, 1)
    return moved


def _refuse(out: Path, patient, labels, present, args, report: dict, problem: str) -> None:
    """The folder gets the picture of what was found and prepare.json (status "refused"), no
    scene; then the one line that says what to try."""
    with written_in_place(out) as tmp:
        write_overview(
            tmp / "overview.png",
            patient,
            labels,
            present,
            f"{Path(args.t1).name}: REFUSED, the brain found and the carried labels",
        )
        report.update(status="refused", refused=problem, made=datetime.datetime.now().isoformat(timespec="seconds"))
        (tmp / PREPARE_RECORD).write_text(json_text.dumps(report) + "\n")
    raise InputError(
        f"prepare: {problem}{hints(patient, labels)}. Look at {out / 'overview.png'}: if the outline is "
        f"on the brain, go on with --force; if not, give an MRI of the whole head (T1, post-contrast T1, "
        f"T2, FLAIR or PD), a 3-D scan that shows the whole brain down to the brain stem"
    )


def _gravity(position: np.ndarray, registration) -> np.ndarray:
    return patient_direction(position, registration.affine.GetMatrix())


def _surface(mask: np.ndarray, grid: sitk.Image, step: int):
    """(points RAS mm, triangles) of marching cubes of a mask ([k, j, i]) on the grid's frame."""
    from skimage.measure import marching_cubes

    pad = 1 + step
    kji, triangles, _, _ = marching_cubes(
        np.pad(mask.astype(np.float32), pad), 0.5, step_size=step, allow_degenerate=False
    )
    ijk = (kji - pad)[:, ::-1]
    return index_to_lps(grid, ijk) @ LPS_TO_RAS, triangles.astype(np.int64)


def _grid(image: sitk.Image) -> dict:
    return {
        "size": list(image.GetSize()),
        "spacing_mm": [round(s, 4) for s in image.GetSpacing()],
        "direction": [round(d, 6) for d in image.GetDirection()],
    }
