"""Obstacle-flood benchmark: the control loop's answers under heavy obstacle input.

Three processes per case, over real DDS on loopback:

- the **subject**: ``safety_filter`` (unicycle, ``trigger:=timer`` at ``--rate`` Hz, default
  100), whose obstacle messages go to its worker process (``polyc2bf_ros.obstacle_intake``);
- the **flooder** (this file, ``--role flood``): publishes the case's obstacle messages,
  serialized in advance as ``VARIANTS`` different versions (every message carries new
  shapes for the same keys, so no shape can be reused);
- the **driver** (this process): publishes odometry and the nominal command at 50 Hz from a
  thread, and records the receipt time of every safe command.

Per case, over the measured window (after ``--warmup`` s)::

    answered  = answers received / control periods elapsed (duration x rate), at most 1
    max gap   = longest time between consecutive answers, in control periods

Cases (the adversarial client's): ``none`` (a few static walls: the floor of the same
setup), ``circle_10k`` and ``star_10k`` (one 10,000-point convex / non-convex polygon,
10 msg/s), ``markers_5000`` (5,000 squares in one message, 1 msg/s; more than the default
``max_obstacles``, so the node answers with stops, which count as answers), ``flood_200hz``
(100 changing squares per message at 200 msg/s).  Each case runs ``--repeats`` times (this
VM's speed drifts); the table gives the median of the runs and the worst run.  Targets, on
the medians: answered >= 0.99 and max gap <= 2 periods.  Results: a table and
``bench/results/obstacle_flood.json`` (one record per case, with every run's values).  A run
in which the driver's own publish call blocked (``DRIVER_STALL_S``) is run again and counted
(column ``reruns``).

    .venv/bin/python bench/bench_obstacle_flood.py [--cases ...] [--duration 10] [--rate 100]
                                                   [--repeats 3]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from bench_io import require_installed_checkout, write_records
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point, Twist
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from sim_bridge.launcher import stop_processes

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'obstacle_flood.json'
NAMESPACE = '/flood'
VARIANTS = 40
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
OBSTACLE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
# case: (messages per second, markers per message, points per marker, star-shaped)
CASES = {
    'none': (2.0, 3, 2, False),
    'circle_10k': (10.0, 1, 10_000, False),
    'star_10k': (10.0, 1, 10_000, True),
    'markers_5000': (1.0, 5000, 5, False),
    'flood_200hz': (200.0, 100, 5, False),
}
TARGET_ANSWERED, TARGET_GAP_PERIODS = 0.99, 2.0
# The driver's own publish calls now and then block for ~0.33 s inside Fast DDS (measured:
# the odometry publish, in about a third of the ``none`` runs, with the subject answering
# every period meanwhile).  A run whose window holds such a stall measures the driver, not
# the subject: it is counted and run again, up to MAX_RERUNS times.
DRIVER_STALL_S = 0.05
MAX_RERUNS = 3


def _outline(points, star, centre, size, rng):
    """Return a closed outline of ``points`` points around ``centre`` (2 points: a wall)."""
    if points == 2:
        return [(centre[0], centre[1] - size), (centre[0], centre[1] + size)]
    angles = np.linspace(0.0, 2.0 * np.pi, points - 1, endpoint=False)
    radii = size * (np.where(np.arange(points - 1) % 2 == 0, 1.0, 0.7) if star
                    else np.ones(points - 1)) * rng.uniform(0.95, 1.05)
    ring = np.column_stack([centre[0] + radii * np.cos(angles),
                            centre[1] + radii * np.sin(angles)])
    return [*map(tuple, ring), tuple(ring[0])]


def case_messages(case, seed=0):
    """``VARIANTS`` serialized MarkerArrays of ``case``: same keys, new shapes in each."""
    _, count, points, star = CASES[case]
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(count)))
    messages = []
    for _ in range(VARIANTS if case != 'none' else 1):
        array = MarkerArray()
        for i in range(count):
            centre = (8.0 + 1.5 * (i % side), -0.75 * side + 1.5 * (i // side)) if count > 3 \
                else (6.0, 4.0 * (i - 1))
            marker = Marker(ns='flood', id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
            marker.header.frame_id = 'odom'
            marker.pose.orientation.w = 1.0
            marker.scale.x = 0.1
            marker.points = [Point(x=float(x), y=float(y))
                             for x, y in _outline(points, star, centre, 0.4, rng)]
            array.markers.append(marker)
        messages.append(serialize_message(array))
    return messages


def run_flood(case, seconds):
    """Publish ``case``'s messages at its rate for ``seconds`` (after the node subscribed)."""
    rate = CASES[case][0]
    messages = case_messages(case)
    rclpy.init()
    node = rclpy.create_node('bench_flooder')
    publisher = node.create_publisher(MarkerArray, f'{NAMESPACE}/obstacles', OBSTACLE_QOS)
    while not publisher.get_subscription_count():
        time.sleep(0.05)
    print('ready', flush=True)
    sys.stdin.readline()
    start = time.monotonic()
    sent = 0
    while time.monotonic() - start < seconds:
        due = start + sent / rate
        delay = due - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
        publisher.publish(messages[sent % len(messages)])
        sent += 1
    print(json.dumps({'sent': sent, 'elapsed_s': time.monotonic() - start}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _drive(node, stop, stalls):
    """Publish odometry (0.5 m/s) and a nominal 0.8 m/s command at 50 Hz until ``stop``.

    Appends to ``stalls`` (monotonic start, seconds) every publish call that blocked for
    more than ``DRIVER_STALL_S``: input the subject could not answer in time.
    """
    odom_pub = node.create_publisher(Odometry, f'{NAMESPACE}/odom', RELIABLE)
    cmd_pub = node.create_publisher(Twist, f'{NAMESPACE}/cmd_vel_in', RELIABLE)
    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = 'odom', 'base_link'
    odom.pose.pose.orientation.w = 1.0
    odom.twist.twist.linear.x = 0.5
    cmd = Twist()
    cmd.linear.x = 0.8
    odom_bytes, cmd_bytes = serialize_message(odom), serialize_message(cmd)
    while not stop.wait(0.02):
        start = time.monotonic()
        odom_pub.publish(odom_bytes)
        cmd_pub.publish(cmd_bytes)
        blocked = time.monotonic() - start
        if blocked > DRIVER_STALL_S:
            stalls.append((start, blocked))


def _window_metrics(times, start, end, rate):
    """Answers per control period in [start, end) (at most 1) and the longest gap in periods."""
    times = np.sort(np.asarray(times))
    times = times[(times >= start) & (times < end)]
    periods = (end - start) * rate
    if not len(times) or periods <= 0.0:
        return 0.0, float('inf')
    edges = np.concatenate([[start], times, [end]])
    return min(1.0, len(times) / periods), float(np.diff(edges).max() * rate)


def _node_values(diagnostics):
    """``{key: value}`` of the subject's last safety-filter status."""
    for msg in reversed(diagnostics):
        for status in msg.status:
            if status.name.startswith(f'{NAMESPACE}/safety_filter: safety filter'):
                return {kv.key: kv.value for kv in status.values}, status.message
    return {}, ''


def run_case(case, rate, duration, warmup):
    """Measure one case; return a flat result record."""
    log = tempfile.TemporaryFile()
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    subject = subprocess.Popen(
        [sys.executable, '-m', 'polyc2bf_ros.safety_filter_node', '--ros-args',
         '-r', f'__ns:={NAMESPACE}', '-p', 'model:=unicycle', '-p', f'rate:={float(rate)}',
         '-p', 'obstacles_timeout:=0.0', '--log-level', 'error'],
        cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    flooder = subprocess.Popen(
        [sys.executable, __file__, '--role', 'flood', '--case', case,
         '--seconds', str(warmup + duration + 1.0)],
        cwd=REPO, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node('bench_flood_driver')
    answers, diagnostics = [], []
    node.create_subscription(Twist, f'{NAMESPACE}/cmd_vel_out',
                             lambda data: answers.append(time.monotonic()), RELIABLE, raw=True)
    node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 10)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop, stalls = threading.Event(), []
    driver = threading.Thread(target=_drive, args=(node, stop, stalls), daemon=True)
    try:
        if flooder.stdout.readline().strip() != 'ready':
            raise RuntimeError('the flooder did not start')
        driver.start()
        deadline = time.monotonic() + 60.0
        while len(answers) < 10:
            executor.spin_once(timeout_sec=0.05)
            if subject.poll() is not None or time.monotonic() > deadline:
                log.seek(0)
                raise RuntimeError(f'no answers from the node:\n{log.read().decode()}')
        flooder.stdin.write('go\n')
        flooder.stdin.flush()
        start = time.monotonic() + warmup
        end = start + duration
        while time.monotonic() < end + 1.5:  # + a diagnostics period
            executor.spin_once(timeout_sec=0.01)
        answered, gap = _window_metrics(answers, start, end, rate)
        flood = json.loads(flooder.stdout.readline() or '{}')
        values, message = _node_values(diagnostics)
    finally:
        stop.set()
        driver.join(1.0)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        stop_processes([subject, flooder], timeout=5.0)
    per_s, markers, points, star = CASES[case]
    return {'bench': 'obstacle_flood', 'case': case, 'rate_hz': rate,
            'messages_per_s': per_s, 'markers_per_message': markers,
            'points_per_marker': points, 'star': star, 'duration_s': duration,
            'answered_frac': answered, 'max_gap_periods': gap,
            'meets_target': answered >= TARGET_ANSWERED and gap <= TARGET_GAP_PERIODS,
            'flood_sent': flood.get('sent'), 'obstacles_in_use': values.get('obstacles_in_use'),
            'obstacles_simplified': values.get('obstacles_simplified'),
            'node_message': message, 'load_1min': os.getloadavg()[0],
            'driver_stalls_s': [round(b, 3) for t, b in stalls if t < end and t + b > start]}


def run_valid(case, args):
    """``run_case`` again while the driver stalled in the window (at most MAX_RERUNS times)."""
    discarded = []
    while True:
        record = run_case(case, args.rate, args.duration, args.warmup)
        if not record['driver_stalls_s'] or len(discarded) == MAX_RERUNS:
            return {**record, 'discarded_driver_stalls': discarded}
        discarded.append(record['driver_stalls_s'])
        print(f'  driver publish blocked {record["driver_stalls_s"]} s: run again', flush=True)


def summarize(runs):
    """One record of a case's runs: medians (targets), worst run, and every run's values."""
    answered = float(np.median([r['answered_frac'] for r in runs]))
    gap = float(np.median([r['max_gap_periods'] for r in runs]))
    return {**runs[-1], 'repeats': len(runs), 'answered_frac': answered,
            'reruns_for_driver_stalls': sum(len(r['discarded_driver_stalls']) for r in runs),
            'max_gap_periods': gap,
            'meets_target': answered >= TARGET_ANSWERED and gap <= TARGET_GAP_PERIODS,
            'worst_answered_frac': min(r['answered_frac'] for r in runs),
            'worst_max_gap_periods': max(r['max_gap_periods'] for r in runs),
            'runs_answered_frac': [r['answered_frac'] for r in runs],
            'runs_max_gap_periods': [r['max_gap_periods'] for r in runs]}


def print_table(records):
    """One row per case: medians over the repeats, then the worst run."""
    print(f'{"case":<14}{"msg/s":>7}{"answered":>10}{"max gap":>9}{"target":>8}'
          f'{"worst gap":>11}{"reruns":>8}{"in use":>8}  node status')
    for r in records:
        print(f'{r["case"]:<14}{r["messages_per_s"]:>7g}{r["answered_frac"]:>10.4f}'
              f'{r["max_gap_periods"]:>9.2f}{"yes" if r["meets_target"] else "NO":>8}'
              f'{r["worst_max_gap_periods"]:>11.2f}{r["reruns_for_driver_stalls"]:>8}'
              f'{str(r["obstacles_in_use"]):>8}  {r["node_message"][:60]}')


def main(argv=None):
    """Run the cases (default all) and write the results."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--role', choices=['driver', 'flood'], default='driver')
    parser.add_argument('--case', choices=list(CASES))
    parser.add_argument('--seconds', type=float, default=10.0)
    parser.add_argument('--cases', nargs='+', choices=list(CASES), default=list(CASES))
    parser.add_argument('--rate', type=float, default=100.0)
    parser.add_argument('--duration', type=float, default=10.0)
    parser.add_argument('--warmup', type=float, default=2.0)
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args(argv)
    if args.role == 'flood':
        return run_flood(args.case, args.seconds)
    require_installed_checkout()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    records = []
    for case in args.cases:
        runs = []
        for repeat in range(args.repeats):
            print(f'case {case} run {repeat + 1}/{args.repeats} ...', flush=True)
            runs.append(run_valid(case, args))
        records.append(summarize(runs))
    print_table(records)
    write_records(records, RESULTS)
    return 0


if __name__ == '__main__':
    sys.exit(main())
