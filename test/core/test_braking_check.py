"""The braking check: braking paths, the path clearance kernel, and the filter's backup."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from oracles import path_clearance_by_rows
from polyc2bf_ros.core.barrier.cones import InflatedCone, PlanarPolygons
from polyc2bf_ros.core.geometry.polygons import convex_hull, PolygonBatch, signed_distance
from polyc2bf_ros.core.kernels.braking import (
    bands_within,
    clear_around,
    grow_bands,
    path_clearance,
    stop_clear,
)
from polyc2bf_ros.core.kernels.unicycle import _braking_after
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.models.base import RobotModel
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import (
    _BrakingNow,
    FilterConfig,
    FilterStatus,
    SafetyFilter,
)
from strategies import convex_polygons, examples, JACKAL, long_path

PERIOD = 0.01
POINT_BODY = (np.zeros((2, 0)), 0.0, np.empty(0))
"""``path_clearance``'s footprint and cover for a guarded point (no footprint), and no
``per_part`` values."""
PER_PART_ARGUMENTS = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 15}
"""``path_clearance``'s arguments with a row per part (polygons, velocities, ..., errors)."""


@pytest.mark.parametrize('speed', [0.0, 0.3, 1.0, 2.0])
def test_unicycle_braking_path_stops_straight_at_the_braking_distance(speed):
    """Straight ahead at v: the path runs along the heading and ends at rest after ~v^2/2a."""
    model = make_model('unicycle', offset_l=0.2, max_accel=2.0)
    path = model.braking_path(np.array([1.0, 2.0, np.pi / 2, speed, 0.0]), PERIOD)
    assert path.shape[1] == 4 and len(path) >= 1
    assert np.allclose(path[:, 0], 1.0)
    travelled = path[-1, 1] - 2.2
    # Euler steps of the held brake, then the damped tail: within two periods of travel.
    assert abs(travelled - speed ** 2 / 4.0) <= 2 * PERIOD * speed + 1e-9
    assert np.all(np.diff(path[:, 1]) >= 0)


def test_unicycle_braking_path_starts_one_period_ahead_and_curves_with_omega():
    """Row 0 is the point after one period of the brake; a turning robot brakes on an arc."""
    model = make_model('unicycle', offset_l=0.0, max_accel=2.0)
    state = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
    path = model.braking_path(state, PERIOD)
    assert np.allclose(path[0, :2], [PERIOD * (1.0 - 0.5 * PERIOD * 2.0), 0.0], atol=1e-4)
    assert path[-1, 1] > 0.01  # turned left while stopping


def test_point_mass_braking_path_ends_at_rest():
    """The double integrator stops per axis at its limit; 3-D rows are [p, v], six numbers."""
    path = make_model('point_mass_2d', max_accel=3.0).braking_path(
        np.array([0.0, 0.0, 1.5, -0.6]), PERIOD)
    assert np.isclose(path[-1, 0], 1.5 ** 2 / 6.0, atol=2 * PERIOD * 1.5)
    assert path[-1, 1] < 0
    assert np.allclose(path[-1, 2:], 0.0, atol=1e-4)
    assert make_model('point_mass_3d').braking_path(np.zeros(6), PERIOD).shape == (1, 6)


def _clearance_by_brute_force(polygons, velocities, accelerations, errors, path, age, cutoff):
    """Return (static, moving) distances along the path; moving ones where it closes.

    A part at velocity v and acceleration a has moved by v t + a t^2 / 2 at time t; one
    with a velocity error e counts as moving, e t nearer.
    """
    distances, moving = [cutoff], [cutoff]
    for polygon, velocity, acceleration, error in zip(polygons, velocities, accelerations,
                                                      errors):
        for k, row in enumerate(path):
            t = age + (k + 1) * PERIOD
            moved = polygon + t * velocity + 0.5 * t * t * acceleration
            distance = signed_distance(row[:2], moved)
            if not velocity.any() and not acceleration.any() and error == 0.0:
                distances.append(distance)
            elif distance <= 0.0 or row[2:4] @ (_nearest_point(row[:2], moved) - row[:2]) > 0:
                moving.append(distance - error * t)
    return min(distances), min(moving)


def _nearest_point(point, polygon):
    """Return the point of the polygon's boundary nearest ``point``."""
    best, best_distance = None, np.inf
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
        t = np.clip((point - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        candidate = a + t * (b - a)
        if np.linalg.norm(point - candidate) < best_distance:
            best, best_distance = candidate, np.linalg.norm(point - candidate)
    return best


def _straight_path(rng, steps, speed):
    """Return rows [x, y, vx, vy] of a straight path at constant ``speed``, 0.05 m apart."""
    start, heading = rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)
    direction = np.array([np.cos(heading), np.sin(heading)])
    positions = start + np.outer(np.arange(1, steps + 1) * 0.05, direction)
    return np.column_stack([positions, np.tile(speed * direction, (steps, 1))])


@settings(max_examples=examples(150), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=3.0), min_size=1, max_size=4),
       seed=st.integers(0, 2 ** 32 - 1), cutoff=st.floats(0.0, 0.5))
def test_path_clearance_matches_brute_force(polygons, seed, cutoff):
    """The kernel (bounding-box pruning included) agrees with point-polygon distances."""
    rng = np.random.default_rng(seed)
    path = _straight_path(rng, rng.integers(1, 60), rng.choice([-1.0, 0.0, 1.0]))
    velocities = rng.uniform(-0.5, 0.5, (len(polygons), 2)) * rng.integers(0, 2)
    accelerations = rng.uniform(-3.0, 3.0, (len(polygons), 2)) * rng.integers(0, 2)
    errors = rng.choice([0.0, 0.0, 1.5], len(polygons))  # 1.5: a velocity not known
    age = float(rng.uniform(0.0, 0.2))
    prepared = PlanarPolygons.from_batch(PolygonBatch.from_polygons(polygons))
    answer = path_clearance(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                            prepared.inv_sq, prepared.counts, prepared.boxes, velocities,
                            np.zeros_like(velocities), accelerations, age, path, PERIOD, cutoff,
                            0.0, errors, True, *POINT_BODY)
    expected = _clearance_by_brute_force(polygons, velocities, accelerations, errors, path, age,
                                         cutoff)
    assert answer == pytest.approx(expected, abs=1e-9)
    moves = velocities.any(axis=1) | accelerations.any(axis=1) | (errors > 0.0)
    assert not moves.all() or answer[0] == cutoff


@settings(max_examples=examples(150), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=1.5), min_size=1, max_size=4),
       seed=st.integers(0, 2 ** 32 - 1), cutoff=st.sampled_from([0.0, 0.1, 0.5, 2.0]),
       closing_only=st.booleans())
def test_path_clearance_is_its_row_by_row_form_bit_for_bit(polygons, seed, cutoff,
                                                           closing_only):
    """Skipping groups of rows far from a part changes no bit of the answer.

    Against every row measured (``oracles.path_clearance_by_rows``): long braking paths
    and random walks, static and moving parts, offsets, ages, a part's velocity error,
    its stated acceleration and the bound on how a moving part may speed up.
    """
    rng = np.random.default_rng(seed)
    path = long_path(rng, polygons[0][0])
    count = len(polygons)
    velocities = rng.uniform(-1.0, 1.0, (count, 2)) * (rng.random((count, 1)) < 0.5)
    offsets = rng.uniform(-0.5, 0.5, (count, 2)) * rng.integers(0, 2)
    accelerations = rng.uniform(-3.0, 3.0, (count, 2)) * (rng.random((count, 1)) < 0.5)
    age = float(rng.choice([0.0, rng.uniform(-0.05, 0.3)]))
    period = float(rng.choice([0.001, 0.01, 0.05]))
    accel = float(rng.choice([0.0, 1.0]))
    error = rng.choice([0.0, 0.2, 1.5], count)  # 1.5: a velocity not known
    prepared = PlanarPolygons.from_batch(PolygonBatch.from_polygons(polygons))
    arguments = (prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
                 prepared.counts, prepared.boxes, velocities, offsets, accelerations, age,
                 path, period, cutoff, accel, error, closing_only, *POINT_BODY[:2])
    answer = path_clearance(*arguments, np.empty(0))
    assert answer == path_clearance_by_rows(*arguments, np.empty(0))
    # Each moving part's own value, pruned against itself: the same bits part by part.
    parts, by_rows = np.empty(count), np.empty(count)
    assert path_clearance(*arguments, parts) == answer
    path_clearance_by_rows(*arguments, by_rows)
    assert parts.tolist() == by_rows.tolist()
    assert parts.min(initial=cutoff) == answer[1]
    for n in np.flatnonzero(parts < cutoff):  # a moving part's value is its own
        alone = [a[n:n + 1] if i in PER_PART_ARGUMENTS else a for i, a in enumerate(arguments)]
        assert path_clearance(*alone, np.empty(0))[1] == parts[n]


@settings(max_examples=examples(100), deadline=None)
@given(polygons=st.lists(convex_polygons(), min_size=0, max_size=5),
       radius=st.sampled_from([0.0, 0.3]))
def test_planar_polygons_hold_each_polygons_bounding_box(polygons, radius):
    """``boxes`` are the extremes of each polygon's own vertices, padded rows or not."""
    prepared = InflatedCone(radius).prepare(PolygonBatch.from_polygons(polygons))
    assert prepared.boxes.shape == (len(polygons), 4) and prepared.boxes.flags.c_contiguous
    for n, count in enumerate(prepared.counts):
        x, y = prepared.x[n, :count], prepared.y[n, :count]
        assert prepared.boxes[n].tolist() == [x.min(), x.max(), y.min(), y.max()]


def test_a_part_coming_at_a_robot_that_backs_away_does_not_count():
    """A box coming at 1.4 m/s: a path that backs away is not refused, one that closes is."""
    box = np.array([[0.6, -0.5], [1.6, -0.5], [1.6, 0.5], [0.6, 0.5]])
    prepared = PlanarPolygons.from_batch(PolygonBatch.from_polygons([box]))
    backing = np.array([[-0.01 * (k + 1), 0.0, -0.5, 0.0] for k in range(50)])
    closing = backing * [-1.0, 1.0, -1.0, 1.0]
    args = (prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
            prepared.counts, prepared.boxes, np.array([[-1.4, 0.0]]), np.zeros((1, 2)),
            np.zeros((1, 2)), 0.0)
    bounds, exact = np.array([0.5]), np.zeros(1)
    assert path_clearance(*args, backing, PERIOD, 0.5, 2.0, bounds, True, *POINT_BODY) == (
        0.5, 0.5)
    assert path_clearance(*args, closing, PERIOD, 0.5, 0.0, exact, True, *POINT_BODY)[1] < 0.0
    # An evasion's look ahead counts every row: the box gains on the slower robot.
    assert path_clearance(*args, backing, PERIOD, 0.5, 0.0, exact, False, *POINT_BODY)[1] < 0.5
    near = PlanarPolygons.from_batch(PolygonBatch.from_polygons([box - [0.3, 0.0]]))
    static = (near.x, near.y, near.edge_x, near.edge_y, near.inv_sq, near.counts, near.boxes,
              np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), 0.0)
    assert path_clearance(*static, backing, PERIOD, 0.5, 2.0, exact, True,
                          *POINT_BODY) == pytest.approx(
        (0.31, 0.5))
    # The same box standing, its velocity not known: it counts as moving where the path
    # closes on it, and not at all while the robot backs away.
    assert path_clearance(*static, backing, PERIOD, 0.5, 2.0, bounds, True,
                          *POINT_BODY) == (0.5, 0.5)
    unknown = path_clearance(*static, closing, PERIOD, 0.5, 0.0, bounds, True, *POINT_BODY)
    assert unknown[0] == 0.5 and unknown[1] < 0.0


def test_a_moving_part_may_stray_from_its_velocity_by_the_bounds():
    """A box crossing ahead at 1 m/s: the closing path loses e t + a t^2 / 2 of clearance."""
    box = np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]])
    prepared = PlanarPolygons.from_batch(PolygonBatch.from_polygons([box]))
    path = np.array([[0.1, 0.0, 1.0, 0.2]])
    args = (prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
            prepared.counts, prepared.boxes, np.array([[1.0, 0.0]]), np.zeros((1, 2)),
            np.zeros((1, 2)), 0.0, path, 0.5, 5.0)
    _, plain = path_clearance(*args, 0.0, np.zeros(1), True, *POINT_BODY)
    _, robust = path_clearance(*args, 2.0, np.array([0.2]), True, *POINT_BODY)
    assert robust == pytest.approx(plain - 0.5 * (0.2 + 0.5 * 2.0 * 0.5))


@settings(max_examples=examples(200), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), period=st.sampled_from([0.001, 0.01, 0.02, 0.05]),
       settling=st.sampled_from([0.05, 0.5]), beyond=st.sampled_from([1.0, 1.5]),
       plan=st.sampled_from([(1.0, 0.0), (0.65, 0.08)]))
def test_unicycle_braking_after_is_the_generic_form_bit_for_bit(seed, period, settling, beyond,
                                                                plan):
    """The one-kernel x+ and path equal ``RobotModel.braking_after``'s numpy steps exactly.

    Also where the path ends full rather than at rest (a slow brake, tau = 0.5 s), for
    inputs beyond the bounds (a QP's tolerance): the row count is ``braking_path``'s, and
    for stops planned slower and later (``plan_braking``: a share and a coast).
    """
    rng = np.random.default_rng(seed)
    model = make_model('unicycle', brake_time_constant=settling).plan_braking(*plan)
    state = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi),
                      rng.uniform(-2.5, 2.5), rng.uniform(-3.0, 3.0)])
    u = beyond * rng.uniform(model.input_lower, model.input_upper)
    rows = model.braking_after(state, u, period)
    generic = RobotModel.braking_after(model, state, u, period)
    assert rows.shape == generic.shape and np.array_equal(rows, generic)
    assert rows.flags.c_contiguous and rows[1:].flags.c_contiguous
    # Too short a buffer: the kernel asks for the rows it needs instead of cutting the path.
    kernel = (np.ascontiguousarray(u), model.offset_l, model.braking_limits,
              settling / plan[0], plan[1], period)
    needed = -_braking_after(state, *kernel, np.empty((1, 4)))
    assert needed >= len(rows)
    out = np.empty((needed, 4))
    assert np.array_equal(out[:_braking_after(state, *kernel, out)], rows)


@settings(max_examples=examples(200), deadline=None)
@given(name=st.sampled_from(['unicycle', 'point_mass_2d']), seed=st.integers(0, 2 ** 32 - 1),
       period=st.sampled_from([0.001, 0.01, 0.02, 0.05]))
def test_braking_reach_bounds_every_path_the_check_could_compute(name, seed, period):
    """From any state and admissible input, the path after one period stays within rho.

    ``RobotModel.braking_reach``: within rho of the body position and ending within t; the
    filter skips the check on this bound.
    """
    rng = np.random.default_rng(seed)
    model = make_model(name)
    if name == 'unicycle':
        state = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi),
                          rng.uniform(-2.5, 2.5), rng.uniform(-3.0, 3.0)])
    else:
        state = np.concatenate([rng.uniform(-5, 5, 2), rng.uniform(-2.5, 2.5, 2)])
    u = rng.uniform(model.input_lower, model.input_upper)
    u[rng.random(len(u)) < 0.3] = model.input_upper[0] * rng.choice([-1.0, 1.0])
    u = np.clip(u, model.input_lower, model.input_upper)
    reach, duration = model.braking_reach(state, period)
    path = model.braking_after(state, u, period)[1:]
    distances = np.linalg.norm(path[:, :2] - state[:2], axis=1)
    assert distances.max() <= reach + 1e-9
    assert (len(path) + 1) * period <= duration + 1e-12


def test_braking_reach_is_unbounded_for_a_period_longer_than_the_brake():
    """T > tau: the held brake can overshoot, and no bound is claimed."""
    model = make_model('unicycle', brake_time_constant=0.05)
    assert model.braking_reach(np.zeros(5), 0.1) == (np.inf, np.inf)
    assert make_model('point_mass_3d').braking_reach(np.zeros(6), 0.01)[0] < np.inf


@settings(max_examples=examples(150), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=4.0), min_size=1, max_size=4),
       seed=st.integers(0, 2 ** 32 - 1), cutoff=st.floats(0.0, 0.5))
def test_clear_around_promises_what_path_clearance_returns(polygons, seed, cutoff):
    """If no box comes within rho + cutoff, any path within rho of the centre gets cutoff."""
    rng = np.random.default_rng(seed)
    centre, rho = rng.uniform(-4, 4, 2), float(rng.uniform(0.0, 1.5))
    angles, radii = rng.uniform(-np.pi, np.pi, 30), rho * np.sqrt(rng.random(30))
    path = np.column_stack([centre + radii[:, None] * np.column_stack([np.cos(angles),
                                                                        np.sin(angles)]),
                            rng.uniform(-1.0, 1.0, (30, 2))])
    velocities = rng.uniform(-0.5, 0.5, (len(polygons), 3)) * rng.integers(0, 2)
    offsets = rng.uniform(-0.3, 0.3, (len(polygons), 3)) * rng.integers(0, 2)
    errors = rng.choice([0.0, 0.0, 1.5], len(polygons))
    accel = float(rng.choice([0.0, 1.0]))
    age = float(rng.uniform(0.0, 0.2))
    prepared = PlanarPolygons.from_batch(PolygonBatch.from_polygons(polygons))
    around = (prepared.boxes, velocities, offsets, errors, accel, age + len(path) * PERIOD,
              float(centre[0]), float(centre[1]), rho + cutoff)
    clearance = (prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
                 prepared.counts, prepared.boxes, velocities, offsets,
                 np.zeros((len(polygons), 2)), age, path, PERIOD, cutoff, accel, errors)
    if clear_around(*around, False):
        assert path_clearance(*clearance, True, *POINT_BODY) == (cutoff, cutoff)
    # Moving parts only, their bounds with them (an evasion's look ahead, ``SafetyFilter``).
    errors[~velocities[:, :2].any(axis=1)] = 0.0  # the array both tuples hold
    if clear_around(*around, True):
        assert path_clearance(*clearance, False, *POINT_BODY)[1] == cutoff
    far = PlanarPolygons.from_batch(PolygonBatch.from_polygons([p + 100.0 for p in polygons]))
    assert clear_around(far.boxes, np.zeros_like(velocities), np.zeros_like(offsets),
                        np.zeros_like(errors), 0.0, age, float(centre[0]), float(centre[1]),
                        rho + cutoff, False)


@settings(max_examples=examples(200), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), period=st.sampled_from([0.001, 0.01, 0.02, 0.05]),
       offset=st.sampled_from([0.0, 0.01, 0.2, -0.1]), axle=st.booleans(),
       plan=st.sampled_from([(1.0, 0.0), (0.65, 0.08)]), far=st.booleans())
def test_stop_bands_hold_every_row_the_check_would_compute(seed, period, offset, axle, plan,
                                                          far):
    """``RobotModel.stop_bands`` bounds ``braking_after``'s rows without computing them.

    Every row's position lies in the position box, its velocity in some band's box, |v|^2
    and |omega| under the bounds, and the rows are no more than the count; also far from
    the origin (rounding), turning fast, at rest, planned slower and later, and for the
    axle's rows (a turning footprint).
    """
    rng = np.random.default_rng(seed)
    model = make_model('unicycle', offset_l=offset).plan_braking(*plan)
    paths = model.body_paths() if axle else model
    state = np.array([*rng.uniform(-1, 1, 2) * (1e3 if far else 5.0),
                      rng.uniform(-10, 10), rng.uniform(-2.5, 2.5), rng.uniform(-5.0, 5.0)])
    state[3:] *= rng.random(2) < 0.8  # some at rest or not turning
    u = rng.uniform(model.input_lower, model.input_upper)
    bands, count = paths.stop_bands(state, u, period)
    rows = paths.braking_after(state, u, period)
    assert len(rows) <= count
    low_x, high_x, low_y, high_y = bands[0, :4]
    assert np.all((low_x <= rows[:, 0]) & (rows[:, 0] <= high_x))
    assert np.all((low_y <= rows[:, 1]) & (rows[:, 1] <= high_y))
    assert np.all(np.all(bands[:, :4] == bands[0, :4], axis=1))
    inside = ((bands[None, :, 4] <= rows[:, 2, None]) & (rows[:, 2, None] <= bands[None, :, 5])
              & (bands[None, :, 6] <= rows[:, 3, None]) & (rows[:, 3, None] <= bands[None, :, 7]))
    assert np.all(inside.any(axis=1))
    assert np.all(rows[:, 2] ** 2 + rows[:, 3] ** 2 <= bands[:, 8].max())
    if axle:
        assert np.all(np.abs(rows[:, 5]) <= bands[0, 9])
    assert model.stop_bands(state, u, 2 * model.brake_time_constant) is None


def _curving_part(acceleration):
    """Return a 0.4 m box 1.2 m right of a unicycle's way, passing at 1.5 m/s.

    ``acceleration`` (2,) or None: what the set states it speeds up at.
    """
    box = np.array([[0.0, -1.4], [0.4, -1.4], [0.4, -1.0], [0.0, -1.0]])
    return ObstacleSet.from_obstacles([Obstacle(
        polygon=box, velocity=np.array([1.5, 0.0, 0.0]), acceleration=acceleration)])


def test_the_check_moves_a_part_with_the_acceleration_it_states():
    """A part curving into the stop: refused with its stated acceleration, kept without.

    Its constant-velocity line passes 1.2 m right of the robot's way, farther than the
    check's bound (1 m/s^2) lets it stray before the robot stops; curving at 3 m/s^2 (a
    1.5 m/s loop of 0.75 m radius) it comes across.  The clearance is the kernel's with
    the stated acceleration, part by part too; the certificate and the box test do not
    pass the refused input.
    """
    filt = _checked_filter(False, PERIOD)
    state, u = np.array([0.0, 0.0, 0.0, 1.5, 0.0]), np.array([2.0, 0.0])
    rows = filt._paths.braking_after(state, u, PERIOD)
    straight = filt._prepare(_curving_part(None))
    curving = filt._prepare(_curving_part(np.array([0.0, 3.0])))
    assert filt._path_clearance(rows[1:], straight, PERIOD) == (filt._clearance,) * 2
    static, moving = filt._path_clearance(rows[1:], curving, PERIOD)
    assert static == filt._clearance and moving < filt._clearance
    footprints = curving.footprints
    assert moving == path_clearance(
        footprints.x, footprints.y, footprints.edge_x, footprints.edge_y, footprints.inv_sq,
        footprints.counts, footprints.boxes, curving.velocities, curving.offsets,
        np.array([[0.0, 3.0]]), PERIOD, rows[1:], PERIOD, filt._clearance,
        filt._braking_accel, curving.velocity_errors[0], True, *POINT_BODY)[1]
    assert filt._moving_parts(rows[1:], curving, PERIOD)[0] == moving
    for prepared, refused in ((straight, False), (curving, True)):
        now = _BrakingNow(filt, state, prepared, 0.0)
        assert filt._must_brake(state, u, prepared, 0.0, now) == refused
        assert not (refused and filt._far_from_all(state, prepared, 0.0))
        stop = filt._paths.stop_bands(state, u, PERIOD)
        assert not (refused and filt._stop_certified(stop, prepared, 0.0))


def _scene(rng, path, spread):
    """Return 1-6 convex parts near ``path``, a third of them moving.

    Each 0-``spread`` m beyond its size from a row, mostly the stop's end, so that some
    come within the check's clearance of the stop and some just miss it.
    """
    obstacles = []
    for _ in range(rng.integers(1, 7)):
        size = rng.uniform(0.05, 0.6)
        row = path[-1] if rng.random() < 0.7 else path[rng.integers(len(path))]
        turn = rng.uniform(-np.pi, np.pi)
        centre = row[:2] + (size + rng.uniform(0.0, spread)) * np.array(
            [np.cos(turn), np.sin(turn)])
        angles = np.sort(rng.uniform(0.0, 2 * np.pi, rng.integers(3, 9)))
        polygon = convex_hull(centre + size * np.column_stack([np.cos(angles), np.sin(angles)]))
        velocity, acceleration = np.zeros(3), None
        if rng.random() < 0.3:
            velocity[:2] = rng.uniform(-1.5, 1.5, 2)
            acceleration = rng.uniform(-1.0, 1.0, 2) * (rng.random() < 0.5)
        obstacles.append(Obstacle(polygon=polygon, velocity=velocity,
                                  acceleration=acceleration))
    return ObstacleSet.from_obstacles(obstacles)


def _checked_filter(footprint, period):
    """Return the disc's default filter, or a Jackal box's, counting moving parts' errors."""
    extra = {'barrier': 'polyc2bf_footprint', 'footprint': JACKAL} if footprint else {}
    return SafetyFilter(make_model('unicycle', offset_l=0.01), FilterConfig(
        robot_radius=0.2, control_period=period, braking_obstacle_accel=1.0,
        obstacle_velocity_error=0.1, **extra))


def _random_motion(rng, filt):
    """Return (state, input, obstacle age): up to 2.5 m/s, a third not turning."""
    state = np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(-4, 4),
                      rng.uniform(-2.5, 2.5), rng.uniform(-3, 3) * (rng.random() < 0.7)])
    u = rng.uniform(filt.model.input_lower, filt.model.input_upper)
    return state, u, float(rng.uniform(0.0, 0.3))


@settings(max_examples=examples(60), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), footprint=st.booleans(),
       period=st.sampled_from([0.001, 0.01]))
def test_the_stop_bands_promise_what_the_computed_path_gives(seed, footprint, period):
    """Each part of the certificate holds on the path it did not compute.

    Where ``stop_clear`` passes, ``path_clearance`` of B(x+) is the cutoff for static and
    moving parts; where the cone model's ``stop_skipped`` passes, H(x+) >= 0
    (``min_h_along``); where ``_look_ahead_clear`` passes, the evasion's look ahead of the
    input keeps the clearance of the moving parts (some speeding up).  Parts placed 0-0.6 m
    beyond their size from the stop, many within the clearance and the horizon.
    """
    rng = np.random.default_rng(seed)
    filt = _checked_filter(footprint, period)
    for _ in range(20):
        state, u, age = _random_motion(rng, filt)
        rows = filt._paths.braking_after(state, u, period)
        prepared = filt._prepare(_scene(rng, rows, 0.6))
        bands, count = filt._paths.stop_bands(state, u, period)
        first = age + period
        last = first + count * period
        footprints = prepared.footprints
        if stop_clear(bands, first, last, footprints.boxes, prepared.velocities,
                      prepared.offsets, prepared.accelerations, prepared.velocity_errors[0],
                      filt._braking_accel, filt._clearance, filt._cover, False):
            assert filt._path_clearance(rows[1:], prepared, first) == (filt._clearance,) * 2
        if filt.cone_model.stop_skipped(prepared.views[0].prepared, prepared.velocities,
                                        prepared.offsets, first, last, bands):
            assert filt._min_h_along(rows[0], rows[1:], prepared, first) >= 0.0
        if filt._look_ahead_clear(filt._paths.stop_bands(state, u, period), prepared, age):
            look_ahead = filt._then_brake(np.zeros((0, filt._paths.columns)),
                                          filt.model.one_period(state, u, period), 1)
            assert filt._look_ahead(look_ahead, prepared, age)[1] >= filt._clearance


@settings(max_examples=examples(60), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), footprint=st.booleans(),
       period=st.sampled_from([0.001, 0.01]))
def test_an_input_the_stop_bands_certify_is_one_the_check_keeps(seed, footprint, period):
    """``SafetyFilter._stop_certified`` is True only where ``_must_brake`` is False.

    Random states (up to 2.5 m/s, turning), inputs in the box and parts around the robot,
    standing and moving (with the velocity error and acceleration the check counts),
    for the guarded disc's horizon barrier and for a turning box footprint.
    """
    rng = np.random.default_rng(seed)
    filt = _checked_filter(footprint, period)
    for _ in range(20):
        state, u, age = _random_motion(rng, filt)
        prepared = filt._prepare(_scene(rng, filt.model.braking_after(state, u, period), 1.2))
        if filt._stop_certified(filt._paths.stop_bands(state, u, period), prepared, age):
            now = _BrakingNow(filt, state, prepared, age)
            assert not filt._must_brake(state, u, prepared, age, now)


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), reach=st.floats(0.0, 0.5),
       speed=st.floats(0.0, 0.5), turn=st.floats(0.0, 0.5), later=st.floats(0.0, 0.5))
def test_widened_bands_hold_the_bands_and_nothing_wider(seed, reach, speed, turn, later):
    """``grow_bands`` holds its bands (``bands_within``); a bound past it is not held.

    Bands of a random stop, widened; then each bound, the band count and either time
    pushed just past the widened one in turn.
    """
    rng = np.random.default_rng(seed)
    model = make_model('unicycle', offset_l=0.1)
    state = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-4, 4), rng.uniform(-2.5, 2.5),
                      rng.uniform(-3, 3)])
    bands, count = model.stop_bands(state, rng.uniform(model.input_lower, model.input_upper),
                                    PERIOD)
    bands = bands.copy()
    first, last = 0.1, 0.1 + count * PERIOD
    held = np.empty_like(bands)
    grow_bands(bands, reach, speed, turn, held)
    assert bands_within(bands, first, last, held, first, last + later)
    assert np.all(held[:, 8] >= bands[:, 8])
    assert not bands_within(bands, first - 1e-3, last, held, first, last + later)
    assert not bands_within(bands, first, last + later + 1e-3, held, first, last + later)
    assert not bands_within(bands[:-1].copy(), first, last, held, first, last + later)
    for column in range(10):
        past, band = bands.copy(), int(rng.integers(len(bands)))
        lower = column < 8 and column % 2 == 0
        past[band, column] = held[band, column] + (-1e-3 if lower else 1e-3)
        assert not bands_within(past, first, last, held, first, last + later), column


@settings(max_examples=examples(40), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), footprint=st.booleans(),
       period=st.sampled_from([0.001, 0.01]))
def test_a_held_certificate_decides_as_the_bands_of_each_step(seed, footprint, period):
    """On one obstacle set, the held certificate changes no decision, and is used.

    A robot drives 60 periods at up to 2.5 m/s, gently, through parts around its way
    (standing and moving, some speeding up); on every step ``_stop_certified`` (which
    keeps a widened certificate, ``STOP_HOLD``) says what ``_bands_clear`` of the step's
    own bands says, and where it certifies ``_must_brake`` keeps u.
    """
    rng = np.random.default_rng(seed)
    filt = _checked_filter(footprint, period)
    state, u, age = _random_motion(rng, filt)
    state[4], u = 0.2 * state[4], 0.05 * u  # steady enough to keep a certificate
    way = filt.model.braking_after(state, np.zeros(2), 0.5)
    prepared = filt._prepare(_scene(rng, way, 1.0))
    for _ in range(60):
        stop = filt._paths.stop_bands(state, u, period)
        if stop is None:
            break
        bands, count = stop
        first = age + period
        exact = filt._bands_clear(bands.copy(), first, first + count * period, prepared)
        certified = filt._stop_certified(filt._paths.stop_bands(state, u, period), prepared,
                                         age)
        assert certified == exact
        if certified:
            assert not filt._must_brake(state, u, prepared, age,
                                        _BrakingNow(filt, state, prepared, age))
        state, age = filt.model.one_period(state, u, period), age + period
    assert filt._held_prepared is prepared


def test_a_cone_model_with_its_own_barrier_test_and_no_certificate_is_never_certified():
    """``ConeModel.stop_skipped``: True where ``min_h_along`` is +inf, else the model's own.

    A model that computes H along the path but has no stop test of its own gets False,
    so the check computes its paths.
    """
    class AlongOnly(InflatedCone):
        def min_h_along(self, *args, **kwargs):
            return -1.0

    bands = np.zeros((1, 10))
    assert InflatedCone(0.2).stop_skipped(None, None, None, 0.0, 0.1, bands)
    assert not AlongOnly(0.2).stop_skipped(None, None, None, 0.0, 0.1, bands)


@pytest.mark.parametrize('barrier', ['polyc2bf_horizon', 'polyc2bf_footprint'])
def test_between_rows_of_parts_the_check_decides_without_a_path(barrier, monkeypatch):
    """Driving between two rows of parts, the stop bands certify every step's input.

    Once it cruises, mostly by the certificate held from an earlier step (``STOP_HOLD``:
    while it speeds up by more than the certificate's widening a period, each step's own).
    And the filter's inputs are those of the check computing every path, bit for bit
    (``_stop_certified`` replaced by False).  A wall inside the stop is not certified.
    """
    def rollout(certify):
        extra = {'footprint': JACKAL} if barrier == 'polyc2bf_footprint' else {}
        filt = SafetyFilter(make_model('unicycle', offset_l=0.01), FilterConfig(
            barrier=barrier, robot_radius=0.2, control_period=PERIOD, **extra))
        certified, passes, counts = [], [], []
        original, clear = filt._stop_certified, filt._bands_clear

        def spy(*args):
            certified.append(original(*args))
            counts.append(len(passes))
            return certified[-1] and certify

        def count(*args):
            passes.append(args[0].shape)
            return clear(*args)
        monkeypatch.setattr(filt, '_stop_certified', spy)
        monkeypatch.setattr(filt, '_bands_clear', count)
        state, inputs = np.array([0.0, 0.0, 0.02, 0.0, 0.0]), []
        for _ in range(300):
            u, _ = filt.step(state, rows, np.array([4.0 * (1.0 - state[3]),
                                                    -0.5 * state[2] - state[4]]))
            inputs.append(u)
            state = filt.model.one_period(state, u, PERIOD)
        return np.array(inputs), certified, filt, np.diff(counts)  # passes a step

    rows = ObstacleSet.from_obstacles([
        Obstacle(polygon=np.array([[x, low], [x + 0.3, low], [x + 0.3, low + 0.4],
                                   [x, low + 0.4]]))
        for x in np.arange(-0.3, 6.0, 0.6) for low in (1.0, -1.4)])
    fast, certified, filt, passes = rollout(True)
    slow, checked, _, _ = rollout(False)
    assert len(certified) >= 100 and all(certified)
    # In its last second, cruising near 1 m/s, mostly by the held certificate.
    assert np.count_nonzero(passes[-100:]) < 20
    assert np.array_equal(fast, slow) and checked == certified
    wall = ObstacleSet.from_obstacles([Obstacle(polygon=np.array(
        [[0.5, -1.0], [0.7, -1.0], [0.7, 1.0], [0.5, 1.0]]))])
    moving = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    stop = filt._paths.stop_bands(moving, np.zeros(2), PERIOD)
    assert not filt._stop_certified(stop, filt._prepare(wall), 0.0)


@pytest.mark.parametrize('wall_x, checked', [(0.4, True), (1.0, False), (30.0, False)])
def test_the_check_computes_paths_only_when_an_obstacle_is_within_reach(wall_x, checked,
                                                                        monkeypatch):
    """A wall 0.4 m ahead of a robot at 1 m/s is checked, one 1 m or 30 m ahead is not.

    One 1 m ahead is beyond its stop (``_stop_certified``), one 30 m away beyond any
    (``_far_from_all``).
    """
    filt, _ = _wall_ahead_filter(True)
    wall = Obstacle(polygon=np.array([[wall_x, -2.0], [wall_x + 0.2, -2.0],
                                      [wall_x + 0.2, 2.0], [wall_x, 2.0]]))
    calls = []
    original = filt._must_brake
    monkeypatch.setattr(filt, '_must_brake', lambda *a: calls.append(1) or original(*a))
    filt.step(np.array([0.0, 0.0, 0.0, 1.0, 0.0]), ObstacleSet.from_obstacles([wall]),
              np.array([1.0, 0.0]))
    assert bool(calls) == checked

def _wall_ahead_filter(check, margin=FilterConfig.braking_margin):
    wall = Obstacle(polygon=np.array([[1.0, -2.0], [1.2, -2.0], [1.2, 2.0], [1.0, 2.0]]))
    filt = SafetyFilter(make_model('unicycle', offset_l=0.01, max_accel=2.0), FilterConfig(
        barrier='polyc2bf_horizon', robot_radius=0.2, horizon=0.1, gamma=5.0,
        braking_check=check, braking_margin=margin, control_period=PERIOD))
    return filt, ObstacleSet.from_obstacles([wall])


def test_filter_brakes_when_the_input_would_leave_no_clear_stop():
    """Closing on a wall at the fastest speed that can still brake to rest clear of it.

    The disc about the guarded point (0.2 m + offset 0.01 m) touches the wall's face at
    x = 0.79.  A short horizon (0.1 s) and gamma = 5 let the barrier accept accelerating
    on; one more period at that speed leaves too little room to stop, so the check brakes.
    """
    model = make_model('unicycle', offset_l=0.01, max_accel=2.0)
    filt, obstacles = _wall_ahead_filter(True)
    assert filt.guard_radius == pytest.approx(0.21)
    limit = 1.0 - filt.guard_radius - FilterConfig().braking_margin

    def stops_clear(state):
        return model.braking_path(state, PERIOD)[-1, 0] < limit

    def after_accelerating(state):
        return state + PERIOD * model.state_derivative(state, np.array([2.0, 0.0]))

    speeds = np.arange(0.5, 3.0, 0.001)
    speed = max(v for v in speeds if stops_clear(np.array([0.0, 0.0, 0.0, v, 0.0])))
    state = np.array([0.0, 0.0, 0.0, speed, 0.0])
    assert not stops_clear(after_accelerating(state))
    u, info = filt.step(state, obstacles, np.array([2.0, 0.0]))
    assert info.status == FilterStatus.BACKUP
    assert np.allclose(u, model.clip_input(model.braking_input(state)))
    unchecked, _ = _wall_ahead_filter(False)
    _, plain = unchecked.step(state, obstacles, np.array([2.0, 0.0]))
    assert plain.status == FilterStatus.OK


def test_filter_leaves_the_input_alone_when_braking_cannot_help_either():
    """Within radius + margin of the wall, braking is not clear either: nothing overridden.

    The CBF rows and the escape act there.
    """
    filt, obstacles = _wall_ahead_filter(True)
    _, info = filt.step(np.array([0.775, 0.0, 0.0, 0.5, 0.0]), obstacles, np.array([0.0, 0.0]))
    assert info.status != FilterStatus.BACKUP


def test_refused_input_keeps_its_steering_when_only_the_speed_must_go():
    """At rest on the band's edge, heading 30 degrees into the wall: driving on is refused.

    Turning left swings the guarded point (offset 0.01 m) away from the wall, so the brake
    keeps that turn; turning right swings it closer, so the brake turns left instead.  A 5 cm
    margin puts the band's edge outside the inflated polygon (the cones exist there).
    """
    filt, obstacles = _wall_ahead_filter(True, margin=0.05)
    yaw = 0.5
    guarded_x = 1.0 - filt.guard_radius - 0.05 - 1e-6
    state = np.array([guarded_x - 0.01 * np.cos(yaw), 0.0, yaw, 0.0, 0.0])
    u, info = filt.step(state, obstacles, np.array([2.0, 4.0]))
    assert info.status == FilterStatus.BACKUP and 'steering' in info.message
    assert u[0] == pytest.approx(0.0, abs=1e-12) and u[1] > 1.0
    kept = u[1]
    u, info = filt.step(state, obstacles, np.array([2.0, -4.0]))
    assert info.status == FilterStatus.BACKUP and 'reversing the steering' in info.message
    assert u[0] == pytest.approx(0.0, abs=1e-12) and u[1] > 1.0
    unchecked, _ = _wall_ahead_filter(False, margin=0.05)
    assert unchecked.step(state, obstacles, np.array([2.0, -4.0]))[0][1] < 0.0 < kept
