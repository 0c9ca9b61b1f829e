"""The obstacle worker's snapshots into the decision, as the control loop takes them.

Markers, scans and static transforms go to the worker (``obstacle_intake``) from their ports;
its newest ``ObstacleSnapshot`` is handed to the decision before each step, stale-command
tick and status.  A new snapshot feeds the scan topics' watchdogs (``scan_port``), and an
unreadable or non-finite obstacle message is reported as invalid input (it brakes).
"""


class ObstacleFeed:
    """Hands the worker's newest obstacle snapshot to the decision (module docstring)."""

    def __init__(self, intake, decision, scans, invalid, log):
        """Feed ``decision`` the snapshots of ``intake``.

        ``scans``: the ``ScanPort`` whose watchdogs a snapshot feeds, or None; ``invalid``:
        the inputs' ``InvalidMessages``; ``log``: the control path's logger.
        """
        self._intake, self._decision, self._scans = intake, decision, scans
        self._invalid, self._log = invalid, log

    def take(self):
        """Hand the worker's newest snapshot to the decision; log what is wrong with it."""
        snapshot, previous = self._intake.snapshot, self._decision.snapshot
        if snapshot is previous:
            return snapshot
        self._decision.obstacles(snapshot)
        if self._scans is not None:
            self._scans.take()
        if snapshot.received != previous.received or snapshot.unreadable != previous.unreadable:
            if snapshot.unreadable:
                self._invalid.report(f'obstacles ({snapshot.unreadable})')
            elif snapshot.invalid:
                self._invalid.report('obstacles (NaN/Inf)')
            if snapshot.error:
                self._log.error(snapshot.error, throttle_s=1.0)
        return snapshot
