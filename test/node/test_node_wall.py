"""Closed loop over real DDS: a unicycle driven into a wall by its planner never crosses it."""
import math
import time

import pytest

from node_harness import Harness, markers, node_log, odometry, running_filter, twist, wall

WALL_X, WALL_HALF_LENGTH, WALL_WIDTH = 1.5, 1.5, 0.1
OFFSET_L = 0.2
MAX_DT = 0.03


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
    (x_dot = v cos(theta), y_dot = v sin(theta), theta_dot = omega), integrated
    over the measured wall-clock step (at most MAX_DT), and checks the axle centre and the
    filter's reference point (l ahead) never pass through the wall.
    """
    params = {'model': 'unicycle', 'rate': 100.0, 'obstacles_timeout': 0.0,
              'model_params.offset_l': OFFSET_L, 'filter.robot_radius': 0.3}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        odom_pub, cmd_pub, safe = io.odom, io.cmd, io.out
        ends = [(WALL_X, -WALL_HALF_LENGTH), (WALL_X, WALL_HALF_LENGTH)]
        io.obstacles.publish(markers(wall(ends, width=WALL_WIDTH)))
        x, y, theta, v, omega = 0.0, 0.2, 0.0, 0.0, 0.0
        nominal = twist(1.0, 0.0)
        centre, reference = [], []
        start = last = time.monotonic()
        while time.monotonic() - start < 10.0:
            now = time.monotonic()
            # A starved harness slows its simulated time down rather than teleporting.
            dt, last = min(now - last, MAX_DT), now
            if safe:
                v, omega = safe[-1][1].linear.x, safe[-1][1].angular.z
            x += v * math.cos(theta) * dt
            y += v * math.sin(theta) * dt
            theta += omega * dt
            centre.append((x, y))
            reference.append((x + OFFSET_L * math.cos(theta), y + OFFSET_L * math.sin(theta)))
            odom_pub.publish(odometry(x, y, theta, v, omega, stamp=h.now()))
            cmd_pub.publish(nominal)
            h.spin_until(lambda: time.monotonic() - now >= 0.01, 0.05)

        assert len(safe) > 200, node_log(proc)
        travelled = sum(math.dist(a, b) for a, b in zip(centre, centre[1:]))
        assert travelled > 1.0, f'robot barely moved ({travelled:.2f} m): nothing was tested'
        for name, path in (('centre', centre), ('reference point', reference)):
            inside = [(px, py) for px, py in path if abs(px - WALL_X) <= 0.5 * WALL_WIDTH
                      and abs(py) <= WALL_HALF_LENGTH]
            assert not inside, f'{name} inside the wall at {inside[0]}'
            assert not _wall_crossings(path), f'{name} crossed the wall at {_wall_crossings(path)}'
