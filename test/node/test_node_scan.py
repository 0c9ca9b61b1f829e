"""LaserScan obstacles over real DDS: a wall in the scan slows the robot; NaN scans are refused."""
import math

import pytest
from sensor_msgs.msg import LaserScan

from node_harness import Harness, latest_status, markers, node_log, odometry, running_filter, twist

WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
SPEED = 0.5
BEAMS = 181


def _scan(wall_x=None, nan=False, frame='base_link'):
    """Return a half-turn scan from the base: a wall at x = ``wall_x`` ahead, or no returns."""
    msg = LaserScan()
    msg.header.frame_id = frame
    msg.angle_min, msg.angle_increment = -0.5 * math.pi, math.pi / (BEAMS - 1)
    msg.angle_max = msg.angle_min + (BEAMS - 1) * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 10.0
    ranges = []
    for i in range(BEAMS):
        angle = msg.angle_min + i * msg.angle_increment
        if nan:
            ranges.append(math.nan)
        elif wall_x is not None and math.cos(angle) > 0.2:
            ranges.append(wall_x / math.cos(angle))
        else:
            ranges.append(math.inf)
    msg.ranges = ranges
    return msg


@pytest.mark.slow
def test_a_wall_in_the_scan_slows_the_robot_and_nan_scans_are_refused():
    """No return: 0.5 m/s passes; a wall 0.6 m ahead in the scan: slower; NaN scans: stop.

    The robot drives at 0.5 m/s as told (odometry; it does not move).  NaN-only scans are
    rejected (counted in /diagnostics, the node lives on), so the scan source goes stale
    after ``scan_timeout`` and the node stops.
    """
    params = {'model': 'unicycle', 'rate': 50.0, 'obstacles_timeout': 0.0,
              'odom_timeout': 10.0, 'cmd_timeout': 10.0, 'stall_timeout': 10.0,
              'deadlock_time': 600.0, 'scan_topics': '[scan]', 'scan_timeout': 1.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        scans = h.publisher(LaserScan, 'scan')
        assert h.wait_for_subscribers(scans), node_log(proc)
        io.obstacles.publish(markers())  # no marker obstacles
        scan = [_scan()]

        def feed():
            io.odom.publish(odometry(v=SPEED))
            io.cmd.publish(twist(SPEED))
            scans.publish(scan[0])

        def speed():
            return io.out[-1][1].linear.x if io.out else None

        assert h.spin_until(lambda: speed() == SPEED, WAIT, feed, 0.02), node_log(proc)

        scan[0] = _scan(wall_x=0.6)
        assert h.spin_until(lambda: speed() is not None and speed() < SPEED - 0.005, WAIT,
                            feed, 0.02), (speed(), node_log(proc))

        def in_use():
            return int(latest_status(io.diagnostics)[1].get('obstacles_in_use', 0)) > 0

        assert h.spin_until(in_use, WAIT, feed, 0.02), node_log(proc)

        scan[0] = _scan(nan=True)

        def rejected():
            return int(latest_status(io.diagnostics)[1].get('scans_rejected scan', 0)) > 0

        assert h.spin_until(rejected, WAIT, feed, 0.02), node_log(proc)
        assert h.spin_until(lambda: speed() == 0.0, WAIT, feed, 0.02), (speed(), node_log(proc))
        assert proc.poll() is None, node_log(proc)
        _, values = latest_status(io.diagnostics)
        assert 'all NaN' in values['last_scan_rejection scan'], values
        assert 'rejected LaserScan' in node_log(proc)

        def stale_reported():
            return 'scan_scan' in latest_status(io.diagnostics)[1].get('stale_inputs', '')

        assert h.spin_until(stale_reported, WAIT, feed, 0.02), node_log(proc)
