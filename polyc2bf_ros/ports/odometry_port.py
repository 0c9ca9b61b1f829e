"""``odom`` (nav_msgs/Odometry): the robot's state, the odometry frames, poses for the scans.

Best effort, depth 1: it matches reliable and best-effort publishers.  Taken serialized;
only the stamp, frame ids, pose and twist are read (``conversions``, CDR section).  Every
message feeds the ``odom`` watchdog; a usable one gives the decision the model's state, yaw
and stamp, an unreadable or non-finite one leaves it without (the step brakes) and is
reported.  The obstacle worker builds the obstacles in the odometry's ``header.frame_id``.
With scan topics the port keeps the stamp and pose of the last ``ODOMETRY_HISTORY`` usable
messages: each scan is placed at their pose at its stamp (``scan_port``).
"""
import collections
import time

from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy

from polyc2bf_ros import conversions
from polyc2bf_ros.obstacle_intake import ODOMETRY_HISTORY

ODOMETRY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


class OdometryPort:
    """The ``odom`` subscription and what it keeps of the odometry (module docstring)."""

    def __init__(self, node, decision, intake, invalid, gate, model_name, keep_history):
        """Subscribe ``odom`` on ``node``; feed ``decision`` the state of ``model_name``.

        ``intake`` gets the odometry frame; ``invalid``: the ``InvalidMessages``; ``gate``:
        the ``LockstepGate`` told of each odometry, or None; ``keep_history``: keep poses for
        placing scans.
        """
        self._decision, self._intake, self._gate = decision, intake, gate
        self._invalid = invalid.report
        self._model_name = model_name
        self.frame = None  # the odometry frame, once odometry came
        self.child_frame = ''  # the odometry child (body) frame
        self._frame_raw = self._child_frame_raw = None
        # (stamp, x, y, yaw) of recent usable odometry, oldest first: with scan topics only.
        self.history = collections.deque(maxlen=ODOMETRY_HISTORY)
        self.callback = self._on_odometry_for_scans if keep_history else self.on_odometry
        node._subscribe(Odometry, 'odom', self.callback, ODOMETRY_QOS)

    def on_odometry(self, data):
        """Read serialized odometry into the decision's state; keep the last finite one."""
        now = time.monotonic()
        try:
            odom = conversions.read_odometry(data)
        except ValueError as exc:
            self._decision.odometry(now)
            self._invalid(f'odometry ({exc})')
            return
        result = conversions.state_from_odometry(self._model_name, odom.pose, odom.twist)
        if result is None:
            self._decision.odometry(now)
            self._invalid('odometry (NaN/Inf)')
            return
        # The state is a tuple of floats: the core converts it once.
        self._decision.odometry(now, result[0], result[1], odom.stamp)
        frame = odom.frame
        if frame != self._frame_raw:
            self._frame_raw = frame
            self.frame = frame.decode(errors='replace').lstrip('/')
            self._intake.set_frame(self.frame)
        if odom.child_frame != self._child_frame_raw:
            self._child_frame_raw = odom.child_frame
            self.child_frame = odom.child_frame.decode(errors='replace').lstrip('/')
        if self._gate is not None:
            self._gate.on_odometry()

    def _on_odometry_for_scans(self, data):
        """``on_odometry``, then keep a usable odometry's stamp and pose for placing scans."""
        self.on_odometry(data)
        decision = self._decision
        if decision.odom_valid:
            state = decision.state
            self.history.append((decision.odom_stamp, state[0], state[1], decision.yaw))
