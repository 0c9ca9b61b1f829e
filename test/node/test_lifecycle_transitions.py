"""The managed node's transitions in process: a transition that raises releases everything."""
import rclpy
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter

from polyc2bf_ros.safety_filter_lifecycle import SafetyFilterLifecycleNode


def test_a_raising_transition_releases_everything_and_returns_to_unconfigured():
    """Activation raises: error processing stops the worker, destroys the topics; again works."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = SafetyFilterLifecycleNode(context=context, parameter_overrides=[
        Parameter('obstacles_timeout', value=0.0)])
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node.count_subscribers('odom') == 1 and node._intake._worker is not None
        intake = node._intake

        def broken():
            raise RuntimeError('activation failed')

        node._activate = broken
        assert node.trigger_activate() == TransitionCallbackReturn.ERROR
        assert node._state_machine.current_state[1] == 'unconfigured'
        assert intake._worker is None and not node._active
        assert node.count_subscribers('odom') == 0 and node.count_publishers('cmd_vel_out') == 0
        del node._activate
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
        assert node._active and node._state_machine.current_state[1] == 'active'
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
