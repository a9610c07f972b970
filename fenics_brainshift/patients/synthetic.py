"""Synthetic patients for checking `brainshift prepare`: the ICBM152 T1 moved by a known rigid
motion and a known smooth deformation, with a bias field and noise, resampled to an oblique
anisotropic grid, and written as a DICOM series (as a scanner exports it), a NIfTI or a NRRD.

``known``: the transform from the patient's points to the template's (LPS mm), the truth a
registration should find. Used by tests/test_prepare.py, benchmarks/prepare.py and demos.
"""

from __future__ import annotations

import datetime
import locale
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import SimpleITK as sitk
from scipy import ndimage

MR_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.4"


@dataclass
class SyntheticPatient:
    image: sitk.Image  # float32, the patient's T1
    known: sitk.Transform  # patient LPS mm -> template LPS mm
    rotation: np.ndarray  # the head's turn (template <- patient, LPS), without the scale


def with_head(template: sitk.Image, head: sitk.Image, head_brain: sitk.Image, brain: sitk.Image) -> sitk.Image:
    """The skull-stripped ``template`` put inside a whole ``head`` (FSL's MNI152, the same
    space; ``head_brain`` its brain mask): the head's intensities resampled onto the template's
    grid and scaled so the two brains' medians agree, the template's own inside its ``brain``
    mask, and CSF (dark) where the head's brain reaches past the template's. A scanner's T1
    shows brain, CSF, skull, scalp and neck; a synthetic patient made from this has them, and
    its brain is still exactly the template's, carried by the known transform."""
    on_grid = sitk.Resample(head, template, sitk.Transform(), sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    head_inside = (
        sitk.GetArrayFromImage(sitk.Resample(head_brain, template, sitk.Transform(), sitk.sitkNearestNeighbor, 0)) > 0
    )
    inside = sitk.GetArrayViewFromImage(brain) > 0
    t, h = sitk.GetArrayFromImage(template), sitk.GetArrayFromImage(on_grid)
    brain_median = np.median(t[inside])
    h *= brain_median / max(np.median(h[inside]), 1e-12)
    csf = ndimage.binary_dilation(head_inside, iterations=2) & ~inside
    h[csf] = 0.15 * brain_median
    out = sitk.GetImageFromArray(np.where(inside, t, h).astype(np.float32))
    out.CopyInformation(template)
    return out


def synthetic_patient(
    template: sitk.Image,
    spacing=(1.0, 1.0, 1.5),
    size=(200, 230, 130),
    angles_deg=(8.0, -6.0, 10.0),
    shift_mm=(6.0, -4.0, 5.0),
    scale=0.9,
    warp_mm=3.0,
    tilt_deg=(15.0, 5.0, -10.0),
    bias=0.15,
    noise=0.03,
    seed=0,
    stripped_by: sitk.Image | None = None,
) -> SyntheticPatient:
    """The template seen by a scanner: a head ``scale`` times the template's size (0.9: a
    brain of 1.5 l, the template's is 2.05 l) turned by ``angles_deg`` (about x, y, z) and
    shifted, a smooth deformation of ``warp_mm`` amplitude (sines of 25-35 mm wavelength/2pi),
    on a grid of ``spacing`` and ``size`` tilted by ``tilt_deg``, with a linear-bilinear bias
    field of ``bias`` and Gaussian noise of ``noise`` of the brightest voxel. ``stripped_by``:
    a brain mask on the template's grid; outside it the T1 is exactly 0, as a skull-stripping
    tool leaves a scan (BraTS's, say)."""
    centre = np.array(template.TransformContinuousIndexToPhysicalPoint([s / 2 for s in template.GetSize()]))
    rotation = sitk.Euler3DTransform()
    rotation.SetRotation(*np.radians(angles_deg))
    rigid = sitk.Similarity3DTransform()
    rigid.SetCenter(centre.tolist())
    rigid.SetMatrix(rotation.GetMatrix())
    rigid.SetScale(1.0 / scale)  # patient -> template: a smaller head is scaled up
    rigid.SetTranslation(tuple(map(float, shift_mm)))
    known = sitk.CompositeTransform(3)
    known.AddTransform(rigid)
    if warp_mm:
        known.AddTransform(_smooth_field(centre, warp_mm))  # applied first: p -> rigid(field(p))
    tilt = sitk.Euler3DTransform()
    tilt.SetRotation(*np.radians(tilt_deg))
    direction = np.array(tilt.GetMatrix()).reshape(3, 3)
    origin = centre - direction @ (np.array(size) * np.array(spacing) / 2)
    image = sitk.Resample(
        template,
        [int(s) for s in size],
        known,
        sitk.sitkLinear,
        origin.tolist(),
        [float(s) for s in spacing],
        direction.ravel().tolist(),
        0.0,
        sitk.sitkFloat32,
    )
    values = sitk.GetArrayFromImage(image)
    z, y, x = np.meshgrid(*[np.linspace(-1.0, 1.0, n) for n in values.shape], indexing="ij")
    values = values * (1.0 + bias * x + 0.7 * bias * y * z)
    values += np.random.default_rng(seed).normal(0.0, noise * values.max(), values.shape)
    values = np.clip(values, 0.0, None)
    if stripped_by is not None:
        kept = sitk.Resample(sitk.Cast(stripped_by, sitk.sitkFloat32), image, known, sitk.sitkLinear, 0.0)
        values[sitk.GetArrayFromImage(kept) < 0.5] = 0.0
    out = sitk.GetImageFromArray(values.astype(np.float32))
    out.CopyInformation(image)
    return SyntheticPatient(out, known, np.array(rotation.GetMatrix()).reshape(3, 3))


def _smooth_field(centre: np.ndarray, amplitude: float) -> sitk.DisplacementFieldTransform:
    shape, step = np.array([40, 48, 40]), 5.5
    origin = centre - shape / 2 * step
    axes = [origin[d] + step * np.arange(shape[d]) for d in range(3)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    d = np.stack(
        [amplitude * np.sin(y / 30.0), 0.8 * amplitude * np.sin(z / 25.0), amplitude * np.cos(x / 35.0)], axis=-1
    )
    field = sitk.GetImageFromArray(np.transpose(d, (2, 1, 0, 3)).astype(np.float64), isVector=True)
    field.SetOrigin(origin.tolist())
    field.SetSpacing([step] * 3)
    return sitk.DisplacementFieldTransform(field)


def write_dicom_series(
    image: sitk.Image, folder: Path, skip: tuple[int, ...] = (), repeat: tuple[int, ...] = ()
) -> Path:
    """``image`` as an MR DICOM series of int16 slices in ``folder`` (one file per slice, the
    geometry in ImagePositionPatient / ImageOrientationPatient); ``skip``: slices left out
    (a series with missing slices), ``repeat``: slices written twice at one position (4-D)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    values = sitk.GetArrayFromImage(image)
    scaled = sitk.GetImageFromArray(np.rint(values / max(values.max(), 1e-12) * 2000.0).astype(np.int16))
    scaled.CopyInformation(image)
    direction = image.GetDirection()
    now = datetime.datetime(2026, 1, 1, 12, 0, 0)
    series_uid = "1.2.826.0.1.3680043.8.498.1." + str(zlib.crc32(folder.name.encode()))
    common = {
        "0008|0060": "MR",
        "0008|0016": MR_IMAGE_STORAGE,
        "0008|0021": now.strftime("%Y%m%d"),
        "0008|0031": now.strftime("%H%M%S"),
        "0008|103e": "T1 synthetic",
        "0010|0010": "Synthetic^Patient",
        "0010|0020": "SYN0001",
        "0020|000d": series_uid + ".0",
        "0020|000e": series_uid,
        "0020|0052": series_uid + ".9",  # the frame of reference a DICOM-SEG of it refers to
        "0020|0037": "\\".join(
            f"{v:.9f}" for v in (direction[0], direction[3], direction[6], direction[1], direction[4], direction[7])
        ),
        "0018|0050": f"{image.GetSpacing()[2]:.6f}",
        "0018|0088": f"{image.GetSpacing()[2]:.6f}",
        "0028|1050": "1000",
        "0028|1051": "2000",
    }
    writer = sitk.ImageFileWriter()
    writer.KeepOriginalImageUIDOn()
    saved = locale.setlocale(locale.LC_ALL)  # GDCM's writer sets the C locale and leaves it: Python's
    try:  # open() then reads UTF-8 text as ASCII
        _write_slices(writer, scaled, image, common, series_uid, folder, skip, repeat)
    finally:
        locale.setlocale(locale.LC_ALL, saved)
    return folder


def _write_slices(writer, scaled, image, common, series_uid, folder, skip, repeat) -> int:
    written = 0
    for k in range(image.GetSize()[2]):
        if k in skip:
            continue
        for _copy in range(2 if k in repeat else 1):
            piece = scaled[:, :, k]
            for tag, value in common.items():
                piece.SetMetaData(tag, value)
            position = image.TransformIndexToPhysicalPoint((0, 0, k))
            written += 1
            piece.SetMetaData("0020|0032", "\\".join(f"{v:.6f}" for v in position))
            piece.SetMetaData("0020|0013", str(written))
            piece.SetMetaData("0008|0018", f"{series_uid}.{written}")
            writer.SetFileName(str(folder / f"slice{written:04d}.dcm"))
            writer.Execute(piece)
    return written


def write_dicom_seg(segments: dict[str, np.ndarray], series: Path, path: Path, kind: str = "BINARY") -> Path:
    """``segments`` (name -> [k, j, i] on the series' grid) as a DICOM-SEG of the DICOM series
    in ``series``, written by highdicom as a planning system would: ``kind`` BINARY (bool
    masks; one frame per plane and segment that holds something), FRACTIONAL (probabilities
    0-1) or LABELMAP (disjoint masks; one frame per plane)."""
    import highdicom as hd
    import pydicom

    sources = [pydicom.dcmread(f) for f in sorted(Path(series).iterdir())]
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(reader.GetGDCMSeriesFileNames(str(series)))
    grid = reader.Execute()
    # the plane k of each source file, by its position: the masks are indexed as the series reads
    planes = [
        int(round(grid.TransformPhysicalPointToContinuousIndex(tuple(float(v) for v in s.ImagePositionPatient))[2]))
        for s in sources
    ]
    masks = list(segments.values())
    if kind == "LABELMAP":
        pixels = np.zeros((len(sources), *masks[0].shape[1:]), dtype=np.uint8)
        for number, mask in enumerate(masks, start=1):
            pixels[mask[planes]] = number
    else:
        pixels = np.stack([mask[planes] for mask in masks], axis=-1)
        pixels = pixels.astype(np.float32 if kind == "FRACTIONAL" else np.uint8)
    tissue = hd.sr.CodedConcept("85756007", "SCT", "Tissue")
    descriptions = [
        hd.seg.SegmentDescription(
            segment_number=n,
            segment_label=name,
            segmented_property_category=tissue,
            segmented_property_type=hd.sr.CodedConcept("108369006", "SCT", "Neoplasm"),
            algorithm_type=hd.seg.SegmentAlgorithmTypeValues.MANUAL,
        )
        for n, name in enumerate(segments, start=1)
    ]
    seg = hd.seg.Segmentation(
        source_images=sources,
        pixel_array=pixels,
        segmentation_type=kind,
        segment_descriptions=descriptions,
        series_instance_uid=hd.UID(),
        series_number=100,
        sop_instance_uid=hd.UID(),
        instance_number=1,
        manufacturer="fenics-brainshift",
        manufacturer_model_name="synthetic",
        software_versions="1",
        device_serial_number="1",
    )
    seg.save_as(path)
    return Path(path)
