"""Obstacle tracker: ADD/MODIFY/DELETE/DELETEALL, velocity estimates, extrapolation, outlines."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.geometry.polygons import signed_area
from polyc2bf_ros.core.obstacles.marker_tracker import (
    ObstacleTracker,
    outline_polygon,
    Placement,
    Shape,
)
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from strategies import examples

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _update(tracker, key, stamp, x, frame='odom'):
    tracker.update(key, frame, stamp, (x + 0.5, 0.5, 0.0), Shape((SQUARE + (x, 0.0),)))


# -- outlines ------------------------------------------------------------------------------------

def test_outline_keeps_a_proper_polygon_ccw_and_drops_the_closing_point():
    """A closed CW square comes back as a CCW 4-gon."""
    closed_cw = np.vstack([SQUARE[::-1], SQUARE[-1:]])
    polygon = outline_polygon(closed_cw, 0.1)
    assert len(polygon) == 4 and signed_area(polygon) == pytest.approx(1.0)


def test_two_point_wall_becomes_a_thin_rectangle():
    """Two points: a rectangle of the given width, extended by half of it at both ends."""
    polygon = outline_polygon([[0.0, 0.0], [2.0, 0.0]], 0.1)
    assert signed_area(polygon) == pytest.approx((2.0 + 0.1) * 0.1)
    np.testing.assert_allclose(polygon.min(axis=0), [-0.05, -0.05])
    np.testing.assert_allclose(polygon.max(axis=0), [2.05, 0.05])


def test_collinear_and_repeated_points_span_the_extremes():
    """Collinear points with repeats: one rectangle between the extreme points."""
    polygon = outline_polygon([[1.0, 1.0], [0.0, 0.0], [1.0, 1.0], [3.0, 3.0]], 0.2)
    assert signed_area(polygon) == pytest.approx((math.sqrt(18.0) + 0.2) * 0.2)


def test_single_point_becomes_a_square():
    """One distinct point: a square of side thickness centred on it."""
    polygon = outline_polygon([[1.0, 2.0]] * 3, 0.5)
    assert signed_area(polygon) == pytest.approx(0.25)
    np.testing.assert_allclose(polygon.mean(axis=0), [1.0, 2.0])


@pytest.mark.parametrize('points, thickness, reason', [
    ([], 0.1, 'no points'),
    ([[0.0, math.nan], [1.0, 0.0], [0.0, 1.0]], 0.1, 'non-finite'),
    ([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]], 0.1, 'self-intersecting'),
    ([[0.0, 0.0], [1.0, 0.0]], 0.0, 'thickness'),
])
def test_unusable_outlines_are_refused_with_a_reason(points, thickness, reason):
    """Empty, non-finite, self-intersecting or zero-width outlines raise a reason."""
    with pytest.raises(ValueError, match=reason):
        outline_polygon(points, thickness)


@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=7))
def test_outline_never_crashes(points):
    """Any finite point set gives a positive-area polygon or a ValueError."""
    try:
        polygon = outline_polygon(points, 0.05)
    except ValueError:
        return
    assert polygon.shape[0] >= 3 and signed_area(polygon) > 0.0


# -- tracking -------------------------------------------------------------------------------------

@settings(max_examples=examples(25), deadline=None)
@given(vx=st.floats(-2.0, 2.0), vy=st.floats(-2.0, 2.0), rate=st.sampled_from([10.0, 30.0, 100.0]))
def test_constant_velocity_is_estimated_within_a_centimetre_per_second(vx, vy, rate):
    """A marker moving at constant velocity: the estimate is within 0.01 m/s after 1 s."""
    tracker = ObstacleTracker()
    for k in range(int(rate) + 1):
        t = k / rate
        tracker.update('a/1', 'odom', t, (vx * t, vy * t, 0.0), Shape((SQUARE,)))
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    np.testing.assert_allclose(obstacle.velocity, [vx, vy], atol=0.01)


def test_a_standing_marker_has_velocity_zero_exactly():
    """Every innovation is 0, so the estimate stays 0 (no tightening of its rows)."""
    tracker = ObstacleTracker()
    for stamp in np.arange(0.0, 2.0, 0.1):
        _update(tracker, 'a/1', float(stamp), 3.0)
    [obstacle], _, _ = tracker.snapshot('odom', 3)
    assert not obstacle.velocity.any()


def test_a_turning_marker_is_followed_within_a_walkers_lag():
    """A walker on a 2 m circle at 1.4 m/s (0.98 m/s^2 toward its centre), from 1 s on.

    Velocity error below 0.15 m/s, acceleration error below 0.3 m/s^2 (the average lags
    the turn, module docstring); a marker that stands has no acceleration, exactly.
    """
    tracker = ObstacleTracker()
    omega, speed_errors, accel_errors = 1.4 / 2.0, [], []
    for k in range(101):
        t = 0.05 * k
        position = 2.0 * np.array([np.cos(omega * t), np.sin(omega * t), 0.0])
        tracker.update('a/1', 'odom', t, position, Shape((SQUARE,)))
        _update(tracker, 'b/1', t, 3.0)
        turning, standing = tracker.snapshot('odom', 2)[0]
        velocity = 1.4 * np.array([-np.sin(omega * t), np.cos(omega * t)])
        speed_errors.append(np.linalg.norm(turning.velocity - velocity))
        accel_errors.append(np.linalg.norm(turning.acceleration + omega * omega * position[:2]))
        assert not standing.acceleration.any()
    assert max(speed_errors[20:]) < 0.15 and max(accel_errors[20:]) < 0.3


@pytest.mark.parametrize('stamp', [0.1, 3.5], ids=['backwards', 'after_max_gap'])
def test_estimate_restarts_at_zero(stamp):
    """A stamp going backwards or a gap over max_gap restarts at zero velocity."""
    tracker = ObstacleTracker(max_gap=1.0)
    for k in range(11):  # speeding up at 2 m/s^2 for a second
        _update(tracker, 'a/1', 0.05 * k, (0.05 * k) ** 2)
    assert tracker.snapshot('odom', 2)[0][0].acceleration[0] > 1.0
    _update(tracker, 'a/1', stamp, 2.0)
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    np.testing.assert_array_equal(obstacle.velocity, [0.0, 0.0])
    np.testing.assert_array_equal(obstacle.acceleration, [0.0, 0.0])


@settings(max_examples=examples(25), deadline=None)
@given(ax=st.floats(-1.4, 1.4), ay=st.floats(-1.4, 1.4), vx=st.floats(-1.5, 1.5),
       rate=st.sampled_from([10.0, 30.0, 100.0]))
def test_constant_acceleration_is_estimated_after_two_seconds(ax, ay, vx, rate):
    """A marker speeding up at a constant rate (up to 2 m/s^2): within 0.05 m/s^2 after 2 s."""
    tracker = ObstacleTracker()
    for k in range(2 * int(rate) + 1):
        t = k / rate
        tracker.update('a/1', 'odom', t, (vx * t + 0.5 * ax * t * t, 0.5 * ay * t * t, 0.0),
                       Shape((SQUARE,)))
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    np.testing.assert_allclose(obstacle.acceleration, [ax, ay], atol=0.05)


def test_an_acceleration_is_capped_at_max_accel():
    """A marker that jumps (a mislabelled key) is taken at most ``max_accel`` fast."""
    tracker = ObstacleTracker(max_accel=3.0)
    for k in range(11):
        _update(tracker, 'a/1', 0.1 * k, 0.0 if k < 5 else 2.0)
        assert np.linalg.norm(tracker.snapshot('odom', 2)[0][0].acceleration) <= 3.0 + 1e-12
    assert np.linalg.norm(tracker.snapshot('odom', 2)[0][0].acceleration) > 1.0


def test_same_stamp_keeps_the_velocity():
    """A re-sent message (same stamp) keeps the estimate."""
    tracker = ObstacleTracker()
    for k in range(11):
        _update(tracker, 'a/1', 0.1 * k, 0.2 * k)
    [before], _, _ = tracker.snapshot('odom', 2)
    _update(tracker, 'a/1', 1.0, 2.0)
    [after], _, _ = tracker.snapshot('odom', 2)
    assert after.velocity[0] == before.velocity[0] == pytest.approx(2.0, abs=0.02)


@pytest.mark.parametrize('name', ['accel_std', 'position_std', 'speed_std', 'max_gap',
                                  'accel_time_constant', 'max_accel'])
@pytest.mark.parametrize('value', [0.0, -1.0, math.nan, math.inf])
def test_bad_estimator_settings_are_refused_by_name(name, value):
    """Each setting must be finite and positive; the error names it."""
    with pytest.raises(ValueError, match=name):
        ObstacleTracker(**{name: value})


def test_snapshot_moves_older_obstacles_to_the_newest_stamp():
    """Obstacles are extrapolated to the newest stamp held."""
    tracker = ObstacleTracker()
    for k in range(11):
        _update(tracker, 'a/1', 0.1 * k, 0.1 * k)     # 1 m/s, last stamp 1.0 at x = 1
    _update(tracker, 'b/1', 3.0, 10.0)    # static, newest stamp 3.0
    obstacles, t_ref, _ = tracker.snapshot('odom', 3)
    assert t_ref == 3.0
    moved = {o.key: o for o in obstacles}['a/1']
    np.testing.assert_allclose(moved.polygon, SQUARE + (1.0 + 2.0 * moved.velocity[0], 0.0))
    assert moved.velocity[0] == pytest.approx(1.0, abs=0.01)
    assert moved.velocity.shape == (3,)


def test_delete_and_delete_all_keep_velocity_history():
    """DELETE/DELETEALL drop obstacles; a re-added key keeps its velocity."""
    tracker = ObstacleTracker()
    for k in range(10):
        _update(tracker, 'a/1', 0.1 * k, 0.1 * k)
    _update(tracker, 'b/1', 0.0, 5.0)
    tracker.delete('b/1')
    tracker.delete('unknown/7')
    assert len(tracker) == 1
    tracker.delete_all()
    assert len(tracker) == 0 and tracker.snapshot('odom', 2)[0] == []
    _update(tracker, 'a/1', 1.0, 1.0)    # cleared and re-added in the same message
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    assert obstacle.velocity[0] == pytest.approx(1.0, abs=0.01)


def test_rejections_and_invalid_flag():
    """Rejections are listed; non-finite ones hold the invalid flag until cleared."""
    tracker = ObstacleTracker()
    _update(tracker, 'a/1', 0.0, 0.0)
    tracker.reject('a/1', 'non-finite pose', invalid=True)
    tracker.reject('a/2', 'polygon is self-intersecting')
    assert len(tracker) == 0 and tracker.has_invalid
    assert tracker.rejected == {'a/1': 'non-finite pose', 'a/2': 'polygon is self-intersecting'}
    _update(tracker, 'a/1', 0.2, 0.0)
    assert not tracker.has_invalid and list(tracker.rejected) == ['a/2']
    tracker.reject('a/3', 'non-finite points', invalid=True)
    tracker.delete('a/3')
    assert not tracker.has_invalid
    tracker.reject('a/3', 'non-finite points', invalid=True)
    tracker.delete_all()
    assert not tracker.has_invalid and tracker.rejected == {}


def test_other_frames_are_reported_not_used():
    """Obstacles in another frame are reported, never used."""
    tracker = ObstacleTracker()
    _update(tracker, 'a/1', 0.0, 0.0, frame='map')
    _update(tracker, 'a/2', 0.0, 3.0)
    obstacles, _, wrong = tracker.snapshot('odom', 2)
    assert [o.key for o in obstacles] == ['a/2']
    assert wrong == {'a/1': "frame 'map' is not the odometry frame 'odom'"}


def test_multi_polygon_markers_get_part_keys_and_z_range():
    """Multi-polygon markers get ns/id#i keys; z range is extrapolated too."""
    tracker = ObstacleTracker()
    shape = Shape((SQUARE, SQUARE + 2.0), z_min=0.0, z_max=1.0)
    tracker.update('t/1', 'odom', 0.0, (0, 0, 0), shape)
    tracker.update('t/1', 'odom', 1.0, (0, 0, 0.5), shape, Placement(z=0.5))
    tracker.update('u/1', 'odom', 2.0, (9, 9, 0), Shape((SQUARE + 9.0,)))
    obstacles = tracker.snapshot('odom', 3)[0]
    parts = [o for o in obstacles if o.key.startswith('t/1')]
    assert [o.key for o in parts] == ['t/1#0', 't/1#1']
    assert (parts[0].z_min, parts[0].z_max) == pytest.approx((1.0, 2.0))


# -- shapes, placements and the filter's obstacle set ---------------------------------------------

L_SHAPE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.5], [0.5, 0.5], [0.5, 2.0], [0.0, 2.0]])


def _assert_same_set(actual, expected):
    """Two ObstacleSets hold the same parts (vertices to 1e-9), velocities, z ranges and keys."""
    assert actual.keys == expected.keys
    np.testing.assert_array_equal(actual.owner, expected.owner)
    np.testing.assert_array_equal(actual.footprints.counts, expected.footprints.counts)
    np.testing.assert_allclose(actual.footprints.vertices, expected.footprints.vertices,
                               atol=1e-9)
    np.testing.assert_allclose(actual.velocities, expected.velocities, atol=1e-12)
    np.testing.assert_allclose(actual.z_ranges, expected.z_ranges, atol=1e-12)
    assert (actual.accelerations is None) == (expected.accelerations is None)
    if actual.accelerations is not None:
        np.testing.assert_allclose(actual.accelerations, expected.accelerations, atol=1e-12)


def test_placement_rotates_about_z_then_translates():
    """Placement (x, y, z, cos, sin): a quarter turn maps (1, 0) to (0, 1), then the offset."""
    quarter = Placement(5.0, 0.0, 1.0, 0.0, 1.0)
    np.testing.assert_allclose(quarter.rotate(np.array([[1.0, 0.0]])) + quarter[:2],
                               [[5.0, 1.0]], atol=1e-15)
    assert Placement().rotate(SQUARE) is SQUARE


def test_shapes_are_placed_and_kept_after_a_delete():
    """Snapshot = R(yaw) shape + offset; ``shape`` returns the last shape, also after DELETE."""
    tracker = ObstacleTracker(max_gap=1.0)
    shape = Shape((SQUARE,), z_min=0.0, z_max=2.0)
    tracker.update('r/1', 'odom', 0.0, (3.0, 0.0, 0.5), shape, Placement(3.0, 0.0, 0.5, 0.0, 1.0))
    [obstacle], _, _ = tracker.snapshot('odom', 3)
    np.testing.assert_allclose(obstacle.polygon, [[3, 0], [3, 1], [2, 1], [2, 0]], atol=1e-15)
    assert (obstacle.z_min, obstacle.z_max) == (0.5, 2.5)
    tracker.delete('r/1')
    assert tracker.shape('r/1') is shape and tracker.shape('r/2') is None
    _update(tracker, 'other/1', 5.0, 0.0)   # beyond max_gap: the deleted key is forgotten
    assert tracker.shape('r/1') is None


def test_obstacle_set_translates_while_shapes_only_move():
    """Only poses change: the last set translated (same edge table); a turn rebuilds it.

    Each set equals the one built from ``snapshot``.
    """
    tracker = ObstacleTracker()
    robot, wall = Shape((SQUARE,), 0.0, 1.0), Shape((L_SHAPE,))
    sets = []
    for step, x in enumerate((0.0, 0.1, 0.2)):
        tracker.update('robots/0', 'odom', 0.1 * step, (x, 0.0, 0.5), robot,
                       Placement(x, 0.0, 0.5))
        tracker.update('walls/0', 'odom', 0.0, (0.0, 0.0, 0.0), wall)
        obstacle_set, t_ref, wrong = tracker.obstacle_set('odom', 2)
        expected = ObstacleSet.from_obstacles(tracker.snapshot('odom', 2)[0])
        _assert_same_set(obstacle_set, expected)
        assert (t_ref, wrong) == (0.1 * step, {})
        sets.append(obstacle_set)
    assert len(sets[0]) == 3 and sets[2].velocities[0, 0] > 0.5
    assert sets[1].footprints.edge_table is sets[0].footprints.edge_table
    tracker.update('robots/0', 'odom', 0.3, (0.3, 0.0, 0.5), robot, Placement(0.3, 0.0, 0.5,
                                                                               0.0, 1.0))
    turned = tracker.obstacle_set('odom', 2)[0]
    assert turned.footprints.edge_table is not sets[0].footprints.edge_table
    _assert_same_set(turned, ObstacleSet.from_obstacles(tracker.snapshot('odom', 2)[0]))


_SHAPES = [Shape((SQUARE,), 0.0, 1.0), Shape((L_SHAPE,)), Shape((SQUARE, SQUARE + 3.0), -1.0, 0.5)]


@given(st.lists(st.tuples(st.integers(0, 3), st.sampled_from(['upd', 'del', 'map', 'all']),
                          st.integers(0, 2), st.floats(-5, 5), st.floats(-5, 5),
                          st.sampled_from([0.0, 0.5 * math.pi, 2.0])),
                min_size=1, max_size=25))
def test_obstacle_set_matches_the_snapshot(steps):
    """Any updates, deletes and frame changes: the set equals the one built from ``snapshot``.

    3-D velocities, so z ranges are extrapolated too.
    """
    tracker = ObstacleTracker()
    for stamp, (key, action, shape, x, y, yaw) in enumerate(steps):
        name = f'k/{key}'
        if action == 'del':
            tracker.delete(name)
        elif action == 'all':
            tracker.delete_all()
        else:
            placement = Placement(x, y, 0.1 * x, math.cos(yaw), math.sin(yaw))
            tracker.update(name, 'odom' if action == 'upd' else 'map', 0.05 * stamp,
                           placement[:3], _SHAPES[shape], placement)
        obstacle_set, t_ref, wrong = tracker.obstacle_set('odom', 3)
        obstacles, snapshot_t_ref, snapshot_wrong = tracker.snapshot('odom', 3)
        _assert_same_set(obstacle_set, ObstacleSet.from_obstacles(obstacles))
        assert wrong == snapshot_wrong
        assert t_ref == snapshot_t_ref or (math.isnan(t_ref) and math.isnan(snapshot_t_ref))
