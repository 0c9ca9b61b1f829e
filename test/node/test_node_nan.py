"""NaN/Inf in odometry, command or obstacle polygons never reaches the output: it brakes."""
import math

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from visualization_msgs.msg import MarkerArray

from node_harness import (
    Harness,
    LATCHED,
    latest_status,
    markers,
    node_log,
    odometry,
    running_filter,
    twist,
    wall,
)

RATE = 50.0
FAR_WALL = [(5.0, -1.0), (5.0, 1.0)]


def _finite(msg):
    return all(map(math.isfinite, (msg.linear.x, msg.linear.y, msg.linear.z,
                                   msg.angular.x, msg.angular.y, msg.angular.z)))


@pytest.mark.slow
def test_non_finite_inputs_brake_and_never_reach_the_output():
    """Odometry x = NaN, velocity = Inf, command NaN, a NaN vertex: each gives zero twists."""
    with running_filter(params={'model': 'unicycle', 'rate': RATE}) as proc, Harness() as h:
        out = h.collect(Twist, 'cmd_vel_out')
        diagnostics = h.collect(DiagnosticArray, '/diagnostics')
        odom_pub = h.publisher(Odometry, 'odom')
        cmd_pub = h.publisher(Twist, 'cmd_vel_in')
        obstacles_pub = h.publisher(MarkerArray, 'obstacles', LATCHED)
        assert h.wait_for_subscribers(odom_pub, cmd_pub, obstacles_pub), node_log(proc)
        good = {'odom': odometry(v=0.5), 'cmd': twist(0.5), 'wall': wall(FAR_WALL)}
        inputs = dict(good)

        def feed():
            odom_pub.publish(inputs['odom'])
            cmd_pub.publish(inputs['cmd'])
            obstacles_pub.publish(markers(inputs['wall']))

        def moving():
            return bool(out) and out[-1][1].linear.x > 0.4

        def stopped():
            return bool(out) and out[-1][1].linear.x == 0.0

        assert h.spin_until(moving, 15.0, feed, 1.0 / RATE), node_log(proc)
        bad_wall = wall(FAR_WALL + [(math.nan, 0.0)])
        for name, bad in (('odom', odometry(x=math.nan, v=0.5)),
                          ('odom', odometry(v=math.inf)),
                          ('cmd', twist(math.nan)),
                          ('cmd', twist(0.5, omega=-math.inf)),
                          ('wall', bad_wall)):
            inputs[name] = bad
            assert h.spin_until(stopped, 5.0, feed, 1.0 / RATE), f'no brake on bad {name}'
            inputs[name] = good[name]
            assert h.spin_until(moving, 5.0, feed, 1.0 / RATE), f'no recovery after {name}'

        bad_outputs = [m for _, m in out if not _finite(m)]
        assert not bad_outputs, f'non-finite output: {bad_outputs[0]}'
        def counted():
            values = latest_status(diagnostics)[1]
            return (int(values.get('steps_invalid_input', 0)) > 0
                    and int(values.get('invalid_messages', 0)) >= 5)

        assert h.spin_until(counted, 3.0, feed, 1.0 / RATE), latest_status(diagnostics)
