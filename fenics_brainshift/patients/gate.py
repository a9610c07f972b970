"""prepare's quality gate: whether the registration found a brain, judged whatever the
scan's contrast, and what about a refused scan may have made it fail."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import SimpleITK as sitk

log = logging.getLogger(__name__)

VOLUME_RANGE = (0.6, 2.6)  # litres: a brain found outside this is a failed registration or a unit slip
PLAUSIBLE = (1.0, 1.7)  # litres: an adult brain; outside it, a warning
# The gate, whatever the contrast: the template's anatomy must explain at least MIN_RATIO of the
# scan's variance in the brain found (the correlation ratio, in its part deeper than 10 mm), and
# MIN_PEAK more than with the registration moved 10 mm along any axis (fit_measures.py).
# Measured (benchmarks/results/prepare_cases.md): an absolute threshold alone cannot judge (right
# registrations by their pictures 0.16-0.65 by contrast and sharpness, a T1's moved 10 mm 0.23);
# the peak is what a right one has: 0.085 (a 2 mm T1) to 0.42 above its surroundings, a 6.5 mm
# slab whose registration sits off its peak -0.10
MIN_RATIO = 0.1
MIN_PEAK = 0.05


def fit_problem(litres: float, ratio: float, moved: float, t1: str) -> str | None:
    """Why the registration is refused, or None: the brain found's volume, and how much of the
    scan's variance in it the template's anatomy explains (the correlation ratio) against what
    it explains with the registration moved 10 mm (a right registration stands on a peak)."""
    low, high = VOLUME_RANGE
    failed = []
    if not low <= litres <= high:
        failed.append(f"the brain found is {litres:.2f} l (a brain is {PLAUSIBLE[0]}-{PLAUSIBLE[1]} l)")
    if ratio < MIN_RATIO or ratio - moved < MIN_PEAK:
        failed.append(
            f"the template's anatomy explains {100 * ratio:.0f} % of the scan's variance in the brain "
            f"found and {100 * moved:.0f} % moved 10 mm (a fit explains {100 * MIN_RATIO:.0f} % or more, "
            f"and {100 * MIN_PEAK:.0f} points more than moved)"
        )
    if failed:
        return f"the registration of the template to '{Path(t1).name}' failed: " + "; ".join(failed)
    if not PLAUSIBLE[0] <= litres <= PLAUSIBLE[1]:
        log.warning(
            "prepare: the brain found is %.2f l, outside an adult's %.1f-%.1f l; check it in 3D Slicer "
            "(anatomy.seg.nrrd over t1.nii.gz)",
            litres,
            *PLAUSIBLE,
        )
    return None


THICK_MM = 3.0  # slices thicker than this: a 2-D series


def hints(patient: sitk.Image, labels: np.ndarray) -> str:
    """What about the scan may have made the registration fail: thick slices, the brain found
    running off the scan's edge."""
    hints = []
    thickest = max(patient.GetSpacing())
    if thickest > THICK_MM:
        hints.append(
            f"its voxels are {thickest:.1f} mm along one axis (a 2-D series; the 3-D one, 1-1.5 mm, registers better)"
        )
    brain = labels > 0
    if brain.any() and any(np.any(np.take(brain, i, axis=a)) for a in range(3) for i in (0, -1)):
        hints.append("the brain found runs off the scan's edge (its field of view cuts the head)")
    return "; " + " and ".join(hints) if hints else ""
