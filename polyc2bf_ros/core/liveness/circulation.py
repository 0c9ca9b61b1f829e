"""Deadlock resolution by circulation: steer the nominal along the blocking obstacle.

Once the deadlock report (``core.liveness.deadlock``) fires, the unicycle's nominal command is
replaced by one that drives along the boundary of the obstacle holding it, on one side,
latched (after Keyumarsi et al. 2025, "circulation" around the active constraint).  The
safety filter then filters that command like any other: no CBF row is dropped or relaxed,
so the guarantee is the filter's, unchanged; only the wish it is asked to grant changes.

Per step while circulating, with p the cone axis of the obstacle part with the smallest
h (from the robot's reference point toward it; the previous step's cones), side
sigma in {+1 left, -1 right} and the circulation speed v_n::

    t      = R(sigma pi/2) p / |p|                      (tangent, on the latched side)
    e      = wrap(atan2(t) - theta)                     (heading error)
    omega* = clip(k_theta e, +-omega_max)
    v*     = v_n max(0, cos e)                          (turn first when facing away)

v_n is the larger of the nominal's current |v| and its |v| when the deadlock was reported.
A go-to-goal law asks for v = 0 whenever the goal lies more than 90 degrees off the
heading, which the tangent of an obstacle straight ahead is: with its current speed alone,
circulation would only turn the robot sideways and stand there.  A nominal stop (every
component zero) is passed through unchanged: circulation never moves a robot told to stand.

The side is chosen once, when the deadlock is reported: the side of p the robot's heading
already lies on (sigma = sign(p x heading), left on a tie), so the robot turns the short
way.  A second report while circulating (held again, e.g. in a corner) flips the side, and
so does a deadlock that outlasts a circulation (``max_time`` ran out, still held): the
next one starts at once, on the other side.
Circulation ends, and the original nominal takes over again, when the way it asks for is
free: once the reference point is ``release_distance`` from where it began, and the filter
would pass the *probe* [max(|v|, v_n / 2), omega] of the nominal [v, omega] without holding
the robot (``core.liveness.deadlock.holds``; ``ControlDecision`` asks the filter, one extra
step per circulating step past that distance).  The probe drives on while it turns where the
nominal turns: a nominal that only turns in place (a go-to-goal law facing away from its
goal) would pass even with the obstacle still in the way.  So the robot follows the
obstacle until it has rounded it far enough to head where the nominal wants, not for a
fixed distance after which the nominal drives it back into the same obstacle.  It also
ends after ``max_time`` s.  Only unicycle velocity commands [v, omega] are circulated;
other models keep their nominal.
"""
import math

import numpy as np


def steer_towards(bearing, yaw, speed, turn_gain, max_turn_rate):
    """Return [v, omega] heading for ``bearing`` [rad], at most ``speed``.

    e = wrap(bearing - yaw), omega = clip(k e, +-omega_max), v = speed max(0, cos e): turn
    first when facing away.
    """
    error = (bearing - yaw + math.pi) % (2.0 * math.pi) - math.pi
    omega = min(max(turn_gain * error, -max_turn_rate), max_turn_rate)
    return np.array([speed * max(0.0, math.cos(error)), omega])


class Circulation:
    """The rule of the module docstring; ``ControlDecision`` drives it."""

    def __init__(self, release_distance=0.5, max_time=10.0, turn_gain=2.0, max_turn_rate=1.5):
        """Circulate at least ``release_distance`` [m] from the start, at most ``max_time`` [s]."""
        if not (release_distance > 0.0 and max_time > 0.0 and turn_gain > 0.0
                and max_turn_rate > 0.0):
            raise ValueError('circulation: release_distance, max_time, turn_gain and '
                             'max_turn_rate must be positive')
        self.release_distance, self.max_time = float(release_distance), float(max_time)
        self.turn_gain, self.max_turn_rate = float(turn_gain), float(max_turn_rate)
        self.side = 0          # +1 left, -1 right, 0 not circulating
        self.engagements = 0   # circulations started (a flipped side counts again)
        self._start = None
        self._since = math.nan
        self._axis = None      # cone axis of the blocking part, last known
        self._info = None      # the last step's filter info, its axis not yet taken
        self._speed = 0.0      # nominal |v| when the deadlock was reported
        self._last_side = 0    # the side of the last circulation

    @property
    def active(self):
        """Return True while circulating."""
        return self.side != 0

    @property
    def mode(self):
        """Return what steers the nominal now: 'circulate' or 'none'."""
        return 'circulate' if self.side else 'none'

    def observe(self, info):
        """Keep the step's filter ``info``; while circulating, take its blocking part's axis.

        Idle, the axis is read only when a circulation engages (``_take_axis``), from the
        last info that had parts: it costs a pass over the parts, which every robot paid on
        every step for an axis hardly ever used (eight A1s in one process: 6 % of the loop).
        """
        if getattr(info, 'evaluation', None) is None or not len(info.h):
            return
        self._info = info
        if self.active:
            self._take_axis()

    def _take_axis(self):
        """Remember the cone axis of the part with the smallest h in the kept info (if any)."""
        info, self._info = self._info, None
        if info is None:
            return
        evaluation = info.evaluation
        h = np.where(evaluation.valid & np.isfinite(info.h), info.h, np.inf)
        index = int(np.argmin(h))
        if math.isfinite(h[index]):
            axis = evaluation.axis(index)
            if axis[0] != 0.0 or axis[1] != 0.0:
                self._axis = np.array(axis)

    def engage(self, now, position, yaw, nominal, obstacles=None, renew=False, views=()):
        """Start (or, while circulating, flip) circulation at the robot's reference point.

        ``nominal``: the command [v, omega] the robot was held against; its |v| is kept.
        ``obstacles``, ``views``: unused (the blocking part's axis comes from ``observe``).
        ``renew``: the deadlock outlasted the last circulation; start on its other side.
        """
        self._take_axis()
        if self._axis is None:
            return
        self._speed = max(abs(float(nominal[0])),
                          self._speed if self.active or renew else 0.0)
        if self.active:
            self.side = -self.side
        elif renew and self._last_side:
            self.side = -self._last_side
        else:
            heading = (math.cos(yaw), math.sin(yaw))
            cross = self._axis[0] * heading[1] - self._axis[1] * heading[0]
            self.side = 1 if cross >= 0.0 else -1
        self.engagements += 1
        self._last_side = self.side
        self._start, self._since = np.array(position, dtype=float), now

    def release_if_done(self, now, position, passes):
        """End circulation after ``max_time``, or once the way of the nominal is free.

        ``passes()``: True when the filter would grant the nominal's ``probe`` without
        holding the robot; called only once ``release_distance`` is covered.
        """
        if not self.active:
            return
        if now - self._since >= self.max_time or (np.linalg.norm(
                np.asarray(position, dtype=float) - self._start) >= self.release_distance
                and passes()):
            self.side = 0

    def probe(self, nominal):
        """Return [max(|v|, v_n / 2), omega] (sign of v kept): the nominal, driving on."""
        speed = max(abs(float(nominal[0])), 0.5 * self._speed)
        return np.array([math.copysign(speed, float(nominal[0])), float(nominal[1])])

    def command(self, yaw, nominal, position=None):
        """Return the unicycle command [v, omega] to ask the filter for (module docstring).

        ``position``: unused (the tangent depends on the heading only).
        """
        if not self.active or self._axis is None or not any(nominal):
            return nominal
        ax, ay = self._axis / float(np.hypot(*self._axis))
        return steer_towards(math.atan2(self.side * ax, -self.side * ay), yaw,
                             max(abs(float(nominal[0])), self._speed), self.turn_gain,
                             self.max_turn_rate)
