"""The weights of the atlas's modes that fit the measurements: a regularised least-squares
problem with linear inequality constraints,

    min_c  |A c - b|^2 / noise^2 + alpha R(c)     subject to  C c >= d,

c the family's weights (>= 0, summing to 1: a convex combination of alternative settled
states) and the swelling amplitudes (within their bounds); R(c) the mean square change of the
displacement from the scene's own prediction over the mesh's nodes, in mm^2 (the update moves
the prediction no farther than the data ask); with a skull, rows of C keep the boundary nodes
inside it (rows.py). Each problem is solved exactly by Lawson and Hanson's reduction
to a least-distance problem solved by scipy's NNLS (Solving Least Squares Problems, 1974,
ch. 23): a factor of the Hessian, one NNLS of the constraints' size.

alpha is chosen by K-fold cross-validation over the measured points (the error at points left
out), from a grid; leave-one-out errors and a bootstrap over the points (the spread of the
displacement over refits) come from the same solver.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.optimize import nnls

from ..errors import SolverError

ALPHAS = tuple(10.0 ** np.arange(-4, 3.5, 1.0))  # the cross-validation grid of alpha (per mm^2)
FOLDS = 5
RIDGE = 1e-9  # of the Hessian's mean diagonal: a numerically positive definite factor
MM2 = 1e-6  # R in mm^2


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

    def with_constraints(self, C: np.ndarray, d: np.ndarray) -> "Problem":
        return Problem(self.A, self.b, self.groups, self.noise, self.gram, self.cross,
                       np.vstack([self.C, C]), np.concatenate([self.d, d]))

    def solve(self, alpha: float, rows: np.ndarray | None = None) -> np.ndarray:
        """The constrained minimiser with the data rows `rows` (default: all)."""
        A, b = (self.A, self.b) if rows is None else (self.A[rows], self.b[rows])
        H = A.T @ A / self.noise ** 2 + (alpha / MM2) * self.gram
        g = A.T @ b / self.noise ** 2 + (alpha / MM2) * self.cross
        H[np.diag_indices_from(H)] += RIDGE * max(float(np.trace(H)) / len(H), 1e-300)
        return least_distance(H, g, self.C, self.d)

    def misfit(self, c: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Each point's error (m): the norm of its rows' residuals."""
        rows = np.arange(len(self.b)) if rows is None else rows
        r = self.A[rows] @ c - self.b[rows]
        return np.sqrt(np.bincount(np.searchsorted(np.unique(self.groups[rows]), self.groups[rows]), weights=r * r))


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


def fold_of(groups: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """The fold of every row: the points dealt at random into `folds` folds."""
    points = np.unique(groups)
    deal = np.random.default_rng(seed).permutation(len(points)) % folds
    return deal[np.searchsorted(points, groups)]


def choose_alpha(problem: Problem, alphas=ALPHAS, folds: int = FOLDS) -> tuple[float, list[dict]]:
    """The alpha of least mean error at points left out (K-fold), and the curve."""
    fold = fold_of(problem.groups, min(folds, len(np.unique(problem.groups))))
    curve = []
    for alpha in alphas:
        errors = []
        for k in np.unique(fold):
            c = problem.solve(alpha, np.flatnonzero(fold != k))
            errors.append(problem.misfit(c, np.flatnonzero(fold == k)))
        e = np.concatenate(errors)
        curve.append({"alpha": float(alpha), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2)) * 1e3)})
    best = min(curve, key=lambda p: p["cv_rms_mm"])
    return best["alpha"], curve


def leave_one_out(problem: Problem, alpha: float, most: int | None = None, seed: int = 2) -> np.ndarray:
    """Each point's error (m) when the fit is made without it; with more points than `most`,
    a random sample of `most` of them (NaN for the others)."""
    points = np.unique(problem.groups)
    out = np.full(len(points), np.nan)
    chosen = np.arange(len(points))
    if most is not None and len(points) > most:
        chosen = np.sort(np.random.default_rng(seed).choice(len(points), most, replace=False))
    for i in chosen:
        p = points[i]
        c = problem.solve(alpha, np.flatnonzero(problem.groups != p))
        out[i] = problem.misfit(c, np.flatnonzero(problem.groups == p))[0]
    return out


def bootstrap(problem: Problem, alpha: float, samples: int, seed: int = 1) -> np.ndarray:
    """(samples, M) weights refitted to the points resampled with replacement."""
    points = np.unique(problem.groups)
    rng = np.random.default_rng(seed)
    rows_of = [np.flatnonzero(problem.groups == p) for p in points]
    out = []
    for _ in range(samples):
        pick = rng.integers(0, len(points), len(points))
        out.append(problem.solve(alpha, np.concatenate([rows_of[i] for i in pick])))
    return np.array(out)


def weight_constraints(family: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                       total: tuple[float, float] = (1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """C c >= d for: the family's weights >= 0, their sum within `total` (1: a convex
    combination; G0/G for a stiffness G: u is proportional to 1/G), the other coefficients
    within [lower, upper] (entries of those arrays at the family's are unused)."""
    m = len(family)
    rows, rhs = [], []
    for k in np.flatnonzero(family):
        rows.append(np.eye(m)[k])
        rhs.append(0.0)
    sum_row = family.astype(float)
    rows += [sum_row, -sum_row]
    rhs += [total[0], -total[1]]
    for k in np.flatnonzero(~family):
        rows += [np.eye(m)[k], -np.eye(m)[k]]
        rhs += [lower[k], -upper[k]]
    return np.array(rows), np.array(rhs)
