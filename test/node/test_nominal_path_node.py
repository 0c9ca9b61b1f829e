"""``nominal_controller`` with ``controller: path``: pure pursuit along a Path over DDS."""
import contextlib
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path as FilePath

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry, Path

from node_harness import Harness, odometry, REPO
from sim_bridge.launcher import ProcessSpec, stop_processes

RATE = 20.0             # Hz of the test's lockstep periods
DURATION = 9.0          # s simulated
ANSWER_TIMEOUT = 30.0   # wall s per period: a starved 2-core machine is slow, not wrong
PLAN = [(0.0, 0.0), (1.5, 0.0), (1.5, 1.5)]


@contextlib.contextmanager
def running_nominal(**parameters):
    """Run ``nominal_controller`` with ``parameters``; yield the process (log in ``log_path``)."""
    spec = ProcessSpec('nominal', 'nominal_controller', 'sim_bridge.nominal_controller_node',
                       parameters=parameters)
    log_dir = tempfile.mkdtemp(prefix='nominal_')
    log_path = FilePath(log_dir) / 'node.log'
    env = dict(os.environ, ROS_LOG_DIR=log_dir, PYTHONUNBUFFERED='1')
    with open(log_path, 'w') as log:
        proc = subprocess.Popen([sys.executable, '-m', spec.module, *spec.ros_args()],
                                cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    proc.log_path = log_path
    try:
        yield proc
    finally:
        stop_processes([proc], timeout=5.0)


def _stamp(seconds):
    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)


def _plan(points):
    msg = Path()
    msg.header.frame_id = 'odom'
    for x, y in points:
        pose = PoseStamped()
        pose.header.frame_id = 'odom'
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        pose.pose.orientation.w = 1.0
        msg.poses.append(pose)
    return msg


def _cross_track(point):
    """Return the distance from ``point`` to the PLAN polyline."""
    best = math.inf
    for (ax, ay), (bx, by) in zip(PLAN, PLAN[1:]):
        ex, ey = bx - ax, by - ay
        t = min(max(((point[0] - ax) * ex + (point[1] - ay) * ey) / (ex * ex + ey * ey), 0.0),
                1.0)
        best = min(best, math.hypot(point[0] - ax - t * ex, point[1] - ay - t * ey))
    return best


def test_path_nominal_follows_a_plan_over_dds():
    """Still without a plan; then along the L-shaped plan to its end, and still again there.

    The harness plays a diff-drive base that tracks [v, omega] exactly, in lockstep
    on simulated time: period k sends odometry stamped k / RATE and integrates over
    1 / RATE with the command answering that stamp.
    """
    with running_nominal(robot_type='diff_drive', controller='path') as proc, Harness() as h:
        commands = h.collect(TwistStamped, 'cmd_vel_in')
        odom = h.publisher(Odometry, 'odom')
        plan = h.publisher(Path, 'plan')
        assert h.wait_for_subscribers(odom, plan), proc.log_path.read_text()
        x, y, theta, v, omega = 0.0, 0.0, 0.0, 0.0, 0.0

        def answer(stamp):
            return next((m.twist for _, m in reversed(commands) if m.header.stamp == stamp),
                        None)

        before = _stamp(0.0)
        assert h.spin_until(lambda: answer(before), ANSWER_TIMEOUT,
                            every=lambda: odom.publish(odometry(stamp=before)), period=0.5), \
            proc.log_path.read_text()
        assert (answer(before).linear.x, answer(before).angular.z) == (0.0, 0.0)

        # Until the plan has arrived the answers stay zero: resend both until one moves.
        start = _stamp(1.0)
        assert h.spin_until(lambda: answer(start) is not None and answer(start).linear.x > 0.0,
                            ANSWER_TIMEOUT, period=0.5, every=lambda: (
                                plan.publish(_plan(PLAN)), odom.publish(odometry(stamp=start)))
                            ), proc.log_path.read_text()
        path = [(x, y)]
        for k in range(round(DURATION * RATE)):
            stamp = _stamp(1.0 + k / RATE)
            odom.publish(odometry(x, y, theta, v, omega, stamp=stamp))
            assert h.spin_until(lambda: answer(stamp) is not None, ANSWER_TIMEOUT), \
                f'period {k} unanswered: {proc.log_path.read_text()}'
            v, omega = answer(stamp).linear.x, answer(stamp).angular.z
            x += v * math.cos(theta + 0.5 * omega / RATE) / RATE
            y += v * math.sin(theta + 0.5 * omega / RATE) / RATE
            theta += omega / RATE
            path.append((x, y))

    assert max(px for px, _ in path) > 1.3, 'never reached the corner'
    assert math.dist(path[-1], PLAN[-1]) < 0.15 and (v, omega) == (0.0, 0.0)
    assert max(_cross_track(p) for p in path) < 0.15
