"""``bag_replay``: play an MCAP bag onto live ROS 2 topics, or re-run the filter on it offline.

Live playback (default)::

    bag_replay BAG [--rate R] [--topics PATTERN ...] [--exclude PATTERN ...]
               [--remap FROM:=TO ...] [--clock [HZ]] [--start-offset S] [--duration S]
               [--delay S] [--wait-for-subscribers S] [--lockstep REQUEST:=RESPONSE]
               [--ros-args -r FROM:=TO ...]

``BAG`` is a rosbag2 directory or one ``.mcap`` file (``sim_bridge.bag_reader``).  A
message logged at bag time ``t`` is published at wall time
``w0 + (t - t0) / rate`` (``t0`` = bag start + ``--start-offset``; pauses, see
``--lockstep``, shift the rest), with the bag's CDR bytes as they are (no
deserialize / serialize round trip).  Each topic is published with the QoS the
bag recorded for it (channel metadata ``offered_qos_profiles``); several
different offers are merged into one every subscriber of any of them matches:
best effort if any offer was, volatile if any was, the largest depth.

Topic selection: ``--topics`` and ``--exclude`` take exact names or shell globs
(``/a1/*``) matched against the bag's topic names; a pattern that matches
nothing is an error, as is a remap source the bag lacks.  Topics whose message
type is not installed (``tf2_msgs`` is not on PyPI) are skipped with a warning,
or refused if named exactly.  ``--remap /a1/odom:=/robot/odom`` renames a bag
topic; ``--ros-args -r /a1/odom:=/robot/odom`` works too (rcl remaps the
publisher names).

``--clock [HZ]`` publishes ``rosgraph_msgs/Clock`` on ``/clock`` at HZ (wall,
default 100) carrying the playback's bag time (frozen while paused) and leaves
the bag's own ``/clock`` out.

``--lockstep REQUEST:=RESPONSE`` plays in lockstep with a system under test,
e.g. a ``safety_filter`` with ``trigger:=command`` and ``match_stamps:=true``:
after each message on the bag topic REQUEST (a stamped type) playback pauses
until a message with the same header stamp arrives on the live topic RESPONSE
(same type, subscribed reliable) or ``--lockstep-timeout`` passes; every
0.5 s without it the messages of the request's log time are sent again (a
best-effort subscriber may have dropped one, or not have matched yet).  The
recorded timing is kept while the system keeps up, and none of its inputs is
overtaken by the next period where it does not, so what it answers does not
depend on the machine's load.  RESPONSE must not be played from the bag.

Progress goes to stderr once a second; at the end (or on Ctrl-C / SIGTERM,
which stop playback cleanly) a summary: messages per topic and the publish
lateness (publish time minus scheduled time) p50 / p99 / max.

Offline check (``--offline``, no DDS)::

    bag_replay BAG --offline [--robot NS] --params-file config/quadruped.yaml
               [-p NAME:=VALUE ...] [--json REPORT] [--tolerance TOL] [--worst N]

feeds the bag's ``/NS/odom``, ``/NS/obstacles`` and nominal commands
(``/NS/cmd_vel_in``, or ``/NS/wrench_in`` for the quadrotor model) straight
into the node's decision, ``core.decision.ControlDecision``, configured from the same
parameter file(s) the node takes (rcl's YAML: the sections whose node name
pattern matches ``/NS/safety_filter``, e.g. ``/**/safety_filter``) plus ``-p``
overrides, with the node's defaults for the rest.  Obstacles go through the
node's own pipeline (``obstacle_intake.ObstaclePipeline``, in process), and the log
times stand in for the node's steady clock.

Each recorded safe command (``/NS/cmd_vel_out`` / ``/NS/wrench_out``, stamped
with the stamp of the nominal command it answers) is paired with the odometry
and nominal command of the same stamp; in lockstep with ``match_stamps`` that
is exactly what the node used, so the outputs must agree to rounding.  Outputs
with no same-stamp inputs (the watchdog's stops, stamped with the node's clock)
are counted as unpaired.  The report gives max and mean |difference| per
command component (``[v, omega]``, ``[vx, vy(, vz)]`` or the wrench
``[T, tau_x, tau_y, tau_z]``, absolute, in command units), the offline
filter's status counts and the worst steps; ``--json`` writes it.  Exit
status: 0 within ``--tolerance``, 3 beyond it (or nothing paired), 1 on bad
input (missing bag, unknown topic, invalid parameters), 2 on bad usage, 130
when interrupted (live playback ends with 0 and its summary on Ctrl-C).
"""
import argparse
import dataclasses
import fnmatch
import json
import math
import signal
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

from polyc2bf_ros import conversions
from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.filter_parameters import build_filter, load_parameters, ParameterError
from polyc2bf_ros.obstacle_intake import ObstacleJob, ObstaclePipeline
from sim_bridge.bag_reader import BagReader, message_class

CLOCK_TOPIC = '/clock'
DEFAULT_CLOCK_HZ = 100.0
DEFAULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
RESPONSE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
ACK_TIMEOUT = 2.0  # wall s to wait at the end for reliable subscribers to acknowledge
LOCKSTEP_RESEND = 0.5  # wall s without a lockstep answer before the period is sent again
EXIT_ERROR, EXIT_DIFFERENT, EXIT_INTERRUPTED = 1, 3, 130  # argparse: 2 on bad usage


class ReplayError(ValueError):
    """Bad input to the replayer (bag, topics, remaps, parameters), with the reason."""


def _log(text):
    print(f'bag_replay: {text}', file=sys.stderr, flush=True)


# -- pure helpers ---------------------------------------------------------------------------


def parse_remaps(items):
    """Return ``{from: to}`` of ``FROM:=TO`` strings (names made absolute)."""
    remaps = {}
    for item in items or ():
        source, sep, target = item.partition(':=')
        if not (sep and source and target):
            raise ReplayError(f'remap {item!r} is not FROM:=TO')
        remaps['/' + source.lstrip('/')] = '/' + target.lstrip('/')
    return remaps


def select_topics(available, include=None, exclude=None):
    """Return the sorted names of ``available`` matching ``include`` and not ``exclude``.

    Patterns are exact names or shell globs; one that matches nothing is an error.
    """
    def matches(pattern):
        name = '/' + pattern.lstrip('/')
        found = {t for t in available if fnmatch.fnmatchcase(t, name)}
        if not found:
            raise ReplayError(f'no topic in the bag matches {pattern!r}; it has '
                              f'{", ".join(sorted(available))}')
        return found

    chosen = set(available) if not include else set().union(*map(matches, include))
    for pattern in exclude or ():
        chosen -= matches(pattern)
    return sorted(chosen)


def merge_qos(profiles):
    """Return one publisher QoS that every subscriber of any recorded offer matches.

    One offer (or identical ones) is used as is; otherwise best effort if any
    offer was, volatile if any was, keep-last with the largest depth.  No
    recorded offer: reliable, volatile, depth 10.
    """
    profiles = list(profiles)
    if not profiles:
        return DEFAULT_QOS
    if all(p == profiles[0] for p in profiles):
        return profiles[0]
    best_effort = any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in profiles)
    volatile = any(p.durability == DurabilityPolicy.VOLATILE for p in profiles)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=max(max(p.depth for p in profiles), 1),
        reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
        durability=(DurabilityPolicy.VOLATILE if volatile
                    else DurabilityPolicy.TRANSIENT_LOCAL))


def stamp_ns(msg):
    """Return ``msg.header.stamp`` in nanoseconds."""
    stamp = msg.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def percentiles(values, qs=(50, 99)):
    """Return the ``qs`` percentiles and the maximum of ``values`` (NaN when empty)."""
    if len(values) == 0:
        return [math.nan] * (len(qs) + 1)
    values = np.asarray(values, dtype=float)
    return [float(v) for v in np.percentile(values, qs)] + [float(values.max())]


class PlaybackClock:
    """Map bag time to wall time: ``wall(t) = w0 + paused + (t - t0) / rate``.

    ``pause()`` freezes the bag time; ``resume()`` shifts every later deadline
    by the time spent paused.
    """

    def __init__(self, t0_ns, rate, wall_start):
        """Start bag time ``t0_ns`` at wall time ``wall_start`` [s], ``rate`` > 0."""
        self.t0_ns = t0_ns
        self.rate = rate
        self.wall_start = wall_start
        self.paused_s = 0.0
        self._paused_at = None
        self._paused_bag_ns = None

    def due(self, t_ns):
        """Wall time [s] at which bag time ``t_ns`` is played."""
        return self.wall_start + self.paused_s + (t_ns - self.t0_ns) * 1e-9 / self.rate

    def bag_time_ns(self, wall):
        """Bag time [ns] at wall time ``wall`` (the pause's time while paused)."""
        if self._paused_at is not None:
            return self._paused_bag_ns
        return self.t0_ns + round((wall - self.wall_start - self.paused_s) * self.rate * 1e9)

    def pause(self, wall, bag_ns):
        """Freeze playback at bag time ``bag_ns``."""
        self._paused_at, self._paused_bag_ns = wall, bag_ns

    def resume(self, wall):
        """Go on; later deadlines move by the pause."""
        if self._paused_at is not None:
            self.paused_s += wall - self._paused_at
            self._paused_at = None


# -- live playback --------------------------------------------------------------------------


@dataclasses.dataclass
class PlayOptions:
    """What and how to play; see the module docstring for each option."""

    rate: float = 1.0
    topics: tuple = ()
    exclude: tuple = ()
    remaps: dict = dataclasses.field(default_factory=dict)
    clock_hz: float = 0.0
    start_offset: float = 0.0
    duration: float = 0.0
    delay: float = 0.0
    wait_for_subscribers: float = 0.0
    lockstep: tuple = ()              # (request bag topic, response live topic) or ()
    lockstep_timeout: float = 10.0
    progress: bool = True


@dataclasses.dataclass
class PlayStats:
    """What a playback did."""

    published: Counter = dataclasses.field(default_factory=Counter)
    lateness_s: list = dataclasses.field(default_factory=list)
    clock_messages: int = 0
    requests: int = 0
    answered: int = 0
    timeouts: int = 0
    resent: int = 0
    paused_s: float = 0.0
    wall_s: float = 0.0
    bag_span_s: float = 0.0
    interrupted: bool = False

    def summary(self):
        """Return a few lines for the terminal."""
        p50, p99, worst = (1e3 * v for v in percentiles(self.lateness_s))
        lines = [f'{"interrupted" if self.interrupted else "done"}: '
                 f'{sum(self.published.values())} messages, {self.bag_span_s:.3f} s of bag '
                 f'time in {self.wall_s:.3f} s wall; lateness p50 {p50:.2f} ms, p99 '
                 f'{p99:.2f} ms, max {worst:.2f} ms']
        lines += [f'  {topic}: {count}' for topic, count in sorted(self.published.items())]
        if self.clock_messages:
            lines.append(f'  {CLOCK_TOPIC} (generated): {self.clock_messages}')
        if self.requests:
            lines.append(f'  lockstep: {self.answered}/{self.requests} answered, '
                         f'{self.timeouts} timed out, {self.resent} messages re-sent, '
                         f'paused {self.paused_s:.3f} s')
        return '\n'.join(lines)


class _Channel:
    """One played topic: publisher, live name, lockstep request or not, message class."""

    __slots__ = ('publisher', 'name', 'request', 'msg_type')

    def __init__(self, publisher, name, request, msg_type):
        self.publisher = publisher
        self.name = name
        self.request = request
        self.msg_type = msg_type


class BagPlayer:
    """Publish a bag's messages at their recorded timing from one ROS node."""

    def __init__(self, bag, options=None, context=None, node_name='bag_replay'):
        """Open ``bag``, check the options against it and create the node and publishers.

        ``context`` is an initialised rclpy context (default: the global one).
        Raises ``ReplayError`` (or ``FileNotFoundError``) with the reason.
        """
        self.options = opts = options or PlayOptions()
        if not opts.rate > 0.0:
            raise ReplayError(f'--rate must be positive, got {opts.rate}')
        self.reader = BagReader(bag)
        self.t0_ns, self.end_ns = self._window()
        names = self._topic_names()
        request = response = None
        if opts.lockstep:
            request, response = ('/' + name.lstrip('/') for name in opts.lockstep)
        if request is not None and request not in names:
            raise ReplayError(f'lockstep request topic {request} is not played from the bag')
        self.node = Node(node_name, context=context)
        self._channels = self._publishers(names, request)
        if response is not None:
            self._subscribe_responses(request, response)
        self._clock_pub = None
        if opts.clock_hz > 0.0:
            self._clock_pub = self.node.create_publisher(Clock, CLOCK_TOPIC, DEFAULT_QOS)
        self.executor = SingleThreadedExecutor(context=self.node.context)
        self.executor.add_node(self.node)
        self.responses = []          # (stamp ns, message) of every response received
        self._answers = Counter()    # stamp ns -> responses received
        self.stats = PlayStats()

    def _window(self):
        """Return the played log-time window ``[t0, end)`` [ns] (start offset, duration)."""
        opts = self.options
        first, last = self.reader.time_range
        if first is None:
            raise ReplayError(f'{self.reader.files[0]} holds no messages')
        t0 = first + round(opts.start_offset * 1e9)
        if not (0.0 <= opts.start_offset and t0 <= last):
            raise ReplayError(f'--start-offset {opts.start_offset} s is outside the bag '
                              f'(0 .. {(last - first) * 1e-9:.3f} s)')
        if opts.duration <= 0.0:
            return t0, last + 1
        return t0, min(last + 1, t0 + round(opts.duration * 1e9))

    def _topic_names(self):
        """Return the bag topics to play (selection, remap sources checked, /clock rule)."""
        opts, topics = self.options, self.reader.topics
        for source in opts.remaps:
            if source not in topics:
                raise ReplayError(f'remap source {source} is not a topic of the bag')
        names = select_topics(topics, opts.topics, opts.exclude)
        if opts.clock_hz > 0.0 and CLOCK_TOPIC in names:
            names.remove(CLOCK_TOPIC)
            _log(f"--clock: not playing the bag's own {CLOCK_TOPIC}")
        return names

    def _publishers(self, names, request):
        """Return ``{bag topic: _Channel}``; a type that is not installed is skipped or refused."""
        opts, topics = self.options, self.reader.topics
        explicit = {'/' + p.lstrip('/') for p in opts.topics}
        channels = {}
        for name in names:
            type_name = topics[name].type_name
            try:
                msg_type = message_class(type_name)
            except (LookupError, ValueError):
                if name in explicit or name == request:
                    raise ReplayError(f'cannot play {name}: message type {type_name} is '
                                      'not installed') from None
                _log(f'skipping {name}: message type {type_name} is not installed')
                continue
            publisher = self.node.create_publisher(
                msg_type, opts.remaps.get(name, name), merge_qos(topics[name].qos_profiles))
            channels[name] = _Channel(publisher, publisher.topic_name, name == request, msg_type)
        if not channels:
            raise ReplayError('no topic to play')
        return channels

    def _subscribe_responses(self, request, response):
        """Lockstep: subscribe to the answers, of the request's (stamped) type."""
        msg_type = self._channels[request].msg_type
        if not hasattr(msg_type, 'header'):
            raise ReplayError(f'lockstep request {request} ({msg_type.__name__}) has no '
                              'header stamp to match answers by')
        response = self.node.resolve_topic_name(response)
        if response in {c.name for c in self._channels.values()}:
            raise ReplayError(f'lockstep response {response} is also played from the bag: '
                              'exclude it or remap it')
        self._request_type = msg_type
        self.node.create_subscription(msg_type, response, self._on_response, RESPONSE_QOS)

    @property
    def topic_map(self):
        """Return ``{bag topic: live topic}`` of what is played."""
        return {name: channel.name for name, channel in self._channels.items()}

    def close(self):
        """Destroy the node (the context stays the caller's)."""
        self.executor.shutdown()
        self.node.destroy_node()

    def _on_response(self, msg):
        stamp = stamp_ns(msg)
        self.responses.append((stamp, msg))
        self._answers[stamp] += 1

    def _wait(self, until):
        """Serve callbacks (lockstep responses) until the monotonic time ``until``.

        Without a subscription a plain sleep is more punctual than the executor.
        """
        while True:
            remaining = until - time.monotonic()
            if remaining <= 0.0:
                return
            if self.options.lockstep:
                self.executor.spin_once(timeout_sec=remaining)
            else:
                time.sleep(remaining)

    def wait_for_subscribers(self, timeout):
        """Wait until every publisher has a subscriber or ``timeout`` s; return the unmatched."""
        deadline = time.monotonic() + timeout
        while True:
            unmatched = [c.name for c in self._channels.values()
                         if c.publisher.get_subscription_count() == 0]
            if not unmatched or time.monotonic() >= deadline:
                return unmatched
            self._wait(min(deadline, time.monotonic() + 0.02))

    def run(self):
        """Play the selected window once; return ``PlayStats`` (also on Ctrl-C)."""
        opts, stats = self.options, self.stats
        if opts.wait_for_subscribers > 0.0:
            unmatched = self.wait_for_subscribers(opts.wait_for_subscribers)
            if unmatched:
                _log(f'no subscriber after {opts.wait_for_subscribers:g} s on '
                     f'{", ".join(unmatched)}; playing anyway')
        if opts.delay > 0.0:
            self._wait(time.monotonic() + opts.delay)
        start = time.monotonic()
        clock = PlaybackClock(self.t0_ns, opts.rate, start)
        period = 1.0 / opts.clock_hz if self._clock_pub is not None else math.inf
        self._next_tick = start if self._clock_pub is not None else math.inf
        self._next_progress = start + 1.0
        last_ns = self.t0_ns
        same_time = []  # (publisher, data) already played at log time last_ns
        try:
            for topic, _, t_ns, data in self.reader.messages(
                    self._channels, raw=True, start_ns=self.t0_ns, end_ns=self.end_ns):
                due = clock.due(t_ns)
                self._serve_until(clock, due, period)
                channel = self._channels[topic]
                channel.publisher.publish(data)
                stats.published[topic] += 1
                stats.lateness_s.append(time.monotonic() - due)
                if t_ns != last_ns:
                    same_time.clear()
                last_ns = t_ns
                same_time.append((channel.publisher, data))
                if channel.request:
                    self._await_answer(clock, data, period, same_time)
            self._wait_for_acks(ACK_TIMEOUT)
        except (KeyboardInterrupt, ExternalShutdownException):
            stats.interrupted = True
        stats.wall_s = time.monotonic() - start
        stats.paused_s = clock.paused_s
        stats.bag_span_s = (last_ns - self.t0_ns) * 1e-9
        if opts.progress:
            self._progress(last_ns, end=True)
        return stats

    def _wait_for_acks(self, timeout):
        """Wait until reliable subscribers hold the last messages (at most ``timeout`` s).

        A process that exits right after publishing can take unacknowledged
        messages with it (``ros2 bag play --wait-for-all-acked`` does the same).
        """
        deadline = time.monotonic() + timeout
        for channel in self._channels.values():
            remaining = max(0.0, deadline - time.monotonic())
            channel.publisher.wait_for_all_acked(Duration(nanoseconds=int(remaining * 1e9)))

    def _serve_until(self, clock, due, period):
        """Until wall time ``due``: publish clock ticks, serve callbacks, show progress."""
        while True:
            now = time.monotonic()
            if self._clock_pub is not None and now >= self._next_tick:
                self._tick(clock, now, period)
            if self.options.progress and now >= self._next_progress:
                self._progress(clock.bag_time_ns(now))
            if now >= due:
                return
            self._wait(min(due, self._next_tick, self._next_progress))

    def _tick(self, clock, now, period):
        """Publish ``/clock`` = bag time now (not past the window's end)."""
        sec, nsec = divmod(min(clock.bag_time_ns(now), self.end_ns), 1_000_000_000)
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = sec, nsec
        self._clock_pub.publish(msg)
        self.stats.clock_messages += 1
        self._next_tick = max(self._next_tick + period, now)

    def _await_answer(self, clock, data, period, same_time):
        """Lockstep: pause until the response with the request's stamp (or the timeout).

        Every ``LOCKSTEP_RESEND`` s without it, the messages of the request's log
        time are sent again (as the bridge re-sends its first period): a best-effort
        subscriber may have dropped one, or not have matched yet.
        """
        stats = self.stats
        stamp = stamp_ns(deserialize_message(data, self._request_type))
        wanted = self._answers[stamp] + 1
        stats.requests += 1
        now = time.monotonic()
        clock.pause(now, clock.bag_time_ns(now))
        deadline = now + self.options.lockstep_timeout
        resend = now + LOCKSTEP_RESEND
        while self._answers[stamp] < wanted and now < deadline:
            if self._clock_pub is not None and now >= self._next_tick:
                self._tick(clock, now, period)
            if now >= resend:
                for publisher, message in same_time:
                    publisher.publish(message)
                stats.resent += len(same_time)
                resend = now + LOCKSTEP_RESEND
            self.executor.spin_once(timeout_sec=max(0.0, min(deadline, resend,
                                                             self._next_tick) - now))
            now = time.monotonic()
        if self._answers[stamp] >= wanted:
            stats.answered += 1
        else:
            stats.timeouts += 1
            _log(f'no answer stamped {stamp * 1e-9:.4f} s within '
                 f'{self.options.lockstep_timeout:g} s; going on')
        clock.resume(time.monotonic())

    def _progress(self, bag_ns, end=False):
        """One progress line on stderr (rewritten in place on a terminal)."""
        span = max(self.end_ns - 1 - self.t0_ns, 1)
        done = min(max(bag_ns - self.t0_ns, 0), span)
        text = (f'{done * 1e-9:8.3f} / {span * 1e-9:.3f} s bag time ({100 * done / span:5.1f} %)'
                f', {sum(self.stats.published.values())} messages, x{self.options.rate:g}')
        if self.stats.requests:
            text += f', {self.stats.answered}/{self.stats.requests} answered'
        tty = sys.stderr.isatty()
        print(('\r' if tty else '') + 'bag_replay: ' + text,
              end='\n' if end or not tty else '', file=sys.stderr, flush=True)
        self._next_progress = time.monotonic() + 1.0


# -- offline check --------------------------------------------------------------------------


def find_robot(topics):
    """Return the one namespace with odometry and a recorded safe command."""
    robots = sorted(name[:-len('/odom')] for name in topics if name.endswith('/odom') and (
        name[:-len('odom')] + 'cmd_vel_out' in topics
        or name[:-len('odom')] + 'wrench_out' in topics))
    if len(robots) != 1:
        raise ReplayError('pass --robot: the bag has ' + (
            f'several robots ({", ".join(r.strip("/") for r in robots)})' if robots
            else 'no <ns>/odom with a <ns>/cmd_vel_out or <ns>/wrench_out'))
    return robots[0].strip('/')


@dataclasses.dataclass
class OfflineStep:
    """One recorded safe command beside the offline filter's answer."""

    stamp_s: float
    status: str
    recorded: np.ndarray
    offline: np.ndarray
    nominal: np.ndarray
    state: np.ndarray

    @property
    def abs_diff(self):
        """Return |offline - recorded| per component."""
        return np.abs(self.offline - self.recorded)


@dataclasses.dataclass
class OfflineReport:
    """The offline comparison of a bag's safe commands."""

    bag: str
    robot: str
    model: str
    topics: dict        # role (odom, obstacles, nominal, safe) -> bag topic
    components: tuple
    steps: list
    unpaired: int
    tolerance: float
    parameters: dict

    @property
    def max_abs_diff(self):
        """Return the max |difference| per component (NaN without steps)."""
        if not self.steps:
            return np.full(len(self.components), np.nan)
        return np.max([s.abs_diff for s in self.steps], axis=0)

    @property
    def mean_abs_diff(self):
        """Return the mean |difference| per component (NaN without steps)."""
        if not self.steps:
            return np.full(len(self.components), np.nan)
        return np.mean([s.abs_diff for s in self.steps], axis=0)

    @property
    def status_counts(self):
        """Return ``{status: steps}`` of the offline filter."""
        return dict(Counter(s.status for s in self.steps))

    @property
    def passed(self):
        """Whether something was paired and every difference is within the tolerance."""
        return bool(self.steps) and float(np.max(self.max_abs_diff)) <= self.tolerance

    def worst(self, count):
        """Return the ``count`` steps with the largest difference, largest first."""
        return sorted(self.steps, key=lambda s: -float(s.abs_diff.max()))[:count]

    def to_json(self, worst=5):
        """Return the report as plain JSON data."""
        def step(s):
            return {'stamp_s': s.stamp_s, 'status': s.status, 'recorded': s.recorded.tolist(),
                    'offline': s.offline.tolist(), 'nominal': s.nominal.tolist(),
                    'max_abs_diff': float(s.abs_diff.max())}

        return {
            'bag': self.bag, 'robot': self.robot, 'model': self.model, 'topics': self.topics,
            'components': list(self.components), 'paired': len(self.steps),
            'unpaired': self.unpaired,
            'max_abs_diff': dict(zip(self.components, self.max_abs_diff.tolist())),
            'mean_abs_diff': dict(zip(self.components, self.mean_abs_diff.tolist())),
            'tolerance': self.tolerance, 'passed': self.passed,
            'status_counts': self.status_counts, 'worst': [step(s) for s in self.worst(worst)],
            'parameters': {k: v for k, v in sorted(self.parameters.items())},
        }

    def summary(self, worst=5):
        """Return the report as text."""
        params = self.parameters
        lines = [f'offline check of /{self.robot} in {self.bag}: {len(self.steps)} safe commands '
                 f'paired by stamp, {self.unpaired} unpaired (no same-stamp odometry and '
                 'command, e.g. watchdog stops)',
                 f'model {self.model}, barrier {params["filter.barrier"]}, rate '
                 f'{params["rate"]:g} Hz, trigger {params["trigger"]}, match_stamps '
                 f'{str(params["match_stamps"]).lower()}']
        if not (params['trigger'] == 'command' and params['match_stamps']):
            lines.append('note: without trigger command and match_stamps the node may have '
                         'used other odometry than the same-stamp one; expect differences')
        lines.append(f'{"component":<10} {"max |diff|":>12} {"mean |diff|":>12}')
        for name, high, mean in zip(self.components, self.max_abs_diff, self.mean_abs_diff):
            lines.append(f'{name:<10} {high:12.3e} {mean:12.3e}')
        lines.append('offline statuses: ' + ', '.join(
            f'{k} {v}' for k, v in sorted(self.status_counts.items())))
        if self.steps:
            lines.append('worst steps:')
            for s in self.worst(worst):
                lines.append(f'  t = {s.stamp_s:.4f} s {s.status}: recorded '
                             f'{np.round(s.recorded, 6).tolist()}, offline '
                             f'{np.round(s.offline, 6).tolist()}, nominal '
                             f'{np.round(s.nominal, 6).tolist()}')
        verdict = 'PASS' if self.passed else 'FAIL'
        high = float(np.max(self.max_abs_diff)) if self.steps else math.nan
        lines.append(f'{verdict}: max |difference| {high:.3e} (tolerance {self.tolerance:g})')
        return '\n'.join(lines)


def _command_vector(msg, velocity, model_name):
    """Command vector of a TwistStamped (velocity models) or WrenchStamped."""
    if velocity:
        return np.array(conversions.twist_to_command(msg.twist, model_name), dtype=float)
    w = msg.wrench
    return np.array([w.force.z, w.torque.x, w.torque.y, w.torque.z], dtype=float)


class _OfflineNode:
    """The node's decision (``ControlDecision``) and obstacle pipeline, fed from a bag.

    Log times stand in for the node's steady clock (the bridge logs what it receives when
    it receives it), so the watchdogs see what the node saw.
    """

    def __init__(self, setup):
        self.setup = setup
        self.filter = setup.command_filter
        self.decision = ControlDecision(setup.command_filter, setup.timeouts,
                                        setup.block_if_invalid, setup.max_extrapolation)
        self.pipeline = ObstaclePipeline()
        self.spec = (setup.model_name, setup.command_filter.safety_filter.config)
        self.frame = None
        self.odometry = {}   # stamp ns -> (log time s, state, yaw)
        self.nominal = {}    # stamp ns -> (log time s, command vector)

    def _obstacles(self, messages, now):
        """Run the node's obstacle pipeline on ``messages`` and hand the result over."""
        self.decision.obstacles(self.pipeline.run(ObstacleJob(
            messages, self.frame, self.setup.intake, self.spec, now)))

    def on_obstacles(self, msg, t_ns):
        """Process a MarkerArray (zero stamps read as the log time)."""
        self._obstacles([(msg, t_ns * 1e-9)], t_ns * 1e-9)

    def on_odometry(self, msg, t_ns):
        """Keep the state of each odometry stamp; a new frame rebuilds the obstacles."""
        state = np.zeros(self.filter.model.state_dim)
        yaw = conversions.odometry_to_state(msg, self.setup.model_name, state)
        self.odometry[stamp_ns(msg)] = (t_ns * 1e-9, state, yaw)
        frame = msg.header.frame_id.lstrip('/')
        if frame != self.frame:
            self.frame = frame
            self._obstacles([], t_ns * 1e-9)

    def on_nominal(self, msg, t_ns):
        """Keep the nominal command of each stamp."""
        self.nominal[stamp_ns(msg)] = (t_ns * 1e-9, _command_vector(
            msg, self.filter.velocity, self.setup.model_name))

    def answer(self, stamp):
        """Return ``(command, status, nominal, state)`` for the stamp, or None if unpaired."""
        if stamp not in self.odometry or stamp not in self.nominal:
            return None
        odom_time, state, yaw = self.odometry[stamp]
        cmd_time, command = self.nominal[stamp]
        decision = self.decision
        finite = bool(np.isfinite(state).all() and math.isfinite(yaw))
        decision.odometry(odom_time, *((state, yaw, stamp * 1e-9) if finite else ()))
        finite_command = bool(np.isfinite(command).all())
        decision.command(cmd_time, *((command,) if finite_command else ()))
        result = decision.step(max(odom_time, cmd_time))
        if result.action == 'filter':
            return result.command, result.info.status.value, command, state
        return result.command, result.reason, command, state


def offline_check(bag, robot=None, parameters=None, tolerance=1e-6):
    """Re-run the node's decision on a bag; return the ``OfflineReport``.

    See the module docstring; ``parameters`` is ``{name: value}`` (e.g. from
    ``load_parameters``).  A recorded safe command logged at ``t`` is answered
    once every message logged at ``t`` is in: the bridge logs what it receives
    during period ``t`` at ``t``, in arrival order, so the same-stamp nominal
    command may come after it.
    """
    reader = BagReader(bag)
    topics = reader.topics
    robot = (robot or find_robot(topics)).strip('/')
    setup = build_filter(parameters or {})
    if setup.ignored:
        _log(f'ignoring parameters the node does not declare: {", ".join(setup.ignored)}')
    node = _OfflineNode(setup)
    velocity = setup.command_filter.velocity
    kind = ('cmd_vel_in', 'cmd_vel_out') if velocity else ('wrench_in', 'wrench_out')
    names = {'odom': f'/{robot}/odom', 'obstacles': f'/{robot}/obstacles',
             'nominal': f'/{robot}/{kind[0]}', 'safe': f'/{robot}/{kind[1]}'}
    for role, name in names.items():
        if name not in topics:
            raise ReplayError(f'the bag has no {name} ({role}); topics: '
                              f'{", ".join(sorted(topics))}')
    for role in ('nominal', 'safe'):
        type_name = topics[names[role]].type_name
        if not type_name.endswith('Stamped'):
            raise ReplayError(f'{names[role]} is {type_name}: pairing commands with odometry '
                              'needs stamped commands (TwistStamped / WrenchStamped)')
    components = (('v', 'omega') if setup.model_name == 'unicycle'
                  else ('vx', 'vy', 'vz')[:setup.command_filter.command_dim] if velocity
                  else ('thrust', 'tau_x', 'tau_y', 'tau_z'))
    steps, pending, unpaired = [], [], 0

    def flush():
        nonlocal unpaired
        for stamp, recorded in pending:
            answer = node.answer(stamp)
            if answer is None:
                unpaired += 1
                continue
            safe, status, command, state = answer
            steps.append(OfflineStep(stamp * 1e-9, status, recorded,
                                     np.asarray(safe, dtype=float), command, state))
        pending.clear()

    role_of = {name: role for role, name in names.items()}
    log_ns = None
    for topic, _, t_ns, msg in reader.messages(names.values()):
        if t_ns != log_ns:
            flush()
            log_ns = t_ns
        role = role_of[topic]
        if role == 'obstacles':
            node.on_obstacles(msg, t_ns)
        elif role == 'odom':
            node.on_odometry(msg, t_ns)
        elif role == 'nominal':
            node.on_nominal(msg, t_ns)
        else:
            pending.append((stamp_ns(msg), _command_vector(msg, velocity, setup.model_name)))
    flush()
    return OfflineReport(str(bag), robot, setup.model_name, names, components, steps,
                         unpaired, tolerance, setup.parameters)


# -- command line ---------------------------------------------------------------------------


def _parser():
    parser = argparse.ArgumentParser(
        prog='bag_replay', description='Play an MCAP bag onto live ROS 2 topics at its '
        'recorded timing, or (--offline) re-run the safety filter on it and compare with '
        'the recorded safe commands.', epilog='ROS arguments (--ros-args -r FROM:=TO ...) are '
        'passed to rclpy.  Exit status: 0 ok, 1 bad input, 2 bad usage, 3 offline '
        'difference beyond --tolerance.')
    parser.add_argument('bag', help='rosbag2 directory or .mcap file')
    live = parser.add_argument_group('live playback')
    live.add_argument('--rate', '-r', type=float, default=1.0,
                      help='playback speed multiplier (default 1)')
    live.add_argument('--topics', nargs='+', default=(), metavar='PATTERN',
                      help='play only these topics (names or globs)')
    live.add_argument('--exclude', nargs='+', default=(), metavar='PATTERN',
                      help='do not play these topics (names or globs)')
    live.add_argument('--remap', '-m', action='append', default=[], metavar='FROM:=TO',
                      help='publish bag topic FROM on TO (repeatable)')
    live.add_argument('--clock', nargs='?', type=float, const=DEFAULT_CLOCK_HZ, default=0.0,
                      metavar='HZ', help='publish /clock from the bag time at HZ (default '
                      f"{DEFAULT_CLOCK_HZ:g}) instead of the bag's own /clock")
    live.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                      help='start S seconds into the bag')
    live.add_argument('--duration', type=float, default=0.0, metavar='S',
                      help='play S seconds of bag time (default: to the end)')
    live.add_argument('--delay', type=float, default=0.0, metavar='S',
                      help='wait S wall seconds after creating the publishers')
    live.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                      help='wait up to S seconds until every played topic has a subscriber')
    live.add_argument('--lockstep', metavar='REQUEST:=RESPONSE',
                      help='after each REQUEST message (bag topic) wait for the RESPONSE '
                      '(live topic) with the same header stamp')
    live.add_argument('--lockstep-timeout', type=float, default=10.0, metavar='S',
                      help='longest wait for one lockstep response (default 10 s)')
    live.add_argument('--quiet', '-q', action='store_true', help='no progress output')
    offline = parser.add_argument_group('offline check (no DDS)')
    offline.add_argument('--offline', action='store_true',
                         help='re-run the filter on the bag and compare')
    offline.add_argument('--robot', metavar='NS', help='robot namespace (default: the only one)')
    offline.add_argument('--params-file', action='append', default=[], metavar='YAML',
                         help="the node's parameter file (repeatable)")
    offline.add_argument('--param', '-p', action='append', default=[], metavar='NAME:=VALUE',
                         help='parameter override, as -p of --ros-args (repeatable)')
    offline.add_argument('--json', metavar='PATH', help='write the report as JSON')
    offline.add_argument('--tolerance', type=float, default=1e-6,
                         help='largest accepted |difference| (default 1e-6)')
    offline.add_argument('--worst', type=int, default=5, help='worst steps to show')
    return parser


def _run_offline(args):
    robot = args.robot or find_robot(BagReader(args.bag).topics)
    parameters = load_parameters(args.params_file, args.param, robot)
    report = offline_check(args.bag, robot, parameters, args.tolerance)
    print(report.summary(args.worst), flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report.to_json(args.worst), indent=1) + '\n')
        print(f'report written to {args.json}', flush=True)
    return 0 if report.passed else EXIT_DIFFERENT


def _run_live(args, argv):
    lockstep = ()
    if args.lockstep:
        (lockstep,) = parse_remaps([args.lockstep]).items()
    options = PlayOptions(
        rate=args.rate, topics=tuple(args.topics), exclude=tuple(args.exclude),
        remaps=parse_remaps(args.remap), clock_hz=args.clock or 0.0,
        start_offset=args.start_offset, duration=args.duration, delay=args.delay,
        wait_for_subscribers=args.wait_for_subscribers, lockstep=lockstep,
        lockstep_timeout=args.lockstep_timeout, progress=not args.quiet)
    # Ctrl-C and SIGTERM raise KeyboardInterrupt in the playback loop, which ends it and
    # then shuts rclpy down; rclpy's own handlers would invalidate the context first,
    # under a publish in progress.
    signal.signal(signal.SIGTERM, _interrupt)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    player = None
    try:
        player = BagPlayer(args.bag, options)
        for source, target in player.topic_map.items():
            if source != target:
                _log(f'{source} -> {target}')
        stats = player.run()
    except KeyboardInterrupt:  # before playback started
        return 0
    finally:
        if player is not None:
            player.close()
        rclpy.try_shutdown()
    print(stats.summary(), flush=True)
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def split_ros_args(argv):
    """Return ``(own arguments, ROS arguments)``: ``--ros-args ... [--]`` blocks go to ROS.

    rclpy's own splitter would also take ``NAME:=VALUE`` words outside the
    blocks (the deprecated remap syntax), which are this tool's ``-p`` values.
    """
    own, ros, inside = [], [], False
    for word in argv:
        if word == '--ros-args':
            inside = True
            ros.append(word)
        elif inside and word == '--':
            inside = False
        elif inside:
            ros.append(word)
        else:
            own.append(word)
    return own, ros


def main(argv=None):
    """Run ``bag_replay`` with ``argv`` (default ``sys.argv[1:]``); see ``--help``."""
    own, ros = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    args = _parser().parse_args(own)
    try:
        if not Path(args.bag).exists():
            raise ReplayError(f'no bag at {args.bag}')
        if args.offline:
            return _run_offline(args)
        return _run_live(args, ['bag_replay', *ros])
    except (ReplayError, ParameterError, FileNotFoundError) as exc:
        _log(f'error: {exc}')
        return EXIT_ERROR
    except KeyboardInterrupt:  # offline: no result to show
        _log('interrupted')
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
