"""The node's decision per control step, without ROS: the latest inputs -> what to publish.

The shell hands over each input as it arrives, with the steady-clock time ``now`` [s]:
``odometry`` (state, yaw and stamp, or None when the message was unreadable or held
NaN/Inf), ``command`` (the nominal command vector, or None when unusable) and ``obstacles``
(an ``ObstacleSnapshot``).  ``step(now)`` returns a ``Decision``::

    filtering disabled           -> 'pass' (the nominal command as it came), or 'stop' if
                                    the command is stale or unusable
    an input stale               -> 'stop', counted 'stale_stop'
    an input unusable            -> 'stop', counted 'invalid_input'
    rejected obstacles blocking  -> 'stop', counted 'blocked_stop'
    otherwise                    -> 'filter': CommandFilter.filter(state, yaw, command,
                                    obstacles, age), counted by the filter's status

An input is stale when it never arrived or is older than its timeout (0: never, once
received; ``core.watchdog``).  Without an ``'obstacles'`` watchdog (no marker input: the
node's ``use_markers`` false) snapshots feed none and nothing blocks on rejected markers.
A new obstacle snapshot with a receipt time is fresh data,
but under ``block_if_invalid`` only when nothing in it was rejected (wrong frame, unusable
marker): rejected input then stops the robot once it has lasted ``obstacles_timeout``, or at
once when that is 0 ('blocked_stop').  The obstacles are moved to the odometry's stamp by
``age = clip(t_odom - t_ref, 0, max_extrapolation)`` (``extrapolation_age``).  A stop is the
model's stop command (``CommandFilter.stop``).  Every filtered step also goes to the
``DeadlockDetector`` (``core.liveness.deadlock``: held in place by the filter for ``deadlock_time``
within ``deadlock_radius``), whose verdict the ``Decision`` carries; any other step
clears it.  With ``deadlock_resolution`` 'circulate' (unicycle only) a reported deadlock
starts a ``core.liveness.circulation.Circulation``: the nominal command handed to the filter is
steered along the blocking obstacle until it releases; with 'route' (unicycle and
``point_mass_2d``) a ``core.liveness.escape_route.RouteEscape`` steers it along a planned route
(``RESOLVED_MODELS``).  The filter's rows stay as they are.
The node, offline bag replay and the evaluation all decide through this class.
"""
import math
from dataclasses import dataclass, field
from typing import NamedTuple, Optional

from polyc2bf_ros.core.liveness.circulation import Circulation
from polyc2bf_ros.core.liveness.deadlock import DeadlockDetector, holds
from polyc2bf_ros.core.liveness.escape_route import RouteEscape
from polyc2bf_ros.core.obstacles.marker_tracker import extrapolation_age
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterStatus
from polyc2bf_ros.core.watchdog import Watchdog

COUNTS = tuple(s.value for s in FilterStatus) + ('stale_stop', 'blocked_stop')
# deadlock_time [s], deadlock_radius [m], stuck_time [s], stuck_radius [m],
# deadlock_repeat_count, deadlock_repeat_window [s]
DEADLOCK_DEFAULTS = (3.0, 0.1, 8.0, 0.3, 3, 60.0)
RESOLUTIONS = ('none', 'circulate', 'route')
#: resolution -> the models it steers (the others keep their nominal)
RESOLVED_MODELS = {'none': (), 'circulate': ('unicycle',), 'route': ('unicycle', 'point_mass_2d')}
ROUTE_MARGIN = 0.02  # m: a route's cells keep the braking check's clearance plus this
# route_ahead [m], route_window [m], route_clear_run [m] (``escape_route.plan_route``'s
# ahead, window and run)
ROUTE_DEFAULTS = (3.0, 10.0, 0.0)


@dataclass(frozen=True)
class ObstacleSnapshot:
    """The obstacle input as of the newest message processed.

    ``received``: monotonic receipt time of that message (None before any readable one);
    ``rejected`` / ``wrong_frame``: ``{key: reason}``; ``invalid``: some marker had NaN/Inf;
    ``unreadable`` / ``error``: why the last message could not be read / the set not be
    built ('' if fine); ``simplified``: obstacles whose outline was replaced by an enclosing
    polygon; ``hulled``: keys replaced by their hull (too many convex parts); ``views``: the
    ``ScanView`` of each laser's newest scan (what it saw: a route avoids the rest).
    """

    obstacles: ObstacleSet = field(default_factory=ObstacleSet.empty)
    t_ref: float = math.nan
    received: Optional[float] = None
    rejected: dict = field(default_factory=dict)
    wrong_frame: dict = field(default_factory=dict)
    invalid: bool = False
    unreadable: str = ''
    error: str = ''
    tracked: int = 0
    simplified: int = 0
    hulled: tuple = ()
    views: tuple = ()

    @property
    def usable(self):
        """Return False when the filter must brake: NaN/Inf, unreadable, or no set built."""
        return not (self.invalid or self.unreadable or self.error)

    @property
    def clean(self):
        """Return True when nothing was refused: fresh data under ``block_if_invalid``."""
        return self.usable and not (self.rejected or self.wrong_frame)


class Decision(NamedTuple):
    """What to publish: ``action`` 'filter', 'stop' or 'pass'; ``command`` for the first two.

    ``info`` is the filter's ``FilterInfo`` for 'filter'; ``reason`` the count a stop went to
    ('stale_stop', 'invalid_input', 'blocked_stop'); ``deadlocked`` the deadlock detector's
    verdict after this step.
    """

    action: str
    command: object = None
    info: object = None
    reason: str = ''
    deadlocked: bool = False


class ControlDecision:
    """Inputs, watchdogs and the ``CommandFilter``: one call per step (module docstring)."""

    def __init__(self, command_filter, timeouts, block_if_invalid=True, max_extrapolation=0.5,
                 deadlock=DEADLOCK_DEFAULTS, resolution='none', route=ROUTE_DEFAULTS):
        """Decide with ``command_filter``; ``timeouts`` = {'odom', 'cmd', 'obstacles': s}.

        ``'obstacles'`` may be left out (no marker input); other names are more watchdogs.

        ``deadlock``: the ``DeadlockDetector``'s arguments (``DEADLOCK_DEFAULTS``);
        ``resolution`` one of ``RESOLUTIONS``; ``route``: (ahead, window, clear run) of its
        routes [m].
        """
        self.watchdog = Watchdog(timeouts)
        self.deadlock = DeadlockDetector(*deadlock)
        self.circulation = None
        self.configure(command_filter, timeouts, block_if_invalid, max_extrapolation, deadlock,
                       resolution, route)
        self.counts = dict.fromkeys(COUNTS, 0)
        self.enabled = True
        self.snapshot = ObstacleSnapshot()
        self.state = None
        self.yaw = 0.0
        self.odom_stamp = -math.inf
        self.odom_valid = False
        self.command_vector = None
        self.command_valid = False

    def configure(self, command_filter, timeouts, block_if_invalid, max_extrapolation,
                  deadlock=DEADLOCK_DEFAULTS, resolution='none', route=ROUTE_DEFAULTS):
        """Take new settings (a parameter change); the inputs held are kept."""
        if resolution not in RESOLUTIONS:
            raise ValueError(f'deadlock resolution must be one of {RESOLUTIONS}, '
                             f'got {resolution!r}')
        self.deadlock.configure(*deadlock)
        model = command_filter.model.name
        if model not in RESOLVED_MODELS[resolution]:
            self.circulation = None
        elif resolution == 'circulate' and not isinstance(self.circulation, Circulation):
            self.circulation = Circulation()
        elif resolution == 'route':
            safety = command_filter.safety_filter
            geometry = safety.geometry
            free = geometry.passage_radius + safety.config.braking_margin + ROUTE_MARGIN
            holonomic = model != 'unicycle'
            # A turning footprint backs out to where its corners clear (escape_route).
            backing = (geometry.robot_radius - geometry.passage_radius + ROUTE_MARGIN
                       if geometry.turning else 0.0)
            options = {'ahead': float(route[0]), 'window': float(route[1]),
                       'run': float(route[2])}
            if not (isinstance(self.circulation, RouteEscape)
                    and self.circulation.free_clearance == free
                    and self.circulation.holonomic == holonomic
                    and self.circulation.backing == backing
                    and self.circulation.route_options == options):
                self.circulation = RouteEscape(free, holonomic, backing=backing, **options)
        self.filter = command_filter
        for name, timeout in timeouts.items():
            self.watchdog.set_timeout(name, timeout)
        self._watch_markers = 'obstacles' in self.watchdog.names
        # Rejected obstacles stop at once: block_if_invalid with obstacles_timeout 0.
        self._block_at_once = (bool(block_if_invalid) and self._watch_markers
                               and self.watchdog.timeout('obstacles') == 0.0)
        self.block_if_invalid = bool(block_if_invalid)
        self.max_extrapolation = float(max_extrapolation)

    def odometry(self, now, state=None, yaw=0.0, stamp=-math.inf):
        """Take odometry that arrived at ``now``: the state, or None if it was unusable."""
        self.watchdog.feed('odom', now)
        self.odom_valid = state is not None
        if state is not None:
            self.state, self.yaw, self.odom_stamp = state, yaw, stamp

    def command(self, now, vector=None):
        """Take a nominal command that arrived at ``now``: its vector, or None if unusable."""
        self.watchdog.feed('cmd', now)
        self.command_valid = vector is not None
        if vector is not None:
            self.command_vector = vector

    def obstacles(self, snapshot):
        """Adopt an obstacle snapshot; feed the watchdog when it is fresh data."""
        if snapshot is self.snapshot:
            return
        self.snapshot = snapshot
        if (self._watch_markers and snapshot.received is not None
                and (snapshot.clean or not self.block_if_invalid)):
            self.watchdog.feed('obstacles', snapshot.received)

    @property
    def resolving(self):
        """Return what steers the nominal now: 'route', 'circulate' or 'none'."""
        return 'none' if self.circulation is None else self.circulation.mode

    @property
    def resolutions(self):
        """Return how many resolutions began (routes planned, circulations started)."""
        return 0 if self.circulation is None else self.circulation.engagements

    def stop(self):
        """Return the stop command from the last usable state (zeros before any)."""
        if self.state is None:
            return self.filter.stop((0.0,) * self.filter.model.state_dim)
        return self.filter.stop(self.state)

    def step(self, now):
        """Return the ``Decision`` for this step (module docstring)."""
        if not self.enabled:
            self.deadlock.clear()
            if self.watchdog.is_stale('cmd', now) or not self.command_valid:
                return self._stop('stale_stop' if self.command_valid else 'invalid_input', now)
            self.filter.published(now, self.command_vector)
            return Decision('pass')
        if self.watchdog.any_stale(now):
            return self._stop('stale_stop', now)
        snapshot = self.snapshot
        if not (self.odom_valid and self.command_valid and snapshot.usable):
            return self._stop('invalid_input', now)
        if self._block_at_once and not snapshot.clean:
            return self._stop('blocked_stop', now)
        age = extrapolation_age(self.odom_stamp, snapshot.t_ref, self.max_extrapolation)
        command, circulation, position = self.command_vector, self.circulation, None
        if circulation is not None and circulation.active:
            position = self._position()
            if circulation.mode == 'route':   # a standing part now on the route: plan again
                circulation.revise(now, position, self.yaw, self.command_vector,
                                   snapshot.obstacles, snapshot.views)
            circulation.release_if_done(
                now, position,
                lambda: self._passes(circulation.probe(command), snapshot, age))
            command = circulation.command(self.yaw, command, position)
        safe, info = self.filter.filter(self.state, self.yaw, command, snapshot.obstacles, age,
                                        now)
        self.filter.published(now, safe)
        self.counts[info.status.value] += 1
        # The reference point costs a model call: only needed while the filter holds (or
        # circulates, which computed it already; the state has not changed since).
        holding = holds(info, command, safe)
        if holding and position is None:
            position = self._position()
        onsets = self.deadlock.onsets
        self.deadlock.track(now, self.state, self.command_vector)
        deadlocked = self.deadlock.update(now, position, holding)
        if circulation is not None:
            circulation.observe(info)
            if self.deadlock.onsets > onsets:
                circulation.engage(now, position, self.yaw, self.command_vector,
                                   snapshot.obstacles, views=snapshot.views)
            elif self.deadlock.held and not circulation.active:
                # Still held after a circulation ran out of time: try the other side.
                circulation.engage(now, position, self.yaw, self.command_vector,
                                   snapshot.obstacles, renew=True, views=snapshot.views)
        return Decision('filter', safe, info, deadlocked=deadlocked)

    def _passes(self, command, snapshot, age):
        """Return True when the filter would grant ``command`` without holding the robot."""
        safe, info = self.filter.filter(self.state, self.yaw, command, snapshot.obstacles, age)
        return not holds(info, command, safe)

    def _position(self):
        return self.filter.model.reference(self.state).position

    def _stop(self, reason, now):
        self.counts[reason] += 1
        self.deadlock.clear()
        stop = self.stop()
        self.filter.published(now, stop)
        return Decision('stop', stop, reason=reason)
