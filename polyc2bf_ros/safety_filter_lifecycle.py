"""``safety_filter_lifecycle``: the safety filter as a managed (lifecycle) node.

The filter of ``safety_filter`` (``safety_filter_node.SafetyFilterMixin``: same parameters,
topics and decisions), driven through the standard lifecycle services
(``<node>/change_state``, ``<node>/get_state``: nav2_lifecycle_manager, ``ros2 lifecycle``)
as Nav2's collision monitor is (doc/lifecycle.md)::

    unconfigured  nothing: no subscription, output, timer, service or worker
    configure     declare (or re-read) and check the parameters; create the subscriptions,
                  outputs (lifecycle publishers, off), timers, ~/enable and the obstacle
                  worker.  Invalid parameters: FAILURE, logged, back to unconfigured
    inactive      inputs are taken (a latched obstacle map is kept), no step runs,
                  nothing is published
    activate      the outputs are enabled; steps and the stall guard run, as in the plain
                  node: commands once a nominal command has come (while inactive too), stops
                  while an input is stale
    deactivate    one stop command, ~/deadlock false and ~/state action 'disabled' (status
                  'inactive', latched), then the outputs are off
    cleanup       everything configure created is destroyed: unconfigured
    shutdown      from active as deactivate, then as cleanup
    error         (a transition raised) as cleanup: unconfigured

A transition that does not exist in the current state (activate while unconfigured) is
refused (``success`` false) and the node goes on: rclpy's own ``change_state`` handler raises
then, which would end the node.
"""
import sys

from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.serialization import serialize_message

from polyc2bf_ros import conversions, rclpy_private
from polyc2bf_ros.node_main import configuration_error_text, CONFIGURATION_ERRORS, run_node
from polyc2bf_ros.safety_filter_node import SafetyFilterMixin

# ~/state while not active, as (action, status, active constraints).
INACTIVE_STATE = ('disabled', 'inactive', 0)
_SUCCESS = TransitionCallbackReturn.SUCCESS


class SafetyFilterLifecycleNode(SafetyFilterMixin, LifecycleNode):
    """The safety filter, set up and started by lifecycle transitions (module docstring)."""

    def __init__(self, **kwargs):
        """Create the node, unconfigured: only its lifecycle services exist."""
        super().__init__('safety_filter', **kwargs)
        service = self._service_change_state  # rclpy's (LifecycleNodeMixin)
        self._rclpy_change_state = service.callback
        service.callback = self._on_change_state

    def _on_change_state(self, request, response):
        """Serve ``change_state``; a transition the current state does not have fails."""
        try:
            return self._rclpy_change_state(request, response)
        except rclpy_private.RCLError as exc:
            self.get_logger().warning(f'transition {request.transition.id} '
                                      f'{request.transition.label!r} refused: {exc}')
            response.success = False
            return response

    def _create_output(self, msg_type, topic, qos):
        """Create a lifecycle publisher: it publishes only while the node is active."""
        return self._keep(self.destroy_lifecycle_publisher,
                          self.create_lifecycle_publisher(msg_type, topic, qos))

    def on_configure(self, state):
        """Read and check the parameters; create subscriptions, timers, worker, outputs."""
        self.get_logger().info('configuring')
        try:
            self._configure()
        except CONFIGURATION_ERRORS as exc:
            self.get_logger().error(f'{configuration_error_text(exc)}: staying unconfigured')
            self._release()
            return TransitionCallbackReturn.FAILURE
        return _SUCCESS

    def on_activate(self, state):
        """Enable the outputs, then step and publish."""
        self.get_logger().info('activating: filtering nominal commands')
        result = super().on_activate(state)
        self._activate()
        return result

    def on_deactivate(self, state):
        """Publish one stop and the inactive state, then turn the outputs off."""
        self.get_logger().info('deactivating: one stop command, then none')
        self._stop_outputs()
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Destroy everything ``on_configure`` created."""
        self.get_logger().info('cleaning up')
        self._release()
        return _SUCCESS

    def on_shutdown(self, state):
        """From active publish one stop first; then release everything."""
        self.get_logger().info(f'shutting down from {state.label}')
        if self._active:
            self._stop_outputs()
        self._release()
        return _SUCCESS

    def on_error(self, state):
        """Release everything after a transition raised; go back to unconfigured."""
        self.get_logger().error(f'a transition from {state.label} failed: releasing '
                                'everything, back to unconfigured')
        self._release()
        return _SUCCESS

    def _stop_outputs(self):
        """Stop stepping; publish the model's stop, ``~/deadlock`` false and the inactive state.

        The stop goes in the last nominal command's message (its frame), or in an empty one
        of the command type when none came.
        """
        self._deactivate()
        cmd = self._commands.last or conversions.SerializedCommand(
            serialize_message(self._command_type()), self._has_header)
        self._publish_stop(cmd, self._decision.stop())
        self._reporter.report_deadlock(False)
        self._reporter.publish_state_once(INACTIVE_STATE)


def main(args=None):
    """Run the managed safety filter until shutdown (it starts unconfigured)."""
    return run_node(SafetyFilterLifecycleNode, 'safety_filter', args)


if __name__ == '__main__':
    sys.exit(main())
