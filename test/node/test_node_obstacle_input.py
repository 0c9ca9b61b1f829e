"""Obstacle messages in the node's decision: an in-process node, its callbacks called directly.

Obstacle messages are processed by the node's worker thread; ``take`` waits for the pass
that covers a submitted message (``ObstacleIntake.process``).
"""
import rclpy
from geometry_msgs.msg import Twist
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message

from node_harness import markers, odometry, twist, wall
from polyc2bf_ros.safety_filter_node import SafetyFilterNode

FAR_WALL = [(6.0, -1.0), (6.0, 1.0)]


def test_unreadable_obstacles_brake_until_a_readable_message():
    """A truncated MarkerArray stops the robot until a readable one arrives.

    The brake survives an odometry frame change (which rebuilds the obstacle set: in
    frame ``map`` the odom-frame wall is not used, so only the unreadable message can
    stop the robot there, with ``block_if_invalid`` off), and the unreadable message is
    not fresh obstacles.
    """
    context = rclpy.Context()
    rclpy.init(context=context)
    node = SafetyFilterNode(context=context, parameter_overrides=[
        Parameter('trigger', value='command'), Parameter('obstacles_timeout', value=0.0),
        Parameter('block_if_invalid', value=False)])
    answers = []
    node._publish = answers.append  # the serialized answers, instead of DDS
    good = serialize_message(markers(wall(FAR_WALL)))
    try:
        def take(data):
            node._on_obstacles(data)
            node._intake.process()

        def answer(frame='odom'):
            node._on_odom(serialize_message(odometry(v=0.5, frame=frame)))
            node._intake.process()  # the frame change rebuilds the set
            node._on_odom(serialize_message(odometry(v=0.5, frame=frame)))  # fresh odometry
            node._on_command(serialize_message(twist(0.5)))
            return deserialize_message(answers[-1], Twist).linear.x

        take(good)
        assert answer() > 0.4 and len(node._decision.snapshot.obstacles) == 1
        take(good[:-40])
        assert answer() == 0.0
        assert answer(frame='map') == 0.0
        counts = node._decision.counts
        assert counts['invalid_input'] == 2 and counts['stale_stop'] == 0
        assert 'truncated' in node._invalid.last
        take(good)
        assert answer(frame='map') > 0.4  # readable again; the wall is in another frame
        assert answer() > 0.4 and len(node._decision.snapshot.obstacles) == 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
