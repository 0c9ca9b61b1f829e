"""Logging from a control loop without rclpy's per-call source inspection.

rclpy's ``RcutilsLogger.log`` names its caller on every call, throttled or not, with
``inspect.getframeinfo``: it reads the caller's source lines and, through
``inspect.getmodule``, walks every loaded module.  ``bench/bench_logging.py`` measures it
in this package's venv (numpy, scipy, rclpy loaded): tens of milliseconds for the first
call of a site and about half a millisecond for every later one, also when the throttle
suppresses the message.  In ``safety_filter`` that first call is what held one control
step for 50 ms when a rejected obstacle message was first reported
(``bench/bench_obstacle_flood.py``, case ``markers_5000``); at 1 kHz half a millisecond
is half a period.

``LoopLogger`` finds its caller with ``sys._getframe`` (a pointer walk), throttles per
call site on the steady clock as rclpy does (the first message passes, then none for
``throttle_s``), and hands the text to the same rcutils function rclpy ends in, so the
message reaches the console, ``/rosout`` and the log file like any node log.
"""
import sys
import time

from rclpy.impl.logging_severity import LoggingSeverity

from polyc2bf_ros import rclpy_private


class LoopLogger:
    """``error`` / ``warning`` / ``info`` of one rclpy logger, cheap enough for every step."""

    def __init__(self, logger, clock=time.monotonic):
        """Log under the name of ``logger`` (``node.get_logger()``)."""
        self.name = logger.name
        self._clock = clock
        self._last = {}  # call site (code object, instruction) -> steady time of its last log

    def error(self, message, throttle_s=0.0):
        """Log ``message`` at ERROR; return whether it was emitted."""
        return self._log(LoggingSeverity.ERROR, message, throttle_s)

    def warning(self, message, throttle_s=0.0):
        """Log ``message`` at WARN; return whether it was emitted."""
        return self._log(LoggingSeverity.WARN, message, throttle_s)

    def info(self, message, throttle_s=0.0):
        """Log ``message`` at INFO; return whether it was emitted."""
        return self._log(LoggingSeverity.INFO, message, throttle_s)

    def _log(self, severity, message, throttle_s):
        if not rclpy_private.logger_is_enabled_for(self.name, severity):
            return False
        frame = sys._getframe(2)  # the caller of error/warning/info
        code = frame.f_code
        if throttle_s > 0.0:
            site, now = (code, frame.f_lasti), self._clock()
            last = self._last.get(site)
            if last is not None and now - last < throttle_s:
                return False
            self._last[site] = now
        rclpy_private.log(severity, self.name, str(message), code.co_name, code.co_filename,
                          frame.f_lineno)
        return True
