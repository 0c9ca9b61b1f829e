"""Node benchmark: end-to-end latency and sustained rate of ``safety_filter`` over real DDS.

A driver process (this one) starts ``safety_filter`` as a subprocess with
``trigger:=command`` and ``stamped:=true`` and, every 1/rate s (from a sender
thread, on a fixed schedule), publishes an odometry message and a stamped
nominal command whose ``header.frame_id`` carries a sequence number.  The
node answers each command with a safe command carrying the same header, so
every answer is matched to its input::

    latency   = receipt time (driver) - input stamp      (same system clock)
    answered  = matched answers / commands sent           (after warm-up)
    rate      = answers per second over the measured window
    rss       = VmRSS of the node process at the end (VmHWM = peak)

Each record also carries the node's own step latency (from its diagnostics),
the load average and the CPU time stolen by the hypervisor during the run, so
numbers from a shared or virtualised machine can be read for what they are.

The obstacles (octagons of radius 0.3 m, 3-8 m around the robot) are
published once, latched.  Results: a table on stdout and
``bench/results/node.json`` (DESIGN.md section 8).  DDS stays on loopback
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).

    .venv/bin/python bench/bench_node.py [--rate 1000] [--obstacles 50] [--duration 10]
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
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker, MarkerArray

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'node.json'
NAMESPACE = '/bench_node'
RELIABLE = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
ANSWERS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def obstacle_markers(count, seed=0):
    """``count`` octagons (radius 0.3 m) at 3-8 m around the origin, as LINE_STRIP markers."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(0.0, 2.0 * np.pi, 9)[:-1]
    octagon = 0.3 * np.column_stack([np.cos(angles), np.sin(angles)])
    result = MarkerArray()
    for i in range(count):
        bearing, distance = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(3.0, 8.0)
        centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
        marker = Marker(ns='bench', id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
        marker.header.frame_id = 'odom'
        marker.pose.orientation.w = 1.0
        marker.points = [Point(x=float(x), y=float(y)) for x, y in centre + octagon]
        result.markers.append(marker)
    return result


def cpu_times():
    """``(steal, total)`` jiffies of all CPUs from /proc/stat (steal = taken by the hypervisor)."""
    fields = [int(v) for v in Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:]]
    return fields[7], sum(fields)


def rss_mb(pid):
    """``(VmRSS, VmHWM)`` of ``pid`` in MB."""
    fields = dict(line.split(':', 1) for line in Path(f'/proc/{pid}/status').read_text()
                  .splitlines() if ':' in line)
    return tuple(int(fields[k].split()[0]) / 1024.0 for k in ('VmRSS', 'VmHWM'))


def start_node(rate, log):
    """Start ``safety_filter`` (unicycle, one step per stamped command), output to ``log``."""
    args = [sys.executable, '-m', 'polyc2bf_ros.safety_filter_node', '--ros-args',
            '-r', f'__ns:={NAMESPACE}', '-p', 'model:=unicycle', '-p', 'trigger:=command',
            '-p', 'stamped:=true', '-p', f'rate:={float(rate)}',
            '-p', 'obstacles_timeout:=0.0', '-p', 'cmd_timeout:=0.5',
            '--log-level', 'warn']
    return subprocess.Popen(args, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)


class Driver:
    """Publishes odometry + stamped commands at a fixed rate and matches the answers."""

    def __init__(self, node):
        """Create publishers and the answer subscription on ``node``."""
        self.node = node
        self.odom_pub = node.create_publisher(Odometry, f'{NAMESPACE}/odom', RELIABLE)
        self.cmd_pub = node.create_publisher(TwistStamped, f'{NAMESPACE}/cmd_vel_in', RELIABLE)
        self.obstacles_pub = node.create_publisher(MarkerArray, f'{NAMESPACE}/obstacles', LATCHED)
        self.sent = {}
        self.latency = {}
        node.create_subscription(TwistStamped, f'{NAMESPACE}/cmd_vel_out', self._on_answer,
                                 ANSWERS)
        self.step_latency = None
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.odom = Odometry()
        self.odom.header.frame_id = 'odom'
        self.odom.pose.pose.orientation.w = 1.0
        self.odom.twist.twist.linear.x = 0.5
        self.cmd = TwistStamped()
        self.cmd.twist.linear.x = 1.0
        self.clock = node.get_clock()

    def _on_answer(self, msg):
        now = self.clock.now().nanoseconds
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        seq = int(msg.header.frame_id) if msg.header.frame_id.isdigit() else -1
        if seq in self.sent and seq not in self.latency:
            self.latency[seq] = (now - stamp) * 1e-6

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith(f'{NAMESPACE}/safety_filter'):
                values = {kv.key: kv.value for kv in status.values}
                self.step_latency = (float(values['latency_p50_ms']),
                                     float(values['latency_p99_ms']))

    def publish(self, seq):
        """Publish odometry and command number ``seq``, both stamped now."""
        stamp = self.clock.now().to_msg()
        self.odom.header.stamp = stamp
        self.odom_pub.publish(self.odom)
        self.cmd.header.stamp = stamp
        self.cmd.header.frame_id = str(seq)
        self.sent[seq] = time.monotonic()
        self.cmd_pub.publish(self.cmd)


class Schedule:
    """Sends command ``seq`` at ``start + seq / rate`` from its own thread (no bursts, no drift).

    The driver's executor only receives, so its own cost cannot delay the sends.
    """

    def __init__(self, driver, rate, warmup, duration):
        """Plan ``warmup`` s of unmeasured sends, then ``duration`` s of measured ones."""
        self.driver, self.rate = driver, rate
        self.warmup, self.end = round(warmup * rate), round((warmup + duration) * rate)
        self.measured = (self.warmup, self.end)

    def run(self):
        """Publish every command on time (sleeping in between)."""
        start = time.monotonic()
        for seq in range(self.end):
            delay = start + seq / self.rate - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            self.driver.publish(seq)


def run(rate, obstacles, duration, warmup):
    """Benchmark one (rate, obstacle count); return a flat result record."""
    log = tempfile.TemporaryFile()
    proc = start_node(rate, log)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_driver', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        driver = Driver(node)
        pubs = (driver.odom_pub, driver.cmd_pub, driver.obstacles_pub)
        deadline = time.monotonic() + 30.0
        while not all(p.get_subscription_count() for p in pubs):
            if proc.poll() is not None:
                log.seek(0)
                raise RuntimeError(f'safety_filter exited:\n{log.read().decode()}')
            if time.monotonic() > deadline:
                raise RuntimeError('safety_filter did not subscribe within 30 s')
            executor.spin_once(timeout_sec=0.05)
        driver.obstacles_pub.publish(obstacle_markers(obstacles))
        schedule = Schedule(driver, rate, warmup, duration)
        sender = threading.Thread(target=schedule.run)
        steal_before, total_before = cpu_times()
        sender.start()
        while sender.is_alive():
            executor.spin_once(timeout_sec=0.01)
        drain = time.monotonic() + 0.2
        while time.monotonic() < drain:
            executor.spin_once(timeout_sec=0.01)
        first_measured, last_measured = schedule.measured
        steal_after, total_after = cpu_times()
        measured = range(first_measured, last_measured)
        latencies = np.array([driver.latency[s] for s in measured if s in driver.latency])
        elapsed = driver.sent[last_measured - 1] - driver.sent[first_measured]
        rss, rss_peak = rss_mb(proc.pid)
        p50, p99 = np.percentile(latencies, (50, 99)) if latencies.size else (np.nan,) * 2
        step = driver.step_latency or (float('nan'),) * 2
        return {
            'bench': 'node', 'rate_hz': int(rate) if float(rate).is_integer() else rate,
            'obstacles': obstacles, 'model': 'unicycle',
            'trigger': 'command', 'duration_s': duration,
            'p50_ms': round(float(p50), 4), 'p99_ms': round(float(p99), 4),
            'max_ms': round(float(latencies.max()), 4) if latencies.size else None,
            'answered_frac': round(latencies.size / len(measured), 5),
            'achieved_hz': round(latencies.size / elapsed, 1),
            'sent_hz': round((len(measured) - 1) / elapsed, 1),
            'rss_mb': round(rss, 1), 'rss_peak_mb': round(rss_peak, 1),
            'node_step_p50_ms': step[0], 'node_step_p99_ms': step[1],
            'cpus': os.cpu_count(), 'load_avg_1min': round(os.getloadavg()[0], 2),
            'cpu_steal_frac': round((steal_after - steal_before)
                                    / max(total_after - total_before, 1), 4),
        }
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def main(argv=None):
    """Run the node benchmark for each ``--rate`` x ``--obstacles`` and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--rate', type=float, nargs='+', default=[1000.0], help='Hz')
    parser.add_argument('--obstacles', type=int, nargs='+', default=[50])
    parser.add_argument('--duration', type=float, default=10.0, help='measured seconds')
    parser.add_argument('--warmup', type=float, default=2.0, help='seconds before measuring')
    parser.add_argument('--output', type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    # Above the test suite's usual domains (test/conftest.py), so parallel test runs
    # on the same machine do not share DDS discovery with the benchmark.
    os.environ.setdefault('ROS_DOMAIN_ID', str(95 + os.getpid() % 7))
    records = [run(rate, count, args.duration, args.warmup)
               for rate in args.rate for count in args.obstacles]
    print(f'{"rate_hz":>8} {"obst":>5} {"p50_ms":>8} {"p99_ms":>8} {"max_ms":>8} '
          f'{"answered":>9} {"achieved":>9} {"rss_mb":>7} {"step_p50":>9} {"step_p99":>9} '
          f'{"steal":>6}')
    for r in records:
        print(f'{r["rate_hz"]:>8g} {r["obstacles"]:>5} {r["p50_ms"]:>8.3f} {r["p99_ms"]:>8.3f} '
              f'{r["max_ms"]:>8.3f} {r["answered_frac"]:>9.4f} {r["achieved_hz"]:>9.1f} '
              f'{r["rss_mb"]:>7.1f} {r["node_step_p50_ms"]:>9.3f} {r["node_step_p99_ms"]:>9.3f} '
              f'{r["cpu_steal_frac"]:>6.3f}')
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(records, indent=2) + '\n')
    print(f'wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
