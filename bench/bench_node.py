"""Node benchmark: end-to-end latency and sustained rate of ``safety_filter`` over real DDS.

Three processes per measurement, so the driver cannot be the bottleneck:

- the **subject**: ``safety_filter`` (unicycle, ``stamped:=true``, 50 latched
  obstacles), with ``trigger:=command`` (one step per command) or
  ``trigger:=timer`` (steps at ``rate`` from its steady timer), both with the default
  filter; ``command_eq7``: ``trigger:=command`` with the filter the package had before
  the horizon barrier (eq. 7 on inflated polygons, midpoint axis, no braking check), the
  reference for what the default's extra work costs; or a bare
  **echo** node that republishes each command (the floor: DDS plus Python),
  spun by this package's ``LeanExecutor`` (``echo``) or by ``rclpy.spin``
  (``echo_rclpy``); and, to compare executors, ``echo_events`` (``echo`` on rclpy's
  ``EventsExecutor``) and ``command_events`` (``command``, same parameters, spun by
  ``EventsExecutor`` instead of ``LeanExecutor``: bench/events_executor_subject.py,
  which says what the pinned rclpy needs for it); not run unless named;
  ``command_footprint`` (``command`` guarding the Jackal's 4-vertex footprint with
  ``polyc2bf_footprint``), not run unless named either;
- the **sender** (this file, ``--role sender``): publishes odometry and a
  stamped command, both serialized in advance, every ``1/rate`` s on a fixed
  schedule; the command's ``header.frame_id`` is its sequence number and both
  stamps are the send time on CLOCK_MONOTONIC.  A cycle the sender wakes up for
  more than half a period late is skipped, as a fixed-rate loop skips a missed
  slot: sent anyway it would land within half a period of the next command,
  and with the commands' depth-1 QoS the node keeps only the newer one, so the
  driver's miss would count as the node's;
- the **receiver** (this process): takes the answers serialized and records,
  per sequence number, ``latency = receipt time - stamp`` (same clock).

Per run::

    answered  = commands answered at least once / commands sent (measured window)
    skipped   = cycles the sender skipped (woke > 1/(2 rate) late) / cycles scheduled
    achieved  = answers per second (trigger:=timer: one per tick, whatever it answers)
    latency   = p50 / p99 / max over the first answer to each command
    rss       = VmRSS (VmHWM = peak) of the subject at the end
    cpu/cycle = subject CPU time (user + system) / commands sent
    node step = median over the 1 s diagnostics windows of the node's own step p50 / p99

plus the sender's lateness against its schedule, the load average and the CPU
share stolen by the hypervisor.  With ``trigger:=timer`` at the command rate
a command can be overtaken by the next before a tick answers it, so its
``answered`` is below 1 by design; its latency includes the wait for the tick.
Results: a table on stdout, ``bench/results/node.json`` (doc/design.md, result records;
each record keeps its latency distribution, ``latency_cdf_ms`` at the
percentiles 0, 0.5, ..., 100) and beside it ``node.png``, those distributions
against the targets.  DDS stays on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).

    .venv/bin/python bench/bench_node.py [--rate 1000] [--obstacles 50] [--duration 10]
        [--subjects echo echo_rclpy command timer] [--layout in_reach] [--out /tmp/node.json]

Layouts (``--layout``): ``scattered`` (the default), 8-gons 3-8 m around the robot, which
odometry puts at the origin at 0.5 m/s: no obstacle within the braking check's reach, so
its quick box test skips it on every step; ``in_reach``, ``bench_core.py``'s layout of that
name (two rows of 8-gons whose near edges lie 0.95-1.05 m either side of the x axis, one
just behind the robot) with odometry at 1 m/s along x, where the check's reach (about
1.2 m: the stop from 1 m/s plus the guard radius) takes in the nearest of them: the check
computes its paths on every step, as it does for a robot driving between obstacles.

``--obstacle-updates`` instead times the node's obstacle handling in-process
(``run_obstacle_updates``): messages shaped like the sim bridge's (``--robots``
cylinders and ``--moving`` outlines every period, plus ``--obstacles`` static
outlines in every full set), ``_on_obstacles`` per message kind (it reads the
serialized message and applies it), with what rclpy's deserialization of the
same message would cost and the next filter step beside it; results in
``bench/results/node_obstacles.json``.
"""
import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from bench_core import in_reach_obstacles
from bench_io import require_installed_checkout, write_records
from diagnostic_msgs.msg import DiagnosticArray
from events_executor_subject import SlicedEventsExecutor
from geometry_msgs.msg import Point, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from polyc2bf_ros.lean_executor import LeanExecutor
from sim_bridge.launcher import stop_processes

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'node.json'
OBSTACLE_RESULTS = REPO / 'bench' / 'results' / 'node_obstacles.json'
NAMESPACE = '/bench_node'
COMMANDS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
ANSWERS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
SEQ_DIGITS = 10  # fixed-width sequence numbers keep the serialized layout fixed
STAMP = struct.Struct('<iI')
SUBJECTS = ('echo', 'echo_rclpy', 'command', 'timer', 'command_eq7')  # the default
EVENTS_SUBJECTS = ('echo_events', 'command_events')  # rclpy's EventsExecutor, on request
ON_REQUEST = EVENTS_SUBJECTS + ('command_footprint',)  # run only when named
EVENTS_NODE = Path(__file__).with_name('events_executor_subject.py')
#: subject -> (trigger, extra node parameters)
FILTER_SUBJECTS = {
    'command': ('command', ()),
    'command_events': ('command', ()),
    'timer': ('timer', ()),
    'command_eq7': ('command', ('filter.barrier:=polyc2bf_inflated', 'filter.cone_axis:=midpoint',
                                'filter.braking_check:=false')),
    'command_footprint': ('command', ('filter.barrier:=polyc2bf_footprint',
                                      'filter.footprint:="[[0.254, 0.215], [-0.254, 0.215], '
                                      '[-0.254, -0.215], [0.254, -0.215]]"')),
}
CDF_PERCENTILES = np.linspace(0.0, 100.0, 201)  # the latency distribution kept per record
TARGET_P50_MS, TARGET_P99_MS = 0.5, 1.5


def scattered_polygons(count, rng):
    """``count`` octagons (radius 0.3 m) at 3-8 m around the origin."""
    angles = np.linspace(0.0, 2.0 * np.pi, 9)[:-1]
    octagon = 0.3 * np.column_stack([np.cos(angles), np.sin(angles)])
    polygons = []
    for _ in range(count):
        bearing, distance = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(3.0, 8.0)
        polygons.append(distance * np.array([np.cos(bearing), np.sin(bearing)]) + octagon)
    return polygons


def in_reach_polygons(count, rng):
    """``count`` 8-gons in ``bench_core.py``'s ``in_reach`` layout (module docstring)."""
    return [obstacle.polygon for obstacle in in_reach_obstacles(count, rng)]


#: layout -> (polygons of ``count`` obstacles, odometry speed along x [m/s])
LAYOUTS = {'scattered': (scattered_polygons, 0.5), 'in_reach': (in_reach_polygons, 1.0)}


def obstacle_markers(count, layout='scattered', seed=0):
    """``count`` obstacles of ``layout`` as LINE_STRIP markers in frame odom."""
    result = MarkerArray()
    for i, polygon in enumerate(LAYOUTS[layout][0](count, np.random.default_rng(seed))):
        marker = Marker(ns='bench', id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
        marker.header.frame_id = 'odom'
        marker.pose.orientation.w = 1.0
        marker.points = [Point(x=float(x), y=float(y)) for x, y in polygon]
        result.markers.append(marker)
    return result


def cpu_times():
    """``(steal, total)`` jiffies of all CPUs from /proc/stat (steal = taken by the hypervisor)."""
    fields = [int(v) for v in Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:]]
    return fields[7], sum(fields)


def process_cpu_s(pid):
    """User + system CPU seconds used so far by ``pid``."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def rss_mb(pid):
    """``(VmRSS, VmHWM)`` of ``pid`` in MB."""
    fields = dict(line.split(':', 1) for line in Path(f'/proc/{pid}/status').read_text()
                  .splitlines() if ':' in line)
    return tuple(int(fields[k].split()[0]) / 1024.0 for k in ('VmRSS', 'VmHWM'))


def percentiles(values, qs):
    """Percentiles of ``values`` (NaN each when empty)."""
    return np.percentile(values, qs) if len(values) else np.full(len(qs), np.nan)


# -- subjects ----------------------------------------------------------------------------------

def subject_args(subject, rate):
    """Command line of the process under test."""
    if subject.startswith('echo'):
        return [sys.executable, __file__, '--role', subject]
    trigger, extra = FILTER_SUBJECTS[subject]
    node = ([str(EVENTS_NODE)] if subject in EVENTS_SUBJECTS
            else ['-m', 'polyc2bf_ros.safety_filter_node'])
    return [sys.executable, *node, '--ros-args',
            '-r', f'__ns:={NAMESPACE}', '-p', 'model:=unicycle', '-p', f'trigger:={trigger}',
            '-p', 'stamped:=true', '-p', f'rate:={float(rate)}',
            '-p', 'obstacles_timeout:=0.0', '-p', 'cmd_timeout:=0.5',
            *[arg for value in extra for arg in ('-p', value)], '--log-level', 'warn']


def run_echo(role):
    """Bare echo: every command is republished as it came (plus an idle odometry subscription).

    ``echo`` and ``echo_events``: serialized in and out, like the filter node, on
    ``LeanExecutor`` or rclpy's ``EventsExecutor``; ``echo_rclpy``: typed messages on
    rclpy's ``SingleThreadedExecutor``.
    """
    rclpy.init()
    node = rclpy.create_node('safety_filter', namespace=NAMESPACE)
    if role != 'echo_rclpy':
        publisher = node.create_publisher(TwistStamped, 'cmd_vel_out', COMMANDS)
        node.create_subscription(Odometry, 'odom', lambda data: None, 1, raw=True)
        node.create_subscription(TwistStamped, 'cmd_vel_in', publisher.publish, COMMANDS,
                                 raw=True)
        executor = LeanExecutor() if role == 'echo' else SlicedEventsExecutor()
    else:
        publisher = node.create_publisher(TwistStamped, 'cmd_vel_out', COMMANDS)
        node.create_subscription(Odometry, 'odom', lambda msg: None, 1)
        node.create_subscription(TwistStamped, 'cmd_vel_in', publisher.publish, COMMANDS)
        executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    return 0


# -- sender ------------------------------------------------------------------------------------

def run_sender(rate, count, speed):
    """Publish ``count`` odometry + command pairs at ``rate`` Hz; print lateness and skips as JSON.

    The odometry says the robot is at the origin, heading along x at ``speed`` m/s.

    Prints ``ready`` once both subscriptions are matched and waits for a line on
    stdin before sending, so the receiver controls the start.
    """
    rclpy.init()
    node = rclpy.create_node('bench_sender')
    odom_pub = node.create_publisher(Odometry, f'{NAMESPACE}/odom', COMMANDS)
    cmd_pub = node.create_publisher(TwistStamped, f'{NAMESPACE}/cmd_vel_in', COMMANDS)
    odom = Odometry()
    odom.header.frame_id = 'odom'
    odom.child_frame_id = 'base_link'
    odom.pose.pose.orientation.w = 1.0
    odom.twist.twist.linear.x = speed
    cmd = TwistStamped()
    cmd.header.frame_id = '0' * SEQ_DIGITS
    cmd.twist.linear.x = 1.0
    odom_bytes, cmd_bytes = serialize_message(odom), serialize_message(cmd)
    seq_at = 16  # frame_id characters follow stamp (8 bytes) and length (4 bytes)
    while not (odom_pub.get_subscription_count() and cmd_pub.get_subscription_count()):
        time.sleep(0.05)
    print('ready', flush=True)
    sys.stdin.readline()
    lateness = np.zeros(count)
    skipped = []
    start = time.monotonic()
    for seq in range(count):
        due = start + seq / rate
        delay = due - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
        sent = time.monotonic_ns()
        lateness[seq] = sent * 1e-9 - due
        if lateness[seq] > 0.5 / rate:
            skipped.append(seq)
            continue
        stamp = STAMP.pack(sent // 1_000_000_000, sent % 1_000_000_000)
        odom_pub.publish(odom_bytes[:4] + stamp + odom_bytes[12:])
        cmd_pub.publish(cmd_bytes[:4] + stamp + cmd_bytes[12:seq_at]
                        + f'{seq:0{SEQ_DIGITS}d}'.encode() + cmd_bytes[seq_at + SEQ_DIGITS:])
    print(json.dumps({'lateness_p50_ms': 1e3 * float(np.median(lateness)),
                      'lateness_p99_ms': 1e3 * float(np.percentile(lateness, 99)),
                      'elapsed_s': time.monotonic() - start, 'skipped': skipped}),
          flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# -- receiver ----------------------------------------------------------------------------------

class Receiver:
    """Records the latency of the first answer to each command and the diagnostics."""

    def __init__(self, node, count):
        """Subscribe (serialized) to the answers and to ``/diagnostics``."""
        self.latency_ns = np.full(count, -1, dtype=np.int64)
        self.answers = 0
        self.diagnostics = []
        self.answers_sub = node.create_subscription(
            TwistStamped, f'{NAMESPACE}/cmd_vel_out', self._on_answer, ANSWERS, raw=True)
        node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append, 10,
                                 raw=True)

    def _on_answer(self, data):
        now = time.monotonic_ns()
        self.answers += 1
        sec, nanosec = STAMP.unpack_from(data, 4)
        digits = data[16:16 + SEQ_DIGITS]
        if not digits.isdigit():
            return
        seq = int(digits)
        if seq < len(self.latency_ns) and self.latency_ns[seq] < 0:
            self.latency_ns[seq] = now - (sec * 1_000_000_000 + nanosec)

    def node_values(self):
        """Per diagnostics message: ``{key: value}`` of the safety filter's status."""
        result = []
        for data in self.diagnostics:
            for status in deserialize_message(data, DiagnosticArray).status:
                if status.name.startswith(f'{NAMESPACE}/safety_filter'):
                    result.append({kv.key: kv.value for kv in status.values})
        return result


def wait_for(predicate, proc, log, what, timeout=30.0):
    """Sleep-poll ``predicate`` until true; fail with the subject's output if it dies or hangs."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if proc.poll() is not None or time.monotonic() > deadline:
            log.seek(0)
            raise RuntimeError(f'{what} failed:\n{log.read().decode(errors="replace")}')
        time.sleep(0.05)


def run(subject, rate, obstacles, duration, warmup, layout='scattered'):
    """Benchmark one subject at ``rate`` Hz among ``layout``'s obstacles; return a record."""
    first, count = round(warmup * rate), round((warmup + duration) * rate)
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(subject_args(subject, rate), cwd=REPO, stdout=log,
                            stderr=subprocess.STDOUT)
    sender = None
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_receiver', context=context)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    try:
        receiver = Receiver(node, count)
        obstacles_pub = node.create_publisher(MarkerArray, f'{NAMESPACE}/obstacles', LATCHED)
        obstacles_pub.publish(obstacle_markers(obstacles, layout))
        spinner.start()
        wait_for(lambda: receiver.answers_sub.get_publisher_count() > 0, proc, log,
                 f'{subject} start')
        if not subject.startswith('echo'):
            wait_for(lambda: obstacles_pub.get_subscription_count() > 0, proc, log,
                     'obstacles subscription')
        sender = subprocess.Popen(
            [sys.executable, __file__, '--role', 'sender', '--rate', str(rate),
             '--count', str(count), '--speed', str(LAYOUTS[layout][1])], cwd=REPO,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        if sender.stdout.readline().strip() != 'ready':
            raise RuntimeError('sender failed to start')
        sender.stdin.write('go\n')
        sender.stdin.flush()
        time.sleep(warmup)
        steal_before, total_before = cpu_times()
        cpu_before, answers_before = process_cpu_s(proc.pid), receiver.answers
        started = time.monotonic()
        summary = json.loads(sender.stdout.readline())
        elapsed = time.monotonic() - started
        cpu_after, answers_after = process_cpu_s(proc.pid), receiver.answers
        steal_after, total_after = cpu_times()
        time.sleep(0.3)  # drain answers in flight
        rss, rss_peak = rss_mb(proc.pid)
        load = os.getloadavg()[0]
    finally:
        executor.shutdown()
        spinner.join(2.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        for p in (sender, proc):
            if p is not None:
                stop_processes([p], timeout=5.0)
        log.close()
    sent = np.ones(count, dtype=bool)
    sent[summary['skipped']] = False
    sent = sent[first:count]
    latency_ms = receiver.latency_ns[first:count][sent] * 1e-6
    answered = latency_ms[latency_ms >= 0.0]
    p50, p99 = percentiles(answered, (50, 99))
    windows = receiver.node_values()[1:]  # the first window includes start-up
    step_p50 = [float(v['latency_p50_ms']) for v in windows if v['latency_p50_ms'] != 'nan']
    step_p99 = [float(v['latency_p99_ms']) for v in windows if v['latency_p99_ms'] != 'nan']
    return {
        'bench': 'node', 'subject': subject, 'rate_hz': int(rate) if rate.is_integer() else rate,
        'obstacles': 0 if subject.startswith('echo') else obstacles, 'model': 'unicycle',
        'layout': layout, 'odometry_speed': LAYOUTS[layout][1],
        'trigger': FILTER_SUBJECTS[subject][0] if not subject.startswith('echo') else None,
        'duration_s': duration,
        'p50_ms': round(float(p50), 4), 'p99_ms': round(float(p99), 4),
        'max_ms': round(float(answered.max()), 4) if answered.size else None,
        'latency_cdf_ms': ([round(float(v), 4) for v in np.percentile(answered, CDF_PERCENTILES)]
                           if answered.size else []),
        'answered_frac': round(answered.size / max(sent.sum(), 1), 5),
        'sender_skipped_frac': round(1.0 - sent.mean(), 5),
        'achieved_hz': round((answers_after - answers_before) / elapsed, 1),
        'rss_mb': round(rss, 1), 'rss_peak_mb': round(rss_peak, 1),
        'cpu_ms_per_cycle': round(1e3 * (cpu_after - cpu_before) / (elapsed * rate), 4),
        'node_step_p50_ms': statistics.median(step_p50) if step_p50 else None,
        'node_step_p99_ms': statistics.median(step_p99) if step_p99 else None,
        'obstacles_in_use': int(windows[-1]['obstacles_in_use']) if windows else None,
        # Stops instead of answers (stale or invalid input): 0 in a healthy run.
        'node_stops': int(windows[-1]['steps_stale_stop']) + int(
            windows[-1]['steps_invalid_input']) if windows else None,
        'sender_late_p50_ms': round(summary['lateness_p50_ms'], 4),
        'sender_late_p99_ms': round(summary['lateness_p99_ms'], 4),
        'cpus': os.cpu_count(), 'load_avg_1min': round(load, 2),
        'cpu_steal_frac': round((steal_after - steal_before)
                                / max(total_after - total_before, 1), 4),
    }


# -- obstacle updates (in-process) ------------------------------------------------------------

def _ring_marker(ns, marker_id, ring, position, height):
    """LINE_STRIP outline as the sim bridge sends it: closed ring relative to ``position``."""
    marker = Marker(ns=ns, id=marker_id, type=Marker.LINE_STRIP, action=Marker.ADD)
    marker.header.frame_id = 'world'
    marker.scale.x, marker.scale.z = 0.02, height
    marker.pose.position = Point(x=float(position[0]), y=float(position[1]))
    marker.pose.orientation.w = 1.0
    marker.points = [Point(x=float(x), y=float(y)) for x, y in np.vstack([ring, ring[:1]])]
    return marker


def sim_markers(static, robots, moving, seed=0):
    """Return ``(static markers, dynamic markers, move(t))`` shaped like the sim bridge's.

    Static obstacles: outlines (rectangles, octagons, every fifth an L-shaped wall)
    in absolute coordinates; moving ones: octagons relative to a moving pose;
    robots: CYLINDERs (ns ``robots``).  ``move(t)`` sets the dynamic poses and
    every stamp for sim time ``t`` [s].
    """
    rng = np.random.default_rng(seed)
    angles = np.linspace(0.0, 2.0 * np.pi, 9)[:-1]
    octagon = 0.3 * np.column_stack([np.cos(angles), np.sin(angles)])
    rectangle = np.array([[-0.4, -0.2], [0.4, -0.2], [0.4, 0.2], [-0.4, 0.2]])
    l_wall = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.2], [0.2, 0.2], [0.2, 1.5], [0.0, 1.5]])
    static_markers = []
    for i in range(static):
        shape = (l_wall, rectangle, octagon)[0 if i % 5 == 0 else 1 + i % 2]
        static_markers.append(_ring_marker('obstacles', i, shape + rng.uniform(-10, 10, 2),
                                           (0.0, 0.0), 1.0))
    dynamic = [_ring_marker('obstacles', static + i, octagon, (0.0, 0.0), 1.0)
               for i in range(moving)]
    for i in range(robots):
        marker = Marker(ns='robots', id=i, type=Marker.CYLINDER, action=Marker.ADD)
        marker.header.frame_id = 'world'
        marker.scale.x = marker.scale.y = 0.6
        marker.scale.z = 0.5
        marker.pose.position.z = 0.25
        marker.pose.orientation.w = 1.0
        dynamic.append(marker)
    centres = rng.uniform(-8.0, 8.0, (len(dynamic), 2))
    velocities = rng.uniform(-0.5, 0.5, (len(dynamic), 2))

    def move(t):
        stamp = STAMP.unpack(STAMP.pack(int(t), int(round(1e9 * (t % 1.0))) % 1_000_000_000))
        for marker, centre, velocity in zip(dynamic, centres, velocities):
            marker.pose.position.x, marker.pose.position.y = (centre + velocity * t).tolist()
        for marker in static_markers + dynamic:
            marker.header.stamp.sec, marker.header.stamp.nanosec = stamp
    return static_markers, dynamic, move


def run_obstacle_updates(static, robots, moving, messages, rate=120.0, full_every=24):
    """Time the node's obstacle handling (and the next filter step) per message.

    ``on_obstacles``: the subscription callback (it only queues the bytes); ``worker
    pass``: until the obstacle worker process has processed the message and its snapshot
    is back (``ObstacleIntake.process``: IPC included).  The node runs in this process
    without spinning; the messages follow the sim bridge's pattern at ``rate`` Hz: the
    dynamic markers every period, everything every ``full_every`` periods.  Returns one
    record per message kind.
    """
    from polyc2bf_ros.safety_filter_node import SafetyFilterNode
    rclpy.init()
    node = SafetyFilterNode()
    odom = Odometry()
    odom.header.frame_id = 'world'
    odom.pose.pose.orientation.w = 1.0
    node._on_odom(serialize_message(odom))
    static_markers, dynamic, move = sim_markers(static, robots, moving)
    timings = {'full': ([], [], [], []), 'moving': ([], [], [], [])}
    state, command = node._decision.state, (0.5, 0.0)
    try:
        for k in range(messages):
            move(k / rate)
            kind = 'full' if k % full_every == 0 else 'moving'
            msg = MarkerArray(markers=static_markers + dynamic if kind == 'full' else dynamic)
            data = serialize_message(msg)
            start = time.perf_counter()
            deserialize_message(data, MarkerArray)
            parsed = time.perf_counter()
            node._on_obstacles(data)
            handled = time.perf_counter()
            node._intake.process()
            processed = time.perf_counter()
            node._filter.filter(state, 0.0, command, node._take_obstacles().obstacles, 0.0)
            stepped = time.perf_counter()
            if k >= 2 * full_every:  # warm-up: kernels compiled, caches filled
                for column, seconds in zip(timings[kind], (
                        parsed - start, handled - parsed, processed - handled,
                        stepped - processed)):
                    column.append(1e6 * seconds)
        snapshot = node._decision.snapshot
        in_use, tracked = len(snapshot.obstacles), snapshot.tracked
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    records = []
    for kind, (parse, handle, work, step) in timings.items():
        p50, p99 = percentiles(handle, (50, 99))
        work_p50, work_p99 = percentiles(work, (50, 99))
        records.append({
            'bench': 'node_obstacles', 'message': kind,
            'markers': static + robots + moving if kind == 'full' else robots + moving,
            'obstacles': static + robots + moving, 'samples': len(handle),
            'on_obstacles_p50_us': round(float(p50), 1), 'on_obstacles_p99_us': round(
                float(p99), 1),
            'worker_pass_p50_us': round(float(work_p50), 1),
            'worker_pass_p99_us': round(float(work_p99), 1),
            'rclpy_deserialize_p50_us': round(float(np.median(parse)), 1),
            'next_step_p50_us': round(float(np.median(step)), 1),
            'obstacles_in_use': in_use, 'obstacles_tracked': tracked,
            'barrier': node._barrier, 'load_avg_1min': round(os.getloadavg()[0], 2)})
    return records


def print_obstacle_table(records):
    """One row per message kind."""
    keys = ('message', 'markers', 'samples', 'rclpy_deserialize_p50_us', 'on_obstacles_p50_us',
            'on_obstacles_p99_us', 'worker_pass_p50_us', 'next_step_p50_us', 'obstacles_in_use',
            'load_avg_1min')
    print(' '.join(f'{key:>{max(len(key), 8)}}' for key in keys))
    for r in records:
        print(' '.join(f'{r[key]!s:>{max(len(key), 8)}}' for key in keys))


def _cell(value, width, digits=3):
    if value is None:
        return f'{"-":>{width}}'
    return f'{value:>{width}.{digits}f}' if isinstance(value, float) else f'{value:>{width}}'


def print_table(records):
    """One row per record."""
    columns = (('subject', 'subject', 10), ('rate_hz', 'rate', 5), ('obstacles', 'obst', 4),
               ('layout', 'layout', 9),
               ('p50_ms', 'p50_ms', 7), ('p99_ms', 'p99_ms', 7), ('max_ms', 'max_ms', 7),
               ('answered_frac', 'answered', 8), ('achieved_hz', 'ach_hz', 7),
               ('rss_mb', 'rss_mb', 6), ('rss_peak_mb', 'hwm_mb', 6),
               ('cpu_ms_per_cycle', 'cpu/cyc', 7), ('node_step_p50_ms', 'step50', 6),
               ('node_step_p99_ms', 'step99', 6), ('sender_late_p99_ms', 'late99', 6),
               ('sender_skipped_frac', 'skip', 6),
               ('load_avg_1min', 'load', 5), ('cpu_steal_frac', 'steal', 5))
    print(' '.join(f'{title:>{width}}' for _, title, width in columns))
    for r in records:
        print(' '.join(_cell(r[key], width) for key, _, width in columns))


def plot_latency(records, path):
    """Write the latency distributions of ``records`` (``latency_cdf_ms``) with the targets."""
    from matplotlib.figure import Figure
    figure = Figure(figsize=(7.5, 4.2), layout='constrained')
    axes = figure.subplots()
    for record in records:
        if record['latency_cdf_ms']:
            axes.plot(record['latency_cdf_ms'], CDF_PERCENTILES,
                      label=f'{record["subject"]} at {record["rate_hz"]} Hz: '
                            f'p50 {record["p50_ms"]:.3f} ms, '
                            f'p99 {record["p99_ms"]:.2f} ms')
    for latency, percentile in ((TARGET_P50_MS, 50.0), (TARGET_P99_MS, 99.0)):
        axes.plot([latency, latency], [0.0, percentile], 'k:', linewidth=1)
    axes.plot([TARGET_P50_MS, TARGET_P99_MS], [50.0, 99.0], 'kx', linestyle='none',
              label=f'targets: p50 <= {TARGET_P50_MS} ms, p99 <= {TARGET_P99_MS} ms')
    axes.set_xscale('log')
    axes.set_xlabel('latency, command stamp to answer received [ms]')
    axes.set_ylabel('percentile of the answered commands')
    axes.set_ylim(0.0, 100.0)
    axes.grid(True, which='both', alpha=0.3)
    axes.legend(loc='lower right', fontsize=8)
    steal = max(r['cpu_steal_frac'] for r in records)
    axes.set_title(f'bench_node.py over DDS on {os.cpu_count()} CPUs '
                   f'(hypervisor steal <= {100 * steal:.1f} %)', fontsize=9)
    figure.savefig(path, dpi=100)
    print(f'wrote {path}')


def main(argv=None):
    """Run the node benchmark for each subject and rate; print the table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--role', choices=('bench', 'sender', 'echo', 'echo_rclpy',
                                           'echo_events'),
                        default='bench', help=argparse.SUPPRESS)
    parser.add_argument('--count', type=int, help=argparse.SUPPRESS)
    parser.add_argument('--speed', type=float, default=0.5, help=argparse.SUPPRESS)
    parser.add_argument('--rate', type=float, nargs='+', default=[1000.0], help='Hz')
    parser.add_argument('--obstacles', type=int, default=50)
    parser.add_argument('--layout', choices=tuple(LAYOUTS), default='scattered',
                        help='where the obstacles lie (module docstring)')
    parser.add_argument('--duration', type=float, default=10.0, help='measured seconds')
    parser.add_argument('--warmup', type=float, default=2.0, help='seconds before measuring')
    parser.add_argument('--subjects', nargs='+', choices=SUBJECTS + ON_REQUEST,
                        default=list(SUBJECTS))
    parser.add_argument('--out', type=Path, help=f'default {RESULTS}, or '
                        f'{OBSTACLE_RESULTS} with --obstacle-updates')
    parser.add_argument('--obstacle-updates', action='store_true',
                        help='instead: time obstacle messages shaped like the sim bridge '
                        "in-process (the node's _on_obstacles): --obstacles static + "
                        '--robots cylinders + --moving outlines')
    parser.add_argument('--robots', type=int, default=7)
    parser.add_argument('--moving', type=int, default=5)
    parser.add_argument('--messages', type=int, default=2400)
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    # Above the test suite's usual domains (test/conftest.py), so parallel test runs
    # on the same machine do not share DDS discovery with the benchmark.
    os.environ.setdefault('ROS_DOMAIN_ID', str(95 + os.getpid() % 7))
    if args.role == 'sender':
        return run_sender(args.rate[0], args.count, args.speed)
    if args.role.startswith('echo'):
        return run_echo(args.role)
    require_installed_checkout()
    if args.obstacle_updates:
        records = run_obstacle_updates(args.obstacles, args.robots, args.moving, args.messages)
        print_obstacle_table(records)
        write_records(records, args.out or OBSTACLE_RESULTS)
        return 0
    records = [run(subject, rate, args.obstacles, args.duration, args.warmup, args.layout)
               for rate in args.rate for subject in args.subjects]
    print_table(records)
    out = args.out or RESULTS
    write_records(records, out)
    plot_latency(records, Path(out).with_suffix('.png'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
