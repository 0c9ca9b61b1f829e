"""``footprint_topic``: a new footprint takes effect over DDS; a bad one is refused, old kept."""
import pytest
from geometry_msgs.msg import Point32, PolygonStamped

from node_harness import Harness, markers, node_log, odometry, running_filter, twist, wall

RATE = 50.0
WAIT = 30.0


def polygon(points, frame='base_link'):
    """Return a PolygonStamped of ``points`` in ``frame``."""
    msg = PolygonStamped()
    msg.header.frame_id = frame
    msg.polygon.points = [Point32(x=float(x), y=float(y)) for x, y in points]
    return msg


def rectangle(half_length, half_width):
    """Return the rectangle about the base's origin, as Nav2 lists it."""
    return [(half_length, half_width), (-half_length, half_width),
            (-half_length, -half_width), (half_length, -half_width)]


@pytest.mark.slow
def test_a_footprint_from_the_topic_takes_effect_and_a_bad_one_leaves_it():
    """A wall 1.2 m ahead: the 0.3 m disc drives on; a 2.6 m long body is already at it.

    Then a crossed polygon, one in another frame and one with three points on a line are
    each refused with its reason in the log, and the long body stays (no forward command).
    """
    params = {'model': 'unicycle', 'rate': RATE, 'stall_timeout': 10.0,
              'footprint_topic': 'footprint'}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        out = io.out
        footprints = h.publisher(PolygonStamped, 'footprint')
        h.wait_for_subscribers(footprints)
        pending = []

        def feed():
            io.odom.publish(odometry())
            io.cmd.publish(twist(0.3))
            io.obstacles.publish(markers(wall([(1.2, -2.0), (1.2, 2.0)])))
            for msg in pending:
                footprints.publish(msg)

        def forward():
            return bool(out) and out[-1][1].linear.x > 0.001

        def not_forward():
            return bool(out) and out[-1][1].linear.x <= 0.0

        assert h.spin_until(forward, WAIT, feed, 1.0 / RATE), (out[-3:], node_log(proc))
        pending[:] = [polygon(rectangle(1.3, 0.3))]
        assert h.spin_until(not_forward, WAIT, feed, 1.0 / RATE), (out[-3:], node_log(proc))
        assert "footprint from 'footprint': [[1.2999" in node_log(proc)
        for bad, reason in (
                (polygon([(1.3, 0.3), (-1.3, -0.3), (-1.3, 0.3), (1.3, -0.3)]),
                 'self-intersecting'),
                (polygon(rectangle(0.2, 0.2), frame='map'),
                 "in frame 'map', not the odometry child frame 'base_link'"),
                (polygon([(0.0, 0.0), (0.1, 0.0), (0.2, 0.0)]), 'collinear')):
            pending[:] = [bad]
            assert h.spin_until(lambda: reason in node_log(proc), WAIT, feed, 1.0 / RATE), \
                node_log(proc)
            h.spin_for(0.3)
            assert not_forward(), out[-3:]
        assert 'keeping [[1.2999' in node_log(proc)
        pending[:] = [polygon(rectangle(0.3, 0.2))]
        assert h.spin_until(forward, WAIT, feed, 1.0 / RATE), (out[-3:], node_log(proc))
