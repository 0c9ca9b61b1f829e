"""The ROS entities one configuration of the safety filter node creates, and their release.

Subscriptions, outputs, timers, guard conditions, services and callbacks are created through
``_keep`` (or ``_subscribe``, ``_create_output``), which remembers how to undo each;
``_release`` undoes them newest first, so a managed node can be configured again.  The
managed node overrides ``_create_output`` with lifecycle publishers.
"""
import functools


class NodeEntitiesMixin:
    """For a ``Node`` subclass: what ``_configure`` created, undone by ``_release``."""

    _undo = ()  # what ``_release`` calls, newest first

    def _keep(self, undo, entity):
        """Remember ``undo(entity)`` for ``_release``; return ``entity``."""
        self._undo.append(functools.partial(undo, entity))
        return entity

    def _subscribe(self, msg_type, topic, callback, qos):
        """Create a serialized (raw) subscription that ``_release`` destroys."""
        return self._keep(self.destroy_subscription, self.create_subscription(
            msg_type, topic, callback, qos, raw=True))

    def _create_output(self, msg_type, topic, qos):
        """Create a publisher of one of the filter's outputs that ``_release`` destroys."""
        return self._keep(self.destroy_publisher, self.create_publisher(msg_type, topic, qos))

    def _release(self):
        """Undo the configuration, newest first."""
        while self._undo:
            self._undo.pop()()

    def destroy_node(self):
        """Release the configuration (obstacle worker, stall guard...), then destroy the node."""
        self._release()
        return super().destroy_node()
