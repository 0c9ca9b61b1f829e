"""``Inbox``: the bridge's wait for messages on its node's subscriptions, without an executor."""
from polyc2bf_ros import rclpy_private


class Inbox:
    """Wait on a node's subscriptions and pass each queued message to its callback.

    The lean path of ``rclpy.wait_for_message``: one rcl wait set built once,
    refilled with the same handles per wait; every queued message is taken.
    This serves subscriptions only (the executor serves the parameter services
    every ``bridge_node.SERVICE_PERIOD``).  The bridge waits several times per period
    between physics steps, and ``LeanExecutor`` keeps its plan only within
    ``spin``: each ``spin_once`` rebuilds its entity lists, wait set and handle
    holds, as ``SingleThreadedExecutor.spin_once`` does.  bench/bench_inbox.py
    (4 subscriptions, parameter services, 2 shared cores): a round of 4
    messages costs 41-62 us CPU here, 300-420 us with ``LeanExecutor`` and
    390-660 us with ``SingleThreadedExecutor``; an empty wait 27-30 us against
    286-302 and 259-275 us.  Private rclpy API, as in ``rclpy.wait_for_message``:
    ``rclpy_implementation.WaitSet`` and the subscription handles'
    ``take_message`` and ``pointer``.
    """

    def __init__(self, node):
        """Take ``node``'s subscriptions as they are now (none may be destroyed meanwhile)."""
        self._subscriptions = [(s.handle, s.handle.pointer, s.msg_type, s.raw, s.callback)
                               for s in node.subscriptions]
        self._wait_set = rclpy_private.WaitSet(len(self._subscriptions), 0, 0, 0, 0, 0,
                                        node.context.handle)

    def wait(self, timeout):
        """Wait up to ``timeout`` s for messages, then run the callback of each one taken."""
        wait_set = self._wait_set
        wait_set.clear_entities()
        for handle, *_ in self._subscriptions:
            wait_set.add_subscription(handle)
        wait_set.wait(int(timeout * 1e9))
        ready = wait_set.get_ready_entities('subscription')
        for handle, pointer, msg_type, raw, callback in self._subscriptions:
            if pointer in ready:
                taken = handle.take_message(msg_type, raw)
                while taken is not None:
                    callback(taken[0])
                    taken = handle.take_message(msg_type, raw)
