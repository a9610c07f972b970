"""The map from a patient's T1 to the ICBM152 template's: rigid, then affine, then a cubic
B-spline, each by Mattes mutual information (robust to the scanner's contrast and bias field)
over a coarse-to-fine pyramid, in SimpleITK.

The ICBM152 2009a T1 the bundled brain was made from is skull-stripped. Registered by
intensities to a scanner's T1, which shows scalp, skull and neck, its brain grows to cover the
head (a real MPRAGE: 6 l). So a whole head is placed first: FSL's whole-head MNI152 T1 (rigid,
then affine, to the patient's head), and the brain stages then start from there and measure
the fit only where the template is brain or within MASK_MARGIN mm of it (the CSF and the skull's
inner table, dark in both). A skull-stripped patient goes straight to the brain stages
(shows_head).

The patient is the fixed image and the template the moving one, so the transform found takes
a patient point (LPS mm) to the template point that lies there: resampling the template's
labels through it gives them on the patient's grid. Measured (benchmarks/results/prepare*.md):
on synthetic patients with and without a head, against their known transform, and on a real
MPRAGE, by its volume and correlation.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import SimpleITK as sitk
from scipy import ndimage

log = logging.getLogger(__name__)

# (stage, shrink factors, smoothing sigmas in mm, iterations)
STAGES = {
    "head rigid": ((4, 2), (2.0, 1.0), 100),
    "head affine": ((4, 2), (2.0, 1.0), 100),
    "rigid": ((4, 2), (2.0, 1.0), 100),
    "affine": ((4, 2), (2.0, 1.0), 200),
    "deformable": ((4, 2), (2.0, 1.0), 20),
}
HEAD_LITRES = 2.2  # a scan with more than this of tissue is a head, not a stripped brain (shows_head)
STRIPPED_ZEROS = 0.2  # a T1 with this share of voxels exactly 0 was skull-stripped by a tool
# mm: after the head, the brain stages' metric sees the template's brain and this much around
# it (the CSF and the skull's inner table, dark in both; not the scalp). Measured on the real
# MPRAGE: unmasked, the B-spline grew the brain onto the skull (1.59 l); on a synthetic head, a
# tighter mask shrank it (a masked metric gains by leaving hard voxels out: 3 % at 6 mm). The
# affine's mask changed little on the real MPRAGE (1.29 l without, 1.32 l with)
MASK_MARGIN = 6.0  # the affine stage
BSPLINE_MARGIN = 10.0  # the B-spline
INVERSE_GRID = 2.0  # mm: the grid the B-spline's displacement is inverted on
FIELD_SPACING = 2.0  # mm: the grid of the displacement field images are resampled through (Registration.sampled)
FIELD_MARGIN = 4.0  # mm: that grid's reach past the patient's image
INVERSE_MARGIN = 20.0  # mm: that grid's reach past the patient's image
BSPLINE_MESH = 6  # control-point intervals along each axis of the patient's image
SAMPLING = {
    "head rigid": 0.1,
    "head affine": 0.1,
    "rigid": 0.1,
    "affine": 0.1,
    "deformable": 0.05,
}  # share of voxels the metric samples
CONVERGENCE = (1e-6, 10)  # gradient descent stops when the metric changes less than this over that many steps
MIN_SAMPLES = 10000  # and at least this many at each level (a small grid's coarse level has a few thousand)


@dataclass
class Registration:
    """``transform``: patient LPS mm -> template LPS mm (the affine after a B-spline, or the
    affine alone); ``affine``: the affine part; ``grid``: an image with the patient's geometry
    (the B-spline's domain); ``stages``: each stage's time (s) and final metric."""

    transform: sitk.CompositeTransform
    affine: sitk.AffineTransform
    grid: sitk.Image
    stages: list[dict] = field(default_factory=list)
    _inverse: sitk.Transform | None = field(default=None, repr=False)

    def sampled(self, spacing: float = FIELD_SPACING) -> sitk.Transform:
        """The transform as a displacement field on a ``spacing`` mm grid over the patient's
        image (and FIELD_MARGIN around it), linearly interpolated: for resampling a whole image,
        where the B-spline evaluated at each of a 0.4 mm navigation T1's 31 million voxels took
        34 s. The affine part is linear, so exact; the B-spline (control points ~30 mm apart) is
        smooth on 2 mm: the labels it carries agree but for voxels on their edges
        (tests/test_prepare.py)."""
        if self.transform.GetNumberOfTransforms() < 2:
            return self.transform
        grid = self.grid
        extent = np.array(grid.GetSpacing()) * np.array(grid.GetSize()) + 2 * FIELD_MARGIN
        size = [int(np.ceil(e / spacing)) + 1 for e in extent]
        direction = np.array(grid.GetDirection()).reshape(3, 3)
        origin = np.array(grid.GetOrigin()) - direction @ (0.5 * np.array(grid.GetSpacing()) + FIELD_MARGIN)
        field = sitk.TransformToDisplacementField(
            self.transform, sitk.sitkVectorFloat64, size, origin.tolist(), [spacing] * 3, grid.GetDirection()
        )
        return sitk.DisplacementFieldTransform(field)

    def to_template(self, points_lps: np.ndarray) -> np.ndarray:
        return np.array([self.transform.TransformPoint(tuple(map(float, p))) for p in points_lps]).reshape(-1, 3)

    def to_patient(self, points_lps: np.ndarray) -> np.ndarray:
        """The patient points the transform takes to ``points_lps`` (template, LPS mm). The
        transform is p -> A(p + d(p)); its inverse q -> r + d'(r), r = A^-1(q), d' the inverse
        of the B-spline's displacement field on an INVERSE_GRID mm grid (ITK's iterative
        inversion). (A fixed-point iteration point by point found spurious roots outside the
        B-spline's domain, where it is the identity, for points near the image's edge.)"""
        inverse = self.affine.GetInverse()
        r = np.array([inverse.TransformPoint(tuple(map(float, x))) for x in np.asarray(points_lps).reshape(-1, 3)])
        if self.transform.GetNumberOfTransforms() < 2:
            return r.reshape(-1, 3)
        if self._inverse is None:
            self._inverse = self._inverse_displacement()
        return np.array([self._inverse.TransformPoint(tuple(map(float, x))) for x in r]).reshape(-1, 3)

    def _inverse_displacement(self) -> sitk.Transform:
        grid = self.grid
        # the patient's grid and INVERSE_MARGIN mm around it: a point near the image's edge is
        # moved past it by the B-spline (identity outside its domain)
        extent = np.array(grid.GetSpacing()) * np.array(grid.GetSize()) + 2 * INVERSE_MARGIN
        spacing = np.maximum(np.array(grid.GetSpacing()), INVERSE_GRID)
        size = [int(np.ceil(e / s)) + 1 for e, s in zip(extent, spacing)]
        direction = np.array(grid.GetDirection()).reshape(3, 3)
        origin = np.array(grid.GetOrigin()) - direction @ (0.5 * np.array(grid.GetSpacing()) + INVERSE_MARGIN)
        forward = sitk.TransformToDisplacementField(
            self.transform.GetNthTransform(1),
            sitk.sitkVectorFloat64,
            size,
            origin.tolist(),
            spacing.tolist(),
            grid.GetDirection(),
        )
        inverse = sitk.InvertDisplacementField(
            forward,
            maximumNumberOfIterations=50,
            maxErrorToleranceThreshold=0.01,
            meanErrorToleranceThreshold=1e-4,
            enforceBoundaryCondition=True,
        )
        return sitk.DisplacementFieldTransform(inverse)


def normalised(image: sitk.Image) -> sitk.Image:
    """Intensities windowed to [0, 1] between the 1st and 99th percentile of the non-zero voxels."""
    values = sitk.GetArrayViewFromImage(image)
    inside = values[values > 0] if np.any(values > 0) else values.ravel()
    lo, hi = np.percentile(inside, [1, 99])
    if hi <= lo:
        hi = lo + 1.0
    return sitk.Cast(sitk.IntensityWindowing(image, float(lo), float(hi), 0.0, 1.0), sitk.sitkFloat32)


def shows_head(patient: sitk.Image) -> bool:
    """Whether the scan shows the head (scalp, skull, neck: 2.7-5.2 l of tissue here, a T2 from
    the vertex to the skull base included) or a skull-stripped brain (1-1.8 l): the volume
    brighter than a tenth of the 99th percentile once smoothed by 2 mm. Smoothed, a T2's dark
    scalp and muscle stay in (unsmoothed that T2 was 2.38 l and went brain to brain, its brain
    stem lost) and a noisy background stays out."""
    values = sitk.GetArrayFromImage(sitk.SmoothingRecursiveGaussian(patient, 2.0))
    bright = np.count_nonzero(values > 0.1 * np.percentile(values, 99))
    return bright * float(np.prod(patient.GetSpacing())) * 1e-6 > HEAD_LITRES


def stripped_region(patient: sitk.Image) -> np.ndarray | None:
    """Where a skull-stripping tool left a T1's intensities ([k, j, i]; dark ventricles inside
    filled): the scan's own brain, which bounds the template's (a stripped BraTS T1 is 1.02 l,
    the ICBM152 mask carried onto it 1.26 l). None when fewer than STRIPPED_ZEROS of the voxels
    are exactly 0 (a scanner's background is noise, not zeros)."""
    zero = sitk.GetArrayViewFromImage(patient) == 0
    if zero.mean() < STRIPPED_ZEROS:
        return None
    kept = ~zero
    # closing pads with zeros: a brain that leaves the image's edge would lose its edge layer
    return ndimage.binary_fill_holes(kept | ndimage.binary_closing(kept, iterations=1))


def register(
    patient: sitk.Image,
    template: sitk.Image,
    deformable: bool = True,
    head: sitk.Image | None = None,
    brain: sitk.Image | None = None,
) -> Registration:
    """Register the template (moving) to the patient (fixed); float32 images. ``head``: a
    whole-head template in the template's space, to place it first (a patient with scalp and
    skull); ``brain``: the template's brain mask, where the brain stages measure the fit after
    that. On one thread: the answer is the same every time (ITK's threads sum the metric in
    varying order)."""
    threads = sitk.ProcessObject.GetGlobalDefaultNumberOfThreads()
    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(1)
    try:
        return _register(patient, template, deformable, head, brain)
    finally:
        sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(threads)


def _as_affine(rigid: sitk.Euler3DTransform) -> sitk.AffineTransform:
    affine = sitk.AffineTransform(3)
    affine.SetCenter(rigid.GetCenter())
    affine.SetMatrix(rigid.GetMatrix())
    affine.SetTranslation(rigid.GetTranslation())
    return affine


def _dilated(brain: sitk.Image, margin_mm: float) -> sitk.Image:
    radius = [max(1, int(round(margin_mm / s))) for s in brain.GetSpacing()]
    return sitk.BinaryDilate(sitk.Cast(brain > 0, sitk.sitkUInt8), radius)


REGISTRATION_SPACING = 1.0  # mm: a finer scan is registered on this grid (its pyramid: 4 and 2 mm)


def coarsened(image: sitk.Image, spacing: float = REGISTRATION_SPACING) -> sitk.Image:
    """The image on a grid no finer than ``spacing`` mm along any axis (same frame and extent),
    smoothed first; unchanged if it is that coarse already. The pyramid's shrink factors count
    voxels: a 0.41 mm navigation T1 (512 x 512 x 120) took 125 s of registration at twice the
    voxel counts of a 1 mm one."""
    old = np.array(image.GetSpacing())
    if old.min() >= 0.95 * spacing:
        return image
    new = np.maximum(old, spacing)
    size = [int(np.ceil(n * o / s)) for n, o, s in zip(image.GetSize(), old, new)]
    variance = [float(0.25 * max(s * s - o * o, 0.0)) for s, o in zip(new, old)]  # (half the new voxel)^2 - ...
    smooth = sitk.DiscreteGaussian(image, variance=variance, useImageSpacing=True)
    # the new grid's first voxel centre shifted so that it spans the same extent
    direction = np.array(image.GetDirection()).reshape(3, 3)
    origin = np.array(image.GetOrigin()) + direction @ (0.5 * (new - old))
    return sitk.Resample(
        smooth,
        size,
        sitk.Transform(),
        sitk.sitkLinear,
        origin.tolist(),
        new.tolist(),
        image.GetDirection(),
        0.0,
        image.GetPixelID(),
    )


def _register(patient, template, deformable, head, brain) -> Registration:
    fixed, moving = normalised(coarsened(patient)), normalised(template)
    stages: list[dict] = []
    mask = wide = None
    if head is not None:
        whole = normalised(head)
        start = sitk.CenteredTransformInitializer(
            fixed, whole, sitk.Euler3DTransform(), sitk.CenteredTransformInitializerFilter.MOMENTS
        )
        rigid = _stage(fixed, whole, sitk.Euler3DTransform(start), "head rigid", stages)
        affine = _stage(fixed, whole, _as_affine(rigid), "head affine", stages)
        if brain is not None:
            mask, wide = _dilated(brain, MASK_MARGIN), _dilated(brain, BSPLINE_MARGIN)
    else:
        start = sitk.CenteredTransformInitializer(
            fixed, moving, sitk.Euler3DTransform(), sitk.CenteredTransformInitializerFilter.MOMENTS
        )
        rigid = _stage(fixed, moving, sitk.Euler3DTransform(start), "rigid", stages)
        affine = _as_affine(rigid)
    affine = _stage(fixed, moving, affine, "affine", stages, mask=mask)
    total = sitk.CompositeTransform(3)
    total.AddTransform(affine)
    if deformable:
        bspline = sitk.BSplineTransformInitializer(fixed, [BSPLINE_MESH] * 3, order=3)
        bspline = _stage(fixed, moving, bspline, "deformable", stages, initial=affine, mask=wide)
        total.AddTransform(bspline)  # applied first: p -> affine(bspline(p))
    grid = sitk.Image(patient.GetSize(), sitk.sitkUInt8)
    grid.CopyInformation(patient)
    return Registration(total, affine, grid, stages)


def _stage(fixed, moving, transform, name: str, stages: list, initial=None, mask=None):
    shrink, smooth, iterations = STAGES[name]
    method = sitk.ImageRegistrationMethod()
    method.SetMetricAsMattesMutualInformation(numberOfHistogramBins=32)
    method.SetMetricSamplingStrategy(method.RANDOM)
    # a share of the voxels, but never a few hundred (a small grid's coarse level: a noisy
    # metric, an optimiser stopping anywhere); seeded, and on one thread: ITK's threads sum
    # the metric in a varying order, and the same T1 gave masks differing by voxels
    voxels = [float(np.prod(np.array(fixed.GetSize()) / f)) for f in shrink]
    method.SetMetricSamplingPercentagePerLevel([min(1.0, max(SAMPLING[name], MIN_SAMPLES / v)) for v in voxels], seed=1)
    method.SetInterpolator(sitk.sitkLinear)
    if mask is not None:
        method.SetMetricMovingMask(mask)
    if name == "deformable":
        method.SetOptimizerAsLBFGSB(
            gradientConvergenceTolerance=1e-5, numberOfIterations=iterations, maximumNumberOfCorrections=5
        )
        method.SetMovingInitialTransform(initial)
    elif name == "affine":
        # a regular step, halved when the gradient turns: gradient descent's convergence check
        # stopped this stage after 9-27 steps, the brain still a voxel off (Dice 0.93 against
        # 0.99 on a synthetic head with the exact answer in reach)
        method.SetOptimizerAsRegularStepGradientDescent(
            learningRate=1.0, minStep=1e-4, numberOfIterations=200, relaxationFactor=0.5
        )
        method.SetOptimizerScalesFromPhysicalShift()
    else:
        method.SetOptimizerAsGradientDescent(
            learningRate=1.0,
            numberOfIterations=iterations,
            convergenceMinimumValue=CONVERGENCE[0],
            convergenceWindowSize=CONVERGENCE[1],
            estimateLearningRate=method.EachIteration,
        )
        method.SetOptimizerScalesFromPhysicalShift()
    method.SetShrinkFactorsPerLevel(list(shrink))
    method.SetSmoothingSigmasPerLevel(list(smooth))
    method.SmoothingSigmasAreSpecifiedInPhysicalUnitsOn()
    method.SetInitialTransform(transform, inPlace=True)
    began = time.perf_counter()
    before = _full_metric(method, fixed, moving)
    start = transform.GetParameters()
    method.Execute(fixed, moving)
    after = _full_metric(method, fixed, moving)
    # a stage is kept only if it improved its own metric at the finest grid: on a post-contrast
    # T1 the brain's affine fell from mutual information 0.48 to 0.17 over its 200 steps and the
    # B-spline started from there (a diverged stage, not a fit)
    accepted = after < before
    if not accepted:
        transform.SetParameters(start)
    seconds = time.perf_counter() - began
    stages.append(
        {
            "stage": name,
            "seconds": round(seconds, 2),
            "metric": round(min(after, before), 4),
            "metric_before": round(before, 4),
            "accepted": bool(accepted),
            "iterations": method.GetOptimizerIteration(),
        }
    )
    log.info(
        "registration %s: %.1f s, mutual information %.3f -> %.3f after %d iterations%s",
        name,
        seconds,
        -before,
        -after,
        method.GetOptimizerIteration(),
        "" if accepted else ": no better, its start kept",
    )
    return transform


def _full_metric(method: sitk.ImageRegistrationMethod, fixed: sitk.Image, moving: sitk.Image) -> float:
    """The stage's metric (lower is better) at its current transform on the finest grid, with
    the same seeded sample: before and after the stage are compared on equal terms."""
    return float(method.MetricEvaluate(fixed, moving))
