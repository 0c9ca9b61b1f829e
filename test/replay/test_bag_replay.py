"""``bag_replay``: live playback to another process over DDS, its options, and bad input.

The live tests start ``python -m sim_bridge.bag_replay`` as a child (it inherits
the per-worker ROS_DOMAIN_ID of test/conftest.py) and subscribe from this
process.  The offline check's agreement with the recorded commands is tested
with the regression bags in ``test_regression_bags.py``.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from visualization_msgs.msg import MarkerArray

from sim_bridge.bag_player import merge_qos, PlaybackClock, ReplayError, select_topics
from sim_bridge.bag_reader import BagReader
from sim_bridge.bag_replay import parse_remaps, split_ros_args

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'test' / 'data' / 'popup_obstacle'
ENV = {**os.environ, 'PYTHONUNBUFFERED': '1', 'PYTHONPATH': os.pathsep.join(
    filter(None, [str(REPO), os.environ.get('PYTHONPATH')]))}
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def replay(*args, **kwargs):
    """Start ``bag_replay`` with ``args``; stdout and stderr are pipes."""
    return subprocess.Popen([sys.executable, '-m', 'sim_bridge.bag_replay', *map(str, args)],
                            env={**ENV, 'ROS_LOG_DIR': str(kwargs.get('log_dir', '/tmp'))},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stamp_ns(msg):
    """Header stamp [ns]."""
    return msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec


# -- pure parts ------------------------------------------------------------------------------


def test_remaps_topics_and_ros_args():
    """Remaps become absolute; globs select, excludes remove; unknown names are errors."""
    assert parse_remaps(['a1/odom:=/x/odom', '/clock:=c']) == {'/a1/odom': '/x/odom',
                                                              '/clock': '/c'}
    for bad in ('a1/odom', ':=x', 'x:='):
        with pytest.raises(ReplayError, match='FROM:=TO'):
            parse_remaps([bad])
    topics = ['/a1/odom', '/a1/cmd_vel_in', '/a1/cmd_vel_out', '/clock']
    assert select_topics(topics) == sorted(topics)
    assert select_topics(topics, ['/a1/*'], ['*cmd_vel_out']) == ['/a1/cmd_vel_in', '/a1/odom']
    assert select_topics(topics, ['clock']) == ['/clock']
    with pytest.raises(ReplayError, match="no topic in the bag matches '/b/odom'"):
        select_topics(topics, ['/b/odom'])
    with pytest.raises(ReplayError, match='matches'):
        select_topics(topics, None, ['/nothing*'])
    own, ros = split_ros_args(['bag', '-p', 'rate:=120', '--ros-args', '-r', 'a:=b', '--',
                               '--rate', '2'])
    assert own == ['bag', '-p', 'rate:=120', '--rate', '2'] and ros == ['--ros-args', '-r',
                                                                          'a:=b']


def test_merge_qos_keeps_one_offer_and_weakens_mixed_ones():
    """One offer as is; best effort / volatile win in a mix; the largest depth is kept."""
    reliable = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    best_effort = QoSProfile(depth=20, reliability=ReliabilityPolicy.BEST_EFFORT)
    assert merge_qos([reliable, reliable]) == reliable
    mixed = merge_qos([reliable, best_effort])
    assert mixed.reliability == ReliabilityPolicy.BEST_EFFORT
    assert mixed.durability == DurabilityPolicy.VOLATILE and mixed.depth == 20
    assert merge_qos([]).reliability == ReliabilityPolicy.RELIABLE


def test_playback_clock_rate_and_pause():
    """wall(t) = w0 + paused + (t - t0) / rate; bag time freezes while paused."""
    clock = PlaybackClock(t0_ns=10 ** 9, rate=2.0, wall_start=100.0)
    assert clock.due(3 * 10 ** 9) == pytest.approx(101.0)
    assert clock.bag_time_ns(100.5) == 2 * 10 ** 9
    clock.pause(100.5, 2 * 10 ** 9)
    assert clock.bag_time_ns(107.0) == 2 * 10 ** 9
    clock.resume(103.5)
    assert clock.due(3 * 10 ** 9) == pytest.approx(104.0)
    assert clock.bag_time_ns(104.0) == 3 * 10 ** 9


def test_bag_reader_time_window():
    """``time_range`` spans the bag; ``messages`` keeps start <= t < end."""
    reader = BagReader(BAG)
    first, last = reader.time_range
    assert first == 0 and last >= 5 * 10 ** 9
    window = [m.log_time_ns for m in reader.messages(['/a1/odom'], raw=True,
                                                     start_ns=2 * 10 ** 9, end_ns=3 * 10 ** 9)]
    assert min(window) == 2 * 10 ** 9 and max(window) < 3 * 10 ** 9 and len(window) == 120


# -- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize('args, text', [
    (['/no/such/bag'], 'error: no bag at /no/such/bag'),
    ([BAG, '--topics', '/a1/nothing'], "no topic in the bag matches '/a1/nothing'"),
    ([BAG, '--remap', '/a1/nope:=/x'], 'remap source /a1/nope is not a topic of the bag'),
    ([BAG, '--rate', '0'], '--rate must be positive'),
    ([BAG, '--lockstep', '/a1/cmd_vel_in:=/a1/cmd_vel_out'],
     'lockstep response /a1/cmd_vel_out is also played'),
    ([BAG, '--offline', '--robot', 'zz'], 'the bag has no /zz/odom'),
])
def test_bad_input_is_a_clear_error(args, text, tmp_path):
    """Exit status 1 and the reason on stderr."""
    proc = replay(*args, log_dir=tmp_path)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and text in err, err


# -- live playback ---------------------------------------------------------------------------


class Listener:
    """This process's subscriptions, each collecting ``(publish time [s], msg)``.

    The publish time is the DDS source timestamp (system clock) of the message
    info, so a subscriber that falls behind under load does not skew it.
    """

    def __init__(self, subscriptions):
        """Subscribe ``{name: (type, topic, qos)}`` in a private context."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('listener', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received = {}
        for name, (msg_type, topic, qos) in subscriptions.items():
            self.received[name] = []
            self.node.create_subscription(
                msg_type, topic, lambda msg, info, got=self.received[name]: got.append(
                    (info['source_timestamp'] * 1e-9, msg)), qos)

    def spin_until(self, done, timeout):
        """Spin until ``done()`` or ``timeout`` s."""
        end = time.monotonic() + timeout
        while not done() and time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)
        self.executor.spin_once(timeout_sec=0.1)

    def close(self):
        """Shut the context down."""
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.mark.slow
def test_live_replay_timing_selection_remap_and_clock(tmp_path):
    """Rate 2, a window of 3 s from 2 s in, /a1/* minus two topics, remaps, /clock at 50 Hz.

    Everything selected arrives, in order and with the bag's stamps, under the
    names given by ``--remap`` and by ``--ros-args -r``; nothing excluded or
    under a remapped-away name does; ``/clock`` carries the bag time and runs at
    twice wall speed; no message goes out before its bag time on that clock.

    Timing without speed: the player computes each ``/clock`` value from the
    wall time at which it publishes it, so every pair (publish time, clock value)
    lies on its line ``bag = rate (wall - w0)`` however late the tick is, and a
    message may be late on that line but never early.  A starved player sends
    fewer ticks, never more than one per period (plus 2).
    """
    start, duration, rate, clock_hz = 2.0, 3.0, 2.0, 50.0
    listener = Listener({
        'odom': (Odometry, '/robot/odom', RELIABLE),
        'old_odom': (Odometry, '/a1/odom', RELIABLE),
        'nominal': (TwistStamped, '/robot/cmd_vel_in', RELIABLE),
        'old_nominal': (TwistStamped, '/a1/cmd_vel_in', RELIABLE),
        'safe': (TwistStamped, '/a1/cmd_vel_out', RELIABLE),
        'obstacles': (MarkerArray, '/a1/obstacles', LATCHED),
        'clock': (Clock, '/clock', RELIABLE),
    })
    try:
        proc = replay(BAG, '--rate', rate, '--topics', '/a1/*', '--exclude', '/a1/cmd_vel_out',
                      '/a1/safety_filter/markers', '--remap', '/a1/odom:=/robot/odom',
                      '--clock', clock_hz, '--start-offset', start, '--duration', duration,
                      '--wait-for-subscribers', 30, '--ros-args', '-r',
                      '/a1/cmd_vel_in:=/robot/cmd_vel_in', log_dir=tmp_path)
        listener.spin_until(lambda: proc.poll() is not None, 90.0)
        out, err = proc.communicate(timeout=30)
    finally:
        listener.close()
    assert proc.returncode == 0, err
    got = listener.received
    reader = BagReader(BAG)
    window = dict(start_ns=round(start * 1e9), end_ns=round((start + duration) * 1e9))
    expected = [stamp_ns(m.message) for m in reader.messages(['/a1/odom'], **window)]
    assert [stamp_ns(m) for _, m in got['odom']] == expected
    nominal = [stamp_ns(m.message) for m in reader.messages(['/a1/cmd_vel_in'], **window)]
    assert [stamp_ns(m) for _, m in got['nominal']] == nominal
    assert got['obstacles'] and not (got['old_odom'] or got['old_nominal'] or got['safe'])
    assert 'done:' in out and '/a1/odom: 360' in out and '/a1/cmd_vel_out' not in out
    # /clock: the bag time of the window, never backwards, at most clock_hz over the span.
    clocks = np.array([m.clock.sec + 1e-9 * m.clock.nanosec for _, m in got['clock']])
    ticked = np.array([t for t, _ in got['clock']])
    assert np.all(np.diff(clocks) >= 0) and clocks[0] >= start and clocks[-1] <= start + duration
    assert clocks[-1] > start + duration - 0.2
    assert 5 <= len(clocks) <= 1.5 * clock_hz * (ticked[-1] - ticked[0]) + 2
    # Its line: bag time advances `rate` times as fast as the wall (ticks clipped at the
    # window's end are off it); w0 = publish time - clock value / rate.
    # Median of pairwise slopes (Theil-Sen): a tick pre-empted between reading the
    # time and publishing is off the line, and does not move it.
    wall, bag = ticked[clocks < start + duration], clocks[clocks < start + duration]
    i, j = np.triu_indices(len(wall), k=1)
    apart = wall[j] - wall[i] > 0.1
    slope = np.median((bag[j] - bag[i])[apart] / (wall[j] - wall[i])[apart])
    assert slope == pytest.approx(rate, rel=0.05)
    w0 = np.median(wall - bag / rate)
    # Messages: never ahead of that clock (5 ms for a tick's own publish delay); a
    # generous bound on how late, many times the few ms a busy machine adds.
    log_s = 1e-9 * np.array([m.log_time_ns for m in reader.messages(['/a1/odom'], raw=True,
                                                                    **window)])
    lateness = np.array([t for t, _ in got['odom']]) - log_s / rate - w0
    assert lateness.min() > -0.005, lateness.min()
    assert np.median(lateness) < 0.5, np.median(lateness)


@pytest.mark.slow
def test_ctrl_c_stops_playback_cleanly(tmp_path):
    """SIGINT mid-playback: exit status 0 and the summary of what was played."""
    proc = replay(BAG, '--rate', 0.2, log_dir=tmp_path)
    line = proc.stderr.readline()          # the first progress line: playing
    deadline = time.monotonic() + 60.0
    while 'bag time' not in line and time.monotonic() < deadline and proc.poll() is None:
        line = proc.stderr.readline()
    assert 'bag time' in line
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert 'interrupted:' in out and '/a1/odom:' in out
