"""The nominal command: the decision's input, and the message that carries the answer.

``cmd_vel_in`` (Twist, or TwistStamped with ``stamped:=true``) for the velocity-interface
models, ``wrench_in`` (WrenchStamped) for ``quadrotor``; reliable, depth 1.  Taken
serialized (``conversions.SerializedCommand``: its six numbers, and the stamp of a stamped
one).  Every message feeds the ``cmd`` watchdog; a finite one is the decision's nominal
command, a non-finite or malformed one leaves it without (the step brakes) and is reported.
The last readable command is kept: the answer is a copy of its bytes with the six numbers
replaced, so a malformed one is answered in the message before it.  With
``trigger:=command`` each command is answered at once, or with ``match_stamps`` once its
inputs are in (``lockstep_gate``).
"""
import time

from geometry_msgs.msg import Twist, TwistStamped, WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy

from polyc2bf_ros import conversions

COMMAND_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)  # in and out


def command_topics(velocity, stamped):
    """Return the command's (message type, input topic, output topic).

    ``velocity``: the model takes velocity commands; ``stamped``: as TwistStamped.
    """
    if velocity:
        return (TwistStamped if stamped else Twist), 'cmd_vel_in', 'cmd_vel_out'
    return WrenchStamped, 'wrench_in', 'wrench_out'


class CommandPort:
    """The nominal command's subscription and its last readable message (module docstring)."""

    def __init__(self, node, decision, invalid, gate, step, msg_type, topic, has_header,
                 model_name):
        """Subscribe ``topic`` (``msg_type``) on ``node``; feed ``decision`` the command.

        ``invalid``: the ``InvalidMessages``; ``gate``: the ``LockstepGate`` that answers a
        stamped command, or None; ``step(now)``: answers each command (``trigger:=command``),
        or None; ``has_header``: the message starts with a header; ``model_name``: whose
        command vector the six numbers make.
        """
        self._decision, self._gate, self._step = decision, gate, step
        self._invalid = invalid.report
        self._has_header, self._model_name = has_header, model_name
        self.last = None  # the last readable nominal command (its bytes carry the answer)
        node._subscribe(msg_type, topic, self.on_command, COMMAND_QOS)

    def on_command(self, data):
        """Store the nominal command; with ``trigger:=command`` answer it right away."""
        now = time.monotonic()
        try:
            cmd = conversions.SerializedCommand(data, self._has_header)
        except ValueError as exc:
            cmd = None  # malformed: the previous command's bytes carry the stop
            self._invalid(f'nominal command ({exc})')
        if cmd is None or not cmd.finite:
            self._decision.command(now)
        else:
            self._decision.command(now, conversions.command_from_values(cmd.values,
                                                                        self._model_name))
        if cmd is not None:
            self.last = cmd
            if not cmd.finite:
                self._invalid('nominal command (NaN/Inf)')
            if self._gate is not None:
                self._gate.hold(cmd.stamp)
                return
        if self._step is not None:
            self._step(now)
