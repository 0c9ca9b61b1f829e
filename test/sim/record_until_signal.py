"""Record Twist and Clock messages at ~1 kHz until a signal stops the process.

Run by test_recorder.py: ``record_until_signal.py BAG_DIR [--rclpy]
[--flush-every N]``.  It installs ``close_on_signals`` first; with ``--rclpy``
it then calls ``rclpy.init()`` and records from a 1 ms timer of a spinning
node (so rclpy's own signal handlers are in the chain), otherwise from a plain
loop.  Record ``i`` is a Twist with ``linear.x = i`` on ``/cmd_vel`` and a Clock
on ``/clock``.  It prints ``recording`` once messages flow, and exits 0 on
KeyboardInterrupt.  With ``--flush-every N`` chunks are finished only by a
``flush()`` after every N records, each followed by ``flushed <records>``.
"""
import argparse
import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from sim_bridge.recorder import BagRecorder, close_on_signals


def main():
    """Record until interrupted."""
    parser = argparse.ArgumentParser()
    parser.add_argument('bag')
    parser.add_argument('--rclpy', action='store_true')
    parser.add_argument('--flush-every', type=int, default=0)
    args = parser.parse_args()
    recorder = BagRecorder(args.bag, flush_interval_s=3600.0 if args.flush_every else 0.1)
    close_on_signals(recorder)
    recorder.add_topic('/cmd_vel', Twist, QoSProfile(depth=10))
    recorder.add_topic('/clock', Clock, QoSProfile(
        depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE))
    count = 0

    def record():
        nonlocal count
        now = time.time_ns()
        twist = Twist()
        twist.linear.x = float(count)
        clock = Clock()
        clock.clock.sec, clock.clock.nanosec = divmod(now, 10 ** 9)
        recorder.write('/cmd_vel', twist, now)
        recorder.write('/clock', clock, now)
        count += 1
        if count == 10:
            print('recording', flush=True)
        if args.flush_every and count % args.flush_every == 0:
            recorder.flush()
            print(f'flushed {count}', flush=True)

    try:
        if args.rclpy:
            rclpy.init()
            node = rclpy.create_node('record_until_signal')
            node.create_timer(0.001, record)
            rclpy.spin(node)
        else:
            while True:
                record()
                time.sleep(0.001)
    except KeyboardInterrupt:
        return 0
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
