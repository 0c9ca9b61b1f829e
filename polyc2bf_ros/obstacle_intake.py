"""Obstacle messages -> a prepared ``ObstacleSet``, off the control path, with bounded work.

The subscription callback only queues the serialized message (``submit``: an append and an
event, microseconds).  All obstacle work runs in a **worker process**
(``python -m polyc2bf_ros.obstacle_intake``, started by ``start``), fed by a thread of the
node that takes everything queued at once, so a flood is conflated rather than replayed.
Per pass (``ObstaclePipeline.run``):

1. every queued message is read (``cdr_reader.read_marker_array``); an unreadable one
   marks the input unreadable until a readable one follows it;
2. their markers are merged, newest per ``ns/id`` (``marker_obstacles.conflate_markers``), and
   applied to the ``ObstacleTracker``: only the newest shape of each key is built, each
   outline capped at ``max_vertices`` points (``core.polygon_limits``);
3. the set in the odometry frame is built (``ObstacleTracker.obstacle_set``, at most
   ``max_parts`` convex parts per footprint and ``max_obstacles`` in all) and its views
   are prepared for the filter (``SafetyFilter.prepare``, stored in the set);
4. the result comes back as one immutable ``ObstacleSnapshot``, published by one
   attribute store (atomic under the GIL), which the control step reads.  A set that is a
   translation of the last one sent (obstacles that only moved) travels as offsets and is
   rebuilt on the node's side from the base it already holds.

Why a process, not a thread (measured, ``bench/bench_obstacle_flood.py``): CPython runs one
thread at a time, and a worker thread descheduled by the OS while it holds the interpreter
lock keeps the control thread waiting for a whole time slice on a loaded machine.  The node
process now does only queueing, one unpickle per pass and its control steps, and the
worker runs at niceness ``WORKER_NICENESS``, so the control thread wins the CPU.

If the worker process dies, the obstacles it held are lost: the snapshot stays unusable
(the node brakes, with the reason in its diagnostics) until the node is restarted.
``process`` waits until everything submitted before the call (messages, frame, settings)
has been processed (tests, tools); without ``start`` it runs the pipeline in the caller.
"""
import math
import os
import pickle
import signal
import subprocess
import sys
import threading
from typing import NamedTuple

from polyc2bf_ros import cdr_reader, marker_obstacles
from polyc2bf_ros.core.decision import ObstacleSnapshot
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacle_tracker import ObstacleTracker
from polyc2bf_ros.core.obstacles import ObstacleSet
from polyc2bf_ros.core.polygon_limits import MAX_PARTS, MAX_VERTICES
from polyc2bf_ros.core.safety_filter import SafetyFilter

MAX_OBSTACLES = 1000
_PROTOCOL = pickle.HIGHEST_PROTOCOL


class IntakeSettings(NamedTuple):
    """How markers become obstacles (node parameters of the same names)."""

    wall_thickness: float = 0.05
    cylinder_sides: int = 12
    max_vertices: int = MAX_VERTICES
    max_parts: int = MAX_PARTS
    max_obstacles: int = MAX_OBSTACLES


class ObstacleJob(NamedTuple):
    """One pass: messages [(data, received)], odometry frame, settings, filter, stamp [s].

    ``data`` is a serialized MarkerArray, or a MarkerArray message (offline replay).
    """

    messages: list
    frame: object
    settings: IntakeSettings
    filter_spec: tuple
    now: float


class ObstaclePipeline:
    """Steps 1-3 of the module docstring, with the tracker they keep between passes."""

    def __init__(self):
        """Start with no obstacles and no filter to prepare for."""
        self._tracker = ObstacleTracker()
        self._unreadable = ''
        self._received = None
        self._filter_spec = self._filter = None

    def run(self, job):
        """Process one ``ObstacleJob``; return the ``ObstacleSnapshot``."""
        markers = []
        for data, received in job.messages:
            try:
                markers += (cdr_reader.read_marker_array(data) if isinstance(data, bytes)
                            else data).markers
            except ValueError as exc:
                self._unreadable = f'malformed obstacle message: {exc}'
                continue
            self._unreadable, self._received = '', received
        settings, tracker = job.settings, self._tracker
        dim = self._filter_for(job.filter_spec).model.position_dim
        marker_obstacles.apply_markers(
            tracker, cdr_reader.MarkerArrayView(tuple(marker_obstacles.conflate_markers(markers))),
            job.now, settings.wall_thickness, settings.cylinder_sides,
            (settings.max_vertices, settings.max_parts))
        obstacles, t_ref, wrong_frame, error = ObstacleSet.empty(), math.nan, {}, ''
        if job.frame is not None:
            try:
                obstacles, t_ref, wrong_frame = tracker.obstacle_set(
                    job.frame, dim, settings.max_parts, settings.max_obstacles)
                self._filter.prepare(obstacles)
            except ValueError as exc:
                obstacles, error = ObstacleSet.empty(), f'obstacle set could not be built: {exc}'
        return ObstacleSnapshot(
            obstacles=obstacles, t_ref=t_ref, received=self._received,
            rejected=tracker.rejected, wrong_frame=wrong_frame, invalid=tracker.has_invalid,
            unreadable=self._unreadable, error=error, tracked=len(tracker),
            simplified=tracker.simplified, hulled=obstacles.capped)

    def _filter_for(self, spec):
        """Return the filter to prepare sets for: ``spec`` = (model name, config)."""
        if spec != self._filter_spec:
            self._filter = SafetyFilter(make_model(spec[0]), spec[1])
            self._filter_spec = spec
        return self._filter


def _encode(snapshot, last_base):
    """Pickle a snapshot; a translation of ``last_base`` goes as its offsets and velocities."""
    obstacles = snapshot.obstacles
    if last_base is not None and obstacles.base is last_base:
        moved = (obstacles.offsets, obstacles.velocities)
        return pickle.dumps((True, moved, _replace(snapshot, ObstacleSet.empty())), _PROTOCOL)
    return pickle.dumps((False, None, snapshot), _PROTOCOL)


def _replace(snapshot, obstacles):
    """Return ``snapshot`` with another obstacle set."""
    return ObstacleSnapshot(**{**snapshot.__dict__, 'obstacles': obstacles})


def serve(inbox, outbox):
    """Worker process loop: pickled ``ObstacleJob``s from ``inbox``, snapshots to ``outbox``.

    Returns 0 when the node closes either pipe (it exited, or stopped the worker).
    """
    pipeline, last_base = ObstaclePipeline(), None
    while True:
        try:
            job = pickle.load(inbox)
        except EOFError:
            return 0
        snapshot = pipeline.run(job)
        payload = _encode(snapshot, last_base)
        obstacles = snapshot.obstacles
        last_base = obstacles.base if obstacles.base is not None else obstacles
        try:
            outbox.write(len(payload).to_bytes(8, 'little') + payload)
            outbox.flush()
        except BrokenPipeError:
            return 0


class ObstacleIntake:
    """Queue obstacle messages and hand them to the worker process (module docstring)."""

    def __init__(self, filter_spec, now, settings=IntakeSettings(), on_snapshot=None):
        """``filter_spec`` = (model name, ``FilterConfig``); ``now()`` [s] stamps markers.

        ``on_snapshot()``, if given, is called from the feeder thread after each pass.
        """
        self._on_snapshot = on_snapshot
        self._filter_spec = filter_spec
        self._now = now
        self._settings = settings
        self._frame = None
        self._pending = []
        self._generation = self._done = 0  # inputs given / processed
        self._dirty = False
        self._failed = ''

        self._lock = threading.Lock()  # the queue, settings and frame
        self._progress = threading.Condition(self._lock)
        self._wake = threading.Event()
        self._stopping = False
        self._feeder = self._worker = None
        self._pipeline = ObstaclePipeline()  # in-line, before ``start``
        self._base = None
        self.snapshot = ObstacleSnapshot()

    def configure(self, settings, filter_spec):
        """Take new settings and filter; rebuild on the next pass."""
        with self._lock:
            self._settings, self._filter_spec, self._dirty = settings, filter_spec, True
            self._generation += 1
        self._wake.set()

    def set_frame(self, frame):
        """Build obstacles in ``frame`` (the odometry's) from the next pass on."""
        with self._lock:
            self._frame, self._dirty = frame, True
            self._generation += 1
        self._wake.set()

    def submit(self, data, received):
        """Queue one serialized MarkerArray received at monotonic time ``received``."""
        with self._lock:
            self._pending.append((data, received))
            self._generation += 1
        self._wake.set()

    def start(self):
        """Start the worker process, wait until it is ready, then the feeder thread (a daemon).

        Ready means one empty pass answered (imports done, the filter built), so the first
        obstacle message is not held up by the worker's start-up (about a second).
        """
        with self._lock:
            warm_up = ObstacleJob([], None, self._settings, self._filter_spec, 0.0)
        self._run_in_worker(warm_up)
        self._feeder = threading.Thread(target=self._feed, name='obstacle_intake', daemon=True)
        self._feeder.start()

    def stop(self, timeout=2.0):
        """End the feeder and the worker process."""
        self._stopping = True
        self._wake.set()
        if self._feeder is not None:
            self._feeder.join(timeout)
        self._stop_worker()

    @property
    def generation(self):
        """Return how many inputs (messages, frames, settings) were given so far."""
        return self._generation

    def covers(self, generation):
        """Return True once the snapshot covers every input up to ``generation``.

        Without ``start`` nothing is processed until ``process`` is called: True.
        """
        return self._feeder is None or self._done >= generation

    def process(self, timeout=30.0):
        """Return the snapshot once every message submitted so far is processed.

        Without ``start`` the pipeline runs here, in the caller's thread.
        """
        if self._feeder is None:
            job, _ = self._take()
            if job is not None:
                self.snapshot = self._pipeline.run(job)
            return self.snapshot
        with self._progress:
            target = self._generation
            self._progress.wait_for(lambda: self._done >= target, timeout)
        return self.snapshot

    def _take(self):
        """Return (the next ``ObstacleJob``, or None if there is nothing to do; generation)."""
        with self._lock:
            messages, self._pending = self._pending, []
            dirty, self._dirty = self._dirty, False
            if not messages and not dirty:
                return None, self._generation
            job = ObstacleJob(messages, self._frame, self._settings, self._filter_spec,
                              self._now())
            return job, self._generation

    def _feed(self):
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            job, generation = (None, 0) if self._stopping else self._take()
            if job is None:
                continue
            snapshot = self._run_in_worker(job)
            with self._progress:
                self.snapshot = snapshot
                self._done = generation
                self._progress.notify_all()
            if self._on_snapshot is not None:
                self._on_snapshot()

    def _run_in_worker(self, job):
        """Send one job to the worker process and decode its answer; unusable if it died."""
        if self._failed:
            return ObstacleSnapshot(error=self._failed)
        try:
            if self._worker is None:
                self._start_worker()
            pickle.dump(job, self._worker.stdin, _PROTOCOL)
            self._worker.stdin.flush()
            size = int.from_bytes(_read_exactly(self._worker.stdout, 8), 'little')
            moved, offsets, snapshot = pickle.loads(_read_exactly(self._worker.stdout, size))
        except Exception as exc:  # noqa: BLE001 - any failure of the worker is the same fault
            self._stop_worker()
            self._failed = (f'obstacle worker process failed ({exc}): the obstacles it held are '
                            'lost; braking until the node is restarted')
            return ObstacleSnapshot(error=self._failed)
        if moved:
            snapshot = _replace(snapshot, self._base.translated(*offsets))
        else:
            obstacles = snapshot.obstacles
            self._base = obstacles.base if obstacles.base is not None else obstacles
        return snapshot

    def _start_worker(self):
        self._worker = subprocess.Popen(
            [sys.executable, '-m', 'polyc2bf_ros.obstacle_intake'],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def _stop_worker(self):
        worker, self._worker = self._worker, None
        if worker is not None:
            try:
                worker.stdin.close()
                worker.wait(2.0)
            except (OSError, subprocess.TimeoutExpired):
                worker.kill()
                worker.wait()


def _read_exactly(stream, size):
    """Read ``size`` bytes from ``stream``; ``EOFError`` if it ends first."""
    data = stream.read(size)
    if len(data) != size:
        raise EOFError('the obstacle worker closed its output')
    return data


# Scheduling niceness of the worker process: the node's control thread goes first.
WORKER_NICENESS = 10


def main():
    """Worker process entry: serve jobs on stdin/stdout until the node goes, at low priority.

    Ctrl-C reaches the whole process group; the worker ignores it and ends with the node.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.nice(WORKER_NICENESS)
    return serve(sys.stdin.buffer, sys.stdout.buffer)


if __name__ == '__main__':
    # Run the importable module's ``main``, so pickles name ``polyc2bf_ros.obstacle_intake``
    # classes, not ``__main__`` ones the node could not resolve.
    from polyc2bf_ros.obstacle_intake import main as module_main
    sys.exit(module_main())
