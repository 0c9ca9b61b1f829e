"""What a laser with a blind sector keeps of what it saw (``core/obstacles/scan_memory.py``)."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.obstacles.scan_conversion import beam_endpoints, ScanSettings
from polyc2bf_ros.core.obstacles.scan_memory import ScanMemory, ScanView
from scan_simulator import simulate_ranges

SETTINGS = ScanSettings()


def _scanner(fov, beams=540):
    """Return (angle_min, increment) of a scan of ``beams`` beams over ``fov`` [rad]."""
    increment = fov / (beams - 1) if fov < 2 * math.pi else fov / beams
    return -0.5 * fov, increment


def _look(memory, stamp, yaw, fov, circles, position=(0.0, 0.0), keep=True):
    """Scan ``circles`` from ``position`` facing ``yaw``; return (obstacles, endpoints seen)."""
    angle_min, increment = _scanner(fov)
    beams = 540
    pose = (*position, yaw)
    ranges = simulate_ranges(pose, beams, angle_min, increment, 10.0, circles=circles)
    points = beam_endpoints(ranges, angle_min, increment, 0.05, 10.0, (0.0, 0.0, 0.0), pose)
    points = points[np.isfinite(points).all(axis=1)]
    view = ScanView(*position, yaw, angle_min, angle_min + (beams - 1) * increment, increment,
                    0.05, 10.0, position, ranges)
    obstacles = memory.update(stamp, view, points if keep else np.zeros((0, 2)), SETTINGS)
    return obstacles, points


def _inside(polygon, point, tolerance=1e-9):
    """Return True when a CCW convex polygon holds ``point`` (or has it on its boundary)."""
    edges, rel = np.roll(polygon, -1, axis=0) - polygon, np.asarray(point) - polygon
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    return bool(((edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0]) / lengths
                 >= -tolerance).all())


@given(fov=st.floats(0.5 * math.pi, 1.8 * math.pi), bearing=st.floats(-math.pi, math.pi),
       distance=st.floats(0.4, 1.2), radius=st.floats(0.05, 0.2),
       turn=st.floats(0.0, 1.0))
def test_a_post_that_leaves_the_view_is_kept_until_the_view_covers_it_again(
        fov, bearing, distance, radius, turn):
    """A post seen ahead is turned into the blind sector, then back into view.

    Out of view, every endpoint the laser saw of it lies in an obstacle the memory gives;
    in view again, the memory gives nothing (the scan sees it itself).
    """
    post = ((distance * math.cos(bearing), distance * math.sin(bearing)), radius)
    blind = 2 * math.pi - fov
    half = math.asin(radius / distance) + 2 * fov / 539
    if blind <= 2 * half:
        return  # the post does not fit in the blind sector
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    obstacles, seen = _look(memory, 0.0, bearing, fov, [post])
    assert not obstacles and len(seen)
    behind = bearing + math.pi + (turn - 0.5) * (blind - 2 * half)  # anywhere in the blind
    obstacles, _ = _look(memory, 0.1, behind, fov, [post], keep=False)
    assert obstacles
    for point in seen:
        assert any(_inside(o.polygon, point) for o in obstacles), point
    assert len(memory) == 2 * len(seen)  # with their backs
    obstacles, _ = _look(memory, 0.2, bearing, fov, [post])
    assert not obstacles and not len(memory)


def _post_behind(memory, position=(0.0, 0.0), stamp=0.1, distance=0.6):
    """See a post ahead at ``stamp - 0.1``, turn about; return the obstacles kept of it."""
    post = ((position[0] + distance, position[1]), 0.1)
    _look(memory, stamp - 0.1, 0.0, 1.5 * math.pi, [post], position)
    return _look(memory, stamp, math.pi, 1.5 * math.pi, [post], position, keep=False)[0]


def test_what_is_near_is_kept_and_drawn_and_what_is_far_ages_out():
    """A post 0.6 m away is drawn only within ``reach``; it ages out once also farther.

    Held beside it, out of view, for longer than ``keep_time``, the robot still has it;
    once the robot is farther than ``reach`` from it, a post older than ``keep_time`` is
    dropped.
    """
    assert _post_behind(ScanMemory(keep_time=1.0, reach=1.0))
    assert not _post_behind(ScanMemory(keep_time=1.0, reach=0.5))
    memory = ScanMemory(keep_time=1.0, reach=1.0)
    assert _post_behind(memory)
    view = ScanView(0.0, 0.0, math.pi, -0.75 * math.pi, 0.75 * math.pi, 0.01, 0.05, 10.0,
                    (0.0, 0.0))
    assert memory.update(0.9, view, np.zeros((0, 2)), SETTINGS)
    assert memory.update(30.0, view, np.zeros((0, 2)), SETTINGS) and len(memory)
    away = view._replace(x=-1.0, base=(-1.0, 0.0))
    assert not memory.update(30.1, away, np.zeros((0, 2)), SETTINGS) and not len(memory)


def test_a_post_seen_beyond_reach_is_drawn_once_the_robot_backs_within_reach():
    """Seen 1.6 m ahead, the post leaves the view; backing towards it brings it back."""
    memory = ScanMemory(keep_time=5.0, reach=1.0)
    post = ((1.6, 0.0), 0.1)
    _look(memory, 0.0, 0.0, 1.5 * math.pi, [post])
    assert not _look(memory, 0.1, math.pi, 1.5 * math.pi, [post], keep=False)[0]
    assert len(memory)
    obstacles, _ = _look(memory, 0.2, math.pi, 1.5 * math.pi, [post], (0.8, 0.0), keep=False)
    assert obstacles and all(o.polygon[:, 0].min() > 1.4 for o in obstacles)


def test_a_laser_that_sees_all_round_keeps_nothing():
    """A full-turn scan has no blind sector: nothing to remember."""
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    post = ((0.6, 0.0), 0.1)
    _look(memory, 0.0, 0.0, 2 * math.pi, [post])
    obstacles, _ = _look(memory, 0.1, math.pi, 2 * math.pi, [post])
    assert not obstacles and not len(memory)


@pytest.mark.parametrize('keep_time, reach', [(0.0, 1.0), (1.0, -1.0), (math.nan, 1.0),
                                              (1.0, math.inf)])
def test_bad_settings_are_refused(keep_time, reach):
    """Times and reaches must be finite and positive."""
    with pytest.raises(ValueError, match='keep_time|reach'):
        ScanMemory(keep_time, reach)


def test_what_is_kept_is_drawn_as_the_laser_would_see_it_from_here():
    """Two points kept on one bearing behind the laser: only the nearer makes an obstacle."""
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    ahead = ScanView(0.0, 0.0, 0.0, -0.75 * math.pi, 0.75 * math.pi, 0.01, 0.05, 10.0,
                     (0.0, 0.0))
    memory.update(0.0, ahead, np.array([[-0.5, 0.0], [-0.8, 0.0]]), SETTINGS)
    obstacles = memory.update(0.1, ahead, np.zeros((0, 2)), SETTINGS)
    assert len(memory) == 4  # with their backs, SETTINGS.depth farther along the bearing
    assert any(_inside(o.polygon, (-0.5, 0.0)) for o in obstacles)
    assert not any(_inside(o.polygon, (-0.8, 0.0)) for o in obstacles)


def test_a_post_hidden_behind_a_nearer_one_is_kept_until_it_is_seen_again():
    """A post seen from the south is hidden behind a nearer post, then left behind the robot.

    While hidden no beam reaches it, so it is kept: in the blind sector it is still drawn.
    A beam that reaches where it was seen drops it.
    """
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    near, far = ((0.5, 0.0), 0.1), ((1.0, 0.0), 0.05)
    _, seen = _look(memory, 0.0, 0.5 * math.pi, 1.5 * math.pi, [near, far], (1.0, -0.6))
    seen = seen[np.hypot(seen[:, 0] - 1.0, seen[:, 1]) < 0.06]  # the far post's endpoints
    assert len(seen)
    _look(memory, 0.1, 0.0, 1.5 * math.pi, [near, far])  # hidden behind the near post
    north = (1.0, 0.5)  # the far post straight behind, in the blind sector
    obstacles, _ = _look(memory, 0.2, 0.5 * math.pi, 1.5 * math.pi, [near, far], north,
                         keep=False)
    for point in seen:
        assert any(_inside(o.polygon, point) for o in obstacles), point
    _look(memory, 0.3, 0.0, 1.5 * math.pi, [far], keep=False)  # the near post is gone
    obstacles, _ = _look(memory, 0.4, 0.5 * math.pi, 1.5 * math.pi, [far], north, keep=False)
    assert not any(_inside(o.polygon, point) for o in obstacles for point in seen)


def test_what_stays_in_view_is_not_kept_even_with_a_deep_depth():
    """A post in view, scan after scan: its points and their backs are dropped as seen.

    A back lies ``depth`` behind its lit surface, which stops the beams that far short of
    it; with ``depth`` above ``cluster_tolerance`` that must not count as hidden.
    """
    deep = ScanSettings(depth=0.3)
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    post = ((0.8, 0.1), 0.1)
    angle_min, increment = _scanner(1.5 * math.pi)
    view = ScanView(0.0, 0.0, 0.0, angle_min, angle_min + 539 * increment, increment, 0.05,
                    10.0, (0.0, 0.0),
                    simulate_ranges((0.0, 0.0, 0.0), 540, angle_min, increment, 10.0,
                                    circles=[post]))
    points = beam_endpoints(view.ranges, angle_min, increment, 0.05, 10.0, (0.0, 0.0, 0.0),
                            (0.0, 0.0, 0.0))
    points = points[np.isfinite(points).all(axis=1)]
    for stamp in (0.0, 0.1, 0.2):
        assert not memory.update(stamp, view, points, deep)
    assert not len(memory)


def test_a_post_kept_from_its_far_side_is_still_covered_on_the_side_facing_the_robot():
    """A post lit from the north, then behind the laser of a robot south-east of it.

    Its side facing the robot was never lit; the obstacles drawn of what was kept still
    cover the post's point nearest the robot, since the post's body lies behind the
    surface the beams lit, seen from where they were cast (the kept backs).
    """
    memory = ScanMemory(keep_time=5.0, reach=2.0)
    post = ((0.0, 0.0), 0.075)
    _look(memory, 0.0, -0.5 * math.pi, 1.5 * math.pi, [post], (0.0, 1.0))
    robot = np.array([0.35, -0.2])
    away = math.atan2(robot[1], robot[0])  # facing away from the post: it is in the blind
    obstacles, _ = _look(memory, 0.1, away, 1.5 * math.pi, [post], tuple(robot), keep=False)
    assert obstacles
    nearest = 0.075 * robot / np.linalg.norm(robot)
    assert any(_inside(o.polygon, nearest, tolerance=0.005) for o in obstacles)


def test_seen_through_is_the_empty_space_in_front_of_the_returns():
    """A point is seen through where the beams either side reach past it by the tolerance.

    A post 2 m ahead: a point 1 m ahead or 0.1 m in front of its face is in empty space, one
    on the face or behind it (hidden) is not, nor one in the blind sector or beyond the
    range; a beam without a return passed (a point 5 m off the post's bearing is seen
    through).
    """
    post = ((2.0, 0.0), 0.2)
    angle_min, increment = _scanner(1.5 * math.pi)
    ranges = simulate_ranges((0.0, 0.0, 0.0), 540, angle_min, increment, 10.0, circles=[post])
    view = ScanView(0.0, 0.0, 0.0, angle_min, angle_min + 539 * increment, increment, 0.05,
                    10.0, (0.0, 0.0), ranges)
    points = np.array([[1.0, 0.0], [1.8, 0.0], [1.7, 0.0], [3.0, 0.0], [-2.0, 0.0],
                       [0.0, 5.0], [0.0, 11.0]])
    through = view.seen_through(*view.bearings(points), 0.05)
    assert through.tolist() == [True, False, True, False, False, True, False]
    assert not view.seen_through(*view.bearings(points[2:3]), 0.15)[0]  # 0.1 m in front
    unseen = view.unseen(*view.bearings(points), 0.05)
    assert not (through & unseen).any()
