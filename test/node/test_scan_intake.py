"""LaserScans in the obstacle pipeline, without DDS: checks, frames, and marker + scan sets."""
import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from sensor_msgs.msg import LaserScan

from node_harness import markers, wall
from polyc2bf_ros.core.barrier.obstacle_geometry import ObstacleGeometry, SCAN_BODY_MARGIN
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline, read_scan
from polyc2bf_ros.obstacle_settings import IntakeSettings
from test_node_scan import _scan

SPEC = ObstacleGeometry(make_model('unicycle'), FilterConfig())
ODOMETRY = ((0.0, 0.0, 0.0, 0.0),)  # one sample (stamp, x, y, yaw): at the origin


def _obstacles(*arguments):
    """Return the obstacles ``read_scan(*arguments)`` makes of a serialized scan."""
    return read_scan(*arguments).obstacles


def _data(**kwargs):
    return serialize_message(_scan(**kwargs))


def test_bad_scans_are_refused_with_the_reason():
    """No odometry, NaN angles, mismatched intensities, all-NaN ranges: ValueError."""
    settings = IntakeSettings()
    with pytest.raises(ValueError, match='no odometry'):
        _obstacles(_data(wall_x=1.0), (), 'base_link', settings, 0.3)
    msg = _scan(wall_x=1.0)
    msg.angle_increment = math.nan
    with pytest.raises(ValueError, match='angle_increment'):
        _obstacles(serialize_message(msg), ODOMETRY, 'base_link', settings, 0.3)
    msg = _scan(wall_x=1.0)
    msg.intensities = [1.0, 2.0]
    with pytest.raises(ValueError, match='intensities'):
        _obstacles(serialize_message(msg), ODOMETRY, 'base_link', settings, 0.3)
    with pytest.raises(ValueError, match='all NaN'):
        _obstacles(_data(nan=True), ODOMETRY, 'base_link', settings, 0.3)
    with pytest.raises(ValueError, match='malformed'):
        _obstacles(b'\x00\x01\x00\x00\x01', ODOMETRY, 'base_link', settings, 0.3)


def test_sensor_pose_applies_to_scans_in_another_frame():
    """A scan in the base frame is at the base; in ``laser`` it is at ``sensor_pose``."""
    settings = IntakeSettings(sensor_pose=(0.5, 0.0, 0.0))
    at_base = _obstacles(_data(wall_x=1.0), ODOMETRY, 'base_link', settings, 0.3)
    at_sensor = _obstacles(_data(wall_x=1.0, frame='laser'), ODOMETRY, 'base_link', settings,
                               0.3)
    assert at_base and at_sensor
    assert min(o.polygon[:, 0].min() for o in at_base) == pytest.approx(1.0, abs=0.06)
    assert min(o.polygon[:, 0].min() for o in at_sensor) == pytest.approx(1.5, abs=0.06)



def test_returns_inside_the_footprint_are_the_robot_itself():
    """By default hits within ``robot_radius`` of the base are dropped, farther ones kept.

    A wall 0.28 m ahead: behind its nearest point no polygon of a 0.3 m robot, one of a
    0.2 m robot.
    """
    behind = np.array([0.285, 0.0])

    def covers(polygon):
        edges, rel = np.roll(polygon, -1, axis=0) - polygon, behind - polygon
        return (edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0] >= 0).all()
    for radius, seen in ((0.3, False), (0.2, True)):
        obstacles = _obstacles(_data(wall_x=0.28), ODOMETRY, 'base_link', IntakeSettings(),
                                   radius)
        assert obstacles and any(covers(o.polygon) for o in obstacles) is seen

def _covers(polygon, point):
    """Return True when a CCW convex polygon contains the point (or has it on its boundary)."""
    edges, rel = np.roll(polygon, -1, axis=0) - polygon, np.asarray(point) - polygon
    return bool((edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0] >= 0).all())


@pytest.mark.parametrize('barrier, wall_x, seen', [
    ('polyc2bf_footprint', 0.244, True), ('polyc2bf_footprint', 0.19, True),
    ('polyc2bf_footprint', 0.18, False), ('polyc2bf_horizon', 0.3, False)])
def test_a_box_guarded_as_itself_drops_only_returns_well_inside_it(barrier, wall_x, seen):
    """A wall ``wall_x`` ahead of a Jackal's centre (its nose at 0.254 m).

    Guarded as its box, only returns within the disc inside it less ``SCAN_BODY_MARGIN``
    (0.185 m) are the robot's own: a scan placed at a pose a moment stale puts an obstacle
    the box stands 2 mm from a little inside it, and a wall 1 cm inside its nose is seen.
    Guarded as its covering disc, everything within 0.333 m is the robot.
    """
    jackal = '[[-0.254, -0.215], [0.254, -0.215], [0.254, 0.215], [-0.254, 0.215]]'
    geometry = ObstacleGeometry(make_model('unicycle'),
                                FilterConfig(footprint=jackal, barrier=barrier))
    assert geometry.own_radius == pytest.approx(
        0.215 - SCAN_BODY_MARGIN if barrier == 'polyc2bf_footprint' else np.hypot(0.254, 0.215))
    snapshot = ObstaclePipeline().run(ObstacleJob([], 'odom', IntakeSettings(), geometry, 1.0, (
        ('scan', _data(wall_x=wall_x), 1.0, ODOMETRY, 'base_link'),)))
    polygons = snapshot.obstacles.footprints.vertices  # padded: repeated corners
    assert any(_covers(polygon, (wall_x + 0.005, 0.0)) for polygon in polygons) is seen


@pytest.mark.parametrize('depth', [0.05, 0.3])
def test_scan_obstacle_depth_sets_how_far_obstacles_reach_behind_the_wall(depth):
    """A wall at x = 1 m: its obstacles end ``scan_obstacle_depth`` beyond it."""
    settings = IntakeSettings(scan_obstacle_depth=depth)
    obstacles = _obstacles(_data(wall_x=1.0), ODOMETRY, 'base_link', settings, 0.3)
    assert obstacles
    assert max(o.polygon[:, 0].max() for o in obstacles) == pytest.approx(1.0 + depth, abs=0.01)


def _post_scan(centre, radius, beams=720, field_of_view=1.5 * math.pi):
    """Return a serialized scan from the base of a post (a circle): BARN's Hokuyo by default."""
    msg = LaserScan()
    msg.header.frame_id = 'base_link'
    msg.angle_min, msg.angle_increment = -0.5 * field_of_view, field_of_view / (beams - 1)
    msg.angle_max = msg.angle_min + (beams - 1) * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 30.0
    angles = msg.angle_min + msg.angle_increment * np.arange(beams)
    along = np.cos(angles) * centre[0] + np.sin(angles) * centre[1]
    square = along ** 2 - (centre[0] ** 2 + centre[1] ** 2 - radius ** 2)
    hit = (square > 0.0) & (along > 0.0)
    msg.ranges = np.where(hit, along - np.sqrt(np.where(hit, square, 0.0)), np.inf).tolist()
    return serialize_message(msg)


@pytest.mark.parametrize('centre', [(1.0, 0.0), (1.5, 0.8), (2.0, -0.5)])
def test_scan_split_tolerance_sets_how_closely_a_post_is_outlined(centre):
    """A smaller ``scan_split_tolerance`` outlines a BARN post (7.5 cm radius) more closely.

    A piece's near corners stand off the post by up to the sagitta of the arc it spans; a
    smaller tolerance splits the arc into more pieces, each nearer the surface.
    """
    radius, standoffs, counts = 0.075, {}, {}
    for split in (0.05, 0.01):
        obstacles = _obstacles(_post_scan(centre, radius), ODOMETRY, 'base_link',
                               IntakeSettings(scan_split_tolerance=split), 0.3)
        corners = np.vstack([o.polygon for o in obstacles])
        near = np.linalg.norm(corners, axis=1) < np.hypot(*centre)  # the lit side's corners
        standoffs[split] = float((np.linalg.norm(corners[near] - centre, axis=1) - radius).max())
        counts[split] = len(obstacles)
    assert standoffs[0.01] < 0.004 < standoffs[0.05]
    assert counts[0.01] > counts[0.05]


def test_a_scan_is_placed_at_the_odometry_interpolated_to_its_stamp():
    """Odometry at x = 0, 1, 2 (stamps 10, 11, 12 s): a scan at 11.4 s is taken at x = 1.4.

    One stamped before the oldest sample is taken there; an unstamped scan (stamp 0) at the
    latest odometry.
    """
    odometry = ((10.0, 0.0, 0.0, 0.0), (11.0, 1.0, 0.0, 0.0), (12.0, 2.0, 0.0, 0.0))
    settings = IntakeSettings()

    def wall_x(**kwargs):
        obstacles = _obstacles(_data(wall_x=1.0, **kwargs), odometry, 'base_link',
                                   settings, 0.3)
        return min(o.polygon[:, 0].min() for o in obstacles)

    assert wall_x(stamp=Time(sec=11, nanosec=400_000_000)) == pytest.approx(2.4, abs=0.06)
    assert wall_x(stamp=Time(sec=9)) == pytest.approx(1.0, abs=0.06)
    assert wall_x() == pytest.approx(3.0, abs=0.06)


def test_pipeline_combines_markers_and_scans_and_keeps_a_topic_on_a_bad_scan():
    """Keys prefixed by the topic; a rejected scan keeps the topic's obstacles and counts."""
    pipeline = ObstaclePipeline()
    marker = serialize_message(markers(wall([(5.0, -1.0), (5.0, 1.0)])))
    job = ObstacleJob([(marker, 1.0)], 'odom', IntakeSettings(), SPEC, 1.0,
                      (('scan', _data(wall_x=1.0), 1.0, ODOMETRY, 'base_link'),))
    snapshot = pipeline.run(job)
    keys = snapshot.obstacles.keys
    assert 'walls/0' in keys and any(k.startswith('scan:scan/') for k in keys)
    assert pipeline.scan_status['scan'].accepted == 1.0 and snapshot.usable
    view, = snapshot.views  # what the laser saw, for the route (``escape_route``)
    assert (view.x, view.y) == pytest.approx(ODOMETRY[0][1:3]) and view.ranges is not None
    bad = ObstacleJob([], 'odom', IntakeSettings(), SPEC, 2.0,
                      (('scan', _data(nan=True), 2.0, ODOMETRY, 'base_link'),))
    again = pipeline.run(bad)
    assert again.obstacles.keys == keys and again.views == snapshot.views
    status = pipeline.scan_status['scan']
    assert (status.accepted, status.received, status.rejected) == (1.0, 2.0, 1)


@pytest.mark.parametrize('keep_time', [10.0, 0.0])
def test_a_wall_that_passes_behind_a_half_turn_laser_is_kept(keep_time):
    """A wall 0.5 m ahead, then the robot turns about: the laser (180 degrees) sees nothing.

    With ``scan_memory_time`` the wall stays an obstacle where it was; 0: it is forgotten.
    """
    pipeline = ObstaclePipeline()
    settings = IntakeSettings(scan_memory_time=keep_time)
    for t, yaw, wall_x in ((1.0, 0.0, 0.5), (1.1, math.pi, None)):
        snapshot = pipeline.run(ObstacleJob([], 'odom', settings, SPEC, t, (
            ('scan', _data(wall_x=wall_x), t, ((t, 0.0, 0.0, yaw),), 'base_link'),)))
    obstacles = snapshot.obstacles
    kept = [polygon for polygon, owner in zip(obstacles.footprints.vertices, obstacles.owner)
            if obstacles.keys[owner].startswith('scan:memory/')]
    assert any(_covers(polygon, (0.505, 0.0)) for polygon in kept) is (keep_time > 0)


@pytest.mark.parametrize('tracking', [True, False])
def test_a_box_coming_at_the_robot_gets_its_velocity_only_when_tracked(tracking):
    """A 0.5 m box coming at a standing robot at 1 m/s from 3 m, scanned at 10 Hz.

    Tracked, its obstacles carry about (-1, 0) m/s once the track is moving (the fourth scan
    on); untracked (``scan_tracking: false``) they stand still.  The set is stamped with
    the scan's stamp, so the filter extrapolates it to the odometry's.
    """
    from test_nav2_chain import scan as box_scan
    pipeline, settings = ObstaclePipeline(), IntakeSettings(scan_tracking=tracking)
    for k in range(10):
        t = 10.0 + 0.1 * k
        x = 3.0 - 1.0 * (t - 10.0)
        msg = box_scan(box=(x, -0.25, x + 0.5, 0.25))
        msg.header.stamp = Time(sec=int(t), nanosec=round((t % 1.0) * 1e9))
        odometry = ((t, 0.0, 0.0, 0.0),)
        snapshot = pipeline.run(ObstacleJob([], 'odom', settings, SPEC, t, (
            ('scan', serialize_message(msg), t, odometry, 'base_link'),)))
    velocities = snapshot.obstacles.velocities
    assert len(velocities) and snapshot.t_ref == pytest.approx(10.9)
    if tracking:
        np.testing.assert_allclose(velocities[:, :2], [[-1.0, 0.0]] * len(velocities),
                                   atol=0.15)
    else:
        assert not velocities.any()


def test_the_worker_prepares_the_views_the_filter_steps_on():
    """The pipeline prepares the views of the geometry it is handed: the filter's own.

    A filter whose model is off its defaults (diff drive: offset_l 0.01) gets its views.
    """
    safety_filter = SafetyFilter(make_model('unicycle', offset_l=0.01), FilterConfig())
    assert safety_filter.geometry != SPEC  # another guard radius: other views
    marker = serialize_message(markers(wall([(5.0, -1.0), (5.0, 1.0)])))
    snapshot = ObstaclePipeline().run(ObstacleJob([(marker, 1.0)], 'odom', IntakeSettings(),
                                                  safety_filter.geometry, 1.0))
    prepared = snapshot.obstacles.base or snapshot.obstacles  # a translation: its base
    assert len(prepared) and safety_filter.geometry.key in prepared.geometry
    assert SPEC.key not in prepared.geometry
