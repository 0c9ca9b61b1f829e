"""A footprint that turns with the unicycle is guarded as itself (``barrier.footprint_cone``)."""
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from oracles import configuration_polygon, footprint_barrier, planar_rotation
from polyc2bf_ros.core.barrier.footprint_cone import FootprintCone
from polyc2bf_ros.core.geometry.footprint import format_footprint
from polyc2bf_ros.core.geometry.polygons import convex_hull, PolygonBatch, signed_distance
from polyc2bf_ros.core.kernels.braking import path_clearance
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus, SafetyFilter
from sim_bridge.rollout import rk4_step
from strategies import convex_polygons, examples

JACKAL = np.array([[0.254, 0.215], [-0.254, 0.215], [-0.254, -0.215], [0.254, -0.215]])
"""The Clearpath Jackal's 0.508 x 0.430 m body about its centre, CCW."""


def _filter(footprint=JACKAL, **config):
    """Return the unicycle's filter guarding ``footprint`` (Jackal-like limits and gamma).

    None: the default barrier guarding the 0.333 m disc that covers the Jackal.
    """
    model = make_model('unicycle', offset_l=0.01, max_accel=2.0, max_angular_accel=4.0)
    settings_ = {'gamma': 5.0, 'robot_radius': 0.333, **config}
    if footprint is not None:
        settings_.update(barrier=FootprintCone.name, footprint=format_footprint(footprint))
    return SafetyFilter(model, FilterConfig(**settings_))


def _separation(first, second):
    """Return the separating-axis gap of two convex polygons (> 0 apart, < 0 overlapping)."""
    best = -np.inf
    for p, q in ((first, second), (second, first)):
        turn = (p[1] - p[0])[0] * (p[2] - p[1])[1] - (p[1] - p[0])[1] * (p[2] - p[1])[0]
        p = p if turn > 0.0 else p[::-1]
        for k in range(len(p)):
            edge = p[(k + 1) % len(p)] - p[k]
            normal = np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)
            best = max(best, float((q @ normal).min() - (p @ normal).max()))
    return best


def _body(state, footprint=JACKAL):
    """Return the footprint placed at the state's pose."""
    return state[:2] + footprint @ planar_rotation(state[2]).T


def _scene(polygons, velocities=None):
    """Return an obstacle set of convex polygons, moving at ``velocities`` (or standing)."""
    velocities = velocities or [np.zeros(2)] * len(polygons)
    return ObstacleSet.from_obstacles([Obstacle(polygon=p, velocity=np.array([*v, 0.0]))
                                       for p, v in zip(polygons, velocities)])


GUARDED = _filter()


@settings(max_examples=examples(200), deadline=None)
@given(obstacle=convex_polygons(centre_range=1.0),
       footprint=convex_polygons(centre_range=0.1, min_size=0.2, max_size=0.8),
       pose=st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1)))
def test_a_part_has_a_cone_exactly_when_the_turned_footprint_keeps_off_it(obstacle, footprint,
                                                                          pose):
    """No overlap wherever the part has a cone (h defined), and a cone wherever apart.

    So h >= 0 on every part, which needs a cone on every part, means no overlap.
    """
    guarded = _filter(footprint)
    state = np.array([*pose, 0.0, 0.0])
    gap = _separation(_body(state, footprint), obstacle)
    assume(abs(gap) > 1e-9)  # touching: either answer is right
    evaluation = guarded.evaluate(state, _scene([obstacle]))
    assert bool(evaluation.usable[0]) == (gap > 0.0)


@settings(max_examples=examples(150), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_the_kernel_computes_the_numpy_formulas(seed):
    """h, Lf h, Lg h of three parts, one moving, against ``oracles.footprint_barrier``."""
    rng = np.random.default_rng(seed)
    polygons = [rng.uniform(-2.0, 2.0, 2) + rng.uniform(0.1, 0.5) * np.column_stack(
        (np.cos(angles), np.sin(angles))) for angles in np.sort(
            rng.uniform(0.0, 2.0 * np.pi, (3, 6)), axis=1)]
    polygons = [convex_hull(p) for p in polygons]
    velocities = [rng.uniform(-1.0, 1.0, 2), np.zeros(2), np.zeros(2)]
    state = np.array([*rng.uniform(-3.0, 3.0, 2), rng.uniform(-3.1, 3.1),
                      rng.uniform(-1.5, 1.5), rng.uniform(-2.0, 2.0)])
    evaluation = GUARDED.evaluate(state, _scene(polygons, velocities))
    terms = evaluation.terms
    for n, (polygon, velocity) in enumerate(zip(polygons, velocities)):
        expected = footprint_barrier(state, polygon, velocity, JACKAL)
        assert evaluation.usable[n] == (expected is not None)
        if expected is not None:
            h, lf, lg = expected
            scale = max(1.0, abs(h), abs(lf))
            assert terms.h[n] == pytest.approx(h, abs=1e-10 * scale)
            assert terms.lf_h[n] == pytest.approx(lf, abs=1e-10 * scale)
            assert terms.lg_h[:, n] == pytest.approx(lg, abs=1e-10 * scale)


@settings(max_examples=examples(150), deadline=None)
@given(obstacle=convex_polygons(centre_range=1.0), seed=st.integers(0, 2 ** 32 - 1),
       spread=st.sampled_from([0.6, 3.0]))
def test_lf_h_plus_lg_h_u_is_the_derivative_along_the_unicycle(obstacle, seed, spread):
    """h_dot by central differences along x_dot = f + g u, the part moving at its velocity.

    Heading, speed and turn rate all random: the rows account for the body's turning.
    ``spread`` 0.6 m keeps many parts within the covering radius, where the turning share
    of v fades (sigma, sigma_dot).
    """
    rng = np.random.default_rng(seed)
    state = np.array([*rng.uniform(-spread, spread, 2), rng.uniform(-3.1, 3.1),
                      rng.uniform(-1.5, 1.5), rng.uniform(-2.0, 2.0)])
    u, velocity = rng.uniform(-2.0, 2.0, 2), rng.uniform(-1.0, 1.0, 2)
    model, dt = GUARDED.model, 1e-6

    def terms(x, shift):
        evaluation = GUARDED.evaluate(x, _scene([obstacle + shift * velocity], [velocity]))
        return evaluation.terms if evaluation.usable[0] else None

    now, ahead = terms(state, 0.0), terms(rk4_step(model, state, u, dt), dt)
    behind = terms(rk4_step(model, state, u, -dt), -dt)
    assume(now is not None and ahead is not None and behind is not None)
    h = now.h[0]
    # A silhouette or nearest-feature switch within +-dt breaks the difference, rarely.
    assume(abs(ahead.h[0] - 2.0 * h + behind.h[0]) <= 1e-9)
    numeric = (ahead.h[0] - behind.h[0]) / (2.0 * dt)
    assert numeric == pytest.approx(now.lf_h[0] + now.lg_h[:, 0] @ u,
                                    abs=1e-5 * max(1.0, abs(numeric)))


def _gap_run(guarded, speed, half_gap=0.225, seconds=8.0):
    """Drive at ``speed`` through a gap between two walls; return (state, closest, statuses).

    The nominal holds the speed and steers to the centre line from 3 cm off it, 0.05 rad
    askew; the filter's input is held for 10 ms (midpoint rule, as the node holds it).
    """
    walls = [np.array([[2.0, half_gap], [3.0, half_gap], [3.0, 1.5], [2.0, 1.5]]),
             np.array([[2.0, -1.5], [3.0, -1.5], [3.0, -half_gap], [2.0, -half_gap]])]
    scene, state, period = _scene(walls), np.array([0.0, 0.03, 0.05, 0.0, 0.0]), 0.01
    closest, statuses = np.inf, set()
    for _ in range(int(seconds / period)):
        u_nom = np.array([(speed - state[3]) / 0.3,
                          (-2.0 * state[1] - 2.0 * state[2] - state[4]) / 0.3])
        u, info = guarded.step(state, scene, u_nom)
        statuses.add(info.status)
        state = guarded.model.one_period(state, u, period)
        closest = min(closest, *(_separation(_body(state), wall) for wall in walls))
    return state, closest, statuses


@pytest.mark.parametrize('speed', [0.5, 1.0, 2.0])
def test_a_box_passes_a_gap_two_centimetres_wider_than_itself(speed):
    """The Jackal's 0.430 m wide box through a 0.450 m gap, never touching either wall."""
    state, closest, statuses = _gap_run(GUARDED, speed)
    assert state[0] > 3.5, state
    assert closest > 0.0
    assert FilterStatus.BRAKE not in statuses and FilterStatus.ESCAPE not in statuses


def test_the_covering_disc_cannot_enter_that_gap():
    """The same run guarding the 0.333 m disc that covers the box stops before the walls."""
    state, closest, _ = _gap_run(_filter(None), 1.0)
    assert state[0] < 2.0 and closest > 0.0  # its centre never reaches the walls' face


def _octagon(centre, radius):
    """Return a regular octagon around a circle of ``radius``."""
    angles = np.arange(8) * np.pi / 4.0
    return np.asarray(centre) + radius / np.cos(np.pi / 8.0) * np.column_stack(
        (np.cos(angles), np.sin(angles)))


@pytest.mark.parametrize('filtered', [False, True])
def test_turning_in_place_beside_a_post_stops_before_a_corner_sweeps_into_it(filtered):
    """A post 7 cm off the box's side, inside the circle its corners sweep.

    Turning in place at 2 rad/s swings the front corner into it unfiltered; filtered, the
    turn is held off before contact.
    """
    post = _octagon((0.0, 0.36), 0.075)
    scene, state, closest = _scene([post]), np.zeros(5), np.inf
    for _ in range(300):
        u_nom = np.array([-state[3] / 0.3, (2.0 - state[4]) / 0.3])
        u = GUARDED.step(state, scene, u_nom)[0] if filtered else GUARDED.model.clip_input(
            u_nom)
        state = GUARDED.model.one_period(state, u, 0.01)
        closest = min(closest, _separation(_body(state), post))
    assert (closest > 0.0) == filtered


def test_a_box_nose_in_between_two_posts_backs_out_when_asked_to_back_and_turn():
    """Posts 1 mm off both sides of the box's front half, inside the braking margin.

    The nominal asks to back out while turning.  Any turn swings a side into a post, so the
    braking check refuses the QP's input, and braking while keeping or reversing the turn
    too: the box stood there for good.  The backup keeps the input's drive and brakes the
    steering instead, and backing straight, which leaves the clearance as it is up to
    rounding, is kept: the box backs out of the slot, touching neither post.
    """
    flat = _octagon((0.0, 0.0), 0.075) @ planar_rotation(np.pi / 8.0).T  # a side faces the box
    posts = [flat + [0.1, side * (0.215 + 0.001 + 0.075)] for side in (1.0, -1.0)]
    scene, state, closest, messages = _scene(posts), np.zeros(5), np.inf, set()
    for _ in range(100):
        u, info = GUARDED.step(state, scene, np.array([-1.0, 3.0]))
        messages.add(info.message)
        state = rk4_step(GUARDED.model, state, u, GUARDED.config.control_period)
        closest = min(closest, *(_separation(_body(state), post) for post in posts))
    assert 'braking check: keeping the drive, braking the steering' in messages
    assert closest > 0.0
    assert state[0] < -0.3  # out of the slot: the front face behind the posts


@settings(max_examples=examples(150), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=1.5), min_size=1, max_size=3),
       seed=st.integers(0, 2 ** 32 - 1))
def test_min_h_along_a_path_is_the_smallest_h_the_filter_evaluates(polygons, seed):
    """The braking check's footprint kernel against ``evaluate`` row by row.

    Random axle paths (heading, speed and turn rate wandering) starting near a standing or
    moving part: where some h along the path is negative the kernel finds that minimum,
    and its pruning skips only rows where h >= 0.
    """
    rng = np.random.default_rng(seed)
    velocities = rng.uniform(-1.0, 1.0, (len(polygons), 3)) * rng.integers(0, 2)
    velocities[:, 2] = 0.0
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=p, velocity=v)
                                            for p, v in zip(polygons, velocities)])
    period, age = 0.01, float(rng.uniform(0.0, 0.1))
    start = np.r_[polygons[0].mean(axis=0) + rng.uniform(-0.8, 0.8, 2),
                  rng.uniform(-np.pi, np.pi), rng.uniform(-2.0, 2.0), rng.uniform(-4.0, 4.0)]
    states = start + np.cumsum(
        np.r_[[np.zeros(5)], rng.uniform(-0.05, 0.05, (int(rng.integers(1, 40)), 5))], axis=0)
    rows = np.column_stack((states[:, :2], states[:, 3] * np.cos(states[:, 2]),
                            states[:, 3] * np.sin(states[:, 2]), states[:, 2], states[:, 4]))
    model = GUARDED.cone_model
    kernel = model.min_h_along(model.prepare(PolygonBatch.from_polygons(polygons)),
                               np.ascontiguousarray(velocities[:, :2]),
                               np.zeros((len(polygons), 2)), age, rows[0],
                               np.ascontiguousarray(rows[1:]), period,
                               GUARDED.config.velocity_epsilon)
    expected = np.inf
    for k, state in enumerate(states):
        evaluation = GUARDED.evaluate(state, obstacles, age + k * period)
        if evaluation.valid.any():
            expected = min(expected, float(evaluation.terms.h[evaluation.valid].min()))
    assert kernel >= expected - 1e-9
    if expected < 0.0:
        assert kernel == pytest.approx(expected, rel=1e-9, abs=1e-9)


@settings(max_examples=examples(150), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=2.0), min_size=1, max_size=4),
       seed=st.integers(0, 2 ** 32 - 1))
def test_min_h_along_skips_a_group_of_rows_only_where_each_row_is_skipped(polygons, seed):
    """The kernel's groups of rows against its rows taken one at a time, bit for bit.

    Long braking paths (hundreds of rows, groups of about twenty) past standing and
    moving parts: a group is skipped only where each of its rows would be, so the value
    is the smallest over the rows, each the kernel's own from that row alone.
    """
    rng = np.random.default_rng(seed)
    velocities = rng.uniform(-1.0, 1.0, (len(polygons), 2)) * rng.integers(0, 2)
    period, age = 0.01, float(rng.uniform(0.0, 0.1))
    count = int(rng.integers(100, 600))
    speed = np.linspace(rng.uniform(-2.0, 2.0), 0.0, count)
    turn = rng.uniform(-2.0, 2.0) * np.linspace(1.0, 0.0, count)
    heading = rng.uniform(-np.pi, np.pi) + np.cumsum(turn) * period
    steps = np.column_stack((np.cos(heading), np.sin(heading))) * speed[:, None] * period
    points = rng.uniform(-2.5, 2.5, 2) + np.cumsum(steps, axis=0)
    rows = np.ascontiguousarray(np.column_stack((points, steps / period, heading, turn)))
    model = GUARDED.cone_model
    prepared = model.prepare(PolygonBatch.from_polygons(polygons))
    offsets = np.zeros((len(polygons), 2))

    def kernel(start, path, at):
        return model.min_h_along(prepared, np.ascontiguousarray(velocities), offsets, at,
                                 start, path, period, GUARDED.config.velocity_epsilon)

    row_by_row = min(kernel(rows[k], np.zeros((0, 6)), age + k * period)
                     for k in range(count))
    assert kernel(rows[0], rows[1:], age) == row_by_row


def test_a_box_overlapping_a_part_escapes_along_its_heading_without_turning():
    """A part appears over the box's rear-left corner (a scan obstacle newly drawn there).

    The way out is C(theta)'s, the body's shortest move off the part; the escape drives
    along the heading and brakes the turn rather than swing the other corners (near the
    axle, steering the reference point out asks for a turn of 1 / offset_l).
    """
    overlap = np.array([[-0.30, 0.20], [-0.20, 0.20], [-0.20, 0.30], [-0.30, 0.30]])
    for turn in (0.0, 0.5):
        state = np.array([0.0, 0.0, 0.0, 0.1, turn])
        u, info = GUARDED.step(state, _scene([overlap]), np.array([0.0, 0.0]))
        assert info.status.value == 'escape'
        assert u[1] == pytest.approx(GUARDED.model.braking_input(state)[1])
        # The shortest way out of the overlap moves the body 1.5 cm to the right.
        direction = GUARDED.escape_direction(info.evaluation, _scene([overlap]))
        np.testing.assert_allclose(direction, [0.0, -1.0], atol=1e-9)


def _box_path_clearance(path, scene, period):
    """Return ``path_clearance`` (static, moving; cutoff 10 m) of the Jackal box along ``path``.

    Rows [x, y, vx, vy, theta] of its axle; ``scene``'s parts standing.
    """
    cone = FootprintCone(JACKAL)
    polygons = cone.prepare(scene.footprints)
    count = len(scene)
    return path_clearance(
        polygons.x, polygons.y, polygons.edge_x, polygons.edge_y, polygons.inv_sq,
        polygons.counts, polygons.boxes, np.zeros((count, 2)), np.zeros((count, 2)),
        np.zeros((count, 2)), 0.0, path, period, 10.0, 0.0, np.zeros(count), True, cone.points,
        float(np.hypot(0.254, 0.215)), np.empty(0))


@settings(max_examples=examples(100), deadline=None)
@given(obstacle=convex_polygons(centre_range=1.5), seed=st.integers(0, 2 ** 32 - 1))
def test_the_braking_clearance_is_the_bodies_signed_distance_along_the_path(obstacle, seed):
    """``path_clearance`` of a footprint, row by row: the axle's signed distance to C(theta_k).

    That is the bodies' distance where they are apart (at least the separating-axis gap),
    and negative where they overlap.
    """
    rng = np.random.default_rng(seed)
    rows = int(rng.integers(1, 12))
    path = np.column_stack((rng.uniform(-2.0, 2.0, (rows, 2)), rng.uniform(-1.0, 1.0, (rows, 2)),
                            rng.uniform(-3.1, 3.1, rows)))
    expected = min(signed_distance(row[:2], configuration_polygon(obstacle, JACKAL,
                                                                  row[4])[0])
                   for row in path)
    static, moving = _box_path_clearance(np.ascontiguousarray(path), _scene([obstacle]), 0.01)
    assert moving == 10.0
    assert static == pytest.approx(min(expected, 10.0), abs=1e-12)
    gaps = [_separation(_body(np.array([*row[:2], row[4]])), obstacle) for row in path]
    if min(gaps) > 1e-9:
        assert static >= min(gaps) - 1e-9
    elif min(gaps) < -1e-9:
        assert static < 0.0


def test_the_footprint_barrier_needs_a_footprint_and_a_heading():
    """Each misuse gets one clear error; the default barrier guards the covering disc."""
    with pytest.raises(ValueError, match='set footprint'):
        FilterConfig(barrier=FootprintCone.name).validate()
    config = FilterConfig(barrier=FootprintCone.name, footprint=format_footprint(JACKAL))
    with pytest.raises(ValueError, match='no heading'):
        SafetyFilter(make_model('point_mass_2d'), config)
    covered = SafetyFilter(make_model('unicycle'),
                           FilterConfig(footprint=format_footprint(JACKAL)))
    assert not isinstance(covered.cone_model, FootprintCone)
    assert covered.guard_radius == pytest.approx(np.hypot(0.254, 0.215) + 0.2)


def _stop_clearance(state, scene):
    """Return c(B(x)): the box's signed distance to ``scene``'s parts along its braking path."""
    return _box_path_clearance(GUARDED.braking_path(state), scene,
                               GUARDED.config.control_period)[0]


def test_a_part_drawn_over_a_creeping_boxs_stop_is_not_driven_into_deeper():
    """A scan draws a post's polygon a few millimetres nearer: braking now stops inside it.

    The box creeps at 0.15 m/s towards the polygon, 3 mm off its nose, and stopping takes
    about 6 mm: c(B(x)) < 0, though the bodies do not touch (the post itself may lie a
    centimetre behind its scan polygon).  Every input the filter returns then keeps the way
    to stop at least as clear as braking now, so the box goes no deeper, whatever the
    nominal asks; without that it slid a centimetre further in (BARN from the laser, a
    1 mm graze).
    """
    state = np.array([0.0, 0.0, 0.5 * np.pi, 0.15, 0.05])
    post = _scene([np.array([[-0.30, 0.257], [0.10, 0.257], [0.10, 0.40], [-0.30, 0.40]])])
    first = _stop_clearance(state, post)
    assert -0.01 < first < 0.0 < _separation(_body(state), post.footprints.vertices[0])
    deepest = first
    for k in range(60):
        u, _ = GUARDED.step(state, post, np.array([2.0, 4.0 * np.cos(k / 5.0)]))
        state = rk4_step(GUARDED.model, state, u, GUARDED.config.control_period)
        deepest = min(deepest, _stop_clearance(state, post))
    assert deepest >= first - 1e-9


def test_a_box_whose_way_out_runs_across_its_heading_drives_as_the_nominal_asks():
    """A part drawn over the middle of the standing box's left side: the way out is to the right.

    Driving along the heading does not lead out, so an escape by the drive would leave the
    box standing inside for good; the drive follows the nominal instead (here forward,
    along the part), the steering still brakes, and the stop is no deeper than before.
    """
    side = np.array([[-0.10, 0.20], [0.10, 0.20], [0.10, 0.30], [-0.10, 0.30]])
    state = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    u, info = GUARDED.step(state, _scene([side]), np.array([1.0, 2.0]))
    assert info.status.value == 'escape'
    direction = GUARDED.escape_direction(info.evaluation, _scene([side]))
    np.testing.assert_allclose(direction, [0.0, -1.0], atol=1e-9)
    assert u[0] == pytest.approx(1.0) and u[1] == pytest.approx(0.0, abs=1e-12)
    after = rk4_step(GUARDED.model, state, u, GUARDED.config.control_period)
    assert _stop_clearance(after, _scene([side])) >= _stop_clearance(state, _scene([side]))
