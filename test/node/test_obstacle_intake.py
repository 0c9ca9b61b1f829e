"""Obstacle intake: conflation, caps and snapshots, in process (no DDS, no node)."""
import numpy as np
import pytest
from hypothesis import given, strategies as st
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker

from node_harness import markers, wall
from polyc2bf_ros import cdr_reader, marker_obstacles
from polyc2bf_ros.core.barrier.obstacle_geometry import ObstacleGeometry
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.marker_tracker import ObstacleTracker
from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.obstacle_intake import ObstacleIntake
from polyc2bf_ros.obstacle_settings import IntakeSettings

SQUARE = [(3.0, -0.5), (4.0, -0.5), (4.0, 0.5), (3.0, 0.5), (3.0, -0.5)]


SPEC = ObstacleGeometry(make_model('unicycle'), FilterConfig())


def _intake(settings=IntakeSettings()):
    """Return an in-line intake (no worker) building obstacles in frame odom."""
    intake = ObstacleIntake(SPEC, lambda: 1.0, settings)
    intake.set_frame('odom')
    return intake


def _square(marker_id, dx=0.0, action=Marker.ADD):
    marker = wall([(x + dx, y) for x, y in SQUARE], marker_id=marker_id)
    marker.action = action
    return marker


def _delete_all():
    marker = Marker()
    marker.action = Marker.DELETEALL
    return marker


actions = st.lists(st.tuples(st.sampled_from(['add', 'delete', 'delete_all']),
                             st.integers(0, 4), st.integers(0, 3)), max_size=30)


@given(actions)
def test_conflated_markers_leave_the_same_obstacles(steps):
    """Applying the conflated list gives the same keys and shapes as applying every marker."""
    sequence = []
    for action, marker_id, shift in steps:
        if action == 'delete_all':
            sequence.append(_delete_all())
        else:
            sequence.append(_square(marker_id, float(shift),
                                    Marker.ADD if action == 'add' else Marker.DELETE))
    every, conflated = ObstacleTracker(), ObstacleTracker()
    for marker in sequence:
        marker_obstacles.apply_markers(every, cdr_reader.MarkerArrayView((marker,)), 1.0, 0.05, 12)
    merged = marker_obstacles.conflate_markers(sequence)
    marker_obstacles.apply_markers(conflated, cdr_reader.MarkerArrayView(tuple(merged)), 1.0, 0.05,
                              12)
    assert len(merged) <= len(sequence)
    a, _, _ = every.snapshot('odom', 2)
    b, _, _ = conflated.snapshot('odom', 2)
    assert sorted(o.key for o in a) == sorted(o.key for o in b)
    by_key = {o.key: o.polygon for o in b}
    for obstacle in a:
        np.testing.assert_allclose(obstacle.polygon, by_key[obstacle.key])


def test_queued_messages_are_processed_in_one_pass():
    """Many queued messages: one pass, one snapshot, newest receipt time, every key kept."""
    intake = _intake()
    for i in range(50):
        intake.submit(serialize_message(markers(_square(i % 5, 0.01 * i))), float(i))
    snapshot = intake.process()
    assert snapshot.received == 49.0 and snapshot.tracked == 5 and snapshot.clean
    assert len(snapshot.obstacles) == 5
    assert snapshot.obstacles.base.geometry  # the views are prepared for the filter
    assert intake.process() is snapshot  # nothing new: no pass


def test_an_unreadable_message_marks_the_input_until_a_readable_one():
    """Truncated bytes: not usable, receipt time unchanged; a readable message clears it."""
    intake = _intake()
    good = serialize_message(markers(_square(1)))
    intake.submit(good, 1.0)
    assert intake.process().usable
    intake.submit(good[:-40], 2.0)
    bad = intake.process()
    assert not bad.usable and 'truncated' in bad.unreadable and bad.received == 1.0
    intake.submit(good, 3.0)
    assert intake.process().usable


def test_a_wrong_frame_is_usable_but_not_clean():
    """A marker in another frame is left out and named; the input is no longer clean."""
    intake = _intake()
    intake.submit(serialize_message(markers(_square(1), wall(SQUARE, marker_id=2,
                                                             frame='map'))), 1.0)
    snapshot = intake.process()
    assert snapshot.usable and not snapshot.clean
    assert list(snapshot.wrong_frame) == ['walls/2'] and len(snapshot.obstacles) == 1


def test_a_huge_outline_is_simplified_to_the_vertex_cap():
    """A 10,000-point circle becomes one obstacle of at most max_vertices vertices."""
    angles = np.linspace(0.0, 2.0 * np.pi, 10_000, endpoint=False)
    circle = wall(list(zip(4.0 + np.cos(angles), np.sin(angles))), marker_id=7)
    intake = _intake(IntakeSettings(max_vertices=32))
    intake.submit(serialize_message(markers(circle)), 1.0)
    snapshot = intake.process()
    assert snapshot.usable and snapshot.simplified == 1
    assert len(snapshot.obstacles) == 1 and snapshot.obstacles.footprints.counts[0] <= 32


def test_a_many_piece_marker_becomes_one_enclosing_polygon():
    """A LINE_LIST of 600 segments (over max_parts) becomes one simplified obstacle."""
    points = [(5.0 + 0.01 * i, 0.3 * (i % 2)) for i in range(1200)]
    segments = wall(points, marker_id=3)
    segments.type = Marker.LINE_LIST
    intake = _intake(IntakeSettings(max_parts=64))
    intake.submit(serialize_message(markers(segments)), 1.0)
    snapshot = intake.process()
    assert snapshot.usable and snapshot.simplified == 1 and len(snapshot.obstacles) == 1


def test_more_obstacles_than_the_cap_make_the_input_unusable():
    """Over max_obstacles: no set, an error naming the count and the cap."""
    intake = _intake(IntakeSettings(max_obstacles=10))
    intake.submit(serialize_message(markers(*[_square(i, 2.0 * i) for i in range(11)])), 1.0)
    snapshot = intake.process()
    assert not snapshot.usable and len(snapshot.obstacles) == 0
    assert '11 obstacle parts exceed max_obstacles (10)' in snapshot.error


def test_the_worker_process_publishes_snapshots_and_moved_sets_keep_their_base():
    """``start``: passes run in the worker process; a moved obstacle keeps the node's base."""
    intake = _intake()
    intake.start()
    try:
        intake.submit(serialize_message(markers(_square(1))), 5.0)
        first = intake.process()
        assert first.received == 5.0 and len(first.obstacles) == 1 and first.usable
        assert first.obstacles.base.geometry  # prepared in the worker, sent along
        moved = _square(1)
        moved.pose.position.x = 0.5  # same shape, new pose: a translation
        intake.submit(serialize_message(markers(moved)), 6.0)
        second = intake.process()
        assert second.received == 6.0 and second.obstacles.base is first.obstacles.base
        np.testing.assert_allclose(second.obstacles.footprints.vertices[0, :4, 0] -
                                   first.obstacles.footprints.vertices[0, :4, 0], 0.5)
        for k in range(1, 21):  # speeding up along x: the acceleration crosses the seam too
            moved.pose.position.x = 0.5 + 0.5 * (0.1 * k) ** 2
            moved.header.stamp.sec, moved.header.stamp.nanosec = 10 + k // 10, k % 10 * 10 ** 8
            intake.submit(serialize_message(markers(moved)), 6.0 + 0.1 * k)
            last = intake.process()
        assert last.obstacles.base is first.obstacles.base
        assert last.obstacles.accelerations[0, 0] == pytest.approx(1.0, abs=0.2)
    finally:
        intake.stop()


def test_a_dead_worker_leaves_the_input_unusable():
    """The worker process killed: every later snapshot says so, and none is usable."""
    intake = _intake()
    intake.start()
    try:
        intake.submit(serialize_message(markers(_square(1))), 1.0)
        assert intake.process().usable
        intake._worker.kill()
        intake._worker.wait()
        intake.submit(serialize_message(markers(_square(1))), 2.0)
        snapshot = intake.process()
        assert not snapshot.usable and 'worker process failed' in snapshot.error
        intake.submit(serialize_message(markers(_square(2))), 3.0)
        assert not intake.process().usable
    finally:
        intake.stop()
