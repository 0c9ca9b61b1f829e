"""An independent stop: a thread that acts when the control loop stops beating.

The control loop calls ``beat`` on every step and control tick; the first beat arms the
guard (start-up takes as long as it takes).  The guard's own thread wakes every
``period`` s on the steady clock; once no beat has come for ``timeout`` s it
calls ``on_stall(silence_s)`` on every wake-up until the beats resume, and counts one stall.
It covers any callback that never returns (a runaway computation, a blocked call): while
CPython's interpreter is shared, a thread that runs Python hands it over every
``sys.getswitchinterval()`` s, and a blocking call releases it.  Only native code that
holds the interpreter lock without end could still silence it.
"""
import threading
import time


class StallGuard:
    """Calls ``on_stall`` from its own thread while the loop is silent (module docstring)."""

    def __init__(self, timeout, on_stall, period=None, clock=time.monotonic):
        """Act after ``timeout`` s without a beat; check every ``period`` (default timeout/4)."""
        if not timeout > 0.0:
            raise ValueError(f'stall timeout must be positive, got {timeout!r}')
        self.timeout = float(timeout)
        self.period = float(period) if period is not None else self.timeout / 4.0
        self._on_stall = on_stall
        self._clock = clock
        self._last = None  # armed by the first beat
        self._stop = threading.Event()
        self._thread = None
        self.stalls = 0
        self.stalled = False

    def beat(self, now=None):
        """Record that the control loop ran (at monotonic ``now``, default the clock)."""
        self._last = self._clock() if now is None else now

    def check(self, now):
        """One wake-up at ``now``: call ``on_stall`` if silent too long; return whether it did."""
        if self._last is None:
            return False
        silence = now - self._last
        if silence < self.timeout:
            self.stalled = False
            return False
        if not self.stalled:
            self.stalls += 1
            self.stalled = True
        self._on_stall(silence)
        return True

    def start(self):
        """Start the guard's thread (a daemon)."""
        self._thread = threading.Thread(target=self._run, name='stall_guard', daemon=True)
        self._thread.start()

    def stop(self, timeout=1.0):
        """End the thread and wait up to ``timeout`` s for it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self):
        while not self._stop.wait(self.period):
            self.check(self._clock())
