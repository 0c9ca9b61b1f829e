"""Obstacle messages -> a prepared ``ObstacleSet``, off the control path, with bounded work.

The subscription callback only queues the serialized message (``submit``: an append and an
event, microseconds).  A worker thread (``start``) takes everything queued at once, so a
flood is conflated rather than replayed:

1. every queued message is read (``conversions.read_marker_array``); an unreadable one
   marks the input unreadable until a readable one follows it;
2. their markers are merged, newest per ``ns/id`` (``conversions.conflate_markers``), and
   applied to the ``ObstacleTracker``: only the newest shape of each key is built;
3. the set in the odometry frame is built (``ObstacleTracker.obstacle_set``, at most
   ``max_parts`` convex parts per footprint and ``max_obstacles`` in all) and its views
   are prepared for the filter (``SafetyFilter.prepare``);
4. the result is published as one immutable ``ObstacleSnapshot`` (one attribute store,
   atomic under the GIL), which the control step reads.

Every outline is capped at ``max_vertices`` points (``core.polygon_limits``), so one message
costs at most (markers x a bounded per-marker cost).  CPython runs one thread at a time: the
worker's pure-Python loops hand the interpreter over every ``sys.getswitchinterval()`` s, and
the node lowers that interval to a quarter of its control period
(``bench/bench_obstacle_flood.py`` measures the control loop under obstacle floods).

``process`` runs steps 1-4 on given messages in the caller's thread (the worker's loop body;
offline tools and benchmarks call it directly).
"""
import math
import threading
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

from polyc2bf_ros import conversions
from polyc2bf_ros.core.obstacle_tracker import ObstacleTracker
from polyc2bf_ros.core.obstacles import ObstacleSet
from polyc2bf_ros.core.polygon_limits import MAX_PARTS, MAX_VERTICES

MAX_OBSTACLES = 1000


class IntakeSettings(NamedTuple):
    """How markers become obstacles (node parameters of the same names)."""

    wall_thickness: float = 0.05
    cylinder_sides: int = 12
    max_vertices: int = MAX_VERTICES
    max_parts: int = MAX_PARTS
    max_obstacles: int = MAX_OBSTACLES


@dataclass(frozen=True)
class ObstacleSnapshot:
    """The obstacle input as of the newest message processed.

    ``received``: monotonic receipt time of that message (None before any readable one);
    ``rejected`` / ``wrong_frame``: ``{key: reason}``; ``invalid``: some marker had NaN/Inf;
    ``unreadable`` / ``error``: why the last message could not be read / the set not be
    built ('' if fine); ``simplified``: obstacles whose outline was replaced by an enclosing
    polygon; ``hulled``: keys replaced by their hull (too many convex parts).
    """

    obstacles: ObstacleSet = field(default_factory=ObstacleSet.empty)
    t_ref: float = math.nan
    received: float = None
    rejected: dict = field(default_factory=dict)
    wrong_frame: dict = field(default_factory=dict)
    invalid: bool = False
    unreadable: str = ''
    error: str = ''
    tracked: int = 0
    simplified: int = 0
    hulled: tuple = ()

    @property
    def usable(self):
        """Return False when the filter must brake: NaN/Inf, unreadable, or no set built."""
        return not (self.invalid or self.unreadable or self.error)

    @property
    def clean(self):
        """Return True when nothing was refused: fresh data under ``block_if_invalid``."""
        return self.usable and not (self.rejected or self.wrong_frame)


class ObstacleIntake:
    """Queue, conflate and process obstacle messages on a worker thread (module docstring)."""

    def __init__(self, position_dim, prepare: Callable, now: Callable,
                 settings=IntakeSettings()):
        """``prepare(ObstacleSet)`` readies a set for the filter; ``now()`` [s] stamps markers."""
        self._dim = position_dim
        self._prepare = prepare
        self._now = now
        self._settings = settings
        self._tracker = ObstacleTracker()
        self._frame = None
        self._unreadable = ''
        self._received = None
        self._pending = []
        self._lock = threading.Lock()  # the queue, settings and frame
        self._work = threading.Lock()  # one processing pass at a time
        self._wake = threading.Event()
        self._stopping = False
        self._thread = None
        self._dirty = False
        self.snapshot = ObstacleSnapshot()

    def configure(self, settings, prepare):
        """Take new settings and a new filter's ``prepare``; rebuild on the next pass."""
        with self._lock:
            self._settings, self._prepare, self._dirty = settings, prepare, True
        self._wake.set()

    def set_frame(self, frame):
        """Build obstacles in ``frame`` (the odometry's) from the next pass on."""
        with self._lock:
            self._frame, self._dirty = frame, True
        self._wake.set()

    def submit(self, data, received):
        """Queue one serialized MarkerArray received at monotonic time ``received``."""
        with self._lock:
            self._pending.append((data, received))
        self._wake.set()

    def start(self):
        """Run the worker thread (a daemon: it never holds up the process's exit)."""
        self._thread = threading.Thread(target=self._run, name='obstacle_intake', daemon=True)
        self._thread.start()

    def stop(self, timeout=1.0):
        """Ask the worker to end and wait up to ``timeout`` s for it."""
        self._stopping = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self):
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            if not self._stopping:
                self.process()

    def process(self, messages=None):
        """Process ``messages`` [(data, received)] (default: all queued); publish a snapshot.

        One pass at a time: a call while the worker is in a pass waits for it, so once it
        returns every message submitted before the call has been processed.
        """
        with self._work:
            return self._process(messages)

    def _process(self, messages):
        with self._lock:
            if messages is None:
                messages, self._pending = self._pending, []
            dirty, self._dirty = self._dirty, False
            settings, prepare, frame = self._settings, self._prepare, self._frame
        if not messages and not dirty:
            return self.snapshot
        markers = []
        for data, received in messages:
            try:
                markers += conversions.read_marker_array(data).markers
            except ValueError as exc:
                self._unreadable = f'malformed obstacle message: {exc}'
                continue
            self._unreadable, self._received = '', received
        tracker = self._tracker
        conversions.apply_markers(
            tracker, conversions.MarkerArrayView(tuple(conversions.conflate_markers(markers))),
            self._now(), settings.wall_thickness, settings.cylinder_sides,
            (settings.max_vertices, settings.max_parts))
        obstacles, t_ref, wrong_frame, error = ObstacleSet.empty(), math.nan, {}, ''
        if frame is not None:
            try:
                obstacles, t_ref, wrong_frame = tracker.obstacle_set(
                    frame, self._dim, settings.max_parts, settings.max_obstacles)
                prepare(obstacles)
            except ValueError as exc:
                obstacles, error = ObstacleSet.empty(), f'obstacle set could not be built: {exc}'
        self.snapshot = ObstacleSnapshot(
            obstacles=obstacles, t_ref=t_ref, received=self._received,
            rejected=tracker.rejected, wrong_frame=wrong_frame, invalid=tracker.has_invalid,
            unreadable=self._unreadable, error=error, tracked=len(tracker),
            simplified=tracker.simplified, hulled=obstacles.capped)
        return self.snapshot
