"""``obstacles`` (visualization_msgs/MarkerArray): obstacle maps for the obstacle worker.

Reliable and transient local, so a filter started late still gets a latched map.  The
callback only queues the serialized message with its receipt time (``obstacle_intake``):
reading, conflating and preparing run in the worker process, and the ``obstacles`` watchdog
is fed from the snapshot it returns (``core.decision``).  Not subscribed with
``use_markers:=false``.
"""
import time

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

MARKER_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


class MarkerPort:
    """The ``obstacles`` subscription (module docstring)."""

    def __init__(self, node, intake):
        """Subscribe ``obstacles`` on ``node``; queue its messages in ``intake``."""
        self._intake = intake
        node._subscribe(MarkerArray, 'obstacles', self.on_markers, MARKER_QOS)

    def on_markers(self, data):
        """Queue a serialized MarkerArray for the obstacle worker."""
        self._intake.submit(data, time.monotonic())
