"""A progress bar with an ETA on stderr, for every suite's long runs."""
import math
import sys
import time


class Progress:
    """A progress bar with ETA on stderr (scenario suite: simulated robot-seconds; BARN: runs)."""

    def __init__(self, total, stream=None, width=30):
        """Expect ``total`` units of work; write to ``stream`` (stderr)."""
        self.total = max(total, 1e-9)
        self.done = 0.0
        self.stream = stream or sys.stderr
        self.width = width
        self.start = time.monotonic()
        self.tty = self.stream.isatty()
        self._last = 0.0

    def update(self, done, label, force=False):
        """Show ``done`` units finished, working on ``label``."""
        self.done = done
        now = time.monotonic()
        if not force and now - self._last < (0.2 if self.tty else 10.0):
            return
        self._last = now
        share = min(self.done / self.total, 1.0)
        elapsed = now - self.start
        eta = elapsed * (1.0 - share) / share if share > 0 else math.nan
        bar = '#' * int(share * self.width)
        text = (f'[{bar:<{self.width}}] {100 * share:5.1f} %  {elapsed:6.0f} s elapsed, '
                f'ETA {eta:5.0f} s  {label}')
        self.stream.write(('\r' + text[:160].ljust(160)) if self.tty else text + '\n')
        self.stream.flush()

    def close(self):
        """End the bar's line."""
        if self.tty:
            self.stream.write('\n')
            self.stream.flush()
