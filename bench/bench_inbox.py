"""Cost of one wake-up of the bridge's wait loop: ``Inbox`` against the executors.

Usage: python bench/bench_inbox.py [--subscriptions 4] [--rounds 3000]

One process, one node with rclpy's parameter services (as the bridge) and
``--subscriptions`` raw TwistStamped subscriptions (``COMMAND_QOS``), each fed
by a publisher of the same node.  A round publishes one message per topic and
waits until every callback ran; an empty wait is ``wait(0)`` with nothing
queued (the bridge's drain after each period).  Printed: wall and CPU time per
round and CPU per empty wait for ``Inbox.wait``, ``LeanExecutor.spin_once``
and ``SingleThreadedExecutor.spin_once``.
"""
import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rclpy  # noqa: E402
from geometry_msgs.msg import TwistStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

from polyc2bf_ros.lean_executor import LeanExecutor  # noqa: E402
from sim_bridge.bridge_node import COMMAND_QOS  # noqa: E402
from sim_bridge.inbox import Inbox  # noqa: E402


def waiter(kind, node):
    """Return ``wait(timeout_s)`` of ``kind`` serving ``node``."""
    if kind == 'Inbox':
        return Inbox(node).wait
    executor = (LeanExecutor if kind == 'LeanExecutor' else SingleThreadedExecutor)(
        context=node.context)
    executor.add_node(node)
    return lambda timeout: executor.spin_once(timeout_sec=timeout)


def measure(kind, subscriptions, rounds):
    """Return (wall us per round, CPU us per round, CPU us per empty wait) for ``kind``."""
    node = rclpy.create_node(f'bench_inbox_{kind.lower()}')
    received = [0]
    publishers = []
    for i in range(subscriptions):
        topic = f'bench_inbox_{i}'
        node.create_subscription(TwistStamped, topic,
                                 lambda data: received.__setitem__(0, received[0] + 1),
                                 COMMAND_QOS, raw=True)
        publishers.append(node.create_publisher(TwistStamped, topic, COMMAND_QOS))
    wait = waiter(kind, node)
    data = serialize_message(TwistStamped())

    def round_trip():
        for publisher in publishers:
            publisher.publish(data)
        wanted = received[0] + subscriptions
        while received[0] < wanted:
            wait(0.1)

    for _ in range(200):
        round_trip()
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(rounds):
        round_trip()
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    empty = time.process_time()
    for _ in range(rounds):
        wait(0.0)
    empty = time.process_time() - empty
    node.destroy_node()
    return 1e6 * wall / rounds, 1e6 * cpu / rounds, 1e6 * empty / rounds


def main():
    """Measure each way of waiting and print one line each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--subscriptions', type=int, default=4)
    parser.add_argument('--rounds', type=int, default=3000)
    args = parser.parse_args()
    rclpy.init()
    try:
        for kind in ('Inbox', 'LeanExecutor', 'SingleThreadedExecutor'):
            wall, cpu, empty = measure(kind, args.subscriptions, args.rounds)
            print(f'{kind:<24} round {wall:7.1f} us wall, {cpu:7.1f} us CPU; '
                  f'empty wait {empty:6.1f} us CPU')
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
