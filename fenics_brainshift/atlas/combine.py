"""The weights of the atlas's modes that fit the measurements: a regularised least-squares
problem with linear inequality constraints,

    min_c  |A c - b|^2 / noise^2 + alpha R(c)     subject to  C c >= d,

c the family's weights (>= 0, summing to 1: a convex combination of alternative settled
states) and the swelling amplitudes (within their bounds); R(c) the mean square change of the
displacement from the scene's own prediction over the mesh's nodes, in mm^2 (the update moves
the prediction no farther than the data ask); with a skull, rows of C keep the boundary nodes
inside it (rows.py). Each problem is solved exactly (active_set.py) by Lawson and Hanson's reduction
to a least-distance problem solved by scipy's NNLS (Solving Least Squares Problems, 1974,
ch. 23): a factor of the Hessian, one NNLS of the constraints' size. The many refits of
cross-validation, leave-one-out and the bootstrap start from a nearby solution with the same
constraints (the data rows change): the full fit's, and for a cross-validation fold the
better of its own fit at the previous alpha and the full fit at this one; by the primal
active-set method, a few small KKT solves over the free weights; NNLS if it does not get there.

alpha is chosen by K-fold cross-validation over the measured points (the error at points left
out), from a grid; leave-one-out errors and a bootstrap over the points (the spread of the
displacement over refits, `brainshift update --bootstrap N`) come from the same solver; the
default spread is the posterior's (posterior.py), without refits.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .active_set import ACTIVE, DataHessian, Slack, bound_rows, least_distance, partners, solve_on_active

ALPHAS = tuple(10.0 ** np.arange(-4, 3.5, 1.0))  # the cross-validation grid of alpha (per mm^2)
FOLDS = 5
# the grid's scan stops once the error at points left out has grown this much (relative) at this many alphas in a
# row: past the minimum, toward the prior, whose large alphas cost the most refit steps (the family's weights
# freed one by one toward the prior's dense ones: a third of the cross-validation on the 5 mm skull atlas). Three,
# not two: on random 8-point problems two rises skipped a lower minimum in 11 of 200
# (a curve with two dips), three in none; on the 5 mm skull atlas neither ever changed the choice
RISE, RISES = 0.01, 3
MM2 = 1e-6  # R in mm^2
WARM_START = True  # False: every refit from scratch by NNLS (the baseline benchmarks/update.py times)
# a start may be this far past its constraints (relative): they join the working set, which its first step holds.
# NNLS's answers are past the skull's rows by up to 2.4e-7 of them, and a refit that needs a feasible start then
# fell back to NNLS every time (1.0-16.2 s an update on the 5 mm skull atlas: benchmarks/results/update_skull.md at
# commit ac99200); re-linearised skull rows start 2 % past
INFEASIBLE = 0.1
NNLS_ACCURACY = 1e-6  # (relative) NNLS's answer: its rows this near equality start as active when it is polished
POLISH_ITERATIONS = 400  # of the polish (each one KKT solve; its set then serves every refit)


class Constraints:
    """C c >= d, and what the solvers derive from it once (the same for every refit, and for
    every update's first round: update.py keeps that one per atlas)."""

    def __init__(self, C: np.ndarray, d: np.ndarray):
        self.C, self.d = C, d

    @cached_property
    def unit_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """C and d with each row scaled to unit norm (the warm start's tolerances, and its
        equality pairs, are then alike for every row; zero rows stay)."""
        norm = np.linalg.norm(self.C, axis=1)
        norm[norm == 0] = 1.0
        return self.C / norm[:, None], self.d / norm

    @cached_property
    def partner(self) -> np.ndarray:
        return partners(*self.unit_rows)

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return bound_rows(self.unit_rows[0])

    @cached_property
    def slack(self) -> Slack:
        """The constraints' C c - d, for every refit (its transposed copy of the general rows
        was a tenth of an update with the skull's rows when each refit made its own)."""
        return Slack(*self.unit_rows, *self.bounds)

    def stacked(self, C: np.ndarray, d: np.ndarray) -> Constraints:
        return Constraints(np.vstack([self.C, C]), np.concatenate([self.d, d]))


@dataclass
class Problem:
    """The data (rows per point: `groups` says which point a row is of), the regulariser's
    quadratic form (m^2) and the constraints every fit keeps (C c >= d; `constraints`: the same
    with what is derived from them, if already made)."""

    A: np.ndarray
    b: np.ndarray
    groups: np.ndarray
    noise: float
    gram: np.ndarray
    cross: np.ndarray
    C: np.ndarray
    d: np.ndarray
    anchor: np.ndarray | None = None  # weights inside every constraint, if known (a start's fallback)
    constraints: Constraints | None = None

    def __post_init__(self):
        if self.constraints is None:
            self.constraints = Constraints(self.C, self.d)
        elif self.constraints.C is not self.C or self.constraints.d is not self.d:
            raise ValueError("Problem: `constraints` must be made of the same C and d")

    unit_rows = property(lambda self: self.constraints.unit_rows)
    partner = property(lambda self: self.constraints.partner)
    bounds = property(lambda self: self.constraints.bounds)
    slack = property(lambda self: self.constraints.slack)

    def with_constraints(self, C: np.ndarray, d: np.ndarray) -> Problem:
        return self.with_all(self.constraints.stacked(C, d))

    def with_all(self, constraints: Constraints) -> Problem:
        """The same data with these constraints instead."""
        return Problem(
            self.A,
            self.b,
            self.groups,
            self.noise,
            self.gram,
            self.cross,
            constraints.C,
            constraints.d,
            self.anchor,
            constraints,
        )

    def solve(self, alpha: float, rows: np.ndarray | None = None, near: np.ndarray | None = None) -> np.ndarray:
        """The constrained minimiser with the data rows `rows` (default: all); `near`: weights
        whose active constraints are tried first (a refit of a nearby problem)."""
        A, b = (self.A, self.b) if rows is None else (self.A[rows], self.b[rows])
        H = DataHessian(A, self.noise, self.gram, alpha / MM2)
        g = A.T @ b / self.noise**2 + (alpha / MM2) * self.cross
        if near is not None and WARM_START:
            c = solve_on_active(
                H, g, *self.unit_rows, near, self.partner, bounds=self.bounds, infeasible=INFEASIBLE, slack=self.slack
            )
            if c is None and self.anchor is not None:  # from the point nearest `near` inside the rows
                inside = towards(self.anchor, near, *self.unit_rows)
                if inside is not None:
                    c = solve_on_active(
                        H, g, *self.unit_rows, inside, self.partner, bounds=self.bounds, slack=self.slack
                    )
            if c is not None:
                return c
        c = least_distance(H.dense(), g, self.C, self.d)
        if WARM_START:  # NNLS's answer polished into an exact vertex, that refits can start from
            polished = solve_on_active(
                H,
                g,
                *self.unit_rows,
                c,
                self.partner,
                iterations=POLISH_ITERATIONS,
                bounds=self.bounds,
                infeasible=INFEASIBLE,
                active=NNLS_ACCURACY,
                slack=self.slack,
            )
            if polished is not None:
                return polished
        return c

    def regulariser(self, c: np.ndarray) -> float:
        """R(c) up to a constant (m^2): c.G.c - 2 cross.c."""
        return float(c @ (self.gram @ c) - 2.0 * self.cross @ c)

    def objective(
        self, alpha: float, c: np.ndarray, rows: np.ndarray | None = None, regulariser: float | None = None
    ) -> float:
        """What the fit with these data rows minimises, at c (up to a constant); `regulariser`:
        R(c) if already known (it does not depend on the rows)."""
        A, b = (self.A, self.b) if rows is None else (self.A[rows], self.b[rows])
        r = A @ c - b
        R = self.regulariser(c) if regulariser is None else regulariser
        return float(r @ r) / self.noise**2 + (alpha / MM2) * R

    def misfit(self, c: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Each point's error (m): the norm of its rows' residuals."""
        rows = np.arange(len(self.b)) if rows is None else rows
        r = self.A[rows] @ c - self.b[rows]
        return np.sqrt(np.bincount(np.searchsorted(np.unique(self.groups[rows]), self.groups[rows]), weights=r * r))


def towards(anchor: np.ndarray, start: np.ndarray, C: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """The point nearest `start` on the segment from `anchor` to it that keeps C c >= d (a
    convex set: all of it from the anchor up to the first row `start` is past), or None if
    the anchor itself is not inside. A start past rows that outnumber its free weights (the
    skull's rows re-linearised at the last fit, several of them past) leaves the primal
    active-set method a dependent working set; from a point inside, it never does."""
    tolerance = ACTIVE * (1.0 + np.abs(d))
    at_anchor, at_start = C @ anchor - d, C @ start - d
    if np.any(at_anchor < -tolerance):
        return None
    past = at_start < -tolerance
    if not past.any():
        return np.array(start, dtype=float)
    t = float(np.min(at_anchor[past] / (at_anchor[past] - at_start[past])))
    return anchor + t * (start - anchor)


def fold_of(groups: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """The fold of every row: the points dealt at random into `folds` folds."""
    points = np.unique(groups)
    deal = np.random.default_rng(seed).permutation(len(points)) % folds
    return deal[np.searchsorted(points, groups)]


def choose_alpha(
    problem: Problem, alphas=ALPHAS, folds: int = FOLDS, near: np.ndarray | None = None
) -> tuple[float, list[dict], np.ndarray]:
    """The alpha of least mean error at points left out (K-fold), the curve, and the fit to all
    the points at that alpha. `near`: weights to start from. The fit to all the points follows
    the grid from alpha to alpha, each from the last; each fold's fit starts from the better
    (lower objective) of its own at the last alpha (the same data: over the grid's flat part the
    same active set, one KKT solve) and the fit to all the points at this alpha (where the
    regulariser dominates, a fold's answer is near it: from the fold's own at the last alpha
    it took 30-55 active-set steps there). The grid is scanned upward and the scan stops when
    the error has grown by more than RISE at RISES alphas in a row (the curve then ends there)."""
    fold = fold_of(problem.groups, min(folds, len(np.unique(problem.groups))))
    rows_of = {k: np.flatnonzero(fold != k) for k in np.unique(fold)}
    curve, fits, last = [], {}, {}  # last[k]: fold k's fit at the last alpha, and its R
    whole = near
    for alpha in alphas:
        whole = fits[alpha] = problem.solve(alpha, near=whole)
        R_whole = problem.regulariser(whole)  # (once an alpha, not once a fold: a 351 x 351 product)
        errors = []
        for k, rows in rows_of.items():
            start = whole
            if k in last and problem.objective(alpha, last[k][0], rows, last[k][1]) < problem.objective(
                alpha, whole, rows, R_whole
            ):
                start = last[k][0]
            c = problem.solve(alpha, rows, near=start)
            last[k] = (c, problem.regulariser(c))
            errors.append(problem.misfit(c, np.flatnonzero(fold == k)))
        e = np.concatenate(errors)
        curve.append({"alpha": float(alpha), "cv_rms_mm": float(np.sqrt(np.mean(e**2)) * 1e3)})
        errors_so_far = [p["cv_rms_mm"] for p in curve]
        if len(curve) > RISES and all(
            b > (1 + RISE) * a for a, b in zip(errors_so_far[-RISES - 1 : -1], errors_so_far[-RISES:])
        ):
            break
    best = min(curve, key=lambda p: p["cv_rms_mm"])
    return best["alpha"], curve, fits[best["alpha"]]


def leave_one_out(
    problem: Problem, alpha: float, most: int | None = None, seed: int = 2, near: np.ndarray | None = None
) -> np.ndarray:
    """Each point's error (m) when the fit is made without it; with more points than `most`,
    a random sample of `most` of them (NaN for the others). `near`: the fit to all of them."""
    near = problem.solve(alpha) if near is None else near
    points = np.unique(problem.groups)
    out = np.full(len(points), np.nan)
    chosen = np.arange(len(points))
    if most is not None and len(points) > most:
        chosen = np.sort(np.random.default_rng(seed).choice(len(points), most, replace=False))
    for i in chosen:
        p = points[i]
        c = problem.solve(alpha, np.flatnonzero(problem.groups != p), near=near)
        out[i] = problem.misfit(c, np.flatnonzero(problem.groups == p))[0]
    return out


def bootstrap(
    problem: Problem, alpha: float, samples: int, seed: int = 1, near: np.ndarray | None = None
) -> np.ndarray:
    """(samples, M) weights refitted to the points resampled with replacement. `near`: the fit
    to all of them."""
    near = problem.solve(alpha) if near is None else near
    points = np.unique(problem.groups)
    rng = np.random.default_rng(seed)
    rows_of = [np.flatnonzero(problem.groups == p) for p in points]
    out = []
    for _ in range(samples):
        pick = rng.integers(0, len(points), len(points))
        out.append(problem.solve(alpha, np.concatenate([rows_of[i] for i in pick]), near=near))
    return np.array(out)


def weight_constraints(
    family: np.ndarray, lower: np.ndarray, upper: np.ndarray, total: tuple[float, float] = (1.0, 1.0)
) -> tuple[np.ndarray, np.ndarray]:
    """C c >= d for: the family's weights >= 0, their sum within `total` (1: a convex
    combination; G0/G for a stiffness G: u is proportional to 1/G), the other coefficients
    within [lower, upper] (entries of those arrays at the family's are unused)."""
    m = len(family)
    weights, others = np.flatnonzero(family), np.flatnonzero(~family)
    C = np.zeros((len(weights) + 2 + 2 * len(others), m))
    C[np.arange(len(weights)), weights] = 1.0
    C[len(weights), family], C[len(weights) + 1, family] = 1.0, -1.0
    first = len(weights) + 2
    C[first + 2 * np.arange(len(others)), others] = 1.0
    C[first + 2 * np.arange(len(others)) + 1, others] = -1.0
    d = np.concatenate(
        [np.zeros(len(weights)), [total[0], -total[1]], np.column_stack([lower[others], -upper[others]]).ravel()]
    )
    return C, d
