"""NaN/Inf in odometry, command or obstacle polygons never reaches the output: it brakes."""
import math

import pytest
from rclpy.serialization import serialize_message

from node_harness import (
    Harness,
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
    """NaN/Inf or malformed odometry or command, a NaN vertex: each gives zero twists."""
    with running_filter(params={'model': 'unicycle', 'rate': RATE}) as proc, Harness() as h:
        io = h.filter_io(proc)
        out, diagnostics = io.out, io.diagnostics
        good = {'odom': odometry(v=0.5), 'cmd': twist(0.5), 'wall': wall(FAR_WALL)}
        inputs = dict(good)

        def feed():
            io.odom.publish(inputs['odom'])
            io.cmd.publish(inputs['cmd'])
            obstacles = inputs['wall']
            io.obstacles.publish(obstacles if isinstance(obstacles, bytes) else markers(obstacles))

        def moving():
            return bool(out) and out[-1][1].linear.x > 0.4

        def stopped():
            return bool(out) and out[-1][1].linear.x == 0.0

        assert h.spin_until(moving, 15.0, feed, 1.0 / RATE), node_log(proc)
        bad_wall = wall(FAR_WALL + [(math.nan, 0.0)])
        infinite_quaternion = odometry(v=0.5)
        infinite_quaternion.pose.pose.orientation.w = math.inf
        # Serialized garbage (published as raw bytes): a foreign encoding, a truncated message.
        for name, bad in (('odom', odometry(x=math.nan, v=0.5)),
                          ('odom', odometry(v=math.inf)),
                          ('odom', infinite_quaternion),
                          ('odom', b'\x00\x07\x00\x00' + bytes(300)),
                          ('cmd', twist(math.nan)),
                          ('cmd', twist(0.5, omega=-math.inf)),
                          ('cmd', b'\x00\x01\x00\x00\x00\x00'),
                          ('wall', bad_wall),
                          ('wall', serialize_message(markers(good['wall']))[:-40])):
            inputs[name] = bad
            assert h.spin_until(stopped, 5.0, feed, 1.0 / RATE), f'no brake on bad {name}'
            if isinstance(bad, bytes):  # refused as malformed, not merely gone stale
                reason = 'encapsulation' if name == 'odom' else 'truncated'
                assert h.spin_until(lambda: reason in latest_status(diagnostics)[1].get(
                    'last_invalid_message', ''), 5.0, feed, 1.0 / RATE), reason
            inputs[name] = good[name]
            assert h.spin_until(moving, 5.0, feed, 1.0 / RATE), f'no recovery after {name}'

        bad_outputs = [m for _, m in out if not _finite(m)]
        assert not bad_outputs, f'non-finite output: {bad_outputs[0]}'
        def counted():
            values = latest_status(diagnostics)[1]
            return (int(values.get('steps_invalid_input', 0)) > 0
                    and int(values.get('invalid_messages', 0)) >= 8)

        assert h.spin_until(counted, 3.0, feed, 1.0 / RATE), latest_status(diagnostics)


@pytest.mark.slow
def test_degenerate_polygons_are_handled_or_rejected_with_a_reason():
    """A point, repeated points, collinear points become thin walls; a bowtie is rejected.

    The node keeps answering throughout, and diagnostics name the rejected marker; with
    ``block_if_invalid`` off the robot keeps driving past the rejected one.
    """
    with running_filter(params={'model': 'unicycle', 'rate': RATE,
                                'block_if_invalid': False}) as proc, Harness() as h:
        io = h.filter_io(proc)
        out, diagnostics = io.out, io.diagnostics
        degenerate = markers(
            wall([(4.0, 0.0)], marker_id=1, width=0.0),
            wall([(4.0, 1.0)] * 3, marker_id=2, width=0.0),
            wall([(4.0, 2.0), (5.0, 2.0), (6.0, 2.0)], marker_id=3),
            wall([(4.0, 3.0), (5.0, 3.0), (5.0, 3.0), (5.0, 4.0), (4.0, 3.0)], marker_id=4),
            wall([(4.0, -3.0), (5.0, -2.0), (5.0, -3.0), (4.0, -2.0)], marker_id=5))

        def feed():
            io.odom.publish(odometry(v=0.5))
            io.cmd.publish(twist(0.5))
            io.obstacles.publish(degenerate)

        def reported():
            values = latest_status(diagnostics)[1]
            return values.get('obstacles_tracked') == '4' and values['obstacles_rejected'] == '1'

        assert h.spin_until(reported, 15.0, feed, 1.0 / RATE), (latest_status(diagnostics),
                                                                 node_log(proc))
        _, values = latest_status(diagnostics)
        assert 'self-intersecting' in values['rejected walls/5']
        assert values['obstacles_in_use'] == '4'
        count = len(out)
        assert h.spin_until(lambda: len(out) > count + 10, 5.0, feed, 1.0 / RATE)
        assert proc.poll() is None and out[-1][1].linear.x > 0.4
