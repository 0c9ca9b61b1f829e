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

A robot can also be stuck without standing: circling a cluster, or held and let go by
turns, as a circulation that keeps finding the way barred does.  So, with ``stuck_time_s``
= T_s and ``stuck_radius_m`` = R_s, the robot is also **stuck** once the nominal has asked
it to move (a component above ``MIN_INTERVENTION``) at every step of the last T_s seconds
while its body stayed within R_s of where it was when they began; a step whose nominal
asks for a stop, or a body farther than R_s from that anchor, starts that count again.
The report is a deadlock either way (``deadlocked``).  T_s = 0 turns the rule off.

A robot can also escape each hold and be held again, on and on: circling a cluster that
it never leaves, it covers more than R_s between reports.  So, with ``repeat_count`` = N
and ``repeat_window_s`` = W, the robot is also **deadlocked repeatedly** while at least N
reports (held or stuck onsets) fell within the last W seconds and the nominal still asks
it to move; N = 0 turns the rule off.  A robot told to stop (at its goal) is not reported.

The detector only reports: it changes no command.  ``onsets`` counts the deadlocks held in
place (a deadlock that ends and starts again counts twice; circulation engages on them),
``stuck_onsets`` the stuck reports, ``repeat_onsets`` the repeated reports.
"""
import math
from collections import deque

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


def asks_to_move(nominal):
    """Return True when a ``nominal`` command component exceeds ``MIN_INTERVENTION``."""
    return any(abs(float(value)) > MIN_INTERVENTION for value in nominal)


class _Stay:
    """One rule's count: since when a point has stayed within a radius while a condition held."""

    __slots__ = ('anchor', 'since', 'reached')

    def __init__(self):
        """Start with nothing counted."""
        self.clear()

    def clear(self):
        """Forget the count."""
        self.anchor, self.since, self.reached = None, math.nan, False

    def update(self, now, point, active, radius, duration):
        """Take one step; return True on the step the stay reaches ``duration`` (an onset).

        An inactive step, or ``point`` farther than ``radius`` from the anchor (where the stay
        began), starts the count again; ``point`` is only read on active steps.
        """
        if not active:
            self.anchor, self.since, self.reached = None, now, False
        elif self.anchor is None or math.dist(point, self.anchor) > radius:
            self.anchor, self.since, self.reached = tuple(map(float, point)), now, False
        elif not self.reached and now - self.since >= duration:
            self.reached = True
            return True
        return False


class DeadlockDetector:
    """The rule of the module docstring, fed one step at a time on a steady clock."""

    def __init__(self, time_s=3.0, radius_m=0.1, stuck_time_s=0.0, stuck_radius_m=1.0,
                 repeat_count=0, repeat_window_s=60.0):
        """Report a deadlock after ``time_s`` [s] held within ``radius_m`` [m].

        ``stuck_time_s`` [s] > 0: also once asked to move for that long within
        ``stuck_radius_m`` [m]; ``repeat_count`` > 0: also while that many reports fell
        within the last ``repeat_window_s`` [s] and the nominal asks to move.
        """
        self.configure(time_s, radius_m, stuck_time_s, stuck_radius_m, repeat_count,
                       repeat_window_s)
        self.onsets = 0
        self.stuck_onsets = 0
        self.repeat_onsets = 0
        self.deadlocked = False
        self.repeated = False
        self._hold = _Stay()   # the reference point, while held (``update``)
        self._stuck = _Stay()  # the body position, while asked to move (``track``)
        self._reports = deque()  # steady times of the recent held and stuck onsets
        self._moving = False     # the last tracked nominal asked to move

    def configure(self, time_s, radius_m, stuck_time_s=0.0, stuck_radius_m=1.0,
                  repeat_count=0, repeat_window_s=60.0):
        """Take new thresholds; the current count goes on."""
        if not (time_s > 0.0 and math.isfinite(time_s)):
            raise ValueError(f'deadlock time must be positive and finite, got {time_s!r}')
        if not (radius_m >= 0.0 and math.isfinite(radius_m)):
            raise ValueError(f'deadlock radius must be >= 0 and finite, got {radius_m!r}')
        if not (stuck_time_s >= 0.0 and math.isfinite(stuck_time_s)):
            raise ValueError(f'stuck time must be >= 0 and finite, got {stuck_time_s!r}')
        if not (stuck_radius_m >= 0.0 and math.isfinite(stuck_radius_m)):
            raise ValueError(f'stuck radius must be >= 0 and finite, got {stuck_radius_m!r}')
        if not (repeat_count >= 0 and float(repeat_count).is_integer()):
            raise ValueError(f'repeat count must be a whole number >= 0, got {repeat_count!r}')
        if not (repeat_window_s > 0.0 and math.isfinite(repeat_window_s)):
            raise ValueError(f'repeat window must be positive and finite, got '
                             f'{repeat_window_s!r}')
        self.time_s, self.radius_m = float(time_s), float(radius_m)
        self.stuck_time_s, self.stuck_radius_m = float(stuck_time_s), float(stuck_radius_m)
        self.repeat_count, self.repeat_window_s = int(repeat_count), float(repeat_window_s)

    @property
    def held(self):
        """Return whether the rule of holding in place reports a deadlock."""
        return self._hold.reached

    @property
    def stuck(self):
        """Return whether the rule of moving without getting away reports a deadlock."""
        return self._stuck.reached

    def held_s(self, now):
        """Return for how long [s] the robot has been held in place at ``now`` (0 if not)."""
        hold = self._hold
        return 0.0 if hold.anchor is None else max(0.0, now - hold.since)

    def update(self, now, position, holding):
        """Take one step at steady time ``now``; return whether the robot is deadlocked.

        ``position``: the reference point (only read when ``holding``: a step that does not
        hold may pass None); ``holding``: ``holds(...)`` of the step.
        """
        if self._hold.update(now, position, holding, self.radius_m, self.time_s):
            self.onsets += 1
            self._reports.append(now)
        self.deadlocked = self._hold.reached or self._stuck.reached or self._repeats(now)
        return self.deadlocked

    def _repeats(self, now):
        """Return the repeated rule's verdict at ``now``; count its onsets."""
        reports = self._reports
        while reports and now - reports[0] > self.repeat_window_s:
            reports.popleft()
        repeated = bool(self.repeat_count and self._moving
                        and len(reports) >= self.repeat_count)
        if repeated and not self.repeated:
            self.repeat_onsets += 1
        self.repeated = repeated
        return repeated

    def track(self, now, body, nominal):
        """Take one step's body position (x, y: ``body``'s first two entries) and nominal.

        The stuck rule of the module docstring; call before ``update``, which reports it.
        """
        self._moving = asks_to_move(nominal)
        if self.stuck_time_s and self._stuck.update(now, (body[0], body[1]), self._moving,
                                                     self.stuck_radius_m, self.stuck_time_s):
            self.stuck_onsets += 1
            self._reports.append(now)

    def clear(self):
        """Forget the current hold and request to move (stopped for another reason).

        The recent reports are kept: a robot stopped for a moment has not escaped.
        """
        self._hold.clear()
        self._stuck.clear()
        self.deadlocked = self.repeated = self._moving = False
