"""atlas/active_set.py's solvers, and atlas/combine.py's problems, on small random problems of
the update's shape (a convex family
of correlated states, bounded swelling amplitudes, the family's sum fixed or within a range,
data rows from 20 points): the constrained least squares against brute force, and the
warm-started refits of cross-validation, leave-one-out and the bootstrap against a solve from
scratch by Lawson and Hanson's NNLS."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import minimize

from fenics_brainshift.atlas.active_set import least_distance, solve_on_active
from fenics_brainshift.atlas.combine import Problem, weight_constraints

pytestmark = pytest.mark.usefixtures("serial_only")


def _problem(
    total: tuple[float, float], seed: int = 0, family_size: int = 40, swelling: int = 3, points: int = 20
) -> Problem:
    rng = np.random.default_rng(seed)
    m = family_size + swelling
    family = np.zeros(m, dtype=bool)
    family[:family_size] = True
    lower, upper = np.zeros(m), np.zeros(m)
    lower[family_size:], upper[family_size:] = -1.0, 1.0
    upper[-1] = lower[-1] = 0.25  # a swelling fixed by its bounds: an equality written as two rows
    C, d = weight_constraints(family, lower, upper, total)
    modes = rng.normal(size=(m, 500)).cumsum(axis=0) * 1e-3  # neighbouring states alike, as a grid's are
    gram = modes @ modes.T / 500
    truth = np.r_[rng.dirichlet(np.full(family_size, 0.2)), rng.uniform(-0.8, 0.8, swelling - 1), 0.25]
    cross = gram @ np.r_[np.full(family_size, 1.0 / family_size), np.zeros(swelling)]
    A = rng.normal(size=(3 * points, m)) * 1e-3
    b = A @ truth + rng.normal(0.0, 5e-4, 3 * points)
    return Problem(A, b, np.repeat(np.arange(points), 3), 5e-4, gram, cross, C, d)


def _hessian(problem: Problem, alpha: float, rows: np.ndarray):
    A, b = problem.A[rows], problem.b[rows]
    H = A.T @ A / problem.noise**2 + alpha / 1e-6 * problem.gram
    g = A.T @ b / problem.noise**2 + alpha / 1e-6 * problem.cross
    H[np.diag_indices_from(H)] += 1e-9 * np.trace(H) / len(H)
    return H, g


@pytest.mark.parametrize("total", [(1.0, 1.0), (0.5, 2.0)])
def test_the_least_distance_solve_is_the_constrained_minimiser(total):
    """Against SLSQP from several starts (brute force on a small problem): the same objective,
    and the KKT answer no worse than any."""
    problem = _problem(total, family_size=8, swelling=3)
    H, g = _hessian(problem, 0.1, np.arange(len(problem.b)))
    c = least_distance(H, g, problem.C, problem.d)
    assert np.all(problem.C @ c - problem.d >= -1e-9)
    objective = lambda x: x @ H @ x - 2 * g @ x  # noqa: E731
    for seed in range(3):
        start = np.random.default_rng(seed).uniform(0, 0.2, len(g))
        other = minimize(
            objective,
            start,
            jac=lambda x: 2 * (H @ x - g),
            method="SLSQP",
            constraints=[{"type": "ineq", "fun": lambda x: problem.C @ x - problem.d, "jac": lambda x: problem.C}],
            options={"ftol": 1e-14, "maxiter": 500},
        )
        assert objective(c) <= objective(other.x) + 1e-9 * abs(objective(c))


@pytest.mark.parametrize("total", [(1.0, 1.0), (0.25, 4.0)])
@pytest.mark.parametrize("alpha", [1e-3, 1e-1, 10.0])
def test_warm_started_refits_are_the_solves_from_scratch(total, alpha):
    """Leave-one-out refits started from the fit to all the points: the primal active-set
    method's answer equals NNLS's from scratch, and it gets there every time (no refit falls
    back to NNLS)."""
    problem = _problem(total, seed=3)
    whole = problem.solve(alpha)
    for point in range(20):
        rows = np.flatnonzero(problem.groups != point)
        scratch = problem.solve(alpha, rows)
        warm = problem.solve(alpha, rows, near=whole)
        assert np.abs(warm - scratch).max() <= 1e-9 * max(np.abs(scratch).max(), 1.0)
        H, g = _hessian(problem, alpha, rows)
        primal = solve_on_active(H, g, *problem.unit_rows, whole, problem.partner, bounds=problem.bounds)
        assert primal is not None, point
        assert np.abs(primal - scratch).max() <= 1e-9 * max(np.abs(scratch).max(), 1.0)


def test_any_feasible_start_reaches_the_minimiser_and_an_infeasible_one_is_refused():
    """From far starts (a vertex of the family's simplex, the family's centre with the swelling
    on a bound), the answer is the minimiser, or None when the iterations run out: never a
    point that breaks the KKT conditions; a start outside the constraints is refused."""
    problem = _problem((0.5, 2.0), seed=5)
    H, g = _hessian(problem, 1e-2, np.arange(len(problem.b)))
    exact = least_distance(H, g, problem.C, problem.d)
    vertex = np.r_[1.0, np.zeros(39), 0.0, 0.0, 0.25]
    centre = np.r_[np.full(40, 1.0 / 40), -1.0, 1.0, 0.25]
    reached = 0
    for start in (vertex, centre):
        assert np.all(problem.C @ start - problem.d >= -1e-12)
        for iterations in (2, 200):
            c = solve_on_active(
                H, g, *problem.unit_rows, start, problem.partner, iterations=iterations, bounds=problem.bounds
            )
            assert c is None or np.abs(c - exact).max() <= 1e-9 * np.abs(exact).max()
            reached += c is not None
    assert reached >= 2  # with room to iterate, both starts get there
    outside = centre.copy()
    outside[0] = -0.01
    assert solve_on_active(H, g, *problem.unit_rows, outside, problem.partner, bounds=problem.bounds) is None


def test_rows_of_any_scale_and_every_weight_pinned():
    """An equality written as two rows of different scale (r.c >= 1, -s r.c >= -s) and a
    problem whose bounds fix every weight: the warm start gives the exact answer (the pair was
    held as two inequalities, a singular system solved to a wrong, feasible c; with no free
    weight the empty system raised)."""
    H, g = np.eye(2), np.zeros(2)
    r = np.array([0.3, 0.7])
    exact = r / (r @ r)  # the nearest point of the line r.c = 1
    for scale in (0.37, 4.1355, 1e3):
        C, d = np.vstack([r, -scale * r]), np.array([1.0, -scale])
        problem = Problem(
            np.zeros((3, 2)), np.zeros(3), np.zeros(3, dtype=int), 1.0, np.eye(2) * 1e-12, np.zeros(2), C, d
        )
        c = solve_on_active(
            H, g, *problem.unit_rows, np.array([1.0 / 0.3, 0.0]), problem.partner, bounds=problem.bounds
        )
        assert c is not None and np.allclose(c, exact, atol=1e-12), scale
    twice = Problem(
        np.zeros((3, 2)),
        np.zeros(3),
        np.zeros(3, dtype=int),
        1.0,
        np.eye(2),
        np.zeros(2),
        np.vstack([r, 2.0 * r]),
        np.array([1.0, 2.0]),
    )  # one constraint written twice, both active
    c = solve_on_active(H, g, *twice.unit_rows, np.array([1.0 / 0.3, 0.0]), twice.partner, bounds=twice.bounds)
    assert c is not None and np.allclose(c, exact, atol=1e-12)  # (the singular start: its rows join one by one)
    pinned = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), np.array([1.0, -1.0, 0.25, -0.25])
    problem = Problem(np.zeros((3, 2)), np.zeros(3), np.zeros(3, dtype=int), 1.0, np.eye(2), np.zeros(2), *pinned)
    c = solve_on_active(
        np.eye(2), np.zeros(2), *problem.unit_rows, np.array([1.0, 0.25]), problem.partner, bounds=problem.bounds
    )
    assert c is not None and np.allclose(c, [1.0, 0.25])


def test_the_hessian_never_formed_is_the_one_written_out():
    """DataHessian's block over some weights and its products with their columns against
    H = A'A / noise^2 + s G + ridge I formed here by hand (a ridge made large enough to see)."""
    from fenics_brainshift.atlas.active_set import DataHessian

    rng = np.random.default_rng(3)
    A, M = rng.normal(size=(9, 7)), rng.normal(size=(7, 7))
    G = M @ M.T
    H = DataHessian(A, 0.5, G, 0.3)
    H.ridge = 0.7
    formed = A.T @ A / 0.25 + 0.3 * G + 0.7 * np.eye(7)
    some, x = np.array([1, 4, 5]), rng.normal(size=3)
    block, times = H.restricted(some)
    assert np.allclose(block, formed[np.ix_(some, some)], rtol=1e-13, atol=0)
    assert np.allclose(times(x), formed[:, some] @ x, rtol=1e-13, atol=1e-13)
    assert np.allclose(H.times(some, x), formed[:, some] @ x, rtol=1e-13, atol=1e-13)
    assert np.allclose(H.dense(), formed, rtol=1e-13, atol=0)


def _with_skull_rows(problem: Problem, alpha: float, count: int = 300, seed: int = 7) -> Problem:
    """The problem with `count` skull-like rows r.c >= e (neighbouring rows alike, as the
    rows of neighbouring boundary nodes are), one in twenty cutting the fit without them."""
    rng = np.random.default_rng(seed)
    m = problem.C.shape[1]
    free = problem.solve(alpha)
    R = rng.normal(size=(count, m)).cumsum(axis=0) * 1e-3
    e = R @ free + rng.uniform(-0.15, 2.85, count) * 1e-3 * np.linalg.norm(R, axis=1)
    return problem.with_constraints(R, e)


@pytest.mark.parametrize("alpha", [1e-3, 1e-1])
def test_with_hundreds_of_skull_rows_the_refits_start_from_an_exact_vertex(alpha, monkeypatch):
    """A fit with 300 skull-like rows, some of them active: NNLS's answer is polished by the
    active-set method into one that keeps every row to round-off and is no worse than SLSQP's,
    and every leave-one-out refit starts from it and gets there (none falls back to NNLS, as
    all did on the 5 mm skull atlas when the start had to be feasible to 1e-9 and NNLS's was
    past 169 rows by up to 2.4e-7)."""
    from fenics_brainshift.atlas import combine

    problem = _with_skull_rows(_problem((1.0, 1.0), seed=11), alpha)
    C, d = problem.unit_rows

    def as_inexact_as_on_the_atlas(*args):  # NNLS's answer 3e-7 past its active rows, as seen on the atlas
        exact = least_distance(*args)
        active = np.abs(C @ exact - d) < 1e-9
        away = C[active].sum(axis=0)
        return exact - 3e-7 * away / np.linalg.norm(away)

    monkeypatch.setattr(combine, "least_distance", as_inexact_as_on_the_atlas)
    c = problem.solve(alpha)
    monkeypatch.undo()
    assert (C @ c - d).min() >= -1e-12
    assert np.count_nonzero(np.abs(C[-300:] @ c - d[-300:]) < 1e-9) >= 3  # skull rows hold it
    H, g = _hessian(problem, alpha, np.arange(len(problem.b)))
    objective = lambda x: x @ H @ x - 2 * g @ x  # noqa: E731
    other = minimize(
        objective,
        c + 1e-3,
        jac=lambda x: 2 * (H @ x - g),
        method="SLSQP",
        constraints=[{"type": "ineq", "fun": lambda x: problem.C @ x - problem.d, "jac": lambda x: problem.C}],
        options={"ftol": 1e-15, "maxiter": 1000},
    )
    assert objective(c) <= objective(other.x) + 1e-9 * abs(objective(c))
    calls = []
    monkeypatch.setattr(combine, "least_distance", lambda *a: calls.append(1) or least_distance(*a))
    for point in range(20):
        rows = np.flatnonzero(problem.groups != point)
        warm = problem.solve(alpha, rows, near=c)
        assert (C @ warm - d).min() >= -1e-12
        H_rows, g_rows = _hessian(problem, alpha, rows)
        scratch = least_distance(H_rows, g_rows, problem.C, problem.d)
        assert np.abs(warm - scratch).max() <= 1e-6 * max(np.abs(scratch).max(), 1.0)
    assert not calls  # (the test's own NNLS is its module's, not combine's)


def test_a_start_a_little_past_its_rows_reaches_the_minimiser():
    """A start past some rows by up to `infeasible` (relative) takes them into its first working
    set and ends at the minimiser (NNLS's, polished); past them by more, it is refused."""
    problem = _with_skull_rows(_problem((1.0, 1.0), seed=13), 1e-2)
    H, g = _hessian(problem, 1e-2, np.arange(len(problem.b)))
    exact = least_distance(H, g, problem.C, problem.d)  # NNLS, not the active-set method under test
    C, d = problem.unit_rows
    rng = np.random.default_rng(4)
    start = exact + rng.normal(size=len(exact)) * 1e-4
    start[:40] = np.maximum(start[:40], 0.0)
    start[:40] /= start[:40].sum()  # (the family's weights kept a convex combination)
    past = -(C @ start - d).min()
    assert past > 1e-9  # the start is past some rows
    c = solve_on_active(H, g, C, d, start, problem.partner, iterations=400, bounds=problem.bounds, infeasible=2 * past)
    assert c is not None and np.abs(c - exact).max() <= 1e-6 * max(np.abs(exact).max(), 1.0)
    assert (C @ c - d).min() >= -1e-12
    assert solve_on_active(H, g, C, d, start, problem.partner, bounds=problem.bounds, infeasible=0.5 * past) is None


def _random_qp(seed: int, duplicated: bool):
    """A small strictly convex QP with unit rows (three of them written twice when
    `duplicated`: dependent rows), bounds x >= -2, its exact answer by NNLS."""
    rng = np.random.default_rng(seed)
    n, k = 8, 10
    M = rng.normal(size=(n, n))
    H, g = M @ M.T + 0.5 * np.eye(n), rng.normal(size=n) * 3
    C = rng.normal(size=(k, n))
    C /= np.linalg.norm(C, axis=1)[:, None]
    d = rng.normal(size=k) * 0.3
    if duplicated:
        C, d = np.vstack([C, C[:3]]), np.r_[d, d[:3]]
    C, d = np.vstack([C, np.eye(n)]), np.r_[d, -2.0 * np.ones(n)]
    return rng, H, g, C, d, least_distance(H, g, C, d)


@pytest.mark.parametrize("seed", [1036] + [k for k in range(0, 120, 3) if k not in (63, 90, 111)])  # (feasible ones)
def test_a_start_past_dependent_rows_never_ends_past_them(seed):
    """A start past rows some of which are written twice (the first working set is then
    singular, and its general rows leave it): the answer is the minimiser or None, never a
    point past those rows below the minimum (seed 1036 ended 0.025 past two rows, its objective
    under the true minimum)."""
    from fenics_brainshift.atlas.active_set import partners

    rng, H, g, C, d, exact = _random_qp(seed, duplicated=True)
    assert (C @ exact - d).min() >= -1e-8
    start = exact + rng.normal(size=len(exact)) * rng.choice([1e-3, 1e-2, 5e-2])
    c = solve_on_active(H, g, C, d, start, partners(C, d), iterations=400, infeasible=0.1)
    if c is not None:
        assert (C @ c - d).min() >= -1e-9
        objective = lambda x: x @ H @ x - 2 * g @ x  # noqa: E731
        assert objective(c) <= objective(exact) + 1e-8 * (1 + abs(objective(exact)))
        assert objective(c) >= objective(exact) - 1e-8 * (1 + abs(objective(exact)))


def test_the_point_nearest_a_start_inside_the_rows_on_the_way_from_an_anchor():
    """combine.towards by hand: the triangle x >= 0, y >= 0, x + y <= 1; from (0.25, 0.25) to
    (1, 1) the way leaves it at (0.5, 0.5), to (-1, 3) (past two rows) at (0, 0.8); a start inside
    is itself; an anchor outside, None."""
    from fenics_brainshift.atlas.combine import towards

    C, d = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]]), np.array([0.0, 0.0, -1.0])
    assert towards(np.array([0.25, 0.25]), np.array([1.0, 1.0]), C, d) == pytest.approx([0.5, 0.5], abs=1e-15)
    assert towards(np.array([0.25, 0.25]), np.array([0.5, 0.1]), C, d) == pytest.approx([0.5, 0.1], abs=1e-15)
    assert towards(np.array([0.25, 0.25]), np.array([-1.0, 0.25]), C, d) == pytest.approx([0.0, 0.25], abs=1e-15)
    assert towards(np.array([0.25, 0.25]), np.array([-1.0, 3.0]), C, d) == pytest.approx([0.0, 0.8], abs=1e-15)
    assert towards(np.array([2.0, 0.0]), np.array([0.1, 0.1]), C, d) is None


@pytest.mark.parametrize("vertex", [0, 7, 23])
def test_a_start_past_rows_it_cannot_hold_goes_in_from_the_anchor(vertex, monkeypatch):
    """The skull's rows re-linearised at the last fit can leave the start past more rows than
    it has free weights to hold them with (the 5 mm skull atlas: past 8, 7 free): the
    active-set method from there fails, and NNLS from scratch took 310 ms. From the point
    nearest the start inside the rows, on the way from an anchor inside (the prior's
    weights in the update), it reaches NNLS's minimiser without NNLS."""
    from fenics_brainshift.atlas import combine

    problem = _with_skull_rows(_problem((1.0, 1.0), seed=11), 1e-2)
    alpha = 1e-2
    H, g = _hessian(problem, alpha, np.arange(len(problem.b)))
    exact = least_distance(H, g, problem.C, problem.d)  # NNLS, before it is taken away
    anchor = problem.solve(1e2)  # the answer of another alpha: inside the same rows
    start = np.eye(len(exact))[vertex]  # one state of the family alone: past many skull rows
    C, d = problem.unit_rows
    assert (C @ start - d).min() < -0.2  # (past them: farther than the warm start takes in)
    assert (
        solve_on_active(H, g, C, d, start, problem.partner, bounds=problem.bounds, infeasible=combine.INFEASIBLE)
        is None
    )

    def no_nnls(*_):
        raise AssertionError("NNLS was called")

    monkeypatch.setattr(combine, "least_distance", no_nnls)
    anchored = Problem(
        problem.A,
        problem.b,
        problem.groups,
        problem.noise,
        problem.gram,
        problem.cross,
        problem.C,
        problem.d,
        anchor=anchor,
    )
    c = anchored.solve(alpha, near=start)
    assert np.abs(c - exact).max() <= 1e-6 * max(np.abs(exact).max(), 1.0)
    assert (C @ c - d).min() >= -1e-12


def test_each_row_s_partner_is_the_last_row_that_is_its_negative():
    """active_set.partners against every pair of rows compared: rows written twice, equality
    pairs (a weight's lower and upper bound alike, the family's sum), a -0.0 against a 0.0,
    rows whose keys nearly tie but differ, and rows with no partner."""
    from fenics_brainshift.atlas.active_set import partners

    rng = np.random.default_rng(4)
    C, d = rng.normal(size=(40, 6)), rng.normal(size=40)
    C[5], d[5] = -C[3], -d[3]  # a pair
    C[9], d[9] = C[3], d[3]  # the pair's first row written twice: its partner is still row 5, 5's is 9
    C[12], d[12] = -C[7], -d[7]
    C[13], d[13] = -C[7], -d[7]  # two negatives of row 7: the last, 13
    C[20], d[20] = 0.0, 0.0
    C[21], d[21] = -0.0, -0.0  # zero rows are each other's negative
    C[30], d[30] = -C[31] * (1 + 1e-10), -d[31]  # nearly, not: no partner
    rows = np.round(np.column_stack([C, d]), 12) + 0.0
    expected = [
        max([j for j in range(len(rows)) if np.array_equal(rows[j], -rows[i] + 0.0)], default=-1)
        for i in range(len(rows))
    ]
    assert partners(C, d).tolist() == expected
    assert expected[3] == 5 and expected[5] == 9 and expected[7] == 13 and expected[30] == -1


def test_the_posterior_spread_by_hand_on_a_two_state_family():
    """Two states in the family (weights t and 1 - t), a third weight held at its bound: the
    posterior lives on the line c = (t, 1 - t, 0), where t has variance 1 / (e.H.e), e = (1, -1, 0),
    H = A'A / noise^2 + (alpha / mm^2) G; a node's spread is then |U_1 - U_2| sqrt(var t) (the
    third mode, at its bound, adds nothing). With the residual 3x what the noise explains, the
    variance scales by the chi-square per degree of freedom."""
    from fenics_brainshift.atlas import posterior

    rng = np.random.default_rng(8)
    modes = rng.normal(size=(3, 50, 3)) * 1e-3
    flat = modes.reshape(3, -1)
    gram = flat @ flat.T / 50
    family = np.array([True, True, True])
    C, d = weight_constraints(family, np.zeros(3), np.zeros(3))
    C, d = np.vstack([C, [0.0, 0.0, -1.0]]), np.r_[d, 0.0]  # the third weight <= 0: held at 0
    points = 6
    pre = rng.integers(0, 50, points)
    A = modes[:, pre, :].reshape(3, -1).T  # (3 points, weights): point-pair rows
    truth = np.array([0.3, 0.7, 0.0])
    noise, alpha = 2e-4, 0.05
    for excess in (1.0, 3.0):
        b = A @ truth + excess * noise * rng.choice([-1.0, 1.0], len(A))  # (residual ~ excess x noise)
        problem = Problem(A, b, np.repeat(np.arange(points), 3), noise, gram, gram @ truth, C, d)
        c = problem.solve(alpha)
        assert c[2] == 0.0 and 0 < c[0] < 1
        H = A.T @ A / noise**2 + alpha / 1e-6 * gram
        e = np.array([1.0, -1.0, 0.0])
        variance = 1.0 / (e @ H @ e)
        r = A @ c - b
        factor = max(1.0, (r @ r) / noise**2 / (len(b) - 1))  # (rows minus the face's dimension, 1)
        expected = np.linalg.norm(modes[0] - modes[1], axis=1) * np.sqrt(variance * factor)
        got = posterior.spread(problem, alpha, c, modes)
        assert np.allclose(got, expected, rtol=1e-6, atol=0.0)
        assert (factor > 1.5) == (excess > 1.0)  # (both branches of the scale)
        # a general inequality the fit presses (a skull's row through it, t <= t*): it bounds the
        # posterior on one side, it does not pin it (held as an equality, the face was the point
        # and the spread 0)
        pressed = Problem(
            A, b, problem.groups, noise, gram, gram @ truth, np.vstack([C, [-1.0, 1.0, 0.0]]), np.r_[d, c[1] - c[0]]
        )  # (-t + (1 - t) >= its value at t*: t <= t*)
        assert np.allclose(pressed.solve(alpha), c, atol=1e-9)
        assert np.allclose(posterior.spread(pressed, alpha, c, modes), expected, rtol=1e-6, atol=0.0)


def test_cross_validation_is_the_k_fold_error_and_stops_past_its_minimum():
    """choose_alpha's curve against K-fold errors computed here by NNLS from scratch at every
    alpha (the same folds), and its scan stopping once the error has grown by more than RISE at
    RISES alphas in a row: the same choice as the whole grid's where the curve is U-shaped."""
    from fenics_brainshift.atlas import combine

    problem = _problem((1.0, 1.0), seed=0)
    fold = combine.fold_of(problem.groups, combine.FOLDS)
    alphas = combine.ALPHAS
    brute = []
    for alpha in alphas:
        errors = []
        for k in np.unique(fold):
            H, g = _hessian(problem, alpha, np.flatnonzero(fold != k))
            c = least_distance(H, g, problem.C, problem.d)
            errors.append(problem.misfit(c, np.flatnonzero(fold == k)))
        brute.append(float(np.sqrt(np.mean(np.concatenate(errors) ** 2)) * 1e3))
    alpha, curve, whole = combine.choose_alpha(problem, near=problem.solve(alphas[0]))
    got = [p["cv_rms_mm"] for p in curve]
    assert np.allclose(got, brute[: len(got)], rtol=1e-6)
    rises = [b > (1 + combine.RISE) * a for a, b in zip(brute, brute[1:])]
    R = combine.RISES  # (rises[i]: at alpha i + 1; a stop after alpha j leaves j + 1 in the curve)
    stop = next((j + 1 for j in range(R, len(brute)) if all(rises[j - R : j])), len(alphas))
    assert len(curve) == stop
    assert stop < len(alphas)  # (this problem's curve does rise: the stop is tested)
    assert alpha == alphas[int(np.argmin(brute))]  # (U-shaped here: the whole grid's choice)
    H, g = _hessian(problem, alpha, np.arange(len(problem.b)))  # (and the fit to every point at it)
    assert np.allclose(whole, least_distance(H, g, problem.C, problem.d), atol=1e-9)


def test_the_posterior_spread_is_that_of_the_exact_vertex_from_an_answer_of_nnls():
    """NNLS's answer (every refit's when warm starts are off; a fit whose polish failed) has its
    weights at their bounds off by up to 2e-8 on the 5 mm skull atlas (1e-15 on these small
    problems: that error is added here): the posterior takes the same active face, and the same
    spread, as from the exact vertex the active-set method polishes it into."""
    from fenics_brainshift.atlas import posterior

    problem = _problem((1.0, 1.0), seed=2)
    modes = np.random.default_rng(1).normal(size=(len(problem.gram), 40, 3)) * 1e-3
    rng = np.random.default_rng(3)
    for alpha in (1e-3, 1e-1, 10.0):
        exact = problem.solve(alpha)
        H, g = _hessian(problem, alpha, np.arange(len(problem.b)))
        rough = least_distance(H, g, problem.C, problem.d)
        at_bound = exact == 0
        assert at_bound.sum() > 10
        rough[at_bound] += rng.uniform(-2e-10, 2e-8, at_bound.sum())
        assert np.allclose(
            posterior.spread(problem, alpha, rough, modes),
            posterior.spread(problem, alpha, exact, modes),
            rtol=1e-4,
            atol=0.0,
        )


def _past_the_prior(seed: int = 5, count: int = 300, past: int = 12):
    """A problem whose prior (the weights nearest the scene's prediction, here a mix of three
    states) is past `past` of `count` skull-like rows (a mix of settled states can be a little
    past the skull where none of them is), and an atlas-like holder of what prepared.py keeps."""
    from types import SimpleNamespace

    from fenics_brainshift.atlas.combine import Constraints

    base = _problem((0.5, 2.0), seed=seed)
    m = base.C.shape[1]
    family = np.zeros(m, dtype=bool)
    family[:40] = True
    prior = np.zeros(m)
    prior[[3, 17, 29]] = [0.5, 0.3, 0.2]
    prior[-1] = 0.25  # (the swelling its bounds fix)
    cross = base.gram @ prior  # (the prediction: this mix exactly)
    rng = np.random.default_rng(seed)
    R = rng.normal(size=(count, m)).cumsum(axis=0) * 1e-3
    room = rng.uniform(0.5, 3.0, count) * 1e-3 * np.linalg.norm(R, axis=1)
    room[rng.choice(count, past, replace=False)] *= -0.2  # the prior past these
    C, d = np.vstack([base.C, R]), np.r_[base.d, R @ prior - room]
    problem = Problem(base.A, base.b, base.groups, base.noise, base.gram, cross, C, d)
    atlas = SimpleNamespace(
        once={"prior_weights": prior, "skull_at_prior": (np.arange(count), Constraints(C, d))},
        gram=base.gram,
        cross=cross,
        family=family,
    )
    return problem, atlas, prior


@pytest.mark.parametrize("alpha", [1e-4, 1e-2, 1.0])
def test_the_first_fit_starts_inside_the_rows_the_prior_is_past(alpha, monkeypatch):
    """prepared.start_inside: the weights nearest the prediction inside every row (no row
    past, its regulariser no larger than SLSQP's over the same rows, the family's unused
    weights exactly 0); the first fit from it reaches NNLS's minimiser without NNLS. From the
    prior itself, past more rows than it has free weights, the active-set method has no step
    (every update at 3 mm then solved by NNLS from scratch: 0.4 s of 0.5)."""
    from fenics_brainshift.atlas import combine
    from fenics_brainshift.atlas.prepared import start_inside

    problem, atlas, prior = _past_the_prior()
    C, d = problem.unit_rows
    assert (C @ prior - d).min() < -1e-4  # (the prior is past rows)
    start = start_inside(atlas)
    assert (C @ start - d).min() >= -1e-9
    G = problem.gram + 1e-9 * np.trace(problem.gram) / len(problem.gram) * np.eye(len(problem.gram))
    regulariser = lambda x: x @ G @ x - 2 * problem.cross @ x  # noqa: E731
    other = minimize(
        regulariser,
        start + 1e-3,
        jac=lambda x: 2 * (G @ x - problem.cross),
        method="SLSQP",
        constraints=[{"type": "ineq", "fun": lambda x: problem.C @ x - problem.d, "jac": lambda x: problem.C}],
        options={"ftol": 1e-16, "maxiter": 1000},
    )
    assert regulariser(start) <= regulariser(other.x) + 1e-9 * abs(regulariser(start))
    assert np.count_nonzero(start[:40]) < 40 and np.count_nonzero(start[:40] == 0.0) > 0
    nnls = least_distance(G, problem.cross, problem.C, problem.d)  # (the answer before its round-off is set to 0)
    assert start[:40].sum() == pytest.approx(nnls[:40].sum(), abs=1e-15)  # (the family's sum kept)
    H, g = _hessian(problem, alpha, np.arange(len(problem.b)))
    exact = least_distance(H, g, problem.C, problem.d)
    from_prior = solve_on_active(H, g, C, d, prior, problem.partner, bounds=problem.bounds, infeasible=0.1)
    assert from_prior is None  # (no step)
    monkeypatch.setattr(combine, "least_distance", lambda *a: pytest.fail("NNLS was called"))
    fit = dataclasses.replace(problem, anchor=start).solve(alpha, near=start)
    assert np.abs(fit - exact).max() <= 1e-6 * max(np.abs(exact).max(), 1.0)


@pytest.mark.parametrize("vertex", [0, 11, 25])
def test_a_refit_past_rows_eased_to_hold_the_first_start_goes_in_from_it(vertex, monkeypatch):
    """rows.ease: skull rows re-linearised at a fit and eased so that the first start (here
    the prior, past 40 of them) is inside, a tenth of SKULL_SLACK off each: a refit from a
    start past many of them reaches NNLS's minimiser from the anchor without NNLS. Eased to
    hold the anchor exactly, it sat on more rows than it had free weights, and NNLS was needed
    (a round of an update at 3 mm took 0.4 s more)."""
    from fenics_brainshift.atlas import combine
    from fenics_brainshift.atlas.rows import ease

    problem, _, prior = _past_the_prior(past=40)
    n = len(problem.d) - 300
    C, d = ease(problem.C[n:], problem.d[n:], prior)
    eased = dataclasses.replace(problem, d=np.r_[problem.d[:n], d], constraints=None, anchor=prior)
    assert np.all(C @ prior - d > 0) and np.count_nonzero(d < problem.d[n:]) == 40
    start = np.eye(len(prior))[vertex]
    Cu, du = eased.unit_rows
    assert np.count_nonzero(Cu @ start - du < -1e-3) > 10  # (past many rows)
    alpha = 1e-2
    H, g = _hessian(eased, alpha, np.arange(len(eased.b)))
    exact = least_distance(H, g, eased.C, eased.d)
    monkeypatch.setattr(combine, "least_distance", lambda *a: pytest.fail("NNLS was called"))
    c = eased.solve(alpha, near=start)
    assert np.abs(c - exact).max() <= 1e-6 * max(np.abs(exact).max(), 1.0)
