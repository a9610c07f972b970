"""The weights of the atlas's modes that fit the measurements: a regularised least-squares
problem with linear inequality constraints,

    min_c  |A c - b|^2 / noise^2 + alpha R(c)     subject to  C c >= d,

c the family's weights (>= 0, summing to 1: a convex combination of alternative settled
states) and the swelling amplitudes (within their bounds); R(c) the mean square change of the
displacement from the scene's own prediction over the mesh's nodes, in mm^2 (the update moves
the prediction no farther than the data ask); with a skull, rows of C keep the boundary nodes
inside it (rows.py). Each problem is solved exactly by Lawson and Hanson's reduction
to a least-distance problem solved by scipy's NNLS (Solving Least Squares Problems, 1974,
ch. 23): a factor of the Hessian, one NNLS of the constraints' size. The many refits of
cross-validation, leave-one-out and the bootstrap start from a nearby solution with the same
constraints (the data rows change): the full fit's, and for a cross-validation fold its own
fit at the previous alpha; by the primal active-set method, a few small KKT solves over the
free weights; NNLS if it does not get there.

alpha is chosen by K-fold cross-validation over the measured points (the error at points left
out), from a grid; leave-one-out errors and a bootstrap over the points (the spread of the
displacement over refits) come from the same solver.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from math import sqrt

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dgesv as gesv
from scipy.optimize import nnls

from ..errors import SolverError

ALPHAS = tuple(10.0 ** np.arange(-4, 3.5, 1.0))  # the cross-validation grid of alpha (per mm^2)
FOLDS = 5
RIDGE = 1e-9  # of the Hessian's mean diagonal: a numerically positive definite factor
MM2 = 1e-6  # R in mm^2
WARM_START = True  # False: every refit from scratch by NNLS (the baseline benchmarks/update.py times)
ACTIVE = 1e-9  # a constraint within this (relative) of equality is active; a multiplier this far below 0 is not
# a start may be this far past its constraints (relative): they join the working set, which its first step holds.
# NNLS's answers are past the skull's rows by up to 2.4e-7 of them, and a refit that needs a feasible start then
# fell back to NNLS every time (1.0-16.2 s an update on the 5 mm skull atlas: benchmarks/results/update_skull.md at
# commit ac99200); re-linearised skull rows start 2 % past
INFEASIBLE = 0.1
NNLS_ACCURACY = 1e-6  # (relative) NNLS's answer: its rows this near equality start as active when it is polished
POLISH_ITERATIONS = 400  # of the polish (each one KKT solve; its set then serves every refit)
# a refit's active-set steps before NNLS takes over: 200 (not 60) as a refit may change 80-95 constraints
# (tests/test_update_solver.py), and a step costs about 0.1 ms against NNLS's hundreds with the skull's rows


@dataclass
class Problem:
    """The data (rows per point: `groups` says which point a row is of), the regulariser's
    quadratic form (m^2) and the constraints every fit keeps."""
    A: np.ndarray
    b: np.ndarray
    groups: np.ndarray
    noise: float
    gram: np.ndarray
    cross: np.ndarray
    C: np.ndarray
    d: np.ndarray

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

    def with_constraints(self, C: np.ndarray, d: np.ndarray) -> "Problem":
        return Problem(self.A, self.b, self.groups, self.noise, self.gram, self.cross,
                       np.vstack([self.C, C]), np.concatenate([self.d, d]))

    def solve(self, alpha: float, rows: np.ndarray | None = None, near: np.ndarray | None = None) -> np.ndarray:
        """The constrained minimiser with the data rows `rows` (default: all); `near`: weights
        whose active constraints are tried first (a refit of a nearby problem)."""
        A, b = (self.A, self.b) if rows is None else (self.A[rows], self.b[rows])
        H = DataHessian(A, self.noise, self.gram, alpha / MM2)
        g = A.T @ b / self.noise ** 2 + (alpha / MM2) * self.cross
        if near is not None and WARM_START:
            c = solve_on_active(H, g, *self.unit_rows, near, self.partner, bounds=self.bounds, infeasible=INFEASIBLE)
            if c is not None:
                return c
        c = least_distance(H.dense(), g, self.C, self.d)
        if WARM_START:  # NNLS's answer polished into an exact vertex, that refits can start from
            polished = solve_on_active(H, g, *self.unit_rows, c, self.partner, iterations=POLISH_ITERATIONS,
                                       bounds=self.bounds, infeasible=INFEASIBLE, active=NNLS_ACCURACY)
            if polished is not None:
                return polished
        return c

    def misfit(self, c: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Each point's error (m): the norm of its rows' residuals."""
        rows = np.arange(len(self.b)) if rows is None else rows
        r = self.A[rows] @ c - self.b[rows]
        return np.sqrt(np.bincount(np.searchsorted(np.unique(self.groups[rows]), self.groups[rows]), weights=r * r))


class DataHessian:
    """H = A'A / noise^2 + s G + ridge I (G symmetric), not formed: a refit's active-set
    iterations need H over the free weights and its columns there times the free weights
    (forming H cost more than the iterations)."""

    def __init__(self, A: np.ndarray, noise: float, gram: np.ndarray, s: float):
        self.A, self.w, self.gram, self.s = A, 1.0 / noise ** 2, gram, s
        trace = self.w * float(np.einsum("ij,ij->", A, A)) + s * float(np.trace(gram))
        self.ridge = RIDGE * max(trace / len(gram), 1e-300)  # a numerically positive definite H

    def times(self, columns: np.ndarray, x: np.ndarray) -> np.ndarray:
        """H[:, columns] x."""
        out = self.w * (self.A.T @ (self.A[:, columns] @ x)) + self.s * (x @ self.gram[columns])
        out[columns] += self.ridge * x
        return out

    def restricted(self, free: np.ndarray):
        """(H[free, free], x -> H[:, free] x): the columns of `free` taken once for both."""
        A_free, G_free = self.A[:, free], self.gram[free]  # (G's rows: its columns, and contiguous)
        block = self.w * (A_free.T @ A_free) + self.s * G_free[:, free]
        block.flat[::len(free) + 1] += self.ridge

        def times(x: np.ndarray) -> np.ndarray:
            out = self.w * (self.A.T @ (A_free @ x)) + self.s * (x @ G_free)
            out[free] += self.ridge * x
            return out
        return block, times

    def dense(self) -> np.ndarray:
        every = np.arange(len(self.gram))
        return self.restricted(every)[0]


class DenseHessian:
    """A formed H with DataHessian's interface."""

    def __init__(self, H: np.ndarray):
        self.H = H

    def times(self, columns: np.ndarray, x: np.ndarray) -> np.ndarray:
        return self.H[:, columns] @ x

    def restricted(self, free: np.ndarray):
        columns = self.H[:, free]
        return columns[free], lambda x: columns @ x


def least_distance(H: np.ndarray, g: np.ndarray, C: np.ndarray, d: np.ndarray) -> np.ndarray:
    """argmin c.H.c - 2 g.c subject to C c >= d (H positive definite), by the reduction to
    least distance: H = R'R, z = R c - R'^-1 g, so that min |z| subject to (C R^-1) z >=
    d - C R^-1 R'^-1 g, whose solution is NNLS's residual of [G'; h'] u = e_last."""
    R = np.linalg.cholesky(H).T  # upper: H = R'R
    f = solve_triangular(R, g, trans="T")
    G = solve_triangular(R, C.T, trans="T").T  # C R^-1
    h = d - G @ f
    E = np.vstack([G.T, h[None, :]])
    e = np.zeros(len(E))
    e[-1] = 1.0
    u, _ = nnls(E, e, maxiter=50 * E.shape[1])
    r = E @ u - e
    if abs(r[-1]) < 1e-14:
        raise SolverError("the update's constraints cannot all hold (the weights' bounds and the skull's rows "
                          "exclude each other)")
    z = -r[:-1] / r[-1]
    return solve_triangular(R, z + f)


def solve_on_active(H: np.ndarray, g: np.ndarray, C: np.ndarray, d: np.ndarray, start: np.ndarray,
                    partner: np.ndarray, iterations: int = 200, bounds: tuple | None = None, infeasible: float = 0.0,
                    active: float = ACTIVE):
    """argmin c.H.c - 2 g.c subject to C c >= d by the primal active-set method (Nocedal and
    Wright, Numerical Optimization, 2006, algorithm 16.3) from a feasible `start` (a nearby
    problem's answer: the refits keep the constraints and change the data), its active
    constraints the first working set. Each iteration solves the problem with the working
    set held as equalities (H c - C_w' lam = g, C_w c = d_w); a step that would cross a
    constraint stops on it and adds it; at the working set's minimiser the inequality of
    most negative multiplier is dropped, until none is negative: the KKT conditions of the
    convex problem, so c is the exact minimiser. None if `start` is not feasible or the
    iterations run out (the caller then solves from scratch). A pair of rows that are each
    other's negative (`partner`: a bound with lower = upper, the family's sum fixed) is one
    equality, its multiplier of either sign. A held bound fixes its weight and leaves the
    problem (most of the family's weights sit at 0): each solve is a small KKT system over
    the free weights. A start past some constraints by at most `infeasible` (relative) has them
    in its first working set: the first step holds them, and they stay in the set until a full
    step, which satisfies them; the other constraints are kept by the steps as usual. `active`:
    how near equality (relative) a start's row must be to join the first working set (an
    inexact start's: NNLS's)."""
    H = H if isinstance(H, (DataHessian, DenseHessian)) else DenseHessian(H)
    tolerance = ACTIVE * (1.0 + np.abs(d))
    bound_of, sign = bounds if bounds is not None else bound_rows(C)
    slack = _Slack(C, d, bound_of, sign)
    c = np.array(start, dtype=float)
    s = slack(c)  # kept along the steps (C c - d: the product with the skull's rows is the cost)
    if np.any(s < -np.maximum(tolerance, infeasible * (1.0 + np.abs(d)))):
        return None
    working = s <= np.maximum(tolerance, active * (1.0 + np.abs(d)))  # (and the rows the start is past)
    rows = np.arange(len(d))
    first = True
    for _ in range(iterations):
        held = _held(working, partner, rows)
        solved = _equality_solve(H, g, C, d, held, bound_of, sign)
        if solved is None and first and np.any(working & (bound_of < 0)):
            working &= bound_of >= 0  # dependent general rows at the start: they join one at a time
            first = False
            continue
        first = False
        if solved is None:
            return None
        x, multipliers = solved
        p = x - c
        if np.abs(p).max() > 1e-12 * (1.0 + np.abs(c).max()):
            Cp = slack.along(p)
            blocking = (~working & (Cp < -1e-12 * np.abs(p).sum())).nonzero()[0]
            step, hit = 1.0, -1
            if len(blocking):
                ratios = np.maximum(s[blocking], 0.0) / -Cp[blocking]
                k = int(np.argmin(ratios))
                if ratios[k] < 1.0:
                    step, hit = float(ratios[k]), int(blocking[k])
            if hit >= 0:
                c = c + step * p
                s = s + step * Cp
                working[hit] = True
                continue
            # a full step: c is now the working set's minimiser x, whose multipliers are known
            # (solving the same system again to learn them was half the steps)
            s = s + Cp
        c = x
        inequality = partner[held] < 0
        scale = max(float(np.abs(multipliers).max(initial=0.0)), 1e-300)
        worst = int(np.argmin(np.where(inequality, multipliers, np.inf))) if inequality.any() else -1
        if worst < 0 or multipliers[worst] >= -ACTIVE * scale:
            # (a start past dependent rows, which left the first working set, can end short of
            # them, below the minimum: then NNLS; a stranger's review found it)
            return c if np.all(slack(c) >= -tolerance) else None
        working[held[worst]] = False
    return None


class _Slack:
    """C c - d and C p with the bound rows (most of them: +-e_k) read off c, not multiplied."""

    def __init__(self, C, d, bound_of, sign):
        self.d, self.is_bound = d, bound_of >= 0
        self.column, self.sign = bound_of[self.is_bound], sign[self.is_bound]
        self.general = np.flatnonzero(~self.is_bound)
        self.C_general = C[self.general]

    def along(self, p: np.ndarray) -> np.ndarray:
        out = np.empty(len(self.d))
        out[self.is_bound] = self.sign * p[self.column]
        out[self.general] = self.C_general @ p
        return out

    def __call__(self, c: np.ndarray) -> np.ndarray:
        return self.along(c) - self.d


def _held(working: np.ndarray, partner: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The working rows held as equalities: of an equality pair both in the set, the first."""
    second = (partner >= 0) & (partner < rows) & working[np.maximum(partner, 0)]
    return (working & ~second).nonzero()[0]


def bound_rows(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each row, the one weight it bounds (a row +-e_k), or -1; and the row's sign there."""
    nonzero = C != 0
    single = (nonzero.sum(axis=1) == 1)
    column = np.argmax(nonzero, axis=1)
    value = C[np.arange(len(C)), column]
    unit = single & (np.abs(np.abs(value) - 1.0) < 1e-12)  # (rows of unit norm: unit_rows)
    return np.where(unit, column, -1), np.where(unit, np.sign(value), 0.0)


def _equality_solve(H, g, C, d, held, bound_of, sign):
    """(c, lam) of H c - C_h' lam = g, C_h c = d_h (lam in the order of `held`): the weights a
    held bound fixes are set, the rest solved from the KKT system of the free weights and the
    other held rows. None if the rows are dependent (a weight bounded twice, dependent rows)."""
    n = len(g)
    of = bound_of[held]
    is_bound = of >= 0  # `bounds` and `general` are held's rows in held's order
    bounds, general, fixed_index = held[is_bound], held[~is_bound], of[is_bound]
    is_free = np.ones(n, dtype=bool)
    is_free[fixed_index] = False
    free = is_free.nonzero()[0]  # (not flatnonzero: its overhead was a tenth of the solve)
    if len(free) != n - len(fixed_index):  # a weight bounded twice
        return None
    c = np.zeros(n)
    c[fixed_index] = d[bounds] * sign[bounds]
    pinned = c.nonzero()[0]  # fixed weights not at 0 (most are: the family's lower bound)
    Hc_pinned = H.times(pinned, c[pinned]) if len(pinned) else np.zeros(n)  # H c of the fixed weights
    C_general = C[general]
    C_free = C_general[:, free]
    nf, k = len(free), len(general)
    kkt = np.zeros((nf + k, nf + k))
    block, times_free = H.restricted(free)
    kkt[:nf, :nf] = block
    kkt[:nf, nf:], kkt[nf:, :nf] = -C_free.T, C_free
    rhs = np.concatenate([g[free] - Hc_pinned[free], d[general] - C_general @ c])
    if kkt.size == 0:  # every weight fixed by its bound
        solution = np.zeros(0)
    else:  # (LAPACK's gesv directly: numpy's solve costs 4x as much on these small systems)
        _, _, solution, info = gesv(kkt, rhs)
        if info != 0:  # dependent rows: NNLS sorts them out
            return None
    # nearly dependent rows solve to garbage without an error: keep only a solution that solves,
    # measured against the weights' part (dependent rows' multipliers grow without bound)
    x = solution[:nf]
    size = max(sqrt(rhs @ rhs) + np.abs(kkt).sum(axis=0).max(initial=0.0) * sqrt(x @ x), 1e-300)
    residual = kkt @ solution - rhs
    if not np.isfinite(size) or not sqrt(residual @ residual) <= 1e-8 * size \
            or np.abs(solution[nf:]).max(initial=0.0) > 1e8 * size:
        return None
    c[free] = solution[:nf]
    lam_general = solution[nf:]
    # a bound's multiplier from the stationarity of its weight: (H c - g)_k = C[:, k]' lam
    Hc = Hc_pinned + times_free(c[free]) if nf else Hc_pinned
    gradient = Hc[fixed_index] - g[fixed_index] - C_general[:, fixed_index].T @ lam_general
    multipliers = np.empty(len(held))
    multipliers[~is_bound] = lam_general
    multipliers[is_bound] = sign[bounds] * gradient
    return c, multipliers


def partners(C: np.ndarray, d: np.ndarray) -> np.ndarray:
    """For each row of C c >= d, the row that is its negative (an equality written as two), or -1
    (of rows alike, the last). Rows are looked up by their bytes (sorting the rows themselves,
    np.unique(axis=0), took 14 ms of an update's ~120 on the 351-mode atlas)."""
    rows = np.round(np.column_stack([C, d]), 12) + 0.0  # + 0.0: -0.0 and 0.0 alike
    negated = -rows + 0.0
    last = {row.tobytes(): i for i, row in enumerate(rows)}  # (a later row alike overwrites)
    return np.array([last.get(row.tobytes(), -1) for row in negated], dtype=np.int64)


def fold_of(groups: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """The fold of every row: the points dealt at random into `folds` folds."""
    points = np.unique(groups)
    deal = np.random.default_rng(seed).permutation(len(points)) % folds
    return deal[np.searchsorted(points, groups)]


def choose_alpha(problem: Problem, alphas=ALPHAS, folds: int = FOLDS,
                 near: np.ndarray | None = None) -> tuple[float, list[dict]]:
    """The alpha of least mean error at points left out (K-fold), and the curve. `near`:
    weights to start from. Each fold's fit starts from the same fold's at the last alpha (the
    same data: over the grid's flat part the same active set, one KKT solve), the first
    alpha's from the fit to all the points."""
    fold = fold_of(problem.groups, min(folds, len(np.unique(problem.groups))))
    curve = []
    whole = problem.solve(alphas[0], near=near)
    last = {}
    for alpha in alphas:
        errors = []
        for k in np.unique(fold):
            c = last[k] = problem.solve(alpha, np.flatnonzero(fold != k), near=last.get(k, whole))
            errors.append(problem.misfit(c, np.flatnonzero(fold == k)))
        e = np.concatenate(errors)
        curve.append({"alpha": float(alpha), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2)) * 1e3)})
    best = min(curve, key=lambda p: p["cv_rms_mm"])
    return best["alpha"], curve


def leave_one_out(problem: Problem, alpha: float, most: int | None = None, seed: int = 2,
                  near: np.ndarray | None = None) -> np.ndarray:
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


def bootstrap(problem: Problem, alpha: float, samples: int, seed: int = 1,
              near: np.ndarray | None = None) -> np.ndarray:
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


def weight_constraints(family: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                       total: tuple[float, float] = (1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
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
    d = np.concatenate([np.zeros(len(weights)), [total[0], -total[1]],
                        np.column_stack([lower[others], -upper[others]]).ravel()])
    return C, d
