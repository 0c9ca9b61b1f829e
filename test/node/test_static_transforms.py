"""``/tf_static`` without DDS: the planar transform tree, and scans placed by it in the worker."""
import math

import pytest
from rclpy.serialization import serialize_message

from polyc2bf_ros.core.barrier.obstacle_geometry import ObstacleGeometry
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline, read_scan
from polyc2bf_ros.obstacle_settings import IntakeSettings
from polyc2bf_ros.static_transforms import read_tf_message, StaticTransforms
from sim_bridge.cdr import tf_message_cdr
from test_node_scan import _scan

SPEC = ObstacleGeometry(make_model('unicycle'), FilterConfig())
ODOMETRY = ((0.0, 0.0, 0.0, 0.0),)  # one sample (stamp, x, y, yaw): at the origin


def _obstacles(*arguments):
    """Return the obstacles ``read_scan(*arguments)`` makes of a serialized scan."""
    return read_scan(*arguments).obstacles


def _yaw(angle):
    """Quaternion (x, y, z, w) of a rotation by ``angle`` about z."""
    return 0.0, 0.0, math.sin(0.5 * angle), math.cos(0.5 * angle)


def _tf(*transforms):
    """Return the serialized TFMessage of ``(parent, child, (x, y, z), quaternion)`` items."""
    return tf_message_cdr([(0, 0, parent, child, translation, rotation)
                           for parent, child, translation, rotation in transforms])


def _tree(*transforms):
    tree = StaticTransforms()
    tree.update(_tf(*transforms))
    return tree


def test_the_message_is_read_as_planar_transforms():
    """Frames without a leading slash; x, y and the yaw of the rotation (z is dropped)."""
    data = _tf(('/base_link', 'laser', (0.1, -0.2, 0.5), _yaw(0.7)),
               ('base_link', 'camera', (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 0.0)))
    (parent, child, pose), (_, camera, identity) = read_tf_message(data)
    assert (parent, child, camera) == ('base_link', 'laser', 'camera')
    assert pose == pytest.approx((0.1, -0.2, 0.7))
    assert identity == pytest.approx((1.0, 2.0, 0.0))  # an all-zero quaternion is identity
    with pytest.raises(ValueError, match='truncated'):
        read_tf_message(data[:-20])


def test_a_chain_is_composed_through_the_nearest_common_ancestor():
    """Down a chain, up to a shared parent and back down, or not linked at all."""
    chain = _tree(('base_link', 'mount', (0.1, 0.0, 0.0), _yaw(0.5 * math.pi)),
                  ('mount', 'laser', (0.2, 0.0, 0.0), _yaw(0.5 * math.pi)))
    assert chain.pose('base_link', 'laser') == pytest.approx((0.1, 0.2, math.pi))
    assert chain.pose('base_link', 'base_link') == (0.0, 0.0, 0.0)
    assert chain.pose('base_link', 'camera') is None
    siblings = _tree(('base_footprint', 'base_link', (0.1, 0.0, 0.0), _yaw(0.5 * math.pi)),
                     ('base_footprint', 'laser', (0.1, 0.3, 0.0), _yaw(0.0)))
    assert siblings.pose('base_link', 'laser') == pytest.approx((0.3, 0.0, -0.5 * math.pi))
    up = siblings.pose('laser', 'base_link')
    assert up == pytest.approx((0.0, -0.3, 0.5 * math.pi))


def test_the_newest_transform_of_a_frame_wins():
    """A frame has one parent: a later transform of the same child replaces the earlier one."""
    tree = _tree(('base_link', 'laser', (0.1, 0.0, 0.0), _yaw(0.0)))
    tree.update(_tf(('base_link', 'laser', (0.4, 0.0, 0.0), _yaw(0.0))))
    assert tree.pose('base_link', 'laser') == pytest.approx((0.4, 0.0, 0.0))


def test_non_finite_transforms_and_unreadable_messages_are_refused():
    """NaN on the chain, inf in a quaternion (its yaw alone would be finite), bad bytes."""
    nan = _tree(('base_link', 'mount', (math.nan, 0.0, 0.0), _yaw(0.0)),
                ('mount', 'laser', (0.2, 0.0, 0.0), _yaw(0.0)),
                ('base_link', 'camera', (0.2, 0.0, 0.0), _yaw(0.0)))
    with pytest.raises(ValueError, match='not finite'):
        nan.pose('base_link', 'laser')
    assert nan.pose('base_link', 'camera') == pytest.approx((0.2, 0.0, 0.0))  # off the chain
    inf = _tree(('base_link', 'laser', (0.0, 0.0, 0.0), (0.0, 0.0, math.inf, 1.0)))
    with pytest.raises(ValueError, match='not finite'):
        inf.pose('base_link', 'laser')
    tree = _tree(('base_link', 'laser', (0.1, 0.0, 0.0), _yaw(0.0)))
    tree.update(b'\x00\x01\x00\x00\xff')
    with pytest.raises(ValueError, match='unreadable /tf_static'):
        tree.pose('base_link', 'laser')
    tree.update(_tf())
    assert tree.pose('base_link', 'laser') == pytest.approx((0.1, 0.0, 0.0))


def _nearest_x(obstacles):
    return min(o.polygon[:, 0].min() for o in obstacles)


def test_a_scan_is_placed_by_the_static_transforms_before_sensor_pose():
    """A laser 0.5 m ahead by /tf_static sees a wall 1 m ahead of it at 1.5 m, not at 1.2 m.

    ``sensor_pose`` (0.2 m) is the fallback for a frame that no transform reaches; a scan in
    the base frame needs none.
    """
    settings = IntakeSettings(sensor_pose=(0.2, 0.0, 0.0))
    tree = _tree(('base_link', 'laser', (0.5, 0.0, 0.0), _yaw(0.0)))
    laser = serialize_message(_scan(wall_x=1.0, frame='laser'))
    other = serialize_message(_scan(wall_x=1.0, frame='sonar'))
    base = serialize_message(_scan(wall_x=1.0))
    assert _nearest_x(_obstacles(laser, ODOMETRY, 'base_link', settings, 0.3, tree)) == \
        pytest.approx(1.5, abs=0.06)
    assert _nearest_x(_obstacles(other, ODOMETRY, 'base_link', settings, 0.3, tree)) == \
        pytest.approx(1.2, abs=0.06)
    assert _nearest_x(_obstacles(base, ODOMETRY, 'base_link', settings, 0.3, tree)) == \
        pytest.approx(1.0, abs=0.06)


def test_the_worker_pipeline_takes_transforms_and_refuses_scans_through_a_non_finite_one():
    """The job's /tf_static messages apply before its scans; a NaN transform is a bad scan."""
    pipeline = ObstaclePipeline()
    laser = serialize_message(_scan(wall_x=1.0, frame='laser'))
    behind = _tf(('base_link', 'laser', (0.0, 0.0, 0.0), _yaw(math.pi)))
    job = ObstacleJob([], 'odom', IntakeSettings(), SPEC, 1.0,
                      (('scan', laser, 1.0, ODOMETRY, 'base_link'),), (behind,))
    snapshot = pipeline.run(job)
    # Turned around, the wall 1 m in front of the laser is 1 m behind the robot.
    assert snapshot.obstacles.footprints.vertices[..., 0].max() == \
        pytest.approx(-1.0, abs=0.06)
    broken = _tf(('base_link', 'laser', (0.0, math.inf, 0.0), _yaw(0.0)))
    again = pipeline.run(ObstacleJob([], 'odom', IntakeSettings(), SPEC, 2.0,
                                     (('scan', laser, 2.0, ODOMETRY, 'base_link'),), (broken,)))
    assert again.obstacles.keys == snapshot.obstacles.keys  # the topic's last obstacles kept
    status = pipeline.scan_status['scan']
    assert (status.accepted, status.received, status.rejected) == (1.0, 2.0, 1)
    assert 'not finite' in status.reason
