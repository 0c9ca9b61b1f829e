"""Obstacle messages -> a prepared ``ObstacleSet``, off the control path: the transport.

This module moves the work to a worker process and the snapshots back; the work itself
is ``obstacle_pipeline`` and its parameters ``obstacle_settings``.

The subscription callback only queues the serialized message (``submit``: an append and an
event, microseconds).  All obstacle work runs in a **worker process**
(``python -m polyc2bf_ros.obstacle_intake``, started by ``start``), fed by a thread of the
node that takes everything queued at once, so a flood is conflated rather than replayed.
Per pass (``obstacle_pipeline.ObstaclePipeline.run``):

1. every queued message is read (``cdr_reader.read_marker_array``); an unreadable one
   marks the input unreadable until a readable one follows it;
2. their markers are merged, newest per ``ns/id`` (``marker_obstacles.conflate_markers``), and
   applied to the ``ObstacleTracker``: only the newest shape of each key is built, each
   outline capped at ``max_vertices`` points (``core.geometry.polygon_limits``);
3. the set in the odometry frame is built (``ObstacleTracker.obstacle_set``, at most
   ``max_parts`` convex parts per footprint and ``max_obstacles`` in all) and its views
   are prepared for the filter (``ObstacleGeometry.prepare``, stored in the set: the
   filter's geometry alone, no filter is built here);
4. the result comes back as one immutable ``ObstacleSnapshot``, published by one
   attribute store (atomic under the GIL), which the control step reads.  A set that is a
   translation of the last one sent (obstacles that only moved) travels as offsets and is
   rebuilt on the node's side from the base it already holds.

Why a process, not a thread (measured, ``bench/bench_obstacle_flood.py``): CPython runs one
thread at a time, and a worker thread descheduled by the OS while it holds the interpreter
lock keeps the control thread waiting for a whole time slice on a loaded machine.  The node
process now does only queueing, one unpickle per pass and its control steps, and the
worker runs at niceness ``WORKER_NICENESS``, so the control thread wins the CPU.

LaserScans (``submit_scan``, the node's ``scan_topics``) take the same path: the newest
scan per topic is queued serialized with the node's recent odometry (its last
``ODOMETRY_HISTORY`` samples), and the worker reads and checks it, places it at the pose
the samples give at the scan's ``header.stamp``
(``core.obstacles.scan_conversion.pose_at``: interpolated between the two around it; a scan
older than the samples takes the oldest, a newer one the newest) and converts it
(``core.obstacles.scan_conversion.scan_to_obstacles``, in ``read_scan``).  With
``scan_tracking`` (the default) every scan's clusters go to one
``core.obstacles.scan_tracker.ScanTracker`` shared by all scan topics, and each obstacle
takes the velocity of its cluster's track (zero unless the track is confirmed and
moving).  A topic's obstacles (keys ``<topic>:scan/<i>``) replace its previous ones and
join the marker obstacles in one ``ObstacleSet``, every obstacle moved along its velocity
to the newest stamp among them (``t_ref``); a rejected scan keeps them and is
reported in ``scan_status``.
``/tf_static`` messages (``submit_transforms``) go to the worker too, which keeps the static
transform tree (``static_transforms``): a scan in another frame than the odometry child
frame is placed by the static transforms from that frame to the scan's, and at
``sensor_pose`` when none links them.

If the worker process dies, the obstacles it held are lost: the snapshot stays unusable
(the node brakes, with the reason in its diagnostics) until the node is restarted.
``process`` waits until everything submitted before the call (messages, frame, settings)
has been processed (tests, tools); without ``start`` it runs the pipeline in the caller.
"""
import os
import pickle
import signal
import subprocess
import sys
import threading

from polyc2bf_ros.core.decision import ObstacleSnapshot
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline
from polyc2bf_ros.obstacle_settings import IntakeSettings

# Odometry samples a scan is matched against: 0.2 s of 1 kHz odometry, 4 s of 50 Hz.
ODOMETRY_HISTORY = 200
_PROTOCOL = pickle.HIGHEST_PROTOCOL


def _encode(snapshot, last_base, scan_status=None):
    """Pickle a snapshot; a translation of ``last_base`` goes as its offsets and motion."""
    obstacles = snapshot.obstacles
    if last_base is not None and obstacles.base is last_base:
        moved = (obstacles.offsets, obstacles.velocities, obstacles.accelerations)
        return pickle.dumps((True, moved, _replace(snapshot, ObstacleSet.empty()), scan_status),
                            _PROTOCOL)
    return pickle.dumps((False, None, snapshot, scan_status), _PROTOCOL)


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
        payload = _encode(snapshot, last_base, pipeline.scan_status)
        obstacles = snapshot.obstacles
        last_base = obstacles.base if obstacles.base is not None else obstacles
        try:
            outbox.write(len(payload).to_bytes(8, 'little') + payload)
            outbox.flush()
        except BrokenPipeError:
            return 0


class ObstacleIntake:
    """Queue obstacle messages and hand them to the worker process (module docstring)."""

    def __init__(self, geometry, now, settings=IntakeSettings(), on_snapshot=None):
        """``geometry``: the filter's (``SafetyFilter.geometry``); ``now()`` [s] stamps markers.

        ``on_snapshot()``, if given, is called from the feeder thread after each pass.
        """
        self._on_snapshot = on_snapshot
        self._geometry = geometry
        self._now = now
        self._settings = settings
        self._frame = None
        self._pending = []
        self._scans = {}  # topic: the newest scan not yet processed
        self._transforms = []  # /tf_static messages not yet processed
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
        self.scan_status = {}  # topic: ScanStatus, as of the newest pass
        self.snapshot = ObstacleSnapshot()

    def configure(self, settings, geometry):
        """Take new settings and filter; rebuild on the next pass."""
        with self._lock:
            self._settings, self._geometry, self._dirty = settings, geometry, True
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

    def submit_scan(self, topic, data, received, odometry, base_frame):
        """Queue a serialized LaserScan of ``topic`` (replacing one not yet processed).

        ``odometry``: the recent odometry samples ``(stamp [s], x, y, yaw)``, oldest first
        (a tuple: empty before any); ``base_frame``: its child frame.
        """
        with self._lock:
            self._scans[topic] = (topic, data, received, odometry, base_frame)
            self._generation += 1
        self._wake.set()

    def submit_transforms(self, data):
        """Queue one serialized ``/tf_static`` message (tf2_msgs/TFMessage)."""
        with self._lock:
            self._transforms.append(data)
            self._generation += 1
        self._wake.set()

    def start(self):
        """Start the worker process, wait until it is ready, then the feeder thread (a daemon).

        Ready means one empty pass answered (imports done, the filter built), so the first
        obstacle message is not held up by the worker's start-up (about a second).
        """
        with self._lock:
            warm_up = ObstacleJob([], None, self._settings, self._geometry, 0.0)
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
                self.scan_status = dict(self._pipeline.scan_status)
            return self.snapshot
        with self._progress:
            target = self._generation
            self._progress.wait_for(lambda: self._done >= target, timeout)
        return self.snapshot

    def _take(self):
        """Return (the next ``ObstacleJob``, or None if there is nothing to do; generation)."""
        with self._lock:
            messages, self._pending = self._pending, []
            scans, self._scans = tuple(self._scans.values()), {}
            transforms, self._transforms = tuple(self._transforms), []
            dirty, self._dirty = self._dirty, False
            if not (messages or scans or transforms or dirty):
                return None, self._generation
            job = ObstacleJob(messages, self._frame, self._settings, self._geometry,
                              self._now(), scans, transforms)
            return job, self._generation

    def _feed(self):
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            job, generation = (None, 0) if self._stopping else self._take()
            if job is None:
                continue
            snapshot, scan_status = self._run_in_worker(job)
            with self._progress:
                if scan_status is not None:
                    self.scan_status = scan_status
                self.snapshot = snapshot
                self._done = generation
                self._progress.notify_all()
            if self._on_snapshot is not None:
                self._on_snapshot()

    def _run_in_worker(self, job):
        """Send one job to the worker; return (snapshot, scan status); unusable if it died."""
        if self._failed:
            return ObstacleSnapshot(error=self._failed), None
        try:
            if self._worker is None:
                self._start_worker()
            pickle.dump(job, self._worker.stdin, _PROTOCOL)
            self._worker.stdin.flush()
            size = int.from_bytes(_read_exactly(self._worker.stdout, 8), 'little')
            moved, offsets, snapshot, scan_status = pickle.loads(
                _read_exactly(self._worker.stdout, size))
        except Exception as exc:  # noqa: BLE001 - any failure of the worker is the same fault
            self._stop_worker()
            self._failed = (f'obstacle worker process failed ({exc}): the obstacles it held are '
                            'lost; braking until the node is restarted')
            return ObstacleSnapshot(error=self._failed), None
        if moved:
            snapshot = _replace(snapshot, self._base.translated(*offsets))
        else:
            obstacles = snapshot.obstacles
            self._base = obstacles.base if obstacles.base is not None else obstacles
        return snapshot, scan_status

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
