"""Which resection stage an update fits: the one told (`--stage N`), or the one whose fit
explains the points best.

Every stage's update is the same problem (the same scenarios, as many modes) on another
brain, so their fits are compared by the chi-square of every point at each: the sum over the
points of their squared error over the noise's variance (a pair's error is over its three
coordinates, a distance to the surface over one), each point's term capped where the update
calls a point an outlier (OUTLIER x the noise per coordinate). So a pointer slip weighs the
same, the cap, in every stage, while a point on the cavity's wall that a stage without that
wall cannot explain still counts against it (had the points each stage set aside been left
out of every sum, the wall's points, set aside by the stage before the resection, would have
been the evidence dropped). The stage of the smallest is chosen; the others are reported with
their difference, and exp(-difference / 2) is the likelihood of the points under each stage's
fit relative to the chosen one's (the weights at their fits, the regularisation alike for
all: its weight alpha is chosen by cross-validation at the first stage that takes the points
and used by the others, which also spares each stage its cross-validation). A stage that
cannot take the points at all (a landmark in the tissue it removed) is left out and says why.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from . import store
from .update import OUTLIER

AMBIGUOUS = 2.0  # chi-square difference below which two stages explain the points about equally


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


def load_stages(folder: str | Path, atlas: store.Atlas, told: int | None) -> list[tuple[int, store.Atlas]]:
    """[(number, atlas)]: the stage told, or every stage (0: the atlas before the resection)."""
    if told is not None:
        return [(told, atlas if told == 0 else store.read_stage(folder, atlas, told))]
    return [(0, atlas)] + [(k, store.read_stage(folder, atlas, k)) for k in range(1, store.stage_count(atlas) + 1)]


def fit_stages(stages: list[tuple[int, store.Atlas]], fit, noise: float, dims: np.ndarray) -> tuple:
    """(the stage's number, its atlas, fit(its atlas), the evidence [{stage, ...}]) of the
    stage whose fit's chi-square is the smallest (of one stage: that one). fit(atlas, alpha)
    -> an object with .result (atlas.update.UpdateResult), alpha None: chosen by
    cross-validation, else the first stage's given; an InputError it raises for a stage
    leaves that stage out (and is raised when every stage raises one); dims: the coordinates
    each point measures (3 a pair, 1 a distance to the surface)."""
    answers, reasons, alpha = [], [], None
    for _, atlas in stages:
        try:
            answers.append(fit(atlas, alpha))
            reasons.append(None)
            alpha = answers[-1].result.alpha
        except InputError as exc:
            if len(stages) == 1:
                raise
            answers.append(None)
            reasons.append(str(exc))
    usable = [i for i, a in enumerate(answers) if a is not None]
    if not usable:
        raise InputError(reasons[0])
    evidence = []
    for i, (number, atlas) in enumerate(stages):
        e = {"stage": number, "removed_ml": float((atlas.info.get("stage") or {}).get("removed_ml", 0.0))}
        if answers[i] is None:
            e["left_out"] = reasons[i]
        else:
            result = answers[i].result
            e["residual_rms_mm"] = float(np.sqrt(np.mean(result.residual**2))) * 1e3  # (every point, as judged)
            e["chi_square"] = chi_square(result.residual, dims, noise)
        evidence.append(e)
    best = min(usable, key=lambda i: evidence[i]["chi_square"])
    for i in usable:
        evidence[i]["delta_chi_square"] = evidence[i]["chi_square"] - evidence[best]["chi_square"]
        evidence[i]["relative_likelihood"] = float(np.exp(-0.5 * evidence[i]["delta_chi_square"]))
    for e in evidence:
        e["points_judged"] = len(answers[best].result.residual)
    return stages[best][0], stages[best][1], answers[best], evidence


def chi_square(residual: np.ndarray, dims: np.ndarray, noise: float) -> float:
    """The points' chi-square at a fit, each term capped at OUTLIER^2 x its coordinates."""
    return float(np.minimum((residual / noise) ** 2, OUTLIER**2 * dims).sum())


def runner_up(evidence: list[dict], chosen: int) -> dict | None:
    """The stage nearest the chosen one's chi-square when within AMBIGUOUS of it, else None."""
    others = [e for e in evidence if e["stage"] != chosen and "delta_chi_square" in e]
    close = [e for e in others if e["delta_chi_square"] < AMBIGUOUS]
    return min(close, key=lambda e: e["delta_chi_square"]) if close else None


def present_in(whole: np.ndarray, stage: np.ndarray) -> np.ndarray:
    """(len(whole),) bool: which of the mesh's cells a stage's atlas still holds."""
    keys = np.sort(whole, axis=1)
    kept = np.sort(stage, axis=1)
    view = lambda a: np.ascontiguousarray(a, dtype=np.int64).view([("", np.int64)] * 4).ravel()  # noqa: E731
    return np.isin(view(keys), view(kept))


def removed(atlas) -> dict:
    """What a stage's atlas removed (its region, ml, fraction), empty before the resection."""
    stage = atlas.info.get("stage")
    if not stage:
        return {"removed_ml": 0.0}
    return {"of": stage["of"], "region": stage["region"], "removed_ml": stage["removed_ml"],
            "removed_fraction": stage["removed_fraction"]}  # fmt: skip


def stage_line(report: dict) -> str:
    """Which resection stage was fitted, and why (and whether the points can tell)."""
    number, evidence = report["number"], report["evidence"]
    removed = f"{report['removed_ml']:.1f} ml removed" if number else "before the resection"
    if report["told"]:
        return f"  resection stage {number} ({removed}), as told"
    chosen = next(e for e in evidence if e["stage"] == number)
    others = "; ".join(
        f"{e['stage']}: {e['residual_rms_mm']:.2f} mm (chi-square +{e['delta_chi_square']:.3g})"
        if "left_out" not in e
        else f"{e['stage']}: left out ({e['left_out'][:120]})"
        for e in evidence
        if e["stage"] != number
    )
    line = (
        f"  resection stage {number} ({removed}), chosen by the data: residual {chosen['residual_rms_mm']:.2f} mm, "
        f"chi-square {chosen['chi_square']:.4g} over all {chosen['points_judged']} points (each capped where a point "
        f"is an outlier); "
        f"the other stages {others}"
    )
    close = runner_up(evidence, number)
    if close is not None:
        line += (
            f"\n  AMBIGUOUS: stage {close['stage']} explains the points about as well (relative likelihood "
            f"{close['relative_likelihood']:.2f}); points on the cavity's wall (--cavity) tell the stages apart, or "
            f"give the stage (--stage)"
        )
    return line
