"""The constrained least-squares solves of the update: C c >= d, H positive definite,

    min  c.H.c - 2 g.c   subject to  C c >= d,

exactly, from scratch by Lawson and Hanson's reduction to a least-distance problem solved by
scipy's NNLS, or from a nearby answer by the primal active-set method (Nocedal and Wright,
algorithm 16.3), a few small KKT solves over the free weights. H is that of the update's data
and regulariser (DataHessian), never formed on the refits' hot path. combine.py poses the
problems; this module only solves them.
"""

from __future__ import annotations

from math import sqrt

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dgesv as gesv
from scipy.optimize import nnls

from ..errors import SolverError

RIDGE = 1e-9  # of the Hessian's mean diagonal: a numerically positive definite factor
ACTIVE = 1e-9  # a constraint within this (relative) of equality is active; a multiplier this far below 0 is not
# a refit's active-set steps before NNLS takes over: 200 (not 60) as a refit may change 80-95 constraints
# (tests/test_update_solver.py), and a step costs about 0.1 ms against NNLS's hundreds with the skull's rows
ITERATIONS = 200


class DataHessian:
    """H = A'A / noise^2 + s G + ridge I (G symmetric), not formed: a refit's active-set
    iterations need H over the free weights and its columns there times the free weights
    (forming H cost more than the iterations). The free weights' block is kept by free set
    within a refit (a weight freed and fixed again comes back to an earlier set)."""

    def __init__(self, A: np.ndarray, noise: float, gram: np.ndarray, s: float):
        self.A, self.w, self.gram, self.s = A, 1.0 / noise**2, gram, s
        self.AT = np.ascontiguousarray(A.T)  # (a weight's data column as a contiguous row)
        trace = self.w * float(np.einsum("ij,ij->", A, A)) + s * float(np.trace(gram))
        self.ridge = RIDGE * max(trace / len(gram), 1e-300)  # a numerically positive definite H
        self._blocks = {}

    def times(self, columns: np.ndarray, x: np.ndarray) -> np.ndarray:
        """H[:, columns] x."""
        out = self.w * (self.AT @ (x @ self.AT[columns])) + self.s * (x @ self.gram[columns])
        out[columns] += self.ridge * x
        return out

    def restricted(self, free: np.ndarray):
        """(H[free, free], x -> H[:, free] x): the columns of `free` taken once for both."""
        key = free.tobytes()
        if key not in self._blocks:
            AT_free, G_free = self.AT[free], self.gram[free]  # (G's rows: its columns, and contiguous)
            block = self.w * (AT_free @ AT_free.T) + self.s * G_free[:, free]
            block.flat[:: len(free) + 1] += self.ridge
            if len(self._blocks) > 64:
                self._blocks.clear()
            self._blocks[key] = (block, AT_free, G_free)
        block, AT_free, G_free = self._blocks[key]

        def times(x: np.ndarray) -> np.ndarray:
            out = self.w * (self.AT @ (x @ AT_free)) + self.s * (x @ G_free)
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
        raise SolverError(
            "the update's constraints cannot all hold (the weights' bounds and the skull's rows exclude each other)"
        )
    z = -r[:-1] / r[-1]
    return solve_triangular(R, z + f)


def solve_on_active(
    H: np.ndarray,
    g: np.ndarray,
    C: np.ndarray,
    d: np.ndarray,
    start: np.ndarray,
    partner: np.ndarray,
    iterations: int = ITERATIONS,
    bounds: tuple | None = None,
    infeasible: float = 0.0,
    active: float = ACTIVE,
    slack: Slack | None = None,
):
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
    inexact start's: NNLS's). `slack`: Slack(C, d, *bounds), made once for problems that share
    the constraints (the refits)."""
    H = H if isinstance(H, (DataHessian, DenseHessian)) else DenseHessian(H)
    tolerance = ACTIVE * (1.0 + np.abs(d))
    bound_of, sign = bounds if bounds is not None else bound_rows(C)
    slack = Slack(C, d, bound_of, sign) if slack is None else slack
    c = np.array(start, dtype=float)
    s = slack(c)  # kept along the steps (C c - d: the product with the skull's rows is the cost)
    if np.any(s < -np.maximum(tolerance, infeasible * (1.0 + np.abs(d)))):
        return None
    working = s <= np.maximum(tolerance, active * (1.0 + np.abs(d)))  # (and the rows the start is past)
    seconds = ((partner >= 0) & (partner < np.arange(len(d)))).nonzero()[0]  # (the second row of each pair)
    first = True
    for _ in range(iterations):
        held = _held(working, partner, seconds)
        solved = _equality_solve(H, g, C, d, held, bound_of, sign)
        if solved is None and first and np.any(working & (bound_of < 0)):
            working &= bound_of >= 0  # dependent general rows at the start: they join one at a time
            first = False
            continue
        first = False
        if solved is None:
            return None
        x, multipliers_of = solved
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
        multipliers = multipliers_of()
        inequality = partner[held] < 0
        scale = max(float(np.abs(multipliers).max(initial=0.0)), 1e-300)
        worst = int(np.argmin(np.where(inequality, multipliers, np.inf))) if inequality.any() else -1
        if worst < 0 or multipliers[worst] >= -ACTIVE * scale:
            # (a start past dependent rows, which left the first working set, can end short of
            # them, below the minimum: then NNLS; tests/test_update_solver.py holds such a case)
            return c if np.all(slack(c) >= -tolerance) else None
        working[held[worst]] = False
    return None


class Slack:
    """C c - d and C p with the bound rows (most of them: +-e_k) read off c, not multiplied."""

    def __init__(self, C, d, bound_of, sign):
        self.d, self.is_bound = d, bound_of >= 0
        self.column, self.sign = bound_of[self.is_bound], sign[self.is_bound]
        self.general = np.flatnonzero(~self.is_bound)
        # by weight (a row of this per weight): a step moves only the free weights, a tenth of
        # them or fewer, and C p then reads their rows alone (the whole of C with a skull's
        # thousand rows was a third of a refit)
        self.by_weight = np.ascontiguousarray(C[self.general].T)

    def along(self, p: np.ndarray) -> np.ndarray:
        out = np.empty(len(self.d))
        out[self.is_bound] = self.sign * p[self.column]
        moved = p.nonzero()[0]
        if 4 * len(moved) > len(p):  # (most weights moved: gathering their rows would copy most of them)
            out[self.general] = p @ self.by_weight
        else:
            out[self.general] = p[moved] @ self.by_weight[moved]
        return out

    def __call__(self, c: np.ndarray) -> np.ndarray:
        return self.along(c) - self.d


def _held(working: np.ndarray, partner: np.ndarray, seconds: np.ndarray) -> np.ndarray:
    """The working rows held as equalities: of an equality pair both in the set, the first
    (`seconds`: the rows that are the second of their pair, a few)."""
    if not len(seconds):
        return working.nonzero()[0]
    both = seconds[working[seconds] & working[partner[seconds]]]
    if not len(both):
        return working.nonzero()[0]
    held = working.copy()
    held[both] = False
    return held.nonzero()[0]


def bound_rows(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each row, the one weight it bounds (a row +-e_k), or -1; and the row's sign there."""
    nonzero = C != 0
    single = nonzero.sum(axis=1) == 1
    column = np.argmax(nonzero, axis=1)
    value = C[np.arange(len(C)), column]
    unit = single & (np.abs(np.abs(value) - 1.0) < 1e-12)  # (rows of unit norm: unit_rows)
    return np.where(unit, column, -1), np.where(unit, np.sign(value), 0.0)


def _equality_solve(H, g, C, d, held, bound_of, sign):
    """(c, multipliers) of H c - C_h' lam = g, C_h c = d_h: c, and a function that gives lam in
    the order of `held` (a blocked step does not need them: computing them every step was a
    fifth of its cost). The weights a held bound fixes are set, the rest solved from the KKT
    system of the free weights and the other held rows. None if the rows are dependent (a
    weight bounded twice, dependent rows)."""
    n = len(g)
    of = bound_of[held]
    is_bound = of >= 0  # `bounds` and `general` are held's rows in held's order
    bounds, general, fixed_index = held[is_bound], held[~is_bound], of[is_bound]
    is_free = np.empty(n, dtype=bool)
    is_free.fill(True)  # (np.ones: a tenth of this line's cost again, in Python)
    is_free[fixed_index] = False
    free = is_free.nonzero()[0]  # (not flatnonzero: its overhead was a tenth of the solve)
    if len(free) != n - len(fixed_index):  # a weight bounded twice
        return None
    c = np.zeros(n)
    c[fixed_index] = d[bounds] * sign[bounds]
    pinned = c.nonzero()[0]  # fixed weights not at 0 (most are: the family's lower bound)
    Hc_pinned = H.times(pinned, c[pinned]) if len(pinned) else None  # H c of the fixed weights
    C_general = C[general]
    nf, k = len(free), len(general)
    kkt = np.empty((nf + k, nf + k))
    block, times_free = H.restricted(free)
    kkt[:nf, :nf] = block  # (a copy: gesv must not overwrite the block kept)
    if k:
        C_free = C_general[:, free]
        kkt[:nf, nf:], kkt[nf:, :nf], kkt[nf:, nf:] = -C_free.T, C_free, 0.0
    rhs = np.empty(nf + k)
    rhs[:nf] = g[free] if Hc_pinned is None else g[free] - Hc_pinned[free]
    rhs[nf:] = d[general] - C_general @ c
    if nf + k == 0:  # every weight fixed by its bound
        solution = np.zeros(0)
    else:  # (LAPACK's gesv directly: numpy's solve costs 4x as much on these small systems)
        _, _, solution, info = gesv(kkt, rhs)
        if info != 0:  # dependent rows: NNLS sorts them out
            return None
        # nearly dependent rows solve to garbage without an error: keep only a solution that
        # solves, measured against the weights' part (dependent rows' multipliers grow without bound)
        x = solution[:nf]
        size = max(sqrt(rhs @ rhs) + np.abs(kkt).sum(axis=0).max() * sqrt(x @ x), 1e-300)
        residual = kkt @ solution - rhs
        if (
            not np.isfinite(size)
            or not sqrt(residual @ residual) <= 1e-8 * size
            or (k and np.abs(solution[nf:]).max() > 1e8 * size)
        ):
            return None
    x = solution[:nf]
    c[free] = x

    def multipliers() -> np.ndarray:
        lam_general = solution[nf:]
        # a bound's multiplier from the stationarity of its weight: (H c - g)_k = C[:, k]' lam
        Hc = times_free(x) if nf else np.zeros(n)
        if Hc_pinned is not None:
            Hc += Hc_pinned
        gradient = (Hc - g - lam_general @ C_general)[fixed_index]
        out = np.empty(len(held))
        out[~is_bound] = lam_general
        out[is_bound] = sign[bounds] * gradient
        return out

    return c, multipliers


def partners(C: np.ndarray, d: np.ndarray) -> np.ndarray:
    """For each row of C c >= d, the row that is its negative (an equality written as two), or -1
    (of rows alike, the last). Candidates by a random projection of the rows (a row and its
    negative project to opposite values), confirmed row by row to 12 decimals (looking up every
    row by its bytes was 5 ms of an update with the skull's thousand rows; sorting the rows, 14)."""
    key = C @ np.random.default_rng(0).standard_normal(C.shape[1]) + 0.7071067811865476 * d
    order = np.argsort(key, kind="stable")  # (of equal keys, the later row last)
    sorted_key = key[order]
    tolerance = 1e-9 * (1.0 + np.abs(key)) + 1e-10 * (1.0 + np.abs(C).sum(axis=1) + np.abs(d))  # (the rounding's)
    out = np.full(len(d), -1, dtype=np.int64)
    lo = np.searchsorted(sorted_key, -key - tolerance, side="left")
    hi = np.searchsorted(sorted_key, -key + tolerance, side="right")
    for i in np.flatnonzero(hi > lo):  # (few: the bounds of a fixed weight, the family's sum)
        negated = np.round(-np.r_[C[i], d[i]], 12) + 0.0  # + 0.0: -0.0 and 0.0 alike
        candidates = order[lo[i] : hi[i]]
        alike = [j for j in candidates if np.array_equal(np.round(np.r_[C[j], d[j]], 12) + 0.0, negated)]
        if alike:
            out[i] = max(alike)
    return out
