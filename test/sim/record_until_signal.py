"""Record Twist and Clock messages at ~1 kHz until a signal stops the process.

Run by test_recorder.py: ``record_until_signal.py BAG_DIR [--rclpy]``.  It
installs ``close_on_signals`` first; with ``--rclpy`` it then calls
``rclpy.init()`` and records from a 1 ms timer of a spinning node (so rclpy's
own signal handlers are in the chain), otherwise from a plain loop.  It prints
``recording`` once messages flow, and exits 0 on KeyboardInterrupt.
"""
import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from sim_bridge.recorder import BagRecorder, close_on_signals


def main():
    """Record until interrupted."""
    recorder = BagRecorder(sys.argv[1], flush_interval_s=0.1)
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

    try:
        if '--rclpy' in sys.argv:
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
