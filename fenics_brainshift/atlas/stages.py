"""Which resection stage an update fits: the one told (`--stage N`), or the one whose fit
explains the points best.

Every stage's update is the same problem (the same scenarios, as many modes) on another
brain, so their fits are compared by the chi-square of the points at each: the sum over the
points of their squared error over the noise's variance (a pair's error is over its three
coordinates, a distance to the surface over one). The stage of the smallest is chosen; the
others are reported with their difference, and exp(-difference / 2) is the likelihood of the
points under each stage's fit relative to the chosen one's (the weights at their fits, the
regularisation alike for all).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from . import store


def parse_stage(text: str | None) -> int | None:
    """--stage: None for "auto" (or not given), else the stage's number (0: before the resection)."""
    if text is None or text.strip().lower() == "auto":
        return None
    try:
        number = int(text)
    except ValueError:
        raise InputError(
            f"--stage {text!r}: give a stage's number (0: before the resection, 1, 2, ...) or auto"
        ) from None
    if number < 0:
        raise InputError(f"--stage {number}: stages are numbered 0 (before the resection), 1, 2, ...")
    return number


def fit_stages(folder: str | Path, atlas: store.Atlas, told: int | None, fit, noise: float) -> tuple:
    """(the stage's number, its atlas, fit(its atlas), the evidence [{stage, ...}]): the stage
    told, or of every stage (0: the atlas before the resection) the one whose fit's chi-square
    is the smallest. fit(atlas) -> an object with .result (atlas.update.UpdateResult)."""
    if told is not None:
        chosen = atlas if told == 0 else store.read_stage(folder, atlas, told)
        answer = fit(chosen)
        return told, chosen, answer, [_evidence(told, chosen, answer.result, noise)]
    count = store.stage_count(atlas)
    candidates = [atlas] + [store.read_stage(folder, atlas, k) for k in range(1, count + 1)]
    answers = [fit(a) for a in candidates]
    evidence = [_evidence(k, a, answer.result, noise) for k, (a, answer) in enumerate(zip(candidates, answers))]
    best = int(np.argmin([e["chi_square"] for e in evidence]))
    for e in evidence:
        e["delta_chi_square"] = e["chi_square"] - evidence[best]["chi_square"]
        e["relative_likelihood"] = float(np.exp(-0.5 * e["delta_chi_square"]))
    return best, candidates[best], answers[best], evidence


def _evidence(number: int, atlas: store.Atlas, result, noise: float) -> dict:
    stage = atlas.info.get("stage") or {}
    return {
        "stage": number,
        "removed_ml": float(stage.get("removed_ml", 0.0)),
        "residual_rms_mm": float(np.sqrt(np.mean(result.residual**2))) * 1e3,
        "chi_square": float(np.sum(result.residual**2) / noise**2),
    }


def present_in(whole: np.ndarray, stage: np.ndarray) -> np.ndarray:
    """(len(whole),) bool: which of the mesh's cells a stage's atlas still holds."""
    keys = np.sort(whole, axis=1)
    kept = np.sort(stage, axis=1)
    view = lambda a: np.ascontiguousarray(a, dtype=np.int64).view([("", np.int64)] * 4).ravel()  # noqa: E731
    return np.isin(view(keys), view(kept))
