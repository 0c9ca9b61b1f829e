"""SafetyFilter behaviour: constraints hold, pruning is exact, fallbacks are flagged, no NaN."""
import numpy as np
import pytest
from hypothesis import assume, given, HealthCheck, settings, strategies as st

from polyc2bf_ros.core.kernels.cones import PLANE_ROWS
from polyc2bf_ros.core.kernels.filter_rows import _assemble_rows, ACTIVE_TOLERANCE
from polyc2bf_ros.core.kernels.qp import row_residuals
from polyc2bf_ros.core.models import make_model, MODEL_NAMES
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.qp.solver import QPSolver, QPStatus
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus, SafetyFilter
from strategies import convex_polygons, examples, JACKAL, random_state

SETTINGS = settings(max_examples=examples(40), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
obstacle_lists = st.lists(convex_polygons(centre_range=6.0), min_size=0, max_size=8)


def _world(polygons, rng):
    """Return obstacles with random velocities and z ranges."""
    return ObstacleSet.from_obstacles([
        Obstacle(polygon=p, velocity=rng.uniform(-0.5, 0.5, 3), z_min=-1.0, z_max=2.0)
        for p in polygons])


def _case(model_name, seed, polygons):
    """Return (model, state, obstacles, u_nom) drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    model = make_model(model_name)
    span = model.input_upper - model.input_lower
    u_nom = model.input_lower + rng.uniform(-0.5, 1.5, model.input_dim) * span
    return model, random_state(model_name, rng), _world(polygons, rng), u_nom


def _constraint_rows(filt, state, obstacles):
    """Return (A, b, usable) of the CBF rows Lg h u >= m - Lf h - gamma h."""
    evaluation = filt.evaluate(state, obstacles)
    terms = evaluation.terms
    b = filt.config.margin - terms.lf_h - filt.config.gamma * terms.h
    return terms.lg_h.T, b, ~evaluation.inside


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@SETTINGS
@given(polygons=obstacle_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_ok_solution_satisfies_every_row_and_bound(model_name, polygons, seed):
    """Status ok: every CBF row and the input box hold; pruning changes nothing."""
    model, state, obstacles, u_nom = _case(model_name, seed, polygons)
    filt = SafetyFilter(model, FilterConfig())
    u, info = filt.step(state, obstacles, u_nom)
    assert np.isfinite(u).all()
    assert np.all(u >= model.input_lower - 1e-9) and np.all(u <= model.input_upper + 1e-9)
    usable_h = info.h[~np.isnan(info.h)]
    assert info.min_h == (usable_h.min() if usable_h.size else np.inf)
    A, b, usable = _constraint_rows(filt, state, obstacles)
    if info.status in (FilterStatus.OK, FilterStatus.RECOVERING):
        assert np.all(A[usable] @ u >= b[usable] - 1e-7)
    elif info.status == FilterStatus.SLACK:
        # The slack relaxes unit-norm rows: A u >= b - s |A_i|.
        relax = info.slack * np.linalg.norm(A[usable], axis=1)
        assert info.slack > 0 and np.all(A[usable] @ u >= b[usable] - relax - 1e-7)
    unpruned = SafetyFilter(model, FilterConfig(prune=False))
    u_full, info_full = unpruned.step(state, obstacles, u_nom)
    assert info_full.status == info.status
    np.testing.assert_allclose(u, u_full, atol=1e-7)


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@SETTINGS
@given(polygons=obstacle_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_backends_agree(model_name, polygons, seed):
    """DAQP and proxsuite (duality-gap check on) give the same safe input.

    proxsuite sometimes stalls where DAQP solves exactly; that must surface as a
    flagged brake with the model's braking input, never as a different answer.
    """
    model, state, obstacles, u_nom = _case(model_name, seed, polygons)
    u_daqp, info_daqp = SafetyFilter(model, FilterConfig(solver='daqp')).step(
        state, obstacles, u_nom)
    u_prox, info_prox = SafetyFilter(model, FilterConfig(solver='proxsuite')).step(
        state, obstacles, u_nom)
    if info_prox.status == FilterStatus.BRAKE and info_daqp.status != FilterStatus.BRAKE:
        np.testing.assert_allclose(u_prox, model.braking_input(state))
        return
    assert info_daqp.status == info_prox.status
    np.testing.assert_allclose(u_daqp, u_prox, atol=1e-5)


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@SETTINGS
@given(polygons=obstacle_lists.filter(len), seed=st.integers(0, 2 ** 32 - 1))
def test_one_pass_answer_is_the_solvers(model_name, polygons, seed):
    """The step's fused pass (rows, QP front end, active parts) answers as the solver would.

    Reference: the same rows (``_assemble_rows``) through ``QPSolver.solve_checked``,
    and the parts whose rows hold with equality at its answer.
    """
    model, state, obstacles, u_nom = _case(model_name, seed, polygons)
    filt = SafetyFilter(model, FilterConfig(braking_check=False))
    u, info = filt.step(state, obstacles, u_nom)
    evaluation = filt.evaluate(state, obstacles)
    assume(not evaluation.inside.any())
    count, dim = len(obstacles), model.input_dim
    lower, upper = (np.ascontiguousarray(bound, dtype=float)
                    for bound in (model.input_lower, model.input_upper))
    rows_a, rows_b, index = np.empty((count, dim)), np.empty(count), np.empty(count, dtype=int)
    rows, _, _ = _assemble_rows(evaluation.block[PLANE_ROWS:], evaluation.usable,
                                filt.config.margin, filt.config.gamma, lower, upper, True,
                                rows_a, rows_b, index, np.empty(count))
    rows_a, rows_b = rows_a[:rows], rows_b[:rows]
    result = filt.solver.solve_checked(u_nom, np.ones(dim), rows_a, rows_b, lower, upper)
    assume(result.status == QPStatus.OPTIMAL)
    assert info.status in (FilterStatus.OK, FilterStatus.RECOVERING)
    np.testing.assert_array_equal(u, result.x)
    residuals = np.empty(rows)
    row_residuals(rows_a, result.x, rows_b, residuals)
    assert sorted(info.active) == sorted(index[:rows][residuals <= ACTIVE_TOLERANCE])


@SETTINGS
@given(polygons=obstacle_lists.filter(len), seed=st.integers(0, 2 ** 32 - 1),
       weight=st.floats(0.01, 4.0))
def test_a_steering_weight_gives_the_weighted_qps_answer(polygons, seed, weight):
    """Unicycle ``steering_weight`` w: the step minimises (a - a_n)^2 + w (alpha - alpha_n)^2.

    Reference: the plain QP in z = sqrt(W) u (rows A W^-1/2, box scaled), mapped back.
    """
    _, state, obstacles, u_nom = _case('unicycle', seed, polygons)
    model = make_model('unicycle', steering_weight=weight)
    filt = SafetyFilter(model, FilterConfig(braking_check=False))
    u, info = filt.step(state, obstacles, u_nom)
    assume(info.status == FilterStatus.OK)
    A, b, usable = _constraint_rows(filt, state, obstacles)
    scale = np.sqrt(np.array([1.0, weight]))
    result = filt.solver.solve_checked(
        scale * u_nom, np.ones(2), np.ascontiguousarray(A[usable] / scale), b[usable],
        scale * model.input_lower, scale * model.input_upper)
    assume(result.status == QPStatus.OPTIMAL)
    np.testing.assert_allclose(u, result.x / scale, atol=1e-6)


def test_steering_weight_must_be_positive():
    """A zero, negative or non-finite weight is refused by name."""
    for bad in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match='steering_weight'):
            make_model('unicycle', steering_weight=bad)


BAD = st.sampled_from([np.nan, np.inf, -np.inf])


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@SETTINGS
@given(polygons=obstacle_lists.filter(len), seed=st.integers(0, 2 ** 32 - 1), bad=BAD,
       where=st.sampled_from(['state', 'u_nom', 'vertex', 'velocity', 'age']))
def test_non_finite_input_brakes_and_never_outputs_nan(model_name, polygons, seed, bad, where):
    """NaN/Inf anywhere gives status invalid_input and a finite braking command."""
    model, state, obstacles, u_nom = _case(model_name, seed, polygons)
    age = 0.0
    if where == 'state':
        state[np.random.default_rng(seed).integers(state.size)] = bad
    elif where == 'u_nom':
        u_nom[0] = bad
    elif where == 'age':
        age = bad
    else:
        field = obstacles.footprints.vertices if where == 'vertex' else obstacles.velocities
        field.reshape(-1)[0] = bad
    u, info = SafetyFilter(model, FilterConfig()).step(state, obstacles, u_nom, age)
    assert info.status == FilterStatus.INVALID_INPUT
    assert np.isfinite(u).all()
    assert np.all(u >= model.input_lower) and np.all(u <= model.input_upper)


WALL = np.array([[1.0, -3.0], [1.2, -3.0], [1.2, 3.0], [1.0, 3.0]])


def _box(x0, y0, x1, y1):
    """Return the axis-aligned rectangle [x0, x1] x [y0, y1]."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def test_infeasible_rows_fall_back_to_shared_slack():
    """At rest, boxed in by four close walls: no input meets every margin; slack is flagged."""
    model = make_model('point_mass_2d')
    filt = SafetyFilter(model, FilterConfig(barrier='polyc2bf_inflated', robot_radius=0.2))
    walls = [_box(0.5, -0.7, 0.7, 0.7), _box(-0.7, -0.7, -0.5, 0.7),
             _box(-0.7, 0.5, 0.7, 0.7), _box(-0.7, -0.7, 0.7, -0.5)]
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=w) for w in walls])
    u, info = filt.step(np.zeros(4), obstacles, np.array([1.0, 0.0]))
    assert info.status == FilterStatus.SLACK
    assert info.slack > 0.0
    np.testing.assert_allclose(u, 0.0, atol=1e-9)  # symmetric room: stay put


class _FailingSolver(QPSolver):
    """A QP backend that always fails, to drive the last fallback (front end shortcut off)."""

    name = 'failing'
    shortcut = False

    def _solve(self, x_ref, weights, A, b, lower, upper):
        """Fail."""
        return x_ref, QPStatus.FAILED, 0


def test_solver_failure_brakes_and_says_so():
    """If the QP and the slack QP both fail, the model's braking input is applied."""
    model = make_model('unicycle')
    filt = SafetyFilter(model, FilterConfig())
    filt.solver = _FailingSolver()
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=WALL + [2.0, 0.0])])
    state = np.array([0.0, 0.0, 0.0, 1.0, 0.5])
    u, info = filt.step(state, obstacles, np.array([1.0, 0.0]))
    assert info.status == FilterStatus.BRAKE
    np.testing.assert_allclose(u, model.braking_input(state))
    assert u[0] < 0 and u[1] < 0


@pytest.mark.parametrize('barrier', ['polyc2bf_paper', 'polyc2bf_inflated', 'c3bf'])
def test_inside_obstacle_escapes_outward(barrier):
    """Reference point inside the inflated obstacle: status escape, pushed out."""
    model = make_model('point_mass_2d')
    filt = SafetyFilter(model, FilterConfig(barrier=barrier, robot_radius=0.3))
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=WALL)])
    u, info = filt.step(np.array([0.9, 0.5, 0.0, 0.0]), obstacles, np.zeros(2))
    assert info.status == FilterStatus.ESCAPE
    assert 'inside' in info.message
    assert np.isnan(info.h).all() and info.min_h == np.inf  # the one part has no cone
    assert u[0] < 0.0  # away from the wall's centroid at x = 1.1


LONG_WALL_3D = Obstacle(polygon=np.array([[3.0, -4.0], [3.2, -4.0], [3.2, 4.0], [3.0, 4.0]]),
                       z_min=0.0, z_max=1.6)


@pytest.mark.parametrize('barrier', ['polyc2bf_paper', 'polyc2bf_inflated', 'c3bf'])
@pytest.mark.parametrize('position, direction', [
    # 1 cm under the top of the inflated wall, mid-wall: straight up (vertical plane).
    ((3.1, 0.5, 1.69), (0.0, 0.0, 1.0)),
    # Beside the wall's end, low down: out past the end (horizontal plane).
    ((3.1, 4.05, 0.8), (0.0, 1.0, 0.0)),
])
def test_3d_escape_takes_the_shallower_plane(barrier, position, direction):
    """Inside a prism, the escape leaves through the plane with the shorter way out.

    C3BF too: its circles (of the shadow rectangle, of the footprint) are crossed there.
    """
    model = make_model('point_mass_3d')
    filt = SafetyFilter(model, FilterConfig(barrier=barrier, robot_radius=0.1))
    obstacles = ObstacleSet.from_obstacles([LONG_WALL_3D])
    state = np.concatenate([position, np.zeros(3)])
    evaluation = filt.evaluate(state, obstacles)
    assert evaluation.inside[0]
    np.testing.assert_allclose(filt.escape_direction(evaluation, obstacles), direction,
                               atol=1e-12)
    u, info = filt.step(state, obstacles, np.zeros(3))
    assert info.status == FilterStatus.ESCAPE
    assert u @ direction > 0.0 and np.linalg.norm(u - (u @ direction) * np.array(direction)) < 1e-9


def test_escape_direction_is_zero_outside():
    """No part is inside: no escape direction."""
    model = make_model('point_mass_3d')
    filt = SafetyFilter(model, FilterConfig())
    obstacles = ObstacleSet.from_obstacles([LONG_WALL_3D])
    evaluation = filt.evaluate(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]), obstacles)
    assert not evaluation.inside.any()
    assert not filt.escape_direction(evaluation, obstacles).any()


def test_far_obstacles_are_pruned_but_h_is_reported():
    """Rows that hold for every input in the box are dropped; h still covers all.

    With gamma = 1 a receding obstacle is rarely prunable: braking hard could make its
    row active.  With gamma = 10 the rows of obstacles 20-30 m behind cannot bind.
    """
    model = make_model('unicycle')
    filt = SafetyFilter(model, FilterConfig(barrier='polyc2bf_inflated', gamma=10.0,
                                            braking_check=False))
    far = [Obstacle(polygon=WALL + [x, 0.0]) for x in (-20.0, -30.0)]
    obstacles = ObstacleSet.from_obstacles(far + [Obstacle(polygon=WALL + [1.5, 0.0])])
    _, info = filt.step(np.array([0.0, 0.0, 0.0, 1.5, 0.0]), obstacles, np.array([1.0, 0.0]))
    assert info.num_obstacles == 3 and np.isfinite(info.h).all()
    assert info.num_constraints == 1
    assert list(info.active) == [2]


def test_config_validation_names_the_field():
    """Bad configuration values are refused with the field name."""
    for field, value in (('gamma', 0.0), ('barrier', 'circles'), ('solver', 'osqp'),
                         ('control_period', -1.0), ('robot_radius', np.nan)):
        with pytest.raises(ValueError, match=field):
            FilterConfig(**{field: value}).validate()


@pytest.mark.parametrize('model_name', MODEL_NAMES)
def test_wrong_shapes_are_refused_with_the_expected_shapes(model_name):
    """A state or nominal input of the wrong length is a clear error, never read past."""
    model = make_model(model_name)
    filt = SafetyFilter(model, FilterConfig())
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=WALL)])
    state, u_nom = np.zeros(model.state_dim), np.zeros(model.input_dim)
    with pytest.raises(ValueError, match=rf'\({model.state_dim},\)'):
        filt.step(state[:-1], obstacles, u_nom)
    with pytest.raises(ValueError, match=rf'\({model.input_dim},\)'):
        filt.step(state, obstacles, np.zeros(model.input_dim + 1))
    with pytest.raises(ValueError, match='state must have shape'):
        model.reference(np.zeros(model.state_dim + 2))


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@pytest.mark.parametrize('barrier', ['polyc2bf_inflated', 'c3bf'])
@SETTINGS
@given(seed=st.integers(0, 2 ** 32 - 1), polygons=obstacle_lists.filter(len))
def test_odd_array_layouts_give_the_same_step(model_name, barrier, seed, polygons):
    """Strided state and input, float32 offsets, Fortran-ordered velocities: same answer.

    The filter's per-step kernels skip their argument check (``jit``, ``unchecked``), so
    the filter itself must turn whatever it is given into C-contiguous float64.
    """
    model, state, obstacles, u_nom = _case(model_name, seed, polygons)
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(-0.5, 0.5, (len(obstacles), 3)).astype(np.float32)
    velocities = np.asfortranarray(rng.uniform(-0.5, 0.5, (len(obstacles), 3)))
    plain = obstacles.translated(offsets.astype(np.float64), np.ascontiguousarray(velocities))
    want_u, want = SafetyFilter(model, FilterConfig(barrier=barrier)).step(
        state, plain, u_nom, 0.1)
    got_u, got = SafetyFilter(model, FilterConfig(barrier=barrier)).step(
        np.repeat(state, 2)[::2], obstacles.translated(offsets, velocities),
        np.repeat(u_nom, 2)[::2], 0.1)
    assert got.status == want.status
    np.testing.assert_array_equal(got_u, want_u)
    np.testing.assert_array_equal(got.h, want.h)


def _jackal_filter(limit):
    """Return a filter guarding the Jackal's box with its controller's limits (jackal.yaml)."""
    model = make_model('unicycle', offset_l=0.01, max_accel=20.0, max_angular_accel=25.0)
    return SafetyFilter(model, FilterConfig(
        barrier='polyc2bf_footprint', footprint=JACKAL, gamma=5.0, max_reverse_speed=limit))


def _post(x, y, radius=0.075):
    """Return a BARN post as an octagon about (x, y)."""
    angles = np.arange(8) * np.pi / 4
    return Obstacle(polygon=np.c_[x + radius * np.cos(angles), y + radius * np.sin(angles)])


def test_the_filter_backs_a_box_no_faster_than_max_reverse_speed():
    """Backing at 0.67 m/s beside a post, asked to drive on and turn hard.

    Unlimited, the filter backs faster to swing the nose clear (0.87 m/s); limited to
    0.5 m/s, it sheds the excess at once, though the nominal asks for no reverse at all.
    """
    state = np.array([0.0, 0.0, 0.0, -0.673, -0.01])
    command = np.array([0.963, -3.925])
    obstacles = ObstacleSet.from_obstacles([_post(-0.316, 0.372)])
    u_nom = (command - state[3:]) / FilterConfig.control_period
    speeds = {}
    for limit in (0.0, 0.5):
        filt = _jackal_filter(limit)
        u, _ = filt.step(state, obstacles, u_nom)
        speeds[limit] = state[3] + FilterConfig.control_period * u[0]
    assert speeds[0.0] < -0.8
    assert speeds[0.5] >= -0.5 - 1e-9


@SETTINGS
@given(speed=st.floats(-1.5, 2.0), turn=st.floats(-3.0, 3.0), asked=st.floats(-1.0, 2.0),
       asked_turn=st.floats(-4.0, 4.0),
       posts=st.lists(st.tuples(st.floats(-0.7, 0.7), st.floats(-0.7, 0.7)), min_size=1,
                      max_size=4))
def test_every_step_keeps_the_reverse_limit_or_the_nominals_own(speed, turn, asked,
                                                               asked_turn, posts):
    """Every step: v + a T >= min(-v_r, v + a_nom T), or brakes hardest if backing faster."""
    filt = _jackal_filter(0.5)
    period = FilterConfig.control_period
    state = np.array([0.0, 0.0, 0.0, speed, turn])
    u_nom = (np.array([asked, asked_turn]) - state[3:]) / period
    u, info = filt.step(state, ObstacleSet.from_obstacles([_post(*p) for p in posts]), u_nom)
    floor = min(-0.5, speed + period * float(np.clip(u_nom[0], -20.0, 20.0)))
    assert speed + period * u[0] >= min(floor, speed + period * 20.0) - 1e-7, info.status
