"""Invalid input messages: each brakes the robot; counted, the last one named, logged."""


class InvalidMessages:
    """What the input ports could not use, for ``/diagnostics`` (``reporter``)."""

    def __init__(self, log):
        """Log through ``log`` (a ``loop_log.LoopLogger``)."""
        self._log = log
        self.count = 0
        self.last = 'none'  # what the last one was, and why

    def report(self, what):
        """Count and log an invalid message (``what``: its input, and why)."""
        self.count += 1
        self.last = what
        self._log.error(f'invalid {what}: braking', throttle_s=1.0)
