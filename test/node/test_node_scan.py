"""LaserScan obstacles over real DDS: a wall in the scan slows the robot; NaN scans are refused.

A scan is placed at the odometry stamped nearest it; with ``use_markers:=false`` scans are the
only obstacle source and no MarkerArray is needed.
"""
import math

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray

from node_harness import (
    FILTERED_STATUSES,
    Harness,
    LATCHED,
    latest_status,
    markers,
    node_log,
    odometry,
    running_filter,
    status_values,
    twist,
)

WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
SPEED = 0.5
BEAMS = 181
PARAMS = {'model': 'unicycle', 'rate': 50.0, 'obstacles_timeout': 0.0, 'odom_timeout': 10.0,
          'cmd_timeout': 10.0, 'stall_timeout': 10.0, 'deadlock_time': 600.0, 'stuck_time': 0.0,
          'scan_topics': '[scan]', 'scan_timeout': 1.0}


def _scan(wall_x=None, nan=False, frame='base_link', stamp=None):
    """Return a half-turn scan from the base: a wall at x = ``wall_x`` ahead, or no returns.

    ``stamp``: its ``header.stamp`` (a ``builtin_interfaces/Time``; default 0).
    """
    msg = LaserScan()
    msg.header.frame_id = frame
    if stamp is not None:
        msg.header.stamp = stamp
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
    with running_filter(params=PARAMS) as proc, Harness() as h:
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
            # By reason: a scan that beat the first odometry to the node was rejected too.
            _, values = latest_status(io.diagnostics)
            return (int(values.get('scans_rejected scan', 0)) > 0
                    and 'all NaN' in values.get('last_scan_rejection scan', ''))

        assert h.spin_until(rejected, WAIT, feed, 0.02), node_log(proc)
        assert h.spin_until(lambda: speed() == 0.0, WAIT, feed, 0.02), (speed(), node_log(proc))
        assert proc.poll() is None, node_log(proc)
        _, values = latest_status(io.diagnostics)
        assert 'all NaN' in values['last_scan_rejection scan'], values
        assert 'rejected LaserScan' in node_log(proc)

        def stale_reported():
            return 'scan_scan' in latest_status(io.diagnostics)[1].get('stale_inputs', '')

        assert h.spin_until(stale_reported, WAIT, feed, 0.02), node_log(proc)


def _stamp(k):
    """Return the stamp of odometry message ``k``: 100 s + 0.02 s k."""
    return Time(sec=100 + k // 50, nanosec=(k % 50) * 20_000_000)


def _drawn_wall_x(drawn):
    """Return the smallest x of the obstacle parts on the newest ``~/markers`` (None: none)."""
    if not drawn:
        return None
    xs = [p.x for m in drawn[-1][1].markers if m.ns == 'obstacles' for p in m.points]
    return min(xs) if xs else None


@pytest.mark.slow
def test_a_scan_is_placed_at_the_odometry_stamped_nearest_it():
    """A scan is placed at the odometry stamped nearest it, not at the latest.

    70 odometry messages 0.02 s apart: the robot drives to x = 0.8 (k = 0-20), stands there
    (k = 20-40), drives on to x = 1.96 (k = 69), then is silent; before them it stands at
    x = 0 (earlier stamps) until the node's diagnostics show odometry arrived.

    A scan with a wall 1 m ahead, stamped as message 30, is drawn on ``~/markers`` at
    x = 1.8, not at 2.96 as from the latest odometry (x = 1.96); stamped past the last
    message, at 2.96.  The node takes odometry best effort with depth 1, so under load it
    may drop messages; the stand makes every message near stamp 30 say x = 0.8, so a
    dropped one cannot move the answer.  No command: the node only builds and draws
    obstacles.
    """
    # Without the scan memory: from x = 2.96 the half-turn laser cannot see x = 1.8, where
    # the first scan drew the wall, and would keep it there (test_scan_memory.py).
    with running_filter(params={**PARAMS, 'scan_memory_time': 0.0}) as proc, Harness() as h:
        drawn = h.collect(MarkerArray, 'safety_filter/markers')
        io = h.filter_io(proc)
        scans = h.publisher(LaserScan, 'scan')
        assert h.wait_for_subscribers(scans), node_log(proc)
        warm_up = [-1000]

        def stand_at_start():
            io.odom.publish(odometry(x=0.0, stamp=_stamp(warm_up[0])))
            warm_up[0] += 1

        def odometry_arrived():
            values = latest_status(io.diagnostics)[1]
            return values.get('age_odom_s', 'inf') != 'inf'

        assert h.spin_until(odometry_arrived, WAIT, stand_at_start, 0.02), node_log(proc)
        for k in range(70):
            io.odom.publish(odometry(x=0.04 * (min(k, 20) + max(k - 40, 0)), stamp=_stamp(k)))
            h.spin_for(0.02)
        scan = [_scan(wall_x=1.0, stamp=_stamp(30))]

        def drawn_at(x):
            wall_x = _drawn_wall_x(drawn)
            return wall_x is not None and abs(wall_x - x) < 0.1

        assert h.spin_until(lambda: drawn_at(1.8), WAIT, lambda: scans.publish(scan[0]), 0.1), \
            (_drawn_wall_x(drawn), node_log(proc))
        scan[0] = _scan(wall_x=1.0, stamp=_stamp(99))
        assert h.spin_until(lambda: drawn_at(2.96), WAIT, lambda: scans.publish(scan[0]),
                            0.1), (_drawn_wall_x(drawn), node_log(proc))


@pytest.mark.slow
def test_a_scan_only_node_needs_no_marker_array():
    """``use_markers:=false``: no ``obstacles`` subscription or watchdog, and none published.

    Before any scan the node stops (stale ``scan_scan``); empty scans pass 0.5 m/s; a wall
    0.6 m ahead in the scan slows it (a step the filter computed, not a watchdog's stop).
    """
    params = {**PARAMS, 'use_markers': False}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc, obstacles=False)
        states = h.collect(DiagnosticStatus, '/safety_filter/state', LATCHED)
        scans = h.publisher(LaserScan, 'scan')
        assert h.wait_for_subscribers(scans), node_log(proc)
        assert h.node.count_subscribers('/obstacles') == 0, node_log(proc)
        scan = [None]

        def feed():
            io.odom.publish(odometry(v=SPEED))
            io.cmd.publish(twist(SPEED))
            if scan[0] is not None:
                scans.publish(scan[0])

        def speed():
            return io.out[-1][1].linear.x if io.out else None

        def stale_scan_stop():
            values = latest_status(io.diagnostics)[1]
            return speed() == 0.0 and 'scan_scan' in values.get('stale_inputs', '')

        assert h.spin_until(stale_scan_stop, WAIT, feed, 0.02), node_log(proc)
        values = latest_status(io.diagnostics)[1]
        assert 'obstacles' not in values['stale_inputs'] and 'age_obstacles_s' not in values

        scan[0] = _scan()
        assert h.spin_until(lambda: speed() == SPEED, WAIT, feed, 0.02), node_log(proc)
        scan[0] = _scan(wall_x=0.6)

        def braked():
            return (speed() < SPEED - 0.005 and bool(states)
                    and status_values(states[-1][1])['status'] in FILTERED_STATUSES)

        assert h.spin_until(braked, WAIT, feed, 0.02), \
            (speed(), [s.message for _, s in states[-3:]], node_log(proc))
        assert h.node.count_subscribers('/obstacles') == 0
        assert proc.poll() is None, node_log(proc)
