"""``match_stamps``: a stamped nominal command is answered once the inputs of its time are in.

With ``trigger:=command`` and ``match_stamps:=true`` a stamped command waits for odometry
stamped no earlier than it, and for the obstacle worker to have processed every obstacle
input received before the command or before that odometry (messages, a new odometry frame);
then it gets its one step.  A lockstep simulation so gets the same answers however long the
worker takes.  The worker's passes end on its feeder thread: they wake the gate through a
guard condition, so the answer is given on the executor's thread.
"""
import time

from rclpy.exceptions import InvalidHandle


class LockstepGate:
    """Holds a stamped command until its odometry and obstacles are in (module docstring)."""

    def __init__(self, node, decision, intake, step):
        """Answer through ``step(now)`` once ``decision`` and ``intake`` have the inputs.

        The guard condition that wakes the gate is created on ``node`` (destroyed with the
        node's configuration).
        """
        self._decision, self._intake, self._step = decision, intake, step
        self.waiting = False  # a command waits for its odometry and obstacles
        self._stamp = 0.0  # the waiting command's stamp [s]
        self._needed = 0  # the obstacle intake generation it needs
        self._obstacles_ready = node._keep(node.destroy_guard_condition,
                                           node.create_guard_condition(self.answer_if_ready))

    def hold(self, stamp):
        """Take a command stamped ``stamp`` [s]; answer it once its inputs are in (maybe now)."""
        self._stamp = stamp
        self._needed = self._intake.generation
        self.waiting = True
        self.answer_if_ready()

    def on_odometry(self):
        """Odometry came: a waiting command's answer uses it, and the obstacles as of it."""
        if self.waiting:
            self._needed = self._intake.generation  # a new frame counts too
            self.answer_if_ready()

    def answer_if_ready(self):
        """Answer the waiting command if its odometry and obstacles are in."""
        if (self.waiting and self._decision.odom_stamp >= self._stamp
                and self._intake.covers(self._needed)):
            self.waiting = False
            self._step(time.monotonic())

    def obstacles_processed(self):
        """Feeder thread, after each obstacle pass: wake a command that waits for its obstacles.

        On a loaded machine a pass can end after ``destroy_node`` gave up waiting for it
        (Ctrl-C while the worker was busy): the guard condition is gone then, and nothing
        waits for it.
        """
        try:
            self._obstacles_ready.trigger()
        except InvalidHandle:
            pass
