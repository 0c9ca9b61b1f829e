"""Per-input staleness on a steady clock.

The node feeds each input with ``time.monotonic()`` when a message arrives and
asks which inputs are stale before every step.  Times are plain arguments, so a
frozen ``/clock`` (simulated time) can never freeze a watchdog and the tests
need no clock at all.

An input is stale when it never arrived, or when ``now - last >= timeout``.  A
timeout of ``0`` means "never stale once received" (e.g. a latched, static
obstacle map that is published once).
"""
import math


class Watchdog:
    """Staleness tracker for a fixed set of named inputs."""

    def __init__(self, timeouts):
        """Create from ``{name: timeout_s}``; every input starts as never received."""
        self._timeouts = {}
        self._last = {}
        for name, timeout in timeouts.items():
            self.set_timeout(name, timeout)
            self._last[name] = None

    @property
    def names(self):
        """Input names, in construction order."""
        return tuple(self._timeouts)

    def set_timeout(self, name, timeout):
        """Set the timeout of ``name`` in seconds (``0`` disables expiry)."""
        timeout = float(timeout)
        if not timeout >= 0.0 or math.isinf(timeout):
            raise ValueError(f'watchdog timeout for {name!r} must be finite and >= 0, '
                             f'got {timeout}')
        self._timeouts[name] = timeout

    def timeout(self, name):
        """Timeout of ``name`` in seconds."""
        return self._timeouts[name]

    def feed(self, name, now):
        """Record that ``name`` arrived at monotonic time ``now``."""
        self._last[name] = now

    def age(self, name, now):
        """Seconds since ``name`` last arrived; ``inf`` if it never did."""
        last = self._last[name]
        return math.inf if last is None else now - last

    def is_stale(self, name, now):
        """Return True if ``name`` never arrived or is older than its (non-zero) timeout."""
        return _expired(self._last[name], self._timeouts[name], now)

    def stale(self, now):
        """Names of all stale inputs, in construction order (empty tuple if none)."""
        return tuple(name for name in self._timeouts if self.is_stale(name, now))

    def any_stale(self, now):
        """Return whether any input is stale (``stale`` without naming them: per step)."""
        last = self._last
        for name, timeout in self._timeouts.items():
            if _expired(last[name], timeout, now):
                return True
        return False


def _expired(last, timeout, now):
    """Return True if an input last seen at ``last`` (None: never) is stale at ``now``."""
    return last is None or (timeout > 0.0 and now - last >= timeout)
