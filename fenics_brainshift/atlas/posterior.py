"""The update's uncertainty from the posterior of the weights, in closed form.

The fit minimises J(c) = |A c - b|^2 / noise^2 + s (c.G.c - 2 cross.c) under C c >= d: the
negative log of a posterior (Gaussian noise of the stated size on every measured coordinate,
a Gaussian prior around the scene's own prediction of precision s G), J/2 up to a constant, so
that the posterior's precision is H = A'A / noise^2 + s G. Its constraints are kept as the
fit's face: the weights at their bounds stay there and the equalities hold (a bound with
lower = upper, the family's sum when it is fixed), and on that face the weights are Gaussian
with covariance

    Sigma = Z (Z' H_ff Z)^-1 Z'

(f the free weights, Z a basis of the null space of the equalities there). The displacement
u_n = sum_k c_k U_kn is then Gaussian too; a node's spread is the root mean square of its
deviation, sqrt(E|u_n - E u_n|^2) = sqrt(sum_d U_nd' Sigma U_nd) (not the standard deviation of
|u_n|: 1-2.5 times that), the same measure as the bootstrap's (update.py), without its refits:
one small factorisation instead of 30 constrained fits.

What it leaves out: the truncation by the inequalities the fit presses that are not bounds (the
skull's rows, a sum at the end of its range) - they bound the posterior on one side only, and
held as equalities they pinned every free weight where the fit sits at a vertex of them (a
spread of exactly 0 in 2 of 40 random updates on the 10 mm skull atlas); so the spread
of a node pressed on the skull includes moving toward it. A weight at its bound that the data
could free (the bootstrap sees that; 0.4-1.4x the truncated posterior's on random problems).
The model's own error (an operation the atlas does not contain), unless the residual says so:
when the fit's residual is larger than the noise explains, the covariance is scaled by the
ratio (the reduced chi-square, as a weighted least-squares fit with an unknown noise scale does).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import null_space

from .active_set import DataHessian
from .combine import MM2, NNLS_ACCURACY


def covariance(problem, alpha: float, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(free weights f, Sigma over them, the face's dimension): the posterior on the fit's face
    at weights c (combine.Problem, its alpha). The weights not in f are fixed by their bounds."""
    C, d = problem.unit_rows
    bound_of, _ = problem.bounds
    # (to NNLS's accuracy, not the active set's 1e-9: an answer of NNLS, unpolished, has its bounds
    # 1e-10 off, and every weight counted free made a spread of metres)
    active = C @ c - d <= NNLS_ACCURACY * (1.0 + np.abs(d))
    fixed = np.zeros(len(c), dtype=bool)
    fixed[bound_of[active & (bound_of >= 0)]] = True
    free = np.flatnonzero(~fixed)
    partner = problem.partner
    equality = np.flatnonzero((bound_of < 0) & (partner >= 0))  # (both rows of a pair: the null space is the same)
    rows = C[np.ix_(equality, free)] if len(equality) else np.zeros((0, len(free)))
    Z = null_space(rows) if len(rows) else np.eye(len(free))
    if Z.shape[1] == 0:  # the equalities fix every free weight too
        return free, np.zeros((len(free), len(free))), 0
    H = DataHessian(problem.A, problem.noise, problem.gram, alpha / MM2).restricted(free)[0]
    reduced = Z.T @ H @ Z
    return free, Z @ np.linalg.solve(reduced, Z.T), Z.shape[1]


def scale(problem, c: np.ndarray, dimension: int) -> float:
    """max(1, the residual's chi-square per degree of freedom): the covariance's factor when the
    fit explains the data worse than the stated noise would (rows minus the face's dimension,
    at least 1)."""
    r = problem.A @ c - problem.b
    dof = max(len(r) - dimension, 1)
    return max(1.0, float(r @ r) / problem.noise**2 / dof)


def spread(problem, alpha: float, c: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """(N,) m: each node's posterior RMS deviation sqrt(E|u - E u|^2) (modes (M, N, 3))."""
    free, sigma, dimension = covariance(problem, alpha, c)
    if not dimension:
        return np.zeros(modes.shape[1])
    sigma = 0.5 * (sigma + sigma.T) * scale(problem, c, dimension)
    w, v = np.linalg.eigh(sigma)
    factor = v * np.sqrt(np.maximum(w, 0.0))  # Sigma = F F'
    fields = np.tensordot(factor.T, modes[free].astype(np.float64), axes=1)  # (r, N, 3)
    return np.sqrt(np.einsum("rnd,rnd->n", fields, fields))
