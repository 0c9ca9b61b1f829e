"""Step statistics for diagnostics: latency percentiles and achieved rate.

Both are cheap to feed on the hot path (one list store, one integer add)
and summarised only when diagnostics are published.
"""
import numpy as np


class LatencyRing:
    """The last ``capacity`` latencies [s] in a preallocated ring (a list: one store per step)."""

    def __init__(self, capacity=4096):
        """Allocate room for ``capacity`` samples."""
        self._buf = [0.0] * int(capacity)
        self._next = 0
        self._count = 0

    def __len__(self):
        """Return the number of samples held (at most ``capacity``)."""
        return self._count

    def add(self, seconds):
        """Record one latency."""
        index = self._next
        self._buf[index] = seconds
        self._next = index + 1 if index + 1 < len(self._buf) else 0
        if self._count <= index:
            self._count = index + 1

    def clear(self):
        """Forget every sample (start a new reporting window)."""
        self._next = self._count = 0

    def percentiles(self, qs=(50.0, 99.0)):
        """Percentiles ``qs`` of the samples held; ``nan`` each when empty."""
        if self._count == 0:
            return tuple(float('nan') for _ in qs)
        return tuple(float(v) for v in np.percentile(self._buf[:self._count], qs))


class RateMeter:
    """Events per second between successive ``rate`` calls."""

    def __init__(self, now):
        """Start the first window at monotonic time ``now``."""
        self._start = now
        self._events = 0

    def tick(self):
        """Count one event."""
        self._events += 1

    def rate(self, now):
        """Events per second since the previous call (or construction); starts a new window."""
        elapsed = now - self._start
        rate = self._events / elapsed if elapsed > 0.0 else float('nan')
        self._start, self._events = now, 0
        return rate
