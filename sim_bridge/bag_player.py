"""Live playback: publish an MCAP bag's messages onto ROS 2 topics at their recorded timing.

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
"""
import dataclasses
import fnmatch
import math
import sys
import time
from collections import Counter

import numpy as np
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock

from sim_bridge.bag_reader import BagReader, message_class

CLOCK_TOPIC = '/clock'
DEFAULT_CLOCK_HZ = 100.0
DEFAULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
RESPONSE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
ACK_TIMEOUT = 2.0  # wall s to wait at the end for reliable subscribers to acknowledge
LOCKSTEP_RESEND = 0.5  # wall s without a lockstep answer before the period is sent again


class ReplayError(ValueError):
    """Bad input to the replayer (bag, topics, remaps, parameters), with the reason."""



def log(text):
    """Print ``text`` on stderr as a ``bag_replay`` line."""
    print(f'bag_replay: {text}', file=sys.stderr, flush=True)


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

    clock_messages: int = 0
    requests: int = 0
    answered: int = 0
    timeouts: int = 0
    resent: int = 0
    paused_s: float = 0.0
    wall_s: float = 0.0
    bag_span_s: float = 0.0
    interrupted: bool = False
    published: Counter = dataclasses.field(default_factory=Counter)  # bag topic -> messages
    lateness_s: list = dataclasses.field(default_factory=list)  # publish - due [s], each message

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
            log(f"--clock: not playing the bag's own {CLOCK_TOPIC}")
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
                log(f'skipping {name}: message type {type_name} is not installed')
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
                log(f'no subscriber after {opts.wait_for_subscribers:g} s on '
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
            log(f'no answer stamped {stamp * 1e-9:.4f} s within '
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
