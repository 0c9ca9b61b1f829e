"""``/tf_static`` (tf2_msgs/TFMessage) for placing scans: no tf2 buffer, the worker chains them.

As tf2's static listener (reliable, transient local, depth 100): every static transform ever
sent, from every broadcaster.  The serialized messages go to the obstacle worker
(``obstacle_intake``, ``static_transforms``).  Without the tf2_msgs Python package (the PyPI
ROS wheels) a warning says that ``/tf_static`` is not read: scans are taken at
``sensor_pose``.
"""
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

try:
    from tf2_msgs.msg import TFMessage
except ImportError:  # the PyPI ROS wheels have no tf2_msgs: scans use sensor_pose only
    TFMessage = None

STATIC_TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


def subscribe_static_transforms(node, intake):
    """Queue ``/tf_static`` messages in ``intake``; without tf2_msgs, say that it is not read."""
    if TFMessage is None:
        node.get_logger().warning(
            'tf2_msgs is not installed: /tf_static is not read, scans in a frame other '
            'than the odometry child frame are taken at sensor_pose')
        return
    node._subscribe(TFMessage, '/tf_static', intake.submit_transforms, STATIC_TF_QOS)
