"""Ctrl-C ends a busy ``safety_filter`` promptly and cleanly (exit 0, no traceback).

Busy: every control period a full obstacle set (60 walls + 7 robot cylinders),
odometry and a command arrive, as from the simulation bridge with several
robots.  The second case starts the node with SIGINT ignored, as a shell
script's background job (``cmd &``) gets it: Python then installs no
``KeyboardInterrupt`` handler and only rclpy's handler (which shuts the
context down) is left to stop the node.
"""
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import Twist
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from node_harness import Harness, node_log, odometry, REPO, twist, wall
from polyc2bf_ros.safety_filter_node import SafetyFilterNode

# The reported failure: still running > 20 s after SIGINT.  A clean exit takes well under
# a second; PROMPT_S is a hang detector that holds with both cores busy, not a latency bound.
PROMPT_S = 15.0


def _busy_obstacles(t):
    """Full set at time ``t``: 60 static walls and 7 CYLINDER robots moving on circles."""
    markers = [wall([(3.0 + i % 10, -5.0 + i // 10), (3.4 + i % 10, -5.0 + i // 10),
                     (3.4 + i % 10, -4.6 + i // 10)], marker_id=i) for i in range(60)]
    for i in range(7):
        robot = Marker(ns='robots', id=i, type=Marker.CYLINDER, action=Marker.ADD)
        robot.header.frame_id = 'odom'
        robot.pose.position.x = -3.0 + math.cos(t + i)
        robot.pose.position.y = 2.0 * i - 6.0 + math.sin(t + i)
        robot.pose.orientation.w = 1.0
        robot.scale.x = robot.scale.y = 0.6
        robot.scale.z = 0.5
        markers.append(robot)
    return MarkerArray(markers=markers)


def _start_filter(ignore_sigint):
    """Start ``safety_filter`` at 120 Hz; its output goes to a log file (``proc.log_path``)."""
    log_path = Path(tempfile.mkdtemp(prefix='safety_filter_')) / 'node.log'
    env = dict(os.environ, ROS_LOG_DIR=str(log_path.parent), PYTHONUNBUFFERED='1')
    with open(log_path, 'w') as log:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'polyc2bf_ros.safety_filter_node', '--ros-args',
             '-p', 'rate:=120.0'], cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT,
            preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
            if ignore_sigint else None)
    proc.log_path = log_path
    return proc


@pytest.mark.parametrize('ignore_sigint', [False, True], ids=['terminal', 'background_job'])
def test_ctrl_c_ends_a_busy_node_promptly(ignore_sigint):
    """SIGINT while flooded: the process exits 0 within PROMPT_S s, without a traceback."""
    proc = _start_filter(ignore_sigint)
    try:
        with Harness() as h:
            io = h.filter_io(proc, command_type=Twist)
            t0 = time.monotonic()

            def flood():
                io.obstacles.publish(_busy_obstacles(time.monotonic() - t0))
                io.odom.publish(odometry())
                io.cmd.publish(twist(0.5))

            assert h.spin_until(lambda: len(io.out) > 50, 60.0, every=flood,
                                period=1 / 120), node_log(proc)
            h.spin_until(lambda: False, 1.0, every=flood, period=1 / 120)
            proc.send_signal(signal.SIGINT)
            sent = time.monotonic()
            h.spin_until(lambda: proc.poll() is not None, PROMPT_S, every=flood,
                         period=1 / 120)
            elapsed = time.monotonic() - sent
        assert proc.poll() is not None, f'still running {elapsed:.1f} s after SIGINT'
        assert proc.returncode == 0, node_log(proc)
        assert 'Traceback' not in node_log(proc), node_log(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_an_obstacle_pass_that_ends_after_destroy_node_is_ignored():
    """A feeder pass that ends after ``destroy_node`` wakes nothing and raises nothing.

    On a loaded machine ``destroy_node`` can give up waiting for the feeder thread's last
    pass; that pass then found the guard condition destroyed: a traceback at Ctrl-C.  Only
    ``match_stamps`` (its lockstep gate) has the feeder wake the node.
    """
    context = rclpy.Context()
    rclpy.init(context=context)
    node = SafetyFilterNode(context=context, parameter_overrides=[
        Parameter('trigger', value='command'), Parameter('stamped', value=True),
        Parameter('match_stamps', value=True)])
    node._obstacles_processed()  # the running node: the guard condition fires
    node.destroy_node()
    try:
        node._obstacles_processed()
    finally:
        rclpy.try_shutdown(context=context)
