"""Two robots, two namespaced filters: each sees the other as a moving obstacle; no contact."""
import contextlib
import math
import time

import pytest
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from visualization_msgs.msg import Marker, MarkerArray

from node_harness import Harness, LATCHED, node_log, odometry, running_filter, twist

RADIUS = 0.3
RATE = 50.0
MAX_DT = 0.05


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


@pytest.mark.slow
def test_two_holonomic_robots_driven_head_on_never_touch():
    """Planners drive two point-mass robots at each other at 0.8 m/s for 6 s; bodies stay apart.

    Robot i runs its filter in /r<i>; the harness integrates both safe velocity
    commands (perfect tracking) and publishes each robot's body to the other's
    ``obstacles`` as a stamped CYLINDER, so only velocity estimation tells the
    filters that the obstacle moves.
    """
    params = {'model': 'point_mass_2d', 'rate': RATE, 'filter.barrier': 'polyc2bf_inflated',
              'filter.robot_radius': RADIUS}
    with contextlib.ExitStack() as stack:
        procs = [stack.enter_context(running_filter('-r', f'__ns:=/r{i}', params=params))
                 for i in (1, 2)]
        h = stack.enter_context(Harness())
        robots = []
        for i, (x, y, vx) in enumerate(((0.0, 0.05, 0.8), (4.0, -0.05, -0.8)), start=1):
            robots.append({
                'position': [x, y], 'velocity': [0.0, 0.0], 'nominal': twist(vx),
                'odom': h.publisher(Odometry, f'/r{i}/odom'),
                'cmd': h.publisher(Twist, f'/r{i}/cmd_vel_in'),
                'obstacles': h.publisher(MarkerArray, f'/r{i}/obstacles', LATCHED),
                'safe': h.collect(Twist, f'/r{i}/cmd_vel_out')})
        pubs = [r[k] for r in robots for k in ('odom', 'cmd', 'obstacles')]
        assert h.wait_for_subscribers(*pubs), [node_log(p) for p in procs]

        distances = []
        start = last = time.monotonic()
        while time.monotonic() - start < 6.0:
            now = time.monotonic()
            # A starved harness slows its simulated time down rather than teleporting.
            dt, last = min(now - last, MAX_DT), now
            stamp = h.now()
            for robot in robots:
                if robot['safe']:
                    safe = robot['safe'][-1][1]
                    robot['velocity'] = [safe.linear.x, safe.linear.y]
                robot['position'] = [p + v * dt for p, v in zip(robot['position'],
                                                                 robot['velocity'])]
            for i, (robot, other) in enumerate(zip(robots, robots[::-1])):
                (x, y), (vx, vy) = robot['position'], robot['velocity']
                msg = odometry(x, y, 0.0, vx, 0.0, stamp=stamp)
                msg.twist.twist.linear.y = vy
                robot['odom'].publish(msg)
                robot['cmd'].publish(robot['nominal'])
                robot['obstacles'].publish(MarkerArray(markers=[
                    _body(other['position'], stamp, 2 - i)]))
            distances.append(math.dist(robots[0]['position'], robots[1]['position']))
            h.spin_until(lambda: time.monotonic() - now >= 1.0 / RATE, 0.1)

        # ~300 answers on an idle machine; a starved one still answers a few dozen.
        assert all(len(r['safe']) > 30 for r in robots), [node_log(p) for p in procs]
        assert min(distances) > 2.0 * RADIUS, f'bodies touched: {min(distances):.3f} m apart'
        assert min(distances) < 2.5, 'robots never approached each other: nothing was tested'
