"""``/tf_static`` over real DDS: a static transform chain places a laser's wall in front.

The PyPI ROS wheels have no tf2_msgs; ``tf2_msgs_stand_in`` builds one (TFMessage only) for
this test and for the node it starts, which finds it on ``PYTHONPATH``.
"""
import fcntl
import math
import os
import sys

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan

from node_harness import (
    braked_by_filter,
    Harness,
    LATCHED,
    latest_status,
    markers,
    node_log,
    odometry,
    running_filter,
    twist,
)
from tf2_msgs_stand_in import tf2_msgs_python_path

WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
SPEED = 0.5
BEAMS = 181
WALL = 1.4  # m behind the laser, which faces backwards: 1.5 m ahead of the base
STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope='session')
def tf2_msgs_path(tmp_path_factory):
    """Return the stand-in's Python folder (None with a real tf2_msgs), built once per run."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get('PYTEST_XDIST_WORKER') else base
    with open(shared / 'tf2_msgs.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # xdist workers share one build
        return tf2_msgs_python_path(shared / 'tf2_msgs')


def _scan_behind():
    """Return a half-turn scan of the laser's back: a wall ``WALL`` m behind it."""
    msg = LaserScan()
    msg.header.frame_id = 'laser'
    msg.angle_min, msg.angle_increment = 0.5 * math.pi, math.pi / (BEAMS - 1)
    msg.angle_max = msg.angle_min + (BEAMS - 1) * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 10.0
    cosines = (math.cos(msg.angle_min + i * msg.angle_increment) for i in range(BEAMS))
    msg.ranges = [-WALL / c if c < -0.2 else math.inf for c in cosines]
    return msg


def _transform(parent, child, x, yaw):
    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = parent, child
    msg.transform.translation.x = float(x)
    msg.transform.rotation.z, msg.transform.rotation.w = math.sin(0.5 * yaw), math.cos(0.5 * yaw)
    return msg


@pytest.fixture
def forget_tf2_msgs(tf2_msgs_path):
    """Drop the stand-in's modules after the test.

    Later tests in this worker (the bag reader's "type not installed" path) must not find
    a tf2_msgs.
    """
    yield
    if tf2_msgs_path is not None:
        for name in [name for name in sys.modules if name.split('.')[0] == 'tf2_msgs']:
            del sys.modules[name]


@pytest.mark.slow
def test_a_static_transform_chain_puts_the_scan_wall_ahead(tf2_msgs_path, monkeypatch,
                                                            forget_tf2_msgs):
    """Before /tf_static the wall is behind (sensor_pose: identity) and 0.5 m/s passes.

    Then ``base_link -> laser_mount -> laser`` (0.1 m ahead, turned by two quarter turns:
    the laser faces backwards) is published, latched: the same scans now put the wall 1.5 m
    ahead, and the filter slows the robot.  The robot drives at 0.5 m/s as told (odometry;
    it does not move).
    """
    env = {}
    if tf2_msgs_path is not None:
        monkeypatch.syspath_prepend(tf2_msgs_path)
        env['PYTHONPATH'] = os.pathsep.join(filter(None, (tf2_msgs_path,
                                                          os.environ.get('PYTHONPATH'))))
    from tf2_msgs.msg import TFMessage

    params = {'model': 'unicycle', 'rate': 50.0, 'obstacles_timeout': 0.0,
              'odom_timeout': 10.0, 'cmd_timeout': 10.0, 'stall_timeout': 10.0,
              'deadlock_time': 600.0, 'stuck_time': 0.0,  # odometry: it does not move
              'scan_topics': '[scan]', 'scan_timeout': 10.0}
    with running_filter(params=params, env=env) as proc, Harness() as h:
        io = h.filter_io(proc)
        states = h.collect(DiagnosticStatus, '/safety_filter/state', LATCHED)
        scans = h.publisher(LaserScan, 'scan')
        assert h.wait_for_subscribers(scans), node_log(proc)
        io.obstacles.publish(markers())  # no marker obstacles
        scan = _scan_behind()

        def feed():
            io.odom.publish(odometry(v=SPEED))
            io.cmd.publish(twist(SPEED))
            scans.publish(scan)

        def speed():
            return io.out[-1][1].linear.x if io.out else None

        def in_use():
            return int(latest_status(io.diagnostics)[1].get('obstacles_in_use', 0)) > 0

        assert h.spin_until(lambda: in_use() and speed() == SPEED, WAIT, feed, 0.02), \
            (speed(), node_log(proc))
        assert 'tf2_msgs is not installed' not in node_log(proc)

        static = h.publisher(TFMessage, '/tf_static', STATIC_QOS)
        static.publish(TFMessage(transforms=[
            _transform('base_link', 'laser_mount', 0.1, 0.5 * math.pi),
            _transform('laser_mount', 'laser', 0.0, 0.5 * math.pi),
            _transform('base_link', 'camera', 0.3, 0.0)]))
        assert h.spin_until(lambda: braked_by_filter(io.out, states, SPEED), WAIT, feed, 0.02), \
            (speed(), [s.message for _, s in states[-3:]], node_log(proc))
        _, values = latest_status(io.diagnostics)
        assert values.get('scans_rejected scan') == '0', values
        assert proc.poll() is None, node_log(proc)
