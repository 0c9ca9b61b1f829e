"""Two robots, two namespaced filters: each sees the other as a moving obstacle; no contact."""
import contextlib
import math

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from visualization_msgs.msg import Marker, MarkerArray

from node_harness import Harness, LATCHED, node_log, odometry, running_filter

RADIUS = 0.3
RATE = 50.0
DURATION = 6.0
START = 100.0  # simulated time of the first period [s]
ANSWER_TIMEOUT = 30.0  # wall-clock wait per period: a starved 2-core machine is slow, not wrong


def _body(position, stamp, robot_id):
    """CYLINDER marker for a robot body of radius RADIUS at ``position``."""
    marker = Marker(ns='robots', id=robot_id, type=Marker.CYLINDER, action=Marker.ADD)
    marker.header.frame_id = 'odom'
    marker.header.stamp = stamp
    marker.pose.position.x, marker.pose.position.y = position
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = 2.0 * RADIUS
    marker.scale.z = 1.0
    return marker


def _stamp(seconds):
    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)


def _nominal(vx, stamp):
    msg = TwistStamped()
    msg.header.frame_id = 'base_link'
    msg.header.stamp = stamp
    msg.twist.linear.x = float(vx)
    return msg


def _publish_state(robots, stamp):
    """Publish each robot's obstacles (the other body), nominal command and odometry.

    All are stamped ``stamp``; the bodies go first, so a filter usually answers
    with this period's obstacles (else with the last period's, extrapolated).
    """
    for i, (robot, other) in enumerate(zip(robots, robots[::-1])):
        robot['obstacles'].publish(MarkerArray(markers=[_body(other['position'], stamp, 2 - i)]))
    for robot in robots:
        robot['cmd'].publish(_nominal(robot['nominal_vx'], stamp))
        (x, y), (vx, vy) = robot['position'], robot['velocity']
        msg = odometry(x, y, 0.0, vx, 0.0, stamp=stamp)
        msg.twist.twist.linear.y = vy
        robot['odom'].publish(msg)


def _answer(robot, stamp):
    """Return the robot's safe command answering the period stamped ``stamp`` (or None)."""
    return next((msg for _, msg in reversed(robot['safe']) if msg.header.stamp == stamp), None)


@pytest.mark.slow
def test_two_holonomic_robots_driven_head_on_never_touch():
    """Planners drive two point-mass robots at each other at 0.8 m/s for 6 s; bodies stay apart.

    Robot i runs its filter in /r<i>; the harness integrates both safe velocity
    commands (perfect tracking) and publishes each robot's body to the other's
    ``obstacles`` as a stamped CYLINDER, so only velocity estimation tells the
    filters that the obstacle moves.  The loop runs in lockstep on simulated
    time: period k publishes bodies, commands and odometry stamped k / RATE, and
    integrates over 1 / RATE once both filters answered that stamp
    (``match_stamps``).  So the result does not depend on how fast the machine
    is; in real time, a starved harness would keep integrating stale answers.
    """
    params = {'model': 'point_mass_2d', 'rate': RATE, 'filter.barrier': 'polyc2bf_inflated',
              'filter.robot_radius': RADIUS, 'stamped': True, 'trigger': 'command',
              'match_stamps': True, 'odom_timeout': 10.0, 'cmd_timeout': 10.0,
              'obstacles_timeout': 10.0}
    with contextlib.ExitStack() as stack:
        procs = [stack.enter_context(running_filter('-r', f'__ns:=/r{i}', params=params))
                 for i in (1, 2)]
        h = stack.enter_context(Harness())
        robots = []
        for i, (x, y, vx) in enumerate(((0.0, 0.05, 0.8), (4.0, -0.05, -0.8)), start=1):
            robots.append({
                'position': [x, y], 'velocity': [0.0, 0.0], 'nominal_vx': vx,
                'odom': h.publisher(Odometry, f'/r{i}/odom'),
                'cmd': h.publisher(TwistStamped, f'/r{i}/cmd_vel_in'),
                'obstacles': h.publisher(MarkerArray, f'/r{i}/obstacles', LATCHED),
                'safe': h.collect(TwistStamped, f'/r{i}/cmd_vel_out')})
        pubs = [r[k] for r in robots for k in ('odom', 'cmd', 'obstacles')]
        assert h.wait_for_subscribers(*pubs), [node_log(p) for p in procs]

        # Until a filter's output has met the harness's subscription, its answers are
        # lost; so repeat the period before the start (robots at rest) until answered.
        warm_up = _stamp(START - 1.0 / RATE)
        assert h.spin_until(lambda: all(r['safe'] for r in robots), ANSWER_TIMEOUT,
                            every=lambda: _publish_state(robots, warm_up), period=0.5), \
            [node_log(p) for p in procs]

        distances = []
        for k in range(round(DURATION * RATE)):
            stamp = _stamp(START + k / RATE)
            _publish_state(robots, stamp)
            answered = h.spin_until(lambda: all(_answer(r, stamp) for r in robots),
                                    ANSWER_TIMEOUT)
            assert answered, f'period {k} unanswered: {[node_log(p) for p in procs]}'
            for robot in robots:
                safe = _answer(robot, stamp).twist.linear
                robot['velocity'] = [safe.x, safe.y]
                robot['position'] = [p + v / RATE for p, v in zip(robot['position'],
                                                                  robot['velocity'])]
            distances.append(math.dist(robots[0]['position'], robots[1]['position']))

        assert min(distances) > 2.0 * RADIUS, f'bodies touched: {min(distances):.3f} m apart'
        assert min(distances) < 2.5, 'robots never approached each other: nothing was tested'
