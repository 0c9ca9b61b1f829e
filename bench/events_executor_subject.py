"""rclpy's ``EventsExecutor`` in place of ``LeanExecutor``: bench_node.py's ``*_events`` subjects.

Run as a script with the node's ``--ros-args``, it is ``command_events``: the
``safety_filter`` node started by ``node_main.run_node`` unchanged (start-up, frozen
garbage collector, shutdown) with only its ``LeanExecutor`` swapped for
``SlicedEventsExecutor``, so that it differs from the ``command`` subject in the
executor alone.  Two adaptations the pinned rclpy (the ``ros_rclpy`` 7.1.6 wheel) needs:

- its ``EventsExecutor.spin()`` and ``spin_once()`` without a timeout never call a
  callback and keep a core busy (the unbounded wait of its event queue returns at
  once), while waits with a timeout work: ``SlicedEventsExecutor`` spins in slices of
  ``SLICE_S`` with ``spin_until_future_complete`` on a future that never completes,
  which serves every event of the slice as it comes;
- it refuses guard conditions (``RuntimeError: Guard conditions not supported`` on
  the first spin), and the node wakes a command waiting for the obstacle worker with
  one (``match_stamps``, set by the worker's thread): ``TaskWakeMixin`` posts that
  callback as a task instead.  With ``match_stamps`` off, as in bench_node.py, the
  callback does nothing, so the difference is off the measured path.

``echo_events`` (bench_node.py's ``run_echo``) imports ``SlicedEventsExecutor`` from
here; the node is imported only by ``main``, so that the echo's memory is an echo's.
"""
import sys

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.task import Future

from polyc2bf_ros import node_main

SLICE_S = 1.0  # longest spin without a look at the context [s]; events end a slice early


class SlicedEventsExecutor:
    """``EventsExecutor`` with the part of the executor API that ``run_node`` uses."""

    def __init__(self, context=None):
        """Create the executor on ``context`` (default: rclpy's)."""
        self._context = context or rclpy.get_default_context()
        self._executor = EventsExecutor(context=self._context)

    def add_node(self, node):
        """Add ``node`` (its ``executor`` becomes the ``EventsExecutor`` itself)."""
        return self._executor.add_node(node)

    def spin(self):
        """Serve events until the context is shut down (a shutdown ends the slice at once)."""
        never = Future()
        while self._context.ok():
            self._executor.spin_until_future_complete(never, SLICE_S)

    def shutdown(self, timeout_sec=None):
        """Stop spinning and detach every node."""
        return self._executor.shutdown(timeout_sec)


class _TaskWake:
    """Stands in for a guard condition: ``trigger`` queues the callback as an executor task."""

    def __init__(self, node, callback):
        self._node, self._callback = node, callback

    def trigger(self):
        """From any thread; before the node is added to an executor there is nothing to wake."""
        executor = self._node.executor
        if executor is not None:
            executor.create_task(self._callback)


class TaskWakeMixin:
    """For a ``Node`` subclass: guard conditions are ``_TaskWake`` objects (module docstring)."""

    def create_guard_condition(self, callback, callback_group=None):
        """Return a ``_TaskWake`` for ``callback`` (EventsExecutor refuses guard conditions)."""
        return _TaskWake(self, callback)

    def destroy_guard_condition(self, guard):
        """Forget a ``_TaskWake``; destroy anything else as ``Node`` does."""
        return isinstance(guard, _TaskWake) or super().destroy_guard_condition(guard)


def main(args=None):
    """Run the safety filter node as ``run_node`` does, on ``SlicedEventsExecutor``."""
    from polyc2bf_ros.safety_filter_node import SafetyFilterNode

    class EventsSafetyFilterNode(TaskWakeMixin, SafetyFilterNode):
        """``SafetyFilterNode`` without guard conditions."""

    node_main.LeanExecutor = SlicedEventsExecutor  # the only executor run_node creates
    return node_main.run_node(EventsSafetyFilterNode, 'safety_filter', args)


if __name__ == '__main__':
    sys.exit(main())
