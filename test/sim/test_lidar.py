"""Simulated lidar: distances, misses, the robot's own body, angles, noise, settings, messages."""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pybullet as pb
import pybullet_data
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores

from sim_bridge.cdr import tf_message_cdr, TF_MESSAGE_TYPE
from sim_bridge.lidar import laser_scan, Lidar, LidarSettings, mount_transform
from sim_bridge.plants import A1_STANDING_POSE, A1_URDF

REPO = Path(__file__).resolve().parents[2]
WALL_X = 2.0        # m, the near face of the test wall (normal -x)
WALL_HALF_Y = 3.0   # m, the wall spans |y| <= this


@pytest.fixture
def client():
    """Yield a fresh PyBullet DIRECT client, disconnected afterwards."""
    client = pb.connect(pb.DIRECT)
    yield client
    pb.disconnect(physicsClientId=client)


def _box(client, half, position, mass=0.0):
    """Return a box body of half extents ``half`` centred at ``position``."""
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    return pb.createMultiBody(mass, shape, basePosition=position, physicsClientId=client)


def _wall(client, y_range=(-WALL_HALF_Y, WALL_HALF_Y)):
    """Return a 2 m tall wall with its near face at x = WALL_X over ``y_range``."""
    low, high = y_range
    return _box(client, (0.1, 0.5 * (high - low), 1.0), (WALL_X + 0.1, 0.5 * (low + high), 1.0))


def _room(client, half=3.0):
    """Build four walls enclosing the square |x|, |y| < ``half``."""
    for x, y, hx, hy in ((half + 0.1, 0, 0.1, half + 0.2), (-half - 0.1, 0, 0.1, half + 0.2),
                         (0, half + 0.1, half + 0.2, 0.1), (0, -half - 0.1, half + 0.2, 0.1)):
        _box(client, (hx, hy, 1.0), (x, y, 1.0))


def test_wall_distances_account_for_the_mount_pose(client):
    """Beams at the wall read the exact distance from the mounted sensor; the rest read +inf."""
    wall = _wall(client)
    settings = LidarSettings(beams=360, mount=(0.3, 0.1, -0.5), height=0.2)
    x, y, z, yaw = 0.5, -0.2, 0.1, 0.4
    scan = Lidar(client, settings=settings).scan((x, y, z, yaw))
    origin = np.array([x + 0.3 * math.cos(yaw) - 0.1 * math.sin(yaw),
                       y + 0.3 * math.sin(yaw) + 0.1 * math.cos(yaw), z + 0.2])
    np.testing.assert_allclose(scan.origin, origin, atol=1e-12)
    world_angles = yaw - 0.5 + np.linspace(-math.pi, math.pi, 360, endpoint=False)
    cos, sin = np.cos(world_angles), np.sin(world_angles)
    with np.errstate(divide='ignore'):
        distance = np.where(cos > 0, (WALL_X - origin[0]) / cos, np.inf)
    wall_y = origin[1] + distance * sin
    hit = (distance <= settings.range_max) & (np.abs(wall_y) < WALL_HALF_Y - 0.01)
    miss = (distance > settings.range_max) | (np.abs(wall_y) > WALL_HALF_Y + 0.01)
    assert hit.sum() > 50 and miss.sum() > 150
    np.testing.assert_allclose(scan.ranges[hit], distance[hit], atol=1e-3)
    assert (scan.bodies[hit] == wall).all()
    assert np.isposinf(scan.ranges[miss]).all()
    assert (scan.bodies[miss] == -1).all()
    assert scan.ranges.dtype == np.float32


def test_open_space_reads_inf_and_the_plane_passes_over_low_obstacles(client):
    """Nothing in the scan plane: every beam is +inf, over a ground slab and a low box."""
    _box(client, (20.0, 20.0, 0.05), (0.0, 0.0, -0.05))   # ground, top at z = 0
    low = _box(client, (0.2, 0.2, 0.1), (1.0, 0.0, 0.1))  # 0.2 m tall
    pose = (0.0, 0.0, 0.15, 0.0)
    above = Lidar(client, settings=LidarSettings(height=0.1)).scan(pose)
    assert np.isposinf(above.ranges).all()
    assert (above.bodies == -1).all()
    below = Lidar(client, settings=LidarSettings(height=0.0)).scan(pose)
    assert below.ranges[180] == pytest.approx(0.8, abs=1e-3)
    assert below.bodies[180] == low


def _legged_robot(client):
    """Return a robot body: a base box at the origin and fixed 'legs' ahead and behind.

    Along the +x axis at z = 0.15 a ray from the base meets two legs (x 0.45..0.55 and
    0.75..0.85) and behind it one (x -0.65..-0.55).
    """
    leg = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=(0.05, 0.05, 0.15),
                                  physicsClientId=client)
    base = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=(0.3, 0.2, 0.15),
                                   physicsClientId=client)
    offsets = [(0.5, 0.0, 0.0), (0.8, 0.0, 0.0), (-0.6, 0.0, 0.0)]
    count = len(offsets)
    return pb.createMultiBody(
        1.0, base, basePosition=(0.0, 0.0, 0.15), linkMasses=[0.1] * count,
        linkCollisionShapeIndices=[leg] * count, linkVisualShapeIndices=[-1] * count,
        linkPositions=offsets, linkOrientations=[(0, 0, 0, 1)] * count,
        linkInertialFramePositions=[(0, 0, 0)] * count,
        linkInertialFrameOrientations=[(0, 0, 0, 1)] * count, linkParentIndices=[0] * count,
        linkJointTypes=[pb.JOINT_FIXED] * count, linkJointAxis=[(0, 0, 1)] * count,
        physicsClientId=client)


def test_the_robots_own_bodies_are_never_hit(client):
    """A sensor inside its base sees through its legs and payload to the wall, and only there.

    The same scan without ``ignore`` does hit them, so the setup really blocks the beams.
    """
    wall = _wall(client)
    robot = _legged_robot(client)
    payload = _box(client, (0.1, 0.1, 0.1), (0.1, 0.6, 0.15), mass=1.0)
    settings = LidarSettings(beams=360, mount=(0.1, 0.0, 0.0), height=0.0)
    pose = (0.0, 0.0, 0.15, 0.0)
    blind = Lidar(client, settings=settings).scan(pose)
    assert blind.ranges[180] == pytest.approx(0.35, abs=1e-3)  # the first leg's near face
    assert {robot, payload} <= set(blind.bodies.tolist())
    scan = Lidar(client, (robot, payload), settings).scan(pose)
    assert set(scan.bodies.tolist()) <= {wall, -1}
    assert scan.ranges[180] == pytest.approx(WALL_X - 0.1, abs=1e-3)  # through both legs
    assert np.isposinf(scan.ranges[0])                                # through the rear leg
    assert np.isposinf(scan.ranges[270])                              # through the payload
    assert np.isfinite(scan.ranges).sum() > 50
    one = Lidar(client, robot, settings).scan(pose)
    assert robot not in one.bodies and one.bodies[270] == payload


@pytest.mark.parametrize('height', [0.0, -0.12])
def test_a_quadrupeds_own_links_are_seen_through(client, height):
    """A standing A1 scanning from its base (trunk, hips, thighs; or thighs and calves).

    Never its links, the wall beyond them; without ``ignore`` its links are hit.
    """
    pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
    wall = _wall(client)
    a1 = pb.loadURDF(A1_URDF, (0.0, 0.0, 0.3), flags=pb.URDF_MERGE_FIXED_LINKS,
                     physicsClientId=client)
    for joint in range(pb.getNumJoints(a1, physicsClientId=client)):  # hip, thigh, calf
        pb.resetJointState(a1, joint, A1_STANDING_POSE[joint % 3], physicsClientId=client)
    settings = LidarSettings(beams=720, height=height)
    pose = (0.0, 0.0, 0.3, 0.0)
    assert (Lidar(client, settings=settings).scan(pose).bodies == a1).sum() > 50
    scan = Lidar(client, a1, settings).scan(pose)
    assert set(scan.bodies.tolist()) <= {wall, -1}
    angles = settings.angles()
    ahead = np.abs(angles) < 0.5
    np.testing.assert_allclose(scan.ranges[ahead], WALL_X / np.cos(angles[ahead]), atol=1e-3)
    assert np.isposinf(scan.ranges[~(np.abs(angles) < 1.0)]).all()


@pytest.mark.parametrize('settings, increment, angle_max', [
    (LidarSettings(beams=360), 2 * math.pi / 360, math.pi - 2 * math.pi / 360),
    (LidarSettings(beams=1081, field_of_view=1.5 * math.pi), 1.5 * math.pi / 1080,
     0.75 * math.pi),
    (LidarSettings(beams=3, field_of_view=0.5 * math.pi), 0.25 * math.pi, 0.25 * math.pi),
    (LidarSettings(beams=1, field_of_view=1.0), 1.0, -0.5),
])
def test_angle_fields_follow_laser_scan(client, settings, increment, angle_max):
    """angle_min = -fov/2; increment fov/beams (full circle) or fov/(beams-1); one range a beam."""
    assert settings.angle_min == pytest.approx(-0.5 * settings.field_of_view, abs=1e-12)
    assert settings.angle_increment == pytest.approx(increment, abs=1e-12)
    assert settings.angle_max == pytest.approx(angle_max, abs=1e-12)
    assert settings.angle_max == pytest.approx(
        settings.angle_min + (settings.beams - 1) * settings.angle_increment, abs=1e-12)
    angles = settings.angles()
    assert angles[0] == settings.angle_min and angles[-1] == pytest.approx(angle_max, abs=1e-12)
    scan = Lidar(client, settings=settings).scan((0.0, 0.0, 0.0, 0.0))
    assert len(scan.ranges) == settings.beams == len(laser_scan(scan, Time()).ranges)


def test_beam_angles_increase_counter_clockwise(client):
    """Three beams over 90 deg: the last (angle_max, +45 deg) is the left one."""
    left = _wall(client, y_range=(0.5, WALL_HALF_Y))
    settings = LidarSettings(beams=3, field_of_view=0.5 * math.pi)
    scan = Lidar(client, settings=settings).scan((0.0, 0.0, 0.5, 0.0))
    assert np.isposinf(scan.ranges[:2]).all()
    assert scan.ranges[2] == pytest.approx(WALL_X * math.sqrt(2.0), abs=1e-3)
    assert scan.bodies[2] == left


def test_noise_has_the_set_spread_and_is_reproducible(client):
    """1000 returns: noise std within 30 % of noise_std, mean ~0; same seed, same scan."""
    _room(client)
    pose = (0.2, -0.3, 0.5, 0.1)
    clean = Lidar(client, settings=LidarSettings(beams=1000)).scan(pose).ranges
    assert np.isfinite(clean).all()
    noisy_settings = LidarSettings(beams=1000, noise_std=0.05)
    noisy = Lidar(client, settings=noisy_settings, seed=7).scan(pose).ranges
    error = noisy.astype(float) - clean
    assert 0.7 * 0.05 < error.std() < 1.3 * 0.05
    assert abs(error.mean()) < 0.01
    again = Lidar(client, settings=noisy_settings, seed=7).scan(pose).ranges
    np.testing.assert_array_equal(noisy, again)
    other = Lidar(client, settings=noisy_settings, seed=8).scan(pose).ranges
    assert not np.array_equal(noisy, other)


def test_noise_leaves_misses_inf_and_clips_at_zero(client):
    """Beams without a return stay +inf with noise; a noisy return is never negative."""
    noisy = LidarSettings(beams=200, field_of_view=0.1, noise_std=0.5, range_min=0.0)
    assert np.isposinf(Lidar(client, settings=noisy).scan((0.0, 0.0, 0.0, 0.0)).ranges).all()
    _wall(client)
    ranges = Lidar(client, settings=noisy).scan((WALL_X - 0.02, 0.0, 0.5, 0.0)).ranges
    assert np.isfinite(ranges).all() and (ranges >= 0.0).all()
    assert (ranges == 0.0).sum() > 50


@pytest.mark.parametrize('field, value', [
    ('beams', 0), ('beams', 4097), ('beams', 2.5), ('beams', True),
    ('field_of_view', 0.0), ('field_of_view', -1.0), ('field_of_view', 2 * math.pi + 0.01),
    ('field_of_view', math.nan), ('range_min', -0.1), ('range_max', 0.05),
    ('range_max', math.inf), ('rate', 0.0), ('noise_std', -0.01), ('height', math.nan),
    ('mount', (0.0, 0.0)), ('mount', (0.0, 0.0, 'a')), ('mount', 1.0), ('frame_id', ''),
])
def test_invalid_settings_name_the_field(client, field, value):
    """validate() and Lidar() raise ValueError naming the bad field."""
    settings = LidarSettings(**{field: value})
    with pytest.raises(ValueError, match=rf'LidarSettings\.{field} '):
        settings.validate()
    with pytest.raises(ValueError, match=rf'LidarSettings\.{field} '):
        Lidar(client, settings=settings)


def test_valid_settings_pass():
    """The defaults and a full-circle field of view validate."""
    settings = LidarSettings()
    assert settings.validate() is settings
    assert LidarSettings(beams=1, field_of_view=2 * math.pi, range_min=0.0).validate()


def test_laser_scan_message_fields(client):
    """The LaserScan carries the settings' angles, limits, timing, frame, stamp and ranges."""
    _wall(client)
    settings = LidarSettings(beams=90, field_of_view=math.pi, range_min=0.1, range_max=5.0,
                             rate=15.0, frame_id='a1/laser')
    scan = Lidar(client, settings=settings).scan((0.0, 0.0, 0.5, 0.0))
    message = laser_scan(scan, Time(sec=3, nanosec=5))
    assert message.header.frame_id == 'a1/laser'
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (3, 5)
    for name in ('angle_min', 'angle_max', 'angle_increment'):
        assert getattr(message, name) == pytest.approx(getattr(settings, name), rel=1e-6)
    assert message.angle_increment == pytest.approx(math.pi / 89, rel=1e-6)
    assert message.scan_time == pytest.approx(1.0 / 15.0, rel=1e-6)
    assert message.time_increment == 0.0
    assert (message.range_min, message.range_max) == pytest.approx((0.1, 5.0), rel=1e-6)
    ranges = np.array(message.ranges, dtype=np.float32)
    np.testing.assert_array_equal(ranges, scan.ranges)
    assert np.isposinf(ranges).any() and np.isfinite(ranges).any()
    assert len(message.intensities) == 0
    assert len(serialize_message(message)) > 4 * settings.beams


def test_mount_transform_message_fields():
    """The static transform is base -> laser: (mount x, y, height), yaw as a quaternion."""
    settings = LidarSettings(mount=(0.2, -0.1, 0.5 * math.pi), height=0.3, frame_id='a1/laser')
    transform = mount_transform(settings, 'a1/base_link')
    types = get_typestore(Stores.ROS2_JAZZY)
    message = types.deserialize_cdr(tf_message_cdr([transform]), TF_MESSAGE_TYPE).transforms[0]
    assert (message.header.frame_id, message.child_frame_id) == ('a1/base_link', 'a1/laser')
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (0, 0)
    translation, rotation = message.transform.translation, message.transform.rotation
    assert (translation.x, translation.y, translation.z) == pytest.approx((0.2, -0.1, 0.3))
    half = math.sqrt(0.5)
    assert (rotation.x, rotation.y, rotation.z, rotation.w) == pytest.approx((0, 0, half, half))


def test_ray_casting_needs_no_ros():
    """Scanning imports neither rclpy nor any message package."""
    code = ('import sys, pybullet as pb\n'
            'from sim_bridge.lidar import Lidar\n'
            'client = pb.connect(pb.DIRECT)\n'
            'assert len(Lidar(client).scan((0, 0, 0, 0)).ranges) == 360\n'
            "loaded = [m for m in sys.modules if m.split('.')[0] in\n"
            "          ('rclpy', 'sensor_msgs', 'geometry_msgs', 'builtin_interfaces')]\n"
            'assert not loaded, loaded\n')
    proc = subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_a_1081_beam_scan_of_a_cluttered_world_runs(client):
    """Cost check without timing: 1081 beams among 100 cylinders, scanned a few times."""
    shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=0.15, height=1.0,
                                    physicsClientId=client)
    for x, y in np.random.default_rng(0).uniform(-5.0, 5.0, (100, 2)):
        if math.hypot(x, y) > 0.5:
            pb.createMultiBody(0.0, shape, basePosition=(x, y, 0.5), physicsClientId=client)
    lidar = Lidar(client, settings=LidarSettings(beams=1081, noise_std=0.01))
    for step in range(3):
        scan = lidar.scan((0.1 * step, 0.0, 0.5, 0.0))
        assert scan.ranges.shape == (1081,)
        assert 0 < np.isfinite(scan.ranges).sum() < 1081
