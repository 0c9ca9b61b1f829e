"""Deadlock detection: the filter holds the robot in place against its nominal command.

A min-norm CBF-QP with a go-to-goal nominal has stable equilibria on the boundary of the
safe set (Reis, Aguiar & Tabuada 2021): in front of a box straight ahead the filter and
the nominal cancel, the robot stands, and nothing in the QP ever changes that.  This
module tells that apart from a robot that stands because it was told to.

Rule, with ``time_s`` = T and ``radius_m`` = R:

- a step **holds** the robot when the filter had to act and changed what the nominal
  asked for: a constraint is active (``FilterInfo.active``) or the step was a slack,
  brake or escape step, and the safe command differs from the nominal one by more than
  ``MIN_INTERVENTION`` (largest component, in the command's units: m/s and rad/s for
  velocity commands, N and N m for wrenches).  At rest before a wall the barrier keeps a
  constraint active even for a nominal stop (it backs off by micrometres per second), so
  the difference is what tells a robot told to stand from one held back;
- the robot is **deadlocked** once every step of the last T seconds held it and its
  reference point stayed within R of where it was when those T seconds began.

A step that does not hold the robot, or a reference point farther than R from that
anchor, starts the count again from that step.  So a robot that creeps slower than R / T
counts as deadlocked, one that stops at its goal (its nominal asks for the stop, so no
constraint is active) does not, and one the filter slows but lets through does not either.
BARN's own stall rule is the same test on the position alone (0.1 m for 10 s).

The detector only reports: it changes no command.  ``onsets`` counts the deadlocks
(a deadlock that ends and starts again counts twice).
"""
import math

from polyc2bf_ros.core.safety_filter import FilterStatus

HOLDING_STATUSES = frozenset({FilterStatus.SLACK, FilterStatus.BRAKE, FilterStatus.ESCAPE,
                              FilterStatus.BACKUP})
MIN_INTERVENTION = 0.05


def holds(info, nominal, safe):
    """Return True when the step of ``info`` (a ``FilterInfo``) held back the ``nominal``.

    ``nominal`` and ``safe``: the step's nominal and safe command vectors (plain Python
    on these few numbers: numpy's per-call cost would be most of the step's share).
    """
    if not (len(info.active) or info.status in HOLDING_STATUSES):
        return False
    return any(abs(float(a) - float(b)) > MIN_INTERVENTION for a, b in zip(nominal, safe))


class DeadlockDetector:
    """The rule of the module docstring, fed one step at a time on a steady clock."""

    def __init__(self, time_s=3.0, radius_m=0.1):
        """Report a deadlock after ``time_s`` [s] held within ``radius_m`` [m]."""
        self.configure(time_s, radius_m)
        self.onsets = 0
        self.deadlocked = False
        self._anchor = None       # reference point where the current hold began
        self._since = math.nan    # steady time it began

    def configure(self, time_s, radius_m):
        """Take new thresholds; the current count goes on."""
        if not (time_s > 0.0 and math.isfinite(time_s)):
            raise ValueError(f'deadlock time must be positive and finite, got {time_s!r}')
        if not (radius_m >= 0.0 and math.isfinite(radius_m)):
            raise ValueError(f'deadlock radius must be >= 0 and finite, got {radius_m!r}')
        self.time_s, self.radius_m = float(time_s), float(radius_m)

    def held_s(self, now):
        """Return for how long [s] the robot has been held in place at ``now`` (0 if not)."""
        return 0.0 if self._anchor is None else max(0.0, now - self._since)

    def update(self, now, position, holding):
        """Take one step at steady time ``now``; return whether the robot is deadlocked.

        ``position``: the reference point (only read when ``holding``: a step that does not
        hold may pass None); ``holding``: ``holds(...)`` of the step.
        """
        if not holding:
            self._anchor, self._since, self.deadlocked = None, now, False
            return False
        if self._anchor is None or math.dist(position, self._anchor) > self.radius_m:
            self._anchor, self._since, self.deadlocked = tuple(map(float, position)), now, False
            return False
        if not self.deadlocked and now - self._since >= self.time_s:
            self.deadlocked = True
            self.onsets += 1
        return self.deadlocked

    def clear(self):
        """Forget the current hold (the robot is stopped for another reason)."""
        self._anchor = None
        self._since = math.nan
        self.deadlocked = False
