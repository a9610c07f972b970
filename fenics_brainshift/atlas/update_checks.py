"""What an update's data and answer do not support, said with numbers: points far from any
prediction (another frame or unit), points that fit far better mirrored (RAS numbers declared
LPS), a shift against the prediction (--pre and --target swapped), residuals the stated noise
cannot explain (their chi-square), and a brain past the skull."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..images.residuals import chi_square
from .prepared import locator
from .rows import PointRows

PAST_SKULL = 0.15e-3  # m: a node deeper past the skull after the last round is reported
FAR_FROM_PREDICTION = 0.25  # of the body's diagonal: the median prior residual of another frame
# the other frame (x, y negated) is tried when the prediction misses the points by this many
# times the noise, and said to fit better when its residual RMS is below this share
OTHER_FRAME_NOISE = 3.0
OTHER_FRAME_BETTER = 0.5
AGAINST = -0.5  # cosine between the measured and the predicted shift below which the points look swapped


def other_frame(atlas, target, prior_residual: np.ndarray, noise: float, surface) -> str | None:
    """A warning when the points fit the scene's prediction far better in the other frame (x and
    y negated: RAS numbers declared LPS, or the reverse), with both residuals; None otherwise.
    Asked only when the prediction misses the points by more than the noise explains."""
    declared = float(np.sqrt(np.mean(prior_residual**2)))
    if declared <= OTHER_FRAME_NOISE * noise:
        return None
    flip = np.array([-1.0, -1.0, 1.0])
    try:
        if target.pre is not None:
            pairs = PointRows(locator(atlas), target.pre * flip, target.measured * flip, target.labels)
            other = pairs.errors(atlas.prior_vertex)
        else:
            other = np.abs(surface.prior_distances(target.measured * flip))
    except InputError:  # (mirrored, the points leave the body: the declared frame stands)
        return None
    mirrored = float(np.sqrt(np.mean(other**2)))
    if mirrored > OTHER_FRAME_BETTER * declared:
        return None
    return (
        f"the points fit the prediction far better in the other frame, x and y negated (residual RMS "
        f"{mirrored * 1e3:.3g} mm against {declared * 1e3:.3g} mm as declared): RAS numbers declared LPS, or the "
        f"reverse? check the markups' coordinateSystem or --frame"
    )


def check_near(atlas, prior_residual: np.ndarray, point_to_point: bool) -> None:
    """Half the points farther from the prediction than a quarter of the body: another frame."""
    body = float(np.linalg.norm(np.ptp(atlas.points, axis=0)))
    median = float(np.median(prior_residual))
    if median > FAR_FROM_PREDICTION * body:
        what = "where --pre's points are predicted" if point_to_point else "the predicted brain surface"
        raise InputError(
            f"--target: half the points lie more than {median * 1e3:.3g} mm from {what} (the body is "
            f"{body * 1e3:.3g} mm across): a frame or unit slip (RAS or LPS, mm; --frame for a CSV or "
            f"an untagged surface), or points of another body"
        )


def against_prediction(measured_shift: np.ndarray, predicted_shift: np.ndarray, noise: float) -> str | None:
    """The measured shift points against the scene's prediction (cosine of their sums over the
    points below AGAINST), and is well past the noise: --pre and --target swapped, most likely.
    Not refused: a swelling brain can rise out of the craniotomy; the fit then says how well
    the atlas's swelling modes explain it."""
    dot = float(np.sum(measured_shift * predicted_shift))
    norms = float(np.sum(np.linalg.norm(measured_shift, axis=1) * np.linalg.norm(predicted_shift, axis=1)))
    moved = float(np.sqrt(np.mean(np.sum(measured_shift**2, axis=1))))
    if norms == 0 or dot / norms > AGAINST or moved < 2 * noise:
        return None
    return (
        f"the measured points moved against the shift the scene predicts (mean cosine {dot / norms:+.2f}, "
        f"{moved * 1e3:.3g} mm RMS): are --pre and --target swapped? (the brain sags with gravity; a swelling "
        f"one may rise)"
    )


def warning(
    residual: np.ndarray, noise: float, coordinates, deepest: float, keep_inside: bool, rounds: int
) -> str | None:
    """What the update's answer does not support: residuals the stated noise cannot explain
    (their chi-square over ``coordinates`` a point, one number or one a point: 3 for a pair's
    distance, 1 for a distance to the surface), or a brain past the skull."""
    parts = []
    rms = float(np.sqrt(np.mean(residual**2))) if len(residual) else 0.0
    test = chi_square(residual, noise, coordinates)
    if test.unexplained:
        parts.append(
            f"the atlas does not explain the data: the updated residual RMS {rms * 1e3:.3g} mm, "
            f"{test.words(noise)}; usually a frame (RAS/LPS) or unit slip, points mismatched between --pre and "
            f"--target, another patient's points, or an operation the atlas lacks (a resection; a wider --vary)"
        )
    if deepest > PAST_SKULL:
        how = f"after {rounds} rounds of its rows" if keep_inside else "the fit without the skull's rows"
        parts.append(
            f"the updated brain passes the skull by {deepest * 1e3:.2f} mm ({how}): not a physical state there"
        )
    return "; ".join(parts) or None
