"""The update: the weights of the atlas's modes that best explain what was measured once the
dura is open, and the displacement they make (combine.py says the problem; rows.py its rows).

Order of the work, each step on the last one's weights:
1. the residuals of the scene's own prediction (the prior), and the weights whose combination
   is nearest to it (where the fit starts);
2. the rows of the data there and, with a skull, the inequality rows of the boundary nodes
   near it (rows.py); alpha by cross-validation over the points, the fit;
3. point to surface: the nearest points found again on the moved surface, and the skull's
   rows taken again at the new weights (nodes the fit brought near join), the fit made again,
   until the weights stand still and no node is past the skull (ROUNDS at most);
4. the leave-one-out error at each point, and the per-node spread of the displacement: from
   the weights' posterior on the fit's face in closed form (posterior.py), or from a
   bootstrap over the points (`samples` refits).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from . import posterior
from .combine import Problem, bootstrap, choose_alpha, leave_one_out, weight_constraints
from .prepared import (
    bounds,
    combination,
    family_sum,
    locator,
    moving_surface,
    prepare,
    prior_weights,
    skull_at_prior,
    skull_rows,
    start_inside,
)
from .rows import PointRows, ease
from .store import Atlas
from .surface_patch import PATCH_MARGIN, PATCH_TRIES
from .update_checks import PAST_SKULL, against_prediction, check_near, other_frame
from .update_checks import warning as answer_warning

__all__ = ["UpdateResult", "prepare", "update"]  # (prepare: made once per atlas, prepared.py)

if TYPE_CHECKING:
    from ..images.targets import Target

LEAVE_OUT_MAX = 100  # points left out one by one (a scan's thousands: a sample of them; the rest NaN)
MIN_POINT_PAIRS = 3
MIN_SURFACE_POINTS = 5
ROUNDS = 4  # of nearest points (point to surface) and of the skull's rows
# the rounds stop once one moves the fit at no point by more than this share of the noise (a
# round past that changes the answer far below what the points can tell; each costs a solve)
ROUND_STILL = 0.1
OUTLIER = 5.0  # a point left out farther than this many times the noise's expected error...
OUTLIER_MEDIAN = 3.0  # ...and this many times the median left-out error is set aside
OUTLIERS_MAX = 0.25  # of the points: more than that is not a few slips, it is the model or the frame


@dataclass
class UpdateResult:
    """An update: the modes' weights and regularisation (alpha, its cross-validation curve),
    the residuals before and after (m), the displacement at the nodes and the fine surface, its
    per-node spread, what the skull's rows did, and the time each part took."""

    weights: np.ndarray
    alpha: float
    curve: list[dict]
    prior_residual: np.ndarray  # (points,) m, the scene's own prediction
    residual: np.ndarray  # (points,) m, updated
    leave_one_out: np.ndarray  # (points,) m
    displacement: np.ndarray  # (N, 3) m at the atlas's nodes
    surface_displacement: np.ndarray | None  # (S, 3) m at the fine surface's vertices
    spread: np.ndarray  # (N,) m: per node, the RMS deviation sqrt(E|u - E u|^2) (posterior or bootstrap)
    skull: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    warning: str | None = None
    outliers: list[int] = field(default_factory=list)  # the points set aside (not in the fit)
    spread_from: str = "posterior"  # or "bootstrap (N resamplings)"
    problem: object = field(default=None, repr=False, compare=False)  # combine.Problem of the fit (its posterior)

    def volume_changes(self, atlas) -> dict[str, float]:
        """Each swelling region's fitted volume change."""
        return {
            s["region"]: s["prior"] + float(c) * s["step"]
            for s, c in zip(atlas.scenarios, self.weights)
            if s["kind"] == "swelling"
        }

    def stiffness(self, atlas) -> float | None:
        """The fitted G (Pa): the scene's over the family's weights' sum."""
        s = atlas.info.get("stiffness")
        return s["G"] / float(self.weights[atlas.family].sum()) if s else None

    def stiffness_at_bound(self, atlas) -> str | None:
        """ "lower" / "upper" when the fitted G sits on the atlas's range (the data would take it
        farther: not a measurement), else None."""
        s, G = atlas.info.get("stiffness"), self.stiffness(atlas)
        if not s or s["lower"] == s["upper"]:
            return None
        near = 1e-3 * (s["upper"] - s["lower"])
        return "lower" if G - s["lower"] <= near else "upper" if s["upper"] - G <= near else None

    def family_weights(self, atlas, smallest: float = 1e-3) -> list[dict]:
        """The family's scenarios with a weight above `smallest`, largest first."""
        out = [
            {"weight": float(c), **s["values"]}
            for s, c in zip(atlas.scenarios, self.weights)
            if s["kind"] == "family" and c > smallest
        ]
        return sorted(out, key=lambda s: -s["weight"])


def update(
    atlas: Atlas,
    target: Target,
    noise: float,
    samples: int = 0,
    keep_inside: bool = True,
    set_aside: bool = True,
    alpha: float | None = None,
) -> UpdateResult:
    """The update of an atlas (store.Atlas) to a target (images.targets.Target), noise in m;
    samples: 0 for the spread from the posterior, else the bootstrap's resamplings;
    keep_inside: the skull's rows in the fit (False: the modes' own contact alone, to measure
    what the rows add); set_aside: points whose left-out error is far past the noise and the
    other points' (a pointer slip, a landmark on the wrong structure) are set aside and the
    update made again without them (they are reported, with their error at the new fit); a
    point not among those left out (LEAVE_OUT_MAX) is judged by its error at the fit; alpha:
    the regularisation's weight if already chosen (a live case's last update), else chosen by
    cross-validation."""
    result = _update(atlas, target, noise, samples, keep_inside, alpha)
    if not set_aside:
        return result
    dims = coordinates(target)
    loo = result.leave_one_out
    limit = np.maximum(OUTLIER * noise * np.sqrt(dims), OUTLIER_MEDIAN * float(np.nanmedian(loo)))
    # a point not left out (a scan's thousands: a sample is) is judged by its error at the
    # fit, which its own weight in the fit can only have made smaller than its left-out one
    judged = np.where(np.isfinite(loo), loo, result.residual)
    far = np.flatnonzero(judged > limit)
    keep = np.setdiff1d(np.arange(len(loo)), far)
    if not len(far) or len(far) > OUTLIERS_MAX * len(loo) or _too_few(target.subset(keep)):
        return result
    kept = target.subset(keep)
    again = _update(atlas, kept, noise, samples, keep_inside, alpha)
    # every point's errors at the new fit (the set-aside ones' "left out" is their error now)
    residual = np.zeros(len(loo))
    residual[keep] = again.residual
    residual[far] = _errors(atlas, target, again.displacement, again.surface_displacement)[far]
    left_out = residual.copy()
    left_out[keep] = again.leave_one_out
    names = ", ".join(f"{target.labels[i]} ({judged[i] * 1e3:.3g} mm)" for i in far[:5])
    note = (
        f"{len(far)} point(s) set aside as outliers, their error when left out far past the noise and "
        f"the others' ({names}; limit {limit.min() * 1e3:.3g} mm; --keep-all fits them): a pointer slip, a landmark"
        f" on another structure, or points mismatched between --pre and --target"
    )
    seconds = {k: v + result.seconds.get(k, 0.0) for k, v in again.seconds.items()}
    return dataclasses.replace(
        again,
        prior_residual=result.prior_residual,
        residual=residual,
        leave_one_out=left_out,
        warning="; ".join(w for w in (note, again.warning) if w),
        outliers=[int(i) for i in far],
        seconds=seconds,
    )


def _errors(atlas, target, u: np.ndarray, surface_u) -> np.ndarray:
    """Each point's distance from where the displacement puts it (pairs) or from the moved
    surface (points on the surface), m."""
    out = np.zeros(len(target.measured))
    pairs = target.pairs
    if len(pairs):
        out[pairs] = PointRows(locator(atlas), target.pre[pairs], target.measured[pairs], target.labels).errors(u)
    others = np.setdiff1d(np.arange(len(out)), pairs)
    if len(others):
        shift = surface_u
        if atlas.surface_points is None:
            shift = u[atlas.boundary.vertices]
        out[others] = np.abs(moving_surface(atlas).distances(shift, target.measured[others]))
    return out


def coordinates(target) -> np.ndarray:
    """(n,) the coordinates each point measures: 3 for a pair, 1 for a distance to the surface."""
    dims = np.ones(len(target.measured))
    dims[target.pairs] = 3.0
    return dims


def _too_few(target) -> str | None:
    """Why these points are too few for an update, or None: at least MIN_POINT_PAIRS pairs, or
    MIN_SURFACE_POINTS points on the surface, or as many coordinates as those together."""
    pairs = len(target.pairs)
    surface = len(target.measured) - pairs
    if pairs >= MIN_POINT_PAIRS or surface >= MIN_SURFACE_POINTS or 3 * pairs + surface >= 3 * MIN_POINT_PAIRS:
        return None
    return (
        f"--target: {len(target.measured)} point(s) are too few for the update: give at least {MIN_POINT_PAIRS} "
        f"point pairs or {MIN_SURFACE_POINTS} points on the surface"
    )


@dataclass
class _Fit:
    """The weights the rounds reached, with what they were found by."""

    c: np.ndarray
    alpha: float
    curve: list
    problem: Problem
    residual: np.ndarray  # each point's error at c (point to surface: signed)
    nodes: np.ndarray  # the boundary nodes with skull rows
    deepest: float
    rounds: int
    cv_s: float


def _rounds(atlas, data_rows, noise: float, skull, point_to_point: bool, C0, d0, alpha=None) -> _Fit:
    """Step 2-3 of the update: alpha and the fit, the rows taken again at the new weights.
    data_rows(c) -> (A, b, groups, each point's error at c: signed to the surface)."""
    c = prior_weights(atlas)
    inside = start_inside(atlas)  # (the prior's weights may be past the skull's rows; these are not)
    curve, cv_s, deepest = [], 0.0, 0.0
    nodes = np.zeros(0, dtype=np.int64)
    for round_ in range(ROUNDS):
        A, b, groups, residual = data_rows(c)
        problem = Problem(A, b, groups, noise, atlas.gram, atlas.cross, C0, d0, anchor=inside)
        if skull is not None and round_ == 0:  # (c: the prior's weights)
            nodes, constraints = skull_at_prior(atlas)
            problem = problem.with_all(constraints)
        elif skull is not None:  # the nodes near the skull at these weights join those before
            nodes = np.union1d(nodes, skull.near(c))
            C, d = skull.rows(c, nodes)
            problem = problem.with_constraints(*ease(C, d, inside))
        near = inside if round_ == 0 else c
        if alpha is None:  # alpha once, at the first rows (the nearest points change little after)
            t = time.perf_counter()
            alpha, curve, near = choose_alpha(problem, near=near)  # (its fit to every point at alpha: nearer)
            cv_s = time.perf_counter() - t
        c_new = problem.solve(alpha, near=near)
        # how far the round moved the fit at the points (the rows' own measure: a pair's coordinates,
        # a distance along the surface's normal); the first round's start is the prior, not a fit
        moved = float(np.abs(A @ (c_new - c)).max(initial=0.0)) if round_ else np.inf
        change, c = float(np.abs(c_new - c).max()), c_new
        deepest = skull.deepest(c) if skull is not None else 0.0
        still = change < 1e-6 or moved < ROUND_STILL * noise
        if (point_to_point or still) and deepest <= PAST_SKULL:
            break
    residual = data_rows(c)[3]
    return _Fit(c, alpha, curve, problem, residual, nodes, deepest, round_ + 1, cv_s)


def _update(atlas, target, noise: float, samples: int, keep_inside: bool, alpha: float | None) -> UpdateResult:
    start = time.perf_counter()
    n_points = len(target.measured)
    too_few = _too_few(target)
    if too_few:
        raise InputError(too_few)
    pair, on_surface = target.pairs, np.setdiff1d(np.arange(n_points), target.pairs)
    point_to_point = not len(on_surface)
    modes = atlas.vertex_modes  # float32; the rows and sums take float64 slices of it
    lower, upper = bounds(atlas)
    C0, d0 = weight_constraints(atlas.family, lower, upper, family_sum(atlas))
    surface = moving_surface(atlas) if len(on_surface) else None
    prior_residual = np.zeros(n_points)
    against, fixed = None, None
    if len(pair):
        pairs = PointRows(locator(atlas), target.pre[pair], target.measured[pair], [target.labels[i] for i in pair])
        A, b, groups = pairs.rows(modes)
        fixed = (A, b, pair[groups])  # (a point's rows are grouped by its place among all the points)
        prior_residual[pair] = pairs.errors(atlas.prior_vertex)
        against = against_prediction(pairs.measured - pairs.pre, pairs.at(atlas.prior_vertex), noise)
    if len(on_surface):
        prior_residual[on_surface] = np.abs(surface.prior_distances(target.measured[on_surface]))
    check_near(atlas, prior_residual, point_to_point)
    # (the other frame is tried on one kind of points: the pairs if there are enough, else the surface's)
    chosen = pair if len(pair) >= MIN_POINT_PAIRS or not len(on_surface) else on_surface
    one_kind = target.subset(chosen) if chosen is pair else dataclasses.replace(target.subset(chosen), pre=None)
    mirrored = other_frame(atlas, one_kind, prior_residual[chosen], noise, surface)
    if against and mirrored:  # (gravity across x and y: negating them reverses the shift too; one note)
        against = (
            f"{against}; or {mirrored.removeprefix('the points ')} (pairs cannot tell the two apart when gravity "
            f"lies across x and y)"
        )
    else:
        against = against or mirrored
    skull = skull_rows(atlas) if keep_inside else None
    whole = None  # (point to surface: the whole surface's displacement at the fit, as its patch was checked)
    setup_s = time.perf_counter() - start

    def data_rows(c, patch=None):
        """The rows of every point at weights c: pairs first, then the surface's (its patch's)."""
        error = np.zeros(n_points)
        parts = []
        if fixed is not None:
            r = fixed[0] @ c - fixed[1]
            error[pair] = np.sqrt(np.bincount(np.searchsorted(pair, fixed[2]), weights=r * r, minlength=len(pair)))
            parts.append(fixed)
        if patch is not None:
            A, b, groups, distance = patch.rows.rows(c, target.measured[on_surface])
            error[on_surface] = distance
            parts.append((A, b, on_surface[groups]))
        return (*(np.concatenate(x) for x in zip(*parts)), error)

    if point_to_point:
        fit = _rounds(atlas, data_rows, noise, skull, True, C0, d0, alpha)
    else:  # on the triangles near the points, wider until none left out could be nearer (surface_patch.py)
        measured = target.measured[on_surface]
        radius = prior_residual[on_surface] + PATCH_MARGIN
        for attempt in range(PATCH_TRIES + 1):
            patch = surface.patch(measured, radius if attempt < PATCH_TRIES else np.full(len(measured), np.inf))
            fit = _rounds(atlas, lambda c, patch=patch: data_rows(c, patch), noise, skull, False, C0, d0, alpha)
            whole = surface.fits(patch, fit.c, measured, fit.residual[on_surface])
            if whole is not None or attempt == PATCH_TRIES:
                break
            radius = 2 * radius
    c, alpha, curve, problem, cv_s = fit.c, fit.alpha, fit.curve, fit.problem, fit.cv_s
    nodes, deepest, round_ = fit.nodes, fit.deepest, fit.rounds - 1
    residual = np.abs(fit.residual)
    fit_s = time.perf_counter() - start - setup_s - cv_s
    t = time.perf_counter()
    loo = leave_one_out(problem, alpha, LEAVE_OUT_MAX, near=c)
    u = combination(c, modes)
    if samples:
        sampled = bootstrap(problem, alpha, samples, near=c)
        used = np.flatnonzero(np.any(sampled != 0, axis=0))  # (most of the family's weights are 0)
        fields = np.tensordot(sampled[:, used], modes[used], axes=1)  # (B, N, 3)
        spread = np.sqrt(np.mean(np.sum((fields - fields.mean(axis=0)) ** 2, axis=2), axis=0))
        spread_from = f"bootstrap ({samples} resamplings)"
    else:
        spread, spread_from = posterior.spread(problem, alpha, c, modes), "posterior"
    spread_s = time.perf_counter() - t
    surface_u = None
    if atlas.surface_modes is not None:  # (a fit to the surface has it: the patch was checked on it)
        surface_u = whole if whole is not None else moving_surface(atlas).displacement(c)
    skull_report = {}
    if atlas.skull_triangles is not None:
        skull_report = {
            "kept_inside": keep_inside,
            "nodes_with_rows": int(len(nodes)),
            "rounds": round_ + 1,
            "deepest_past_mm": (deepest if skull is not None else skull_rows(atlas).deepest(c)) * 1e3,
        }
    warning = (
        "; ".join(
            w
            for w in (
                against,
                answer_warning(
                    residual,
                    noise,
                    coordinates(target),
                    skull_report.get("deepest_past_mm", 0.0) * 1e-3,
                    keep_inside,
                    ROUNDS,
                ),
            )
            if w
        )
        or None
    )
    # (cross-validation fits every point at each alpha: the fit's rounds start from its fit at the chosen one;
    # weights_ms: until the weights are known, before leave-one-out and the spread)
    seconds = {
        "setup_ms": setup_s * 1e3,
        "fit_ms": fit_s * 1e3,
        "cross_validation_ms": cv_s * 1e3,
        "weights_ms": (setup_s + cv_s + fit_s) * 1e3,
        "leave_one_out_and_spread_ms": spread_s * 1e3,
        "total_ms": (time.perf_counter() - start) * 1e3,
    }
    return UpdateResult(
        c,
        alpha,
        curve,
        prior_residual,
        residual,
        loo,
        u,
        surface_u,
        spread,
        skull_report,
        seconds,
        warning,
        spread_from=spread_from,
        problem=problem,
    )
