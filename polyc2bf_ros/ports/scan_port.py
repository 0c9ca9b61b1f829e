"""``scan_topics`` (sensor_msgs/LaserScan): scans for the obstacle worker, a watchdog per topic.

Best effort, depth 5.  Each scan is queued serialized with the recent odometry
(``odometry_port``); the worker (``obstacle_intake``) places it at the odometry's pose at
its ``header.stamp`` (interpolated between the messages around it), through the static
transforms from the odometry child frame to its frame (``transform_port``) or else at
``sensor_pose``, and its obstacles join the markers'.  Each topic has its own
``scan_timeout`` watchdog, fed with the receipt time of its newest accepted scan (of any
scan without ``block_if_invalid``); a rejected scan is logged, and its topic's last
obstacles are kept until the watchdog stops the robot.
"""
import functools
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan

SCAN_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)


class ScanPort:
    """The scan subscriptions and their watchdogs (module docstring)."""

    def __init__(self, node, decision, intake, log, odometry, watchdogs):
        """Subscribe on ``node`` each topic of ``watchdogs`` (``{topic: its watchdog}``).

        Scans go to ``intake`` with the poses kept by ``odometry`` (an ``OdometryPort``);
        ``decision`` holds the watchdogs; rejections are logged through ``log``.
        """
        self._decision, self._intake, self._log = decision, intake, log
        self._odometry, self._watchdogs = odometry, watchdogs
        self._fed = {}  # topic: receipt time last fed to its watchdog
        self._rejected = {}  # topic: rejections reported so far
        for topic in watchdogs:
            node._subscribe(LaserScan, topic, functools.partial(self.on_scan, topic), SCAN_QOS)

    def on_scan(self, topic, data):
        """Queue a serialized LaserScan of ``topic`` with the recent odometry."""
        odometry = self._odometry
        self._intake.submit_scan(topic, data, time.monotonic(), tuple(odometry.history),
                                 odometry.child_frame)

    def take(self):
        """Feed each topic's watchdog with its accepted scans; log rejected ones.

        Under ``block_if_invalid`` only accepted scans are fresh data, as for markers.
        """
        block = self._decision.block_if_invalid
        for topic, status in self._intake.scan_status.items():
            fresh = status.accepted if block else status.received
            if fresh is not None and fresh != self._fed.get(topic):
                self._fed[topic] = fresh
                self._decision.watchdog.feed(self._watchdogs[topic], fresh)
            if status.rejected != self._rejected.get(topic, 0):
                self._rejected[topic] = status.rejected
                self._log.error(f'rejected LaserScan on {topic!r}: {status.reason} (its last '
                                'obstacles kept; stop once it is stale)', throttle_s=1.0)
