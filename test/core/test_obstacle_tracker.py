"""Obstacle tracker: ADD/MODIFY/DELETE/DELETEALL, velocity estimates, extrapolation, outlines."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.geometry import signed_area
from polyc2bf_ros.core.obstacle_tracker import ObstacleTracker, outline_polygon

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _update(tracker, key, stamp, x, frame='odom', polygons=None):
    shifted = [SQUARE + (x, 0.0)] if polygons is None else polygons
    tracker.update(key, frame, stamp, (x + 0.5, 0.5, 0.0), shifted)


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

def test_velocity_from_successive_stamps():
    """Velocity = displacement / stamp difference (no smoothing)."""
    tracker = ObstacleTracker(smoothing=1.0)
    _update(tracker, 'a/1', 1.0, 0.0)
    _update(tracker, 'a/1', 1.5, 1.0)
    [obstacle], t_ref, wrong = tracker.snapshot('odom', 2)
    np.testing.assert_allclose(obstacle.velocity, [2.0, 0.0])
    assert (t_ref, wrong, obstacle.key) == (1.5, {}, 'a/1')


def test_smoothing_blends_with_the_previous_estimate():
    """v_k = a v_raw + (1 - a) v_{k-1}."""
    tracker = ObstacleTracker(smoothing=0.5)
    for i, stamp in enumerate((0.0, 0.1, 0.2)):
        _update(tracker, 'a/1', stamp, 0.1 * i)
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    np.testing.assert_allclose(obstacle.velocity, [0.75, 0.0])


@pytest.mark.parametrize('stamp', [0.1, 3.5], ids=['backwards', 'after_max_gap'])
def test_estimate_restarts_at_zero(stamp):
    """A stamp going backwards or a gap over max_gap restarts at zero velocity."""
    tracker = ObstacleTracker(smoothing=1.0, max_gap=1.0)
    _update(tracker, 'a/1', 0.0, 0.0)
    _update(tracker, 'a/1', 0.5, 1.0)
    _update(tracker, 'a/1', stamp, 2.0)
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    np.testing.assert_array_equal(obstacle.velocity, [0.0, 0.0])


def test_same_stamp_keeps_the_velocity():
    """A re-sent message (same stamp) keeps the estimate."""
    tracker = ObstacleTracker(smoothing=1.0)
    _update(tracker, 'a/1', 0.0, 0.0)
    _update(tracker, 'a/1', 0.5, 1.0)
    _update(tracker, 'a/1', 0.5, 1.0)
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    assert obstacle.velocity[0] == pytest.approx(2.0)


def test_snapshot_moves_older_obstacles_to_the_newest_stamp():
    """Obstacles are extrapolated to the newest stamp held."""
    tracker = ObstacleTracker(smoothing=1.0)
    _update(tracker, 'a/1', 0.0, 0.0)
    _update(tracker, 'a/1', 1.0, 1.0)     # 1 m/s, stamp 1.0
    _update(tracker, 'b/1', 3.0, 10.0)    # static, newest stamp 3.0
    obstacles, t_ref, _ = tracker.snapshot('odom', 3)
    assert t_ref == 3.0
    moved = {o.key: o for o in obstacles}['a/1']
    np.testing.assert_allclose(moved.polygon, SQUARE + (3.0, 0.0))
    assert moved.velocity.shape == (3,)


def test_delete_and_delete_all_keep_velocity_history():
    """DELETE/DELETEALL drop obstacles; a re-added key keeps its velocity."""
    tracker = ObstacleTracker(smoothing=1.0)
    _update(tracker, 'a/1', 0.0, 0.0)
    _update(tracker, 'b/1', 0.0, 5.0)
    tracker.delete('b/1')
    tracker.delete('unknown/7')
    assert len(tracker) == 1
    tracker.delete_all()
    assert len(tracker) == 0 and tracker.snapshot('odom', 2)[0] == []
    _update(tracker, 'a/1', 0.1, 0.1)    # cleared and re-added in the same message
    [obstacle], _, _ = tracker.snapshot('odom', 2)
    assert obstacle.velocity[0] == pytest.approx(1.0)


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
    tracker = ObstacleTracker(smoothing=1.0)
    tracker.update('t/1', 'odom', 0.0, (0, 0, 0), [SQUARE, SQUARE + 2.0], z_min=0.0, z_max=1.0)
    tracker.update('t/1', 'odom', 1.0, (0, 0, 0.5), [SQUARE, SQUARE + 2.0], z_min=0.5,
                   z_max=1.5)
    tracker.update('u/1', 'odom', 2.0, (9, 9, 0), [SQUARE + 9.0])
    obstacles = tracker.snapshot('odom', 3)[0]
    parts = [o for o in obstacles if o.key.startswith('t/1')]
    assert [o.key for o in parts] == ['t/1#0', 't/1#1']
    assert (parts[0].z_min, parts[0].z_max) == pytest.approx((1.0, 2.0))


def test_bad_construction():
    """Smoothing outside (0, 1] or a non-positive max_gap is refused."""
    for smoothing, gap in ((0.0, 1.0), (1.5, 1.0), (0.5, 0.0)):
        with pytest.raises(ValueError):
            ObstacleTracker(smoothing, gap)
