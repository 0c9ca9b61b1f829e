"""Closed loop over real DDS: a unicycle driven into a wall by its planner never crosses it."""
import math

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TwistStamped

from node_harness import Harness, markers, node_log, odometry, running_filter, wall

WALL_X, WALL_HALF_LENGTH, WALL_WIDTH = 1.5, 1.5, 0.1
OFFSET_L = 0.2
RATE = 100.0
DURATION = 10.0
START = 100.0  # simulated time of the first period [s]
ANSWER_TIMEOUT = 30.0  # wall-clock wait per period: a starved 2-core machine is slow, not wrong


def _stamp(seconds):
    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)


def _nominal(stamp):
    msg = TwistStamped()
    msg.header.frame_id = 'base_link'
    msg.header.stamp = stamp
    msg.twist.linear.x = 1.0
    return msg


def _wall_crossings(path):
    """Points where consecutive samples pass x = WALL_X with |y| inside the wall's extent."""
    hits = []
    for (x0, y0), (x1, y1) in zip(path, path[1:]):
        if (x0 - WALL_X) * (x1 - WALL_X) <= 0.0 and x0 != x1:
            y = y0 + (y1 - y0) * (WALL_X - x0) / (x1 - x0)
            if abs(y) <= WALL_HALF_LENGTH + 0.5 * WALL_WIDTH:
                hits.append((WALL_X, y))
    return hits


@pytest.mark.slow
def test_unicycle_never_crosses_the_wall():
    """A planner pushes 1 m/s straight at a 3 m wall 1.5 m ahead for 10 s; it is never crossed.

    The harness plays a robot that tracks the safe velocity command exactly
    (x_dot = v cos(theta), y_dot = v sin(theta), theta_dot = omega), and checks the
    axle centre and the filter's reference point (l ahead) never pass through the
    wall.  Lockstep on simulated time: period k sends the command and odometry
    stamped k / RATE and integrates over 1 / RATE with the answer to that stamp
    (``match_stamps``), so the path does not depend on how fast the machine is.
    """
    params = {'model': 'unicycle', 'rate': RATE, 'obstacles_timeout': 0.0,
              'model_params.offset_l': OFFSET_L,
              # the guarded point keeps robot_radius + offset_l = 0.3 m from the wall
              'filter.robot_radius': 0.3 - OFFSET_L,
              'stamped': True, 'trigger': 'command', 'match_stamps': True,
              'odom_timeout': 10.0, 'cmd_timeout': 10.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc, command_type=TwistStamped)
        ends = [(WALL_X, -WALL_HALF_LENGTH), (WALL_X, WALL_HALF_LENGTH)]
        io.obstacles.publish(markers(wall(ends, width=WALL_WIDTH)))
        x, y, theta, v, omega = 0.0, 0.2, 0.0, 0.0, 0.0

        def publish(stamp):
            io.cmd.publish(_nominal(stamp))
            io.odom.publish(odometry(x, y, theta, v, omega, stamp=stamp))

        def answer(stamp):
            return next((m for _, m in reversed(io.out) if m.header.stamp == stamp), None)

        # Until the output has met this subscription answers are lost: repeat the
        # period before the start (at rest) until one arrives.
        warm_up = _stamp(START - 1.0 / RATE)
        assert h.spin_until(lambda: answer(warm_up), ANSWER_TIMEOUT,
                            every=lambda: publish(warm_up), period=0.5), node_log(proc)
        centre, reference = [], []
        for k in range(round(DURATION * RATE)):
            stamp = _stamp(START + k / RATE)
            publish(stamp)
            assert h.spin_until(lambda: answer(stamp), ANSWER_TIMEOUT), \
                f'period {k} unanswered: {node_log(proc)}'
            safe = answer(stamp).twist
            v, omega = safe.linear.x, safe.angular.z
            x += v * math.cos(theta) / RATE
            y += v * math.sin(theta) / RATE
            theta += omega / RATE
            centre.append((x, y))
            reference.append((x + OFFSET_L * math.cos(theta), y + OFFSET_L * math.sin(theta)))

        travelled = sum(math.dist(a, b) for a, b in zip(centre, centre[1:]))
        # The reference point stops about 0.3 m before the wall's face (x = 1.45), the axle
        # 0.2 m behind it: 0.94 m of travel at most.
        assert travelled > 0.8, f'robot barely moved ({travelled:.2f} m): nothing was tested'
        for name, path in (('centre', centre), ('reference point', reference)):
            inside = [(px, py) for px, py in path if abs(px - WALL_X) <= 0.5 * WALL_WIDTH
                      and abs(py) <= WALL_HALF_LENGTH]
            assert not inside, f'{name} inside the wall at {inside[0]}'
            assert not _wall_crossings(path), f'{name} crossed the wall at {_wall_crossings(path)}'
