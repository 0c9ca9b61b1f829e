"""``footprint_topic`` (geometry_msgs/PolygonStamped): the robot's footprint as it changes.

As Nav2's collision monitor takes a footprint from a topic: each polygon replaces the
``filter.footprint`` parameter, through the node's own parameter check, so a polygon is
taken or refused exactly as the same string set by hand would be (``geometry.footprint``)
and the filter is rebuilt for it.  A refused polygon is logged with the reason and the
previous footprint stays.  The polygon must be in the odometry child frame (an empty
``frame_id`` is taken to be it; before the first odometry the frame is not checked).
Reliable, volatile, depth 1: a newer polygon supersedes an older one.
"""
from geometry_msgs.msg import PolygonStamped
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from polyc2bf_ros.core.geometry.footprint import format_footprint

FOOTPRINT_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
FOOTPRINT_PARAMETER = 'filter.footprint'


class FootprintPort:
    """The footprint subscription (module docstring)."""

    def __init__(self, node, topic, odometry, log):
        """Subscribe on ``node`` to ``topic``; frames are checked against ``odometry``'s."""
        self._node, self._topic, self._odometry, self._log = node, topic, odometry, log
        node._keep(node.destroy_subscription, node.create_subscription(
            PolygonStamped, topic, self.on_footprint, FOOTPRINT_QOS))

    def on_footprint(self, message):
        """Set ``filter.footprint`` to the polygon of ``message``, or log why it is refused."""
        frame, body = message.header.frame_id.lstrip('/'), self._odometry.child_frame
        if frame and body and frame != body:
            self._refuse(f'it is in frame {frame!r}, not the odometry child frame {body!r}')
            return
        text = format_footprint([(point.x, point.y) for point in message.polygon.points])
        if text == self._node.get_parameter(FOOTPRINT_PARAMETER).value:
            return
        result = self._node.set_parameters([Parameter(FOOTPRINT_PARAMETER, value=text)])[0]
        if result.successful:
            self._log.info(f'footprint from {self._topic!r}: {text}')
        else:
            self._refuse(result.reason)

    def _refuse(self, reason):
        """Log a refused polygon with the footprint that stays."""
        kept = self._node.get_parameter(FOOTPRINT_PARAMETER).value
        self._log.error(f'footprint on {self._topic!r} refused: {reason}; keeping {kept}',
                        throttle_s=1.0)
