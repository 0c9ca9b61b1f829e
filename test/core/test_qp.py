"""Tests of the QP backends against an exact active-set enumeration, and of the fallbacks."""
import math

import numpy as np
import pytest
from hypothesis import example, given, HealthCheck, settings, strategies as st
from hypothesis.extra.numpy import arrays
from proxsuite import proxqp

from oracles import ReferenceSolver
from polyc2bf_ros.core.qp import solver as qp
from polyc2bf_ros.core.qp.backends import make_solver, SOLVERS
from polyc2bf_ros.core.qp.proxsuite_backend import ProxsuiteSolver
from polyc2bf_ros.core.qp.solver import DaqpSolver, QPStatus, solve_with_shared_slack
from strategies import examples

# One instance per backend for the whole module, so that DAQP's per-size models are reused
# across examples of the same size (stale buffers would show up as wrong answers).
BACKENDS = {'daqp': DaqpSolver(), 'proxsuite': ProxsuiteSolver()}
REFERENCE = ReferenceSolver()
AGREEMENT_TOL = 1e-8
PROPERTY = settings(max_examples=examples(120), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

coefficient = st.floats(-2.0, 2.0).map(lambda v: round(v, 3))  # exact zeros and duplicates
positive = st.floats(0.1, 10.0)


def vector(n, elements):
    """Return a strategy for float vectors of length n."""
    return arrays(np.float64, n, elements=elements)


@st.composite
def boxes(draw, centre, finite=False):
    """Draw a box around ``centre``; some sides are infinite unless ``finite``."""
    n = centre.shape[0]
    lower = centre - draw(vector(n, st.floats(0.0, 3.0)))
    upper = centre + draw(vector(n, st.floats(0.0, 3.0)))
    if not finite:
        lower[draw(arrays(np.bool_, n))] = -math.inf
        upper[draw(arrays(np.bool_, n))] = math.inf
    return lower, upper


@st.composite
def feasible_problems(draw, max_n=4, max_m=8, finite_box=False):
    """Draw a problem feasible at a point ``x_feas``, with degenerate rows mixed in.

    Rows with zero margin pass through ``x_feas`` (several of them make a degenerate vertex);
    duplicates, positive multiples and parallel looser copies of rows are added; ``x_ref`` is far
    from ``x_feas`` so that rows and bounds are active at the optimum.
    """
    n = draw(st.integers(2, max_n))
    m = draw(st.integers(0, max_m))
    x_feas = draw(vector(n, st.floats(-1.0, 1.0)))
    lower, upper = draw(boxes(x_feas, finite_box))
    x_ref = x_feas + draw(vector(n, st.floats(-6.0, 6.0)))
    weights = draw(vector(n, positive))
    rows = draw(arrays(np.float64, (m, n), elements=coefficient))
    margins = draw(vector(m, st.sampled_from([0.0, 0.0, 0.01, 0.5, 2.0])))
    b = rows @ x_feas - margins
    A = list(rows)
    bs = list(b)
    for i in draw(st.lists(st.integers(0, m - 1), max_size=3)) if m else []:
        kind = draw(st.sampled_from(['duplicate', 'multiple', 'looser']))
        scale = 1.0 if kind == 'duplicate' else draw(st.floats(0.25, 4.0))
        A.append(scale * rows[i])
        bs.append(scale * b[i] - (1.0 if kind == 'looser' else 0.0))
    order = draw(st.permutations(range(len(bs))))
    A = np.array(A, dtype=np.float64).reshape(-1, n)[order]
    b = np.array(bs, dtype=np.float64)[order]
    return x_ref, weights, A, b, lower, upper


@st.composite
def infeasible_problems(draw, max_n=4, max_m=6):
    """Draw a feasible problem and add rows that contradict each other or the box."""
    x_ref, weights, A, b, lower, upper = draw(feasible_problems(max_n, max_m, finite_box=True))
    n = x_ref.shape[0]
    a = draw(vector(n, coefficient).filter(lambda v: np.abs(v).max() > 0.0))
    gap = draw(st.floats(0.01, 1.0))
    if draw(st.booleans()):
        beta = draw(st.floats(-2.0, 2.0))
        scale = draw(st.floats(0.25, 4.0))  # a x >= beta and a x <= beta - gap
        new_rows, new_b = [a, -scale * a], [beta, -scale * (beta - gap)]
        if not draw(st.booleans()):
            lower, upper = -np.full(n, math.inf), np.full(n, math.inf)
    else:
        box_max = np.maximum(a * lower, a * upper).sum()  # a x <= box_max on the box
        new_rows, new_b = [a], [box_max + gap]
    A = np.vstack([A, new_rows])
    b = np.concatenate([b, new_b])
    order = draw(st.permutations(range(b.shape[0])))
    return x_ref, weights, A[order], b[order], lower, upper


def assert_feasible(x, A, b, lower, upper, slack=0.0):
    """Assert that x is finite, in the box and satisfies ``A x + slack >= b`` to 1e-9."""
    assert np.isfinite(x).all()
    assert (lower <= x).all() and (x <= upper).all()
    if b.size:
        assert (A @ x + slack - b).min() >= -qp.FEASIBILITY_TOL


@PROPERTY
@given(feasible_problems())
def test_backends_agree_with_reference(problem):
    """DAQP and proxsuite find the enumerated optimum to 1e-8, degenerate rows included."""
    expected = REFERENCE.solve(*problem)
    assert expected.status is QPStatus.OPTIMAL
    for name, solver in BACKENDS.items():
        result = solver.solve(*problem)
        assert result.status is QPStatus.OPTIMAL, name
        np.testing.assert_allclose(result.x, expected.x, rtol=0.0, atol=AGREEMENT_TOL,
                                   err_msg=name)


TINY = 3.4642038e-08


@pytest.mark.parametrize('problem, optimum', [
    # x_0 is held 4 from x_ref: total cost 16 + 6e-16 against 16 + 1.2e-15, both 16.0.
    ((np.array([4.0, TINY, 0.0, 0.0]), np.ones(4),
      np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.0]]),
      np.zeros(3), np.zeros(4), np.array([0.0, 1.0, 0.0, 1.0])),
     [0.0, TINY / 2, 0.0, TINY / 2]),
    # x_ref in the box but for x_0 and x_2 by 3.5e-8: only x_1 keeps its value.
    ((np.full(3, TINY), np.array([2.0, 0.125, 0.125]), np.array([[0.0, 1.0, 1.0]]),
      np.zeros(1), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
     [0.0, TINY, 0.0]),
    # x_0 fixed at 1, x_ref inside for x_1: [1 + 2e-16, 1] (outside the box by rounding,
    # on the row) costs 1.3e-15 less than the optimum [1, 1 + TINY].
    ((np.array([4.0, 1.0 + TINY]), np.ones(2), np.array([[1.5, 1.0]]), np.array([2.5]),
      np.array([1.0, 1.0]), np.array([1.0, 2.0])),
     [1.0, 1.0 + TINY]),
])
def test_reference_tells_optima_apart_below_the_cost_rounding(problem, optimum):
    """Candidates whose costs differ below the rounding of the total (found by hypothesis).

    Near the optimum the cost is flat: points 3.5e-8 apart differ in cost by ~1e-15.
    """
    expected = REFERENCE.solve(*problem).x
    np.testing.assert_allclose(expected, optimum, rtol=1e-7, atol=1e-20)
    for name, solver in BACKENDS.items():
        np.testing.assert_allclose(solver.solve(*problem).x, expected, rtol=0.0,
                                   atol=AGREEMENT_TOL, err_msg=name)


@PROPERTY
@given(st.one_of(feasible_problems(), infeasible_problems()))
def test_optimal_answers_are_feasible_and_no_answer_is_nan(problem):
    """An optimal answer meets every row and bound to 1e-9; no answer is ever NaN."""
    for solver in (*BACKENDS.values(), REFERENCE):
        result = solver.solve(*problem)
        assert np.isfinite(result.x).all()
        if result.status is QPStatus.OPTIMAL:
            assert_feasible(result.x, *problem[2:])


@PROPERTY
@given(infeasible_problems())
def test_infeasible_problems_are_reported(problem):
    """Contradictory rows and rows the box cannot meet give INFEASIBLE and the clipped x_ref."""
    x_ref, _, _, _, lower, upper = problem
    for solver in (*BACKENDS.values(), REFERENCE):
        result = solver.solve(*problem)
        assert result.status is QPStatus.INFEASIBLE, solver.name
        np.testing.assert_array_equal(result.x, np.clip(x_ref, lower, upper))


@settings(max_examples=examples(60), deadline=None)
@given(feasible_problems(max_n=3, max_m=4), st.floats(1.0, 1e4))
def test_shared_slack_is_zero_when_feasible(problem, slack_weight):
    """A feasible problem needs no slack: s = 0 and x is the plain optimum."""
    for solver in BACKENDS.values():
        plain = solver.solve(*problem)
        x, s, result = solve_with_shared_slack(solver, *problem, slack_weight)
        assert result.status is QPStatus.OPTIMAL
        assert abs(s) <= 1e-9
        np.testing.assert_array_equal(x, plain.x)


@settings(max_examples=examples(60), deadline=None)
@given(infeasible_problems(max_n=3, max_m=3), st.floats(1.0, 1e4))
# Boxes 1e-8 wide around x_ref: the reference once took the corner, 1e-8 off (its
# multipliers, -1.1e-9, passed a solver's certificate tolerance).
@example(problem=(np.array([1.0, 0.0, 0.53582162]), np.array([0.109375, 0.109375, 0.25390625]),
                  np.array([[0.0, 0.0, 2.0]]), np.array([7.88981452]),
                  np.array([1.0 - 1e-8, -1e-8, 0.535821609]),
                  np.array([1.0, 0.0, 3.44490726])), slack_weight=3.0)
def test_shared_slack_relaxes_infeasible_rows(problem, slack_weight):
    """An infeasible problem gets the relaxed optimum: s > 0, A x + s >= b, bounds hard."""
    x_ref, weights, A, b, lower, upper = problem
    expected = REFERENCE.solve(np.append(x_ref, 0.0), np.append(weights, slack_weight),
                               np.hstack([A, np.ones((b.size, 1))]), b,
                               np.append(lower, 0.0), np.append(upper, math.inf))
    for solver in BACKENDS.values():
        x, s, result = solve_with_shared_slack(solver, *problem, slack_weight)
        assert result.status is QPStatus.OPTIMAL, solver.name
        assert s > 0.0
        assert_feasible(x, A, b, lower, upper, slack=s)
        np.testing.assert_allclose(np.append(x, s), expected.x, rtol=0.0, atol=AGREEMENT_TOL,
                                   err_msg=solver.name)


def test_shared_slack_reuses_the_plain_result_given():
    """A plain result passed in is not solved again; iterations of both solves add up."""
    problem = ([3.0, 1.0], [1.0, 1.0], [[1.0, 0.0], [-1.0, 0.0]], [1.0, 0.0],
               [-5.0, -5.0], [5.0, 5.0])
    solver = DaqpSolver()
    solver.shortcut = False  # so that the relaxed problem, too, is solved by DAQP
    plain = solver.solve(*problem)
    assert plain.status is QPStatus.INFEASIBLE
    x, s, result = solve_with_shared_slack(solver, *problem, 100.0, plain=plain)
    # min (x1 - 3)^2 + 100 s^2 with 1 - s <= x1 <= s: x1 = s = 1/2 (the x1 term is flat there).
    np.testing.assert_allclose([*x, s], [0.5, 1.0, 0.5], atol=1e-12)
    assert result.status is QPStatus.OPTIMAL
    assert result.iterations > plain.iterations


def test_shared_slack_with_an_empty_box_fails_cleanly():
    """With an empty box even the relaxed problem is infeasible; s = 0, x finite."""
    x, s, result = solve_with_shared_slack(DaqpSolver(), [0.0, 0.0], [1.0, 1.0], [[1.0, 0.0]],
                                           [1.0], [1.0, 0.0], [0.0, 1.0], 10.0)
    assert result.status is QPStatus.INFEASIBLE
    assert s == 0.0 and np.isfinite(x).all()


@pytest.mark.parametrize('name', sorted(SOLVERS))
def test_feasible_reference_is_returned_as_is(name):
    """A feasible x_ref (rows to 1e-12) is returned unchanged, as a copy, with 0 iterations."""
    x_ref = np.array([0.3, -0.2])
    A = np.array([[1.0, 1.0], [0.0, 1.0]])
    b = A @ x_ref + np.array([0.0, 1e-13])  # one row active, one violated by less than 1e-12
    result = make_solver(name).solve(x_ref, [1.0, 2.0], A, b, [-1.0, -1.0], [1.0, 1.0])
    assert result.status is QPStatus.OPTIMAL and result.iterations == 0
    np.testing.assert_array_equal(result.x, x_ref)
    assert result.x is not x_ref


@pytest.mark.parametrize('name', sorted(SOLVERS))
def test_without_rows_the_answer_is_the_clipped_reference(name):
    """With no rows (or only trivial zero rows) the optimum is x_ref clipped to the box."""
    solver = make_solver(name)
    for A in (np.zeros((0, 3)), [], [[0.0, 0.0, 0.0]]):
        b = [] if len(A) == 0 else [-1.0]
        result = solver.solve([3.0, -4.0, 0.5], [1.0, 2.0, 3.0], A, b,
                              [-1.0, -1.0, -math.inf], [1.0, 1.0, math.inf])
        assert result.status is QPStatus.OPTIMAL
        np.testing.assert_array_equal(result.x, [1.0, -1.0, 0.5])


@pytest.mark.parametrize('name', sorted(SOLVERS))
def test_zero_rows_are_dropped_or_infeasible(name):
    """A zero row with b <= 0 is ignored; one with b > 0 makes the problem infeasible."""
    solver = make_solver(name)
    x_ref, weights, lower, upper = [2.0, 2.0], [1.0, 1.0], [-5.0, -5.0], [5.0, 5.0]
    A = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    result = solver.solve(x_ref, weights, A, [0.0, 6.0, -3.0], lower, upper)
    assert result.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(result.x, [3.0, 3.0], atol=1e-9)
    result = solver.solve(x_ref, weights, A, [0.0, 6.0, 1e-3], lower, upper)
    assert result.status is QPStatus.INFEASIBLE
    np.testing.assert_array_equal(result.x, x_ref)


@pytest.mark.parametrize('name', sorted(SOLVERS))
def test_empty_box_is_infeasible(name):
    """Lower > upper anywhere is infeasible, whatever the rows."""
    result = make_solver(name).solve([0.0, 0.0], [1.0, 1.0], [[1.0, 0.0]], [-1.0],
                                     [-1.0, 1.0], [1.0, -1.0])
    assert result.status is QPStatus.INFEASIBLE
    assert np.isfinite(result.x).all()


@pytest.mark.parametrize('name', sorted(SOLVERS))
@pytest.mark.parametrize('where', ['x_ref', 'A', 'b', 'lower'])
def test_nan_data_never_gives_a_nan_answer(name, where):
    """NaN in the data gives a non-optimal status and a finite answer."""
    data = {'x_ref': np.array([3.0, 1.0]), 'weights': np.ones(2),
            'A': np.array([[1.0, 1.0], [1.0, -1.0]]), 'b': np.array([1.0, -5.0]),
            'lower': np.full(2, -2.0), 'upper': np.full(2, 2.0)}
    data[where].flat[0] = math.nan
    result = make_solver(name).solve(**data)
    assert result.status is not QPStatus.OPTIMAL
    assert np.isfinite(result.x).all()


def test_bad_shapes_and_weights_raise():
    """Inconsistent shapes and weights that are not positive and finite raise ValueError."""
    solver = DaqpSolver()
    good = dict(x_ref=np.zeros(2), weights=np.ones(2), A=np.ones((1, 2)), b=np.zeros(1),
                lower=-np.ones(2), upper=np.ones(2))
    for key, bad in [('A', np.ones((1, 3))), ('b', np.zeros(2)), ('weights', np.ones(3)),
                     ('upper', np.ones(1)), ('x_ref', np.zeros((2, 1)))]:
        with pytest.raises(ValueError, match='shape'):
            solver.solve(**{**good, key: bad})
    for weights in ([1.0, 0.0], [1.0, -1.0], [1.0, math.nan], [1.0, math.inf]):
        with pytest.raises(ValueError, match='weights'):
            solver.solve(**{**good, 'weights': np.array(weights)})


def test_make_solver():
    """make_solver builds every backend by name and lists the names for an unknown one."""
    assert sorted(SOLVERS) == ['daqp', 'proxsuite']
    for name, cls in SOLVERS.items():
        solver = make_solver(name)
        assert isinstance(solver, cls) and solver.name == name
    with pytest.raises(ValueError, match='daqp, proxsuite'):
        make_solver('osqp')


def test_daqp_models_are_reused_without_stale_data():
    """A cached DAQP model answers exactly as a fresh one, problem after problem."""
    rng = np.random.default_rng(7)
    shared = DaqpSolver()
    for _ in range(200):
        n, m = 2, int(rng.integers(3, 5))
        A = rng.normal(size=(m, n))
        x_ref = rng.normal(size=n) * 3.0
        weights = rng.uniform(0.5, 2.0, size=n)
        b = A @ rng.normal(size=n) - rng.uniform(0.0, 0.5, size=m)
        bound = rng.uniform(1.0, 3.0)
        problem = (x_ref, weights, A, b, np.full(n, -bound), np.full(n, bound))
        expected = DaqpSolver().solve(*problem)
        result = shared.solve(*problem)
        assert result.status is expected.status
        np.testing.assert_array_equal(result.x, expected.x)
    assert len(shared._workspaces) == 2


def test_proxsuite_default_settings_report_a_wrong_answer_as_solved():
    """Show why ProxsuiteSolver checks the duality gap and the KKT conditions.

    On this 2-variable, 1-row problem proxsuite 0.8.0 with default settings stops after two
    iterations at a feasible point with twice the optimal cost and says PROXQP_SOLVED.
    """
    x_ref, weights = np.array([0.42, -3.1]), np.ones(2)
    A, b = np.array([[0.28, 1.66]]), np.array([-0.69])
    lower, upper = np.full(2, -2.0), np.full(2, 2.0)
    expected = REFERENCE.solve(x_ref, weights, A, b, lower, upper).x

    default = proxqp.dense.solve(np.diag(weights), -weights * x_ref, None, None, A, b,
                                 np.full(1, math.inf), l_box=lower, u_box=upper)
    assert default.info.status == proxqp.PROXQP_SOLVED
    assert np.abs(default.x - expected).max() > 0.5

    result = ProxsuiteSolver().solve(x_ref, weights, A, b, lower, upper)
    assert result.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(result.x, expected, rtol=0.0, atol=AGREEMENT_TOL)
